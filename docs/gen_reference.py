"""MkDocs hook: the reference pages generated from the code at every build, so that they
cannot fall behind it (none is committed): every command and option from the argparse
parsers, config.yaml's and calib.yaml's keys from their pydantic models (the texts from
the comments beside each field), the MCAP topics and schemas from the recorder's adapters
and the protobuf descriptors, and the exit statuses from :mod:`acq.cli.main`.

Each ``*_markdown()`` function returns one page; ``tests/docs`` checks them against the
parsers and models they come from.
"""

from __future__ import annotations

import argparse
import ast
import importlib
import inspect
import io
import re
import textwrap
import tokenize
import types
import typing
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import yaml
from pydantic import BaseModel

GENERATED = "*Generated from the code when the site is built; do not edit.*"
USAGE_WIDTH = 100  # characters of a usage line, whatever the terminal building the site


def _md(text: str) -> str:
    """``text`` (a docstring's or a help's) as Markdown: Sphinx roles dropped
    (``:class:`X``` is ``X`` in code), code spans kept as they are, and outside them the
    characters Markdown would take as markup escaped (Python-Markdown has no backslash
    escape for ``<``, ``>`` and ``|``: entities)."""
    text = re.sub(r":[a-z]+:(`+)", r"\1", text)
    parts = re.split(r"(`+[^`]+`+)", text)
    for i in range(0, len(parts), 2):  # the text between code spans
        part = re.sub(r"([\\*_\[\]#])", r"\\\1", parts[i])
        parts[i] = part.replace("<", "&lt;").replace(">", "&gt;").replace("|", "&#124;")
    return "".join(parts)


# --- the command line ---------------------------------------------------------------------


def _commands(
    parser: argparse.ArgumentParser, help_: str | None = None
) -> Iterator[tuple[argparse.ArgumentParser, str | None]]:
    """Every parser under ``parser`` (itself first), depth first in the order --help lists
    them, each with the one-line help its parent gives it."""
    yield parser, help_
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            helps = {a.dest: a.help for a in action._choices_actions}
            for name, child in action.choices.items():
                yield from _commands(child, helps.get(name))


def visible_options(parser: argparse.ArgumentParser) -> list[argparse.Action]:
    """The arguments ``parser``'s --help shows (not its sub-commands, listed apart)."""
    return [
        a
        for a in parser._actions
        if a.help != argparse.SUPPRESS and not isinstance(a, argparse._SubParsersAction)
    ]


def _argument(parser: argparse.ArgumentParser, action: argparse.Action) -> str:
    """One list item: the argument as it is typed, what it does, its default."""
    fmt = parser._get_formatter()
    if action.option_strings:
        spelt = list(action.option_strings)
        if action.nargs != 0:
            spelt[-1] += " " + fmt._format_args(
                action, fmt._get_default_metavar_for_optional(action)
            )
    else:
        spelt = [fmt._format_args(action, fmt._get_default_metavar_for_positional(action))]
    names = ", ".join(f"`{s}`" for s in spelt)
    help_ = " ".join(fmt._expand_help(action).split()) if action.help else ""
    default = ""
    if (
        action.option_strings
        and action.nargs != 0
        and action.default not in (None, argparse.SUPPRESS, [], "")
        and "%(default)" not in (action.help or "")
        and "default" not in help_
    ):
        default = f" (default: `{action.default}`)"
    return f"- {names}: {_md(help_)}{default}"


def cli_markdown(parser: argparse.ArgumentParser) -> str:
    """The CLI reference: a section per command (sub-commands nested), its usage, and
    every argument its --help shows."""
    out = [
        "# Command line",
        "",
        GENERATED,
        " Every command also takes `--version`; `--debug` (before or after the command) "
        "prints a runtime failure's traceback instead of one line. Exit statuses: "
        "[Exit statuses](exit-codes.md).",
        "",
    ]
    for sub, help_ in _commands(parser):
        depth = sub.prog.count(" ")
        out.append(f"{'#' * min(depth + 1, 6) if depth else '##'} `{sub.prog}`")
        out.append("")
        if help_ or sub.description:
            out += [_md(" ".join((sub.description or help_ or "").split())), ""]
        fmt = sub.formatter_class(prog=sub.prog, width=USAGE_WIDTH)
        fmt.add_usage(sub.usage, sub._actions, sub._mutually_exclusive_groups)
        out += ["```text", fmt.format_help().strip(), "```", ""]
        for action in sub._actions:
            if isinstance(action, argparse._SubParsersAction):
                out.append("Commands:")
                out.append("")
                for choice in action._choices_actions:
                    anchor = f"{sub.prog} {choice.dest}".replace(" ", "-")
                    out.append(f"- [`{choice.dest}`](#{anchor}): {_md(choice.help or '')}")
                out.append("")
        options = visible_options(sub)
        if options:
            out += ["Arguments:", ""] + [_argument(sub, a) for a in options] + [""]
        if sub.epilog:
            out += [_md(" ".join(sub.epilog.split())), ""]
    return "\n".join(out)


# --- YAML files from their pydantic models ------------------------------------------------


def _field_notes(model: type[BaseModel]) -> dict[str, str]:
    """The comments written beside each field of ``model``'s class body (above it and at
    the end of its lines), joined: what the key means and in which unit."""
    source = textwrap.dedent(inspect.getsource(model))
    comments: dict[int, str] = {}
    for tok in tokenize.generate_tokens(io.StringIO(source).readline):
        if tok.type == tokenize.COMMENT:
            comments[tok.start[0]] = tok.string.lstrip("#").strip()
    lines = source.splitlines()
    notes: dict[str, str] = {}
    body = ast.parse(source).body[0]
    assert isinstance(body, ast.ClassDef)
    for node in body.body:
        if isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name):
            above = []
            n = node.lineno - 1
            while n >= 1 and lines[n - 1].strip().startswith("#"):
                above.insert(0, comments.get(n, ""))
                n -= 1
            beside = [comments[i] for i in range(node.lineno, node.end_lineno + 1) if i in comments]
            notes[node.target.id] = " ".join(above + beside)
    return notes


def _strip(tp: Any) -> Any:
    """``tp`` without ``Annotated[...]``'s metadata."""
    while typing.get_origin(tp) is typing.Annotated:
        tp = typing.get_args(tp)[0]
    return tp


def _type_name(tp: Any) -> str:
    """A YAML reader's name for a field's type."""
    tp = _strip(tp)
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin in (typing.Union, types.UnionType):
        return " or ".join(_type_name(a) for a in args if a is not type(None))
    if origin is typing.Literal:
        return " | ".join(f"`{a}`" for a in args)
    if origin is list:
        return f"list of {_type_name(args[0])}"
    if origin is dict:
        return f"mapping of {_type_name(args[0])} to {_type_name(args[1])}"
    if isinstance(tp, type) and issubclass(tp, BaseModel):
        return "mapping"
    if tp is Any:
        return "any"
    names = {str: "string", int: "integer", float: "number", bool: "true/false", Path: "path"}
    return names.get(tp, getattr(tp, "__name__", str(tp)))


def _bounds(metadata: list[Any]) -> str:
    """The field's range as pydantic checks it (ge, gt, le, lt, min_length)."""
    signs = {"ge": "≥", "gt": ">", "le": "≤", "lt": "<", "min_length": "length ≥"}
    found = []
    for m in metadata:
        for attr, sign in signs.items():
            value = getattr(m, attr, None)
            if value is not None:
                found.append(f"{sign} {value:g}" if isinstance(value, float) else f"{sign} {value}")
    return ", ".join(found)


def _nested(tp: Any) -> tuple[type[BaseModel], str] | None:
    """The model a field holds (directly, optional, in a list or a mapping) and the suffix
    its keys' paths take below the field's name."""
    tp = _strip(tp)
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin in (typing.Union, types.UnionType):
        for a in args:
            found = _nested(a)
            if found is not None:
                return found
        return None
    if origin is list:
        found = _nested(args[0])
        return None if found is None else (found[0], "[]" + found[1])
    if origin is dict:
        found = _nested(args[1])
        return None if found is None else (found[0], ".<name>" + found[1])
    if isinstance(tp, type) and issubclass(tp, BaseModel):
        return tp, ""
    return None


def _yaml(value: Any) -> str:
    """A default as it is written in the YAML file, in code."""
    if isinstance(value, Path):
        value = str(value)
    text = yaml.safe_dump(value, default_flow_style=True, width=1000)
    return f"`{text.removesuffix(chr(10) + '...' + chr(10)).strip()}`"


def model_keys(model: type[BaseModel], prefix: str = "") -> Iterator[tuple[str, str, str, str]]:
    """(key path, type, default, meaning) of every key of ``model``, nested keys after
    their parent, as the YAML file has them (``scanners[].latency_s``)."""
    notes = _field_notes(model)
    for name, field in model.model_fields.items():
        if field.exclude:
            continue
        path = f"{prefix}{name}"
        if field.is_required():
            default = "required"
        else:
            value = field.get_default(call_default_factory=True)
            default = "" if value is None or isinstance(value, BaseModel) else _yaml(value)
        bounds = _bounds(field.metadata)
        kind = _type_name(field.annotation) + (f" ({bounds})" if bounds else "")
        yield path, kind, default, notes.get(name, "")
        nested = _nested(field.annotation)
        if nested is not None:
            yield from model_keys(nested[0], f"{path}{nested[1]}.")


def _key_table(model: type[BaseModel]) -> list[str]:
    rows = ["| key | type | default | meaning |", "|---|---|---|---|"]
    for path, kind, default, note in model_keys(model):
        rows.append(f"| `{path}` | {kind.replace('|', '&#124;')} | {default} | {_md(note)} |")
    return rows


def _sections(model: type[BaseModel]) -> list[str]:
    """Each model's docstring under the key path it sits at, for the page's prose."""
    out: list[str] = []
    seen: set[type[BaseModel]] = set()

    def walk(m: type[BaseModel], path: str) -> None:
        if m in seen:
            return
        seen.add(m)
        if m.__doc__:
            title = f"`{path}`" if path else "The file"
            out.extend([f"- {title}: {_md(' '.join(inspect.cleandoc(m.__doc__).split()))}"])
        for name, field in m.model_fields.items():
            nested = _nested(field.annotation)
            if nested is not None and not field.exclude:
                walk(nested[0], f"{path}{'.' if path else ''}{name}{nested[1]}")

    walk(model, "")
    return out


def config_markdown() -> str:
    from acq.record import config

    return "\n".join(
        [
            "# config.yaml",
            "",
            GENERATED + " From `acq.record.config`: the recorder's configuration "
            "(`acq record -c FILE`), validated with pydantic; an unknown key or a value out "
            "of range is one line naming the file and the key path, exit status 2. "
            "Relative paths are relative to the file's folder. Examples: `config/sim.yaml` "
            "(the default), `config/utm30lx.yaml`, `config/lms111.yaml`, "
            "`config/vehicle_example.yaml`.",
            "",
            *_sections(config.Config),
            "",
            *_key_table(config.Config),
            "",
        ]
    )


def calib_markdown() -> str:
    from acq.camera import calibfile

    model = calibfile._File
    return "\n".join(
        [
            "# calib.yaml",
            "",
            GENERATED + " From `acq.camera.calibfile`: the rig's calibration, written by "
            "`acq calibrate` and read by every command that projects. Lengths in metres, "
            "pixels in px, times in seconds; a pose `A_to_B` maps a point of frame A into "
            "frame B (`P_B = rotation @ P_A + translation`).",
            "",
            *_sections(model),
            "",
            *_key_table(model),
            "",
            "## The format, in the module's words",
            "",
            "```text",
            inspect.cleandoc(calibfile.__doc__ or ""),
            "```",
            "",
        ]
    )


# --- MCAP topics and schemas --------------------------------------------------------------


def _device_channels() -> list[tuple[str, str, str]]:
    """(device, topic, schema) of each kind of device the recorder logs, from its adapter."""
    from acq.record import adapters, config

    devices = [
        ("a scanner", adapters.ScannerAdapter(config.ScannerConfig.model_construct(
            name="<scanner>", driver="hokuyo"))),
        ("a camera", adapters.CameraAdapter(config.CameraConfig.model_construct(
            name="<camera>", driver="opencv"))),
        ("the CAN bus (`can:`)", adapters.CanAdapter(config.CanConfig.model_construct(
            driver="python-can"))),
        ("the GNSS receiver (`gnss:`)", adapters.GnssAdapter(config.GnssConfig.model_construct(
            driver="nmea"))),
    ]  # fmt: skip
    return [(kind, topic, schema) for kind, a in devices for topic, schema in a.channels()]


def _schema_fields(descriptor: Any, depth: int = 0) -> list[str]:
    """A list item per field of a protobuf message, nested messages indented."""
    from google.protobuf.descriptor import FieldDescriptor

    out = []
    for f in descriptor.fields:
        kind = (
            f.message_type.full_name
            if f.type == FieldDescriptor.TYPE_MESSAGE
            else f.enum_type.full_name
            if f.type == FieldDescriptor.TYPE_ENUM
            else {v: k for k, v in vars(FieldDescriptor).items() if k.startswith("TYPE_")}[f.type]
            .removeprefix("TYPE_")
            .lower()
        )
        # protobuf 6 has is_repeated; label, older, is gone from its upb descriptors
        many = f.is_repeated if hasattr(f, "is_repeated") else f.label == f.LABEL_REPEATED
        repeated = "repeated " if many else ""
        out.append(f"{'    ' * depth}- `{f.name}`: {repeated}`{kind}`")
        if (
            f.type == FieldDescriptor.TYPE_MESSAGE
            and f.message_type.file.package == "acq"
            and depth < 2
        ):
            out += _schema_fields(f.message_type, depth + 1)
    return out


def mcap_markdown() -> str:
    from acq.log import schemas
    from acq.record import live_colour

    out = [
        "# MCAP topics and schemas",
        "",
        GENERATED + " Every message is protobuf; the schema records carry the whole "
        "`FileDescriptorSet`, so Foxglove and `@mcap/core` decode them from the file alone. "
        "Times: see [the architecture's conventions](../architecture.md#conventions).",
        "",
        "## Topics a device writes",
        "",
        "| device | topic | schema |",
        "|---|---|---|",
    ]
    out += [f"| {kind} | `{topic}` | `{schema}` |" for kind, topic, schema in _device_channels()]
    out += [
        "",
        "## Topics the recorder writes",
        "",
        "| topic | schema | what |",
        "|---|---|---|",
        "| `/acq/status` | `acq.Status` | each device's state, once a second |",
        "| `/acq/clock` | `acq.Clock` | (realtime, monotonic) pairs of the host clocks |",
        "| `/acq/timebase` | `acq.TimeBase` | the host clock's time base, 1 Hz |",
        "| `/tf_static` | `foxglove.FrameTransforms` | the rig's poses from the calibration, "
        "at the start of every file |",
        "| `/<camera>/calibration` | `foxglove.CameraCalibration` | each calibrated camera's "
        "model, at the start of every file |",
        "",
        "## Topics only `acq record --live` serves",
        "",
        "| topic | schema |",
        "|---|---|",
        f"| `{live_colour.coloured_topic('<scanner>')}` | `foxglove.PointCloud` |",
        f"| `{live_colour.SWATH_TOPIC}` | `foxglove.PointCloud` |",
        f"| `{live_colour.TF_TOPIC}` | `foxglove.FrameTransforms` |",
        "",
        "## Schemas",
        "",
        "The module's own description (`acq.log.schemas`):",
        "",
        "```text",
        inspect.cleandoc(schemas.__doc__ or ""),
        "```",
        "",
    ]
    for name, schema in schemas.SCHEMAS.items():
        descriptor = schemas.message_class(name).DESCRIPTOR
        out += [f"### `{name}`", "", f"Encoding `{schema.encoding}`.", ""]
        out += [*_schema_fields(descriptor), ""]
    return "\n".join(out)


# --- exit statuses ------------------------------------------------------------------------


def exit_codes_markdown() -> str:
    # the module: acq.cli's `main` attribute is its function
    main = importlib.import_module("acq.cli.main")

    doc = inspect.cleandoc(main.__doc__ or "")
    statuses = next(p for p in doc.split("\n\n") if p.startswith("Exit status"))
    names = sorted((value, name) for name, value in vars(main).items() if name.startswith("EXIT_"))
    return "\n".join(
        [
            "# Exit statuses",
            "",
            GENERATED + " From `acq.cli.main`, the one place where an error becomes a "
            "line on stderr and an exit status.",
            "",
            _md(" ".join(statuses.split())),
            "",
            "| status | name in `acq.cli.main` |",
            "|---|---|",
            "| 0 | success |",
            *[f"| {value} | `{name}` |" for value, name in names],
            "",
            "Commands add their own meaning to 1 where a check fails: `acq status` exits 1 "
            "when a device is stale or a required one is down, `acq record` when a "
            "configured device recorded nothing; see [the command line](cli.md).",
            "",
        ]
    )


# --- the hook -----------------------------------------------------------------------------


def pages() -> dict[str, str]:
    """Each generated page's path under docs/ and its Markdown."""
    from acq.cli import build_parser

    return {
        "reference/cli.md": cli_markdown(build_parser()),
        "reference/config.md": config_markdown(),
        "reference/calib.md": calib_markdown(),
        "reference/mcap.md": mcap_markdown(),
        "reference/exit-codes.md": exit_codes_markdown(),
    }


def on_files(files: Any, config: Any) -> Any:
    """MkDocs' hook: the generated pages added to the site's files."""
    from mkdocs.structure.files import File

    for path, text in pages().items():
        files.append(File.generated(config, path, content=text))
    return files
