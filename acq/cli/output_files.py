"""What a command may write over, checked before it runs, and writing a file so that a
failure leaves the old one as it was.

The rule every command that writes follows (its --help says it in :data:`RULE`):

- an output that is one of the command's inputs is refused, naming both, except a
  calibration updated in place (``--calib C -o C``), which needs --force as below;
- an output that exists and is recognisably another kind of file (an MCAP log, an image,
  a point cloud where a YAML goes, or any binary file there) is refused, even with --force;
- an existing calibration or configuration (YAML) is replaced only with --force, and then
  kept beside it as ``NAME.bak``;
- an existing product (a cloud, an image, a JSON report) is replaced when acq wrote it
  (its mark, :mod:`acq.provenance`: the same command run again), otherwise only with
  --force; an existing MCAP log never;
- two outputs of one command never name the same file;
- an output goes into an existing folder, unless the command makes it (``-o DIR``).
"""

from __future__ import annotations

import os
import shutil
import sys
from collections.abc import Collection, Sequence
from dataclasses import dataclass
from pathlib import Path

from acq.atomic_write import atomic
from acq.errors import InputError
from acq.provenance import made_by_acq

__all__ = [
    "FORCE_HELP",
    "IMAGE_SUFFIXES",
    "RULE",
    "Output",
    "atomic",
    "backup_name",
    "check",
    "check_folder_replace",
    "folder_output",
    "foreign_files",
    "keep_backup",
    "keep_backups",
    "kind_of",
]

RULE = (
    "An output that is one of the inputs, or an existing file of another kind (a log or "
    "an image where a YAML goes), is refused; an existing YAML is replaced only with "
    "--force, its old content kept as NAME.bak; an existing cloud, image or report only "
    "when acq wrote it, or with --force."
)

FORCE_HELP = "replace existing outputs that acq did not write"

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")  # the images a command writes, by their name

# what an existing file holds, by its first bytes
_MAGIC: dict[bytes, str] = {
    b"\x89MCAP": "mcap",
    b"\x89PNG\r\n\x1a\n": "png",
    b"\xff\xd8\xff": "jpeg",
    b"BM": "bmp",
    b"II*\x00": "tiff",
    b"MM\x00*": "tiff",
    b"RIFF": "webp",
    b"ply\n": "ply",
    b"ply\r\n": "ply",
    b"LASF": "las",
    b"glTF": "glb",
    b"%PDF": "pdf",
    b"PK\x03\x04": "zip",
    b"\x1f\x8b": "gzip",
    b"\x7fELF": "elf",
}
_NAMES = {
    "mcap": "an MCAP log",
    "png": "a PNG image",
    "jpeg": "a JPEG image",
    "bmp": "a BMP image",
    "tiff": "a TIFF image",
    "webp": "a WebP image",
    "ply": "a PLY cloud",
    "las": "a LAS cloud",
    "glb": "a glTF model",
    "pdf": "a PDF",
    "zip": "a zip archive",
    "gzip": "a gzip file",
    "elf": "a program",
    "data": "binary data",
    "text": "text",
    "yaml": "a YAML file",
    "image": "an image",
    "cloud": "a point cloud",
    "mesh": "a mesh",
    "json": "a JSON file",
}
# the kinds an output of each kind may replace ("text" and "data": no known format)
_REPLACES: dict[str, frozenset[str]] = {
    "yaml": frozenset({"text"}),
    "image": frozenset({"png", "jpeg", "bmp", "tiff", "webp", "text", "data"}),
    "cloud": frozenset({"ply", "las", "text", "data"}),
    "json": frozenset({"text"}),
    "mesh": frozenset({"ply", "glb", "text"}),
    "mcap": frozenset({"mcap", "data"}),
}
_PRECIOUS = frozenset({"yaml"})  # replaced only with --force, with a backup


def kind_of(path: Path) -> str:
    """What the existing file ``path`` holds, by its first bytes: a key of the known
    formats, ``text`` (UTF-8 without NUL: YAML, JSON, CSV...) or ``data``."""
    with path.open("rb") as f:
        head = f.read(4096)
    for magic, kind in _MAGIC.items():
        if head.startswith(magic):
            return kind
    if b"\x00" in head:
        return "data"
    try:
        head.decode("utf-8")
    except UnicodeDecodeError as e:
        if e.start < len(head) - 3:  # not just a character cut at the 4096th byte
            return "data"
    return "text"


@dataclass(frozen=True)
class Output:
    """A file a command writes: the option naming it (``-o``), its path, and its kind
    (``yaml``: a calibration or configuration, replaced only with --force; ``image``,
    ``json``, ``cloud``, ``mesh``: products, replaced when acq wrote them; ``mcap``: never
    replaced). ``update``: the command reads
    the existing file and writes it back changed (``calibrate fisheye -o``): no --force
    needed, the old one is kept as NAME.bak all the same. ``in_place_of``: the input
    options (``--calib``) this output may be the same file as, to update it in place
    (with --force, as any existing YAML). ``makes_folder``: the command creates the
    folder the output goes into (``-o DIR``), so it need not exist."""

    option: str
    path: Path
    kind: str
    update: bool = False
    in_place_of: tuple[str, ...] = ()
    makes_folder: bool = False

    def named(self) -> str:
        return f"{self.option} {self.path}"


def _same(a: Path, b: Path) -> bool:
    try:
        return os.path.samefile(a, b)
    except OSError:  # one of them does not exist (yet)
        return a.absolute().resolve() == b.absolute().resolve()


def check(
    inputs: Sequence[tuple[str, Path]], outputs: Sequence[Output], *, force: bool = False
) -> list[Output]:
    """Refuse (InputError, exit 2) what the rule of this module forbids, before a
    command runs; ``inputs``: (option or metavar, path). Returns the outputs that exist
    and will be replaced with a backup (:func:`keep_backup` them before writing)."""
    backups: list[Output] = []
    for i, out in enumerate(outputs):
        for other in outputs[:i]:
            if _same(out.path, other.path):
                raise InputError(f"{other.named()} and {out.option} name the same file")
        same_input = next(((opt, p) for opt, p in inputs if _same(out.path, p)), None)
        if same_input is not None and same_input[0] not in out.in_place_of:
            opt, p = same_input
            raise InputError(f"{out.named()}: is the input {opt} {p}; give another file")
        _check_folder(out)
        if not out.path.exists():
            continue
        if out.path.is_dir():
            raise InputError(f"{out.named()}: is a folder; give a file")
        found = kind_of(out.path)
        if found not in _REPLACES[out.kind]:
            raise InputError(
                f"{out.named()}: exists and is {_NAMES[found]}, not {_NAMES[out.kind]}; "
                "not overwritten"
            )
        if out.kind not in _PRECIOUS:
            if out.kind == "mcap":
                raise InputError(f"{out.named()}: exists and is an MCAP log; not overwritten")
            if not (force or made_by_acq(out.path)):
                raise InputError(
                    f"{out.named()}: exists and was not written by acq; --force replaces it"
                )
            continue
        if not (force or out.update):
            what, does = (
                (f"is the input {same_input[0]} {same_input[1]}", "updates it in place")
                if same_input
                else ("exists", "replaces it")
            )
            raise InputError(
                f"{out.named()}: {what}; --force {does}, keeping the old one as "
                f"{backup_name(out.path).name}"
            )
        backups.append(out)
    return backups


def _check_folder(out: Output) -> None:
    """Refuse an output whose folder is not a folder or is under a file, or is missing
    (unless the command makes it), naming it: before the work, not after."""
    folder = out.path.absolute().parent
    if folder.is_dir():
        return
    missing = folder
    while not missing.parent.exists() and missing.parent != missing:
        missing = missing.parent
    if missing.exists():
        raise InputError(f"{out.named()}: {missing} is a file, not a folder")
    if not missing.parent.is_dir():
        raise InputError(f"{out.named()}: {missing.parent} is a file, not a folder")
    if not out.makes_folder:
        raise InputError(f"{out.named()}: the folder {missing} does not exist; create it first")


def backup_name(path: Path) -> Path:
    """Where :func:`keep_backup` keeps the old ``path``: ``NAME.bak``."""
    return path.with_name(path.name + ".bak")


def keep_backup(path: Path) -> Path:
    """Copy the existing ``path`` to ``NAME.bak`` (atomically); the backup's path."""
    bak = backup_name(path)
    with atomic(bak) as tmp:
        shutil.copy2(path, tmp)
    return bak


def keep_backups(prog: str, outputs: Sequence[Output]) -> None:
    """:func:`keep_backup` each output :func:`check` returned, saying so on stderr."""
    for out in outputs:
        bak = keep_backup(out.path)
        print(f"{prog}: kept the old {out.path} as {bak}", file=sys.stderr, flush=True)


# a folder a command replaces whole (``export ros2 -o BAG``)


def folder_output(option: str, path: Path) -> Path:
    """``path`` as an absolute folder with a name of its own (``.``, ``..`` and ``/``
    resolved); InputError for the current folder, one that holds it, or the root."""
    folder = Path(os.path.abspath(path))
    if not folder.name or Path.cwd().is_relative_to(folder):
        raise InputError(
            f"{option} {path}: is the current folder or holds it; give a folder of its own"
        )
    return folder


def foreign_files(folder: Path, ours: Collection[str]) -> list[str]:
    """The names in ``folder`` (sorted) that are not among ``ours``, the files acq wrote
    there; none for a folder that does not exist."""
    if not folder.is_dir():
        return []
    return sorted(p.name for p in folder.iterdir() if p.name not in ours or not p.is_file())


def check_folder_replace(
    option: str, folder: Path, ours: Collection[str], *, force: bool = False
) -> Path | None:
    """Refuse (InputError) to replace ``folder`` unless it is absent, empty or holds only
    ``ours`` (the files acq wrote there, which the new folder replaces). A folder with
    other files is refused, naming them; with ``force`` it is kept whole beside as
    ``NAME.bak`` (refused when that exists): the path it is kept as, else None. A file
    acq did not write is never deleted."""
    if folder.exists() and not folder.is_dir():
        raise InputError(f"{option} {folder}: is a file; give a folder")
    others = foreign_files(folder, ours)
    if not others:
        return None
    shown = ", ".join(others[:3]) + (f" and {len(others) - 3} more" if len(others) > 3 else "")
    bak = backup_name(folder)
    if not force:
        raise InputError(
            f"{option} {folder}: holds {shown}, which acq did not write; give a new or "
            f"empty folder (--force keeps the old folder whole as {bak.name})"
        )
    if bak.exists() or bak.is_symlink():
        raise InputError(
            f"{option} {folder}: holds {shown}, which acq did not write, and {bak} exists "
            "to keep it; move one of them away"
        )
    return bak
