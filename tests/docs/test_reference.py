"""The generated reference pages (docs/gen_reference.py, run by `make docs`) against what
they describe: every command and option `acq --help` shows, every key of the shipped
configurations and calibration, every schema the logs carry."""

from __future__ import annotations

import argparse
import contextlib
import hashlib
import importlib.util
import io
import json
import re
from collections.abc import Iterator
from types import ModuleType
from typing import Any

import pytest
import yaml

from acq.cli import build_parser, main
from tests.docs.runnable import DOCS

ROOT = DOCS.parent


@pytest.fixture(scope="module")
def gen() -> ModuleType:
    spec = importlib.util.spec_from_file_location("gen_reference", DOCS / "gen_reference.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _parsers(
    parser: argparse.ArgumentParser,
) -> Iterator[argparse.ArgumentParser]:
    yield parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for child in action.choices.values():
                yield from _parsers(child)


def _sections(markdown: str) -> dict[str, str]:
    """The CLI page cut at its headings: the command each names and the text below it."""
    parts = re.split(r"^#{2,6} `(acq[^`]*)`$", markdown, flags=re.M)
    return dict(zip(parts[1::2], parts[2::2], strict=True))


def test_the_cli_reference_lists_every_command_and_option(gen: ModuleType) -> None:
    parser = build_parser()
    sections = _sections(gen.cli_markdown(parser))
    every = list(_parsers(parser))
    assert len(every) > 20  # acq, its commands and theirs
    for sub in every:
        assert sub.prog in sections, f"no section for {sub.prog}"
        text = sections[sub.prog]
        for action in sub._actions:
            if action.help == argparse.SUPPRESS:
                continue  # --help does not show it either
            if isinstance(action, argparse._SubParsersAction):
                for name in action.choices:
                    assert f"[`{name}`]" in text, f"{sub.prog}: command {name} not listed"
            elif action.option_strings:
                for option in action.option_strings:
                    assert f"`{option}" in text, f"{sub.prog}: {option} not listed"
            else:  # a positional: its metavar, else its name or its choices
                shown = [str(action.metavar or action.dest)]
                if action.choices is not None and action.metavar is None:
                    shown.append("{" + ",".join(map(str, action.choices)) + "}")
                listed = [re.search(r"`\[?" + re.escape(s), text) for s in shown]
                assert any(listed), f"{sub.prog}: {shown[0]} not listed"


def test_the_cli_reference_has_every_command_acq_help_shows(gen: ModuleType) -> None:
    shown = io.StringIO()
    with contextlib.redirect_stdout(shown):
        assert main(["--help"]) == 0
    commands = re.findall(r"^ {4}([a-z][a-z0-9-]*)(?: |$)", shown.getvalue(), re.M)
    assert len(commands) >= 14, shown.getvalue()
    sections = _sections(gen.cli_markdown(build_parser()))
    assert [c for c in commands if f"acq {c}" not in sections] == []


def _yaml_paths(node: Any, prefix: str, mapping_of_names: set[str]) -> Iterator[str]:
    """The key paths of a YAML tree as the reference writes them (``scanners[].url``,
    ``cameras.<name>.fx``), not below a driver's free ``options``."""
    if isinstance(node, dict):
        for key, value in node.items():
            path = f"{prefix}{key}"
            yield path
            if key == "options":
                continue
            if key in mapping_of_names and isinstance(value, dict):
                for entry in value.values():
                    yield from _yaml_paths(entry, f"{path}.<name>.", mapping_of_names)
            else:
                yield from _yaml_paths(value, f"{path}.", mapping_of_names)
    elif isinstance(node, list):
        for item in node:
            if isinstance(item, dict):
                yield from _yaml_paths(item, prefix[:-1] + "[].", mapping_of_names)


@pytest.mark.parametrize("name", sorted(p.name for p in (ROOT / "config").glob("*.yaml")))
def test_every_key_of_the_shipped_files_is_in_the_reference(gen: ModuleType, name: str) -> None:
    data = yaml.safe_load((ROOT / "config" / name).read_text())
    calib = "cameras" in data and isinstance(data["cameras"], dict)
    page = gen.calib_markdown() if calib else gen.config_markdown()
    paths = set(_yaml_paths(data, "", {"cameras"} if calib else set()))
    assert paths, name
    missing = sorted(p for p in paths if f"| `{p}` |" not in page)
    assert missing == [], f"{name}: keys not in the reference: {missing}"


def test_every_schema_and_device_topic_is_in_the_mcap_reference(gen: ModuleType) -> None:
    from acq.log import schemas

    page = gen.mcap_markdown()
    for name in schemas.SCHEMAS:
        assert f"### `{name}`" in page
    for topic in ("/<scanner>/scan", "/<camera>/image/compressed", "/vehicle/odometry",
                  "/gnss/fix", "/acq/timing/<scanner>", "/acq/status", "/live/swath"):  # fmt: skip
        assert f"`{topic}`" in page, topic


def test_the_exit_statuses_come_from_the_cli(gen: ModuleType) -> None:
    page = gen.exit_codes_markdown()
    for value, name in ((1, "EXIT_FAILURE"), (2, "EXIT_USAGE"), (3, "EXIT_DISK_FULL")):
        assert f"| {value} | `{name}` |" in page


def test_the_vendored_mermaid_is_what_its_record_says() -> None:
    folder = DOCS / "javascripts" / "mermaid"
    record = json.loads((folder / "VENDORED.json").read_text())
    assert record["package"] == "mermaid" and record["integrity"].startswith("sha512-")
    for entry in record["files"]:
        digest = hashlib.sha256((folder / entry["path"]).read_bytes()).hexdigest()
        assert digest == entry["sha256"], entry["path"]


def test_the_api_reference_shows_sphinx_roles_as_code() -> None:
    """The docstrings' roles (``:class:`X```) as the site's Markdown shows them: code."""
    import griffe

    ext = griffe.load_extensions(str(DOCS / "griffe_roles.py") + ":SphinxRoles")
    errors = griffe.load("acq.errors", extensions=ext, search_paths=[str(ROOT)])
    text = errors.docstring.value
    assert ":class:" not in text and "`InputError` 2" in text, text
    rt = griffe.load("acq.records", extensions=ext, search_paths=[str(ROOT)])
    for obj in [rt, *rt.members.values()]:
        if not obj.is_alias and obj.docstring is not None:
            assert not re.search(r":(class|func|meth|mod|attr|data):`", obj.docstring.value)
    spec = importlib.util.spec_from_file_location("griffe_roles", DOCS / "griffe_roles.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    assert module.plain(":func:`~acq.log.reader.read_metadata` and :mod:`acq.time`") == (
        "`read_metadata` and `acq.time`"
    )
