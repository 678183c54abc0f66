"""Every runnable block of the quick start and the how-to guides, run against the
simulated rig: each command must exit 0 (its output shown when it does not)."""

from __future__ import annotations

from pathlib import Path

import pytest

from acq.cli import build_parser
from tests.conftest import once_per_run
from tests.docs.runnable import DOCS, blocks, pages_with_blocks, run


def test_the_quick_start_and_the_guides_have_runnable_blocks() -> None:
    pages = {p.relative_to(DOCS).as_posix() for p in pages_with_blocks()}
    assert {"quickstart.md", "how-to/calibrate-fisheye.md"} <= pages, pages


@pytest.mark.parametrize(
    "page",
    [p.relative_to(DOCS).as_posix() for p in pages_with_blocks() if p.name != "quickstart.md"],
)
def test_a_guides_blocks_run(page: str, tmp_path: Path) -> None:
    for block in blocks(DOCS / page):
        for argv in block:
            code, printed = run(argv, tmp_path)
            assert code == 0, f"{page}: {' '.join(argv)} exited {code}:\n{printed}"


def _demo_options(argv: list[str]) -> dict[str, object]:
    args = vars(build_parser("demo").parse_args(argv))
    return {k: v for k, v in args.items() if k not in ("handler", "_prog")}


@pytest.mark.realtime  # its demo drives the simulated rig in real time
def test_the_quick_starts_blocks_run(tmp_path_factory: pytest.TempPathFactory) -> None:
    """The demo command is the one tests/sim/test_demo.py runs (asserted, option by
    option): it runs once for both, and the block's other commands run on its output."""
    from tests.sim.test_demo import SECONDS, _run_demo

    (block,) = blocks(DOCS / "quickstart.md")
    demo, *rest = block
    assert _demo_options(demo[1:]) == _demo_options(
        ["demo", "--out", "demo", "--seconds", repr(SECONDS)]
    ), f"the quick start's demo is not the one tests/sim/test_demo.py runs: {demo}"
    folder, ran = once_per_run(tmp_path_factory, "demo_run", _run_demo)
    assert ran["code"] == 0, ran["printed"]
    work = tmp_path_factory.mktemp("quickstart")
    (work / "demo").symlink_to(folder / "demo")
    for argv in rest:
        code, printed = run(argv, work)
        assert code == 0, f"quickstart.md: {' '.join(argv)} exited {code}:\n{printed}"
    assert (work / "drive.laz").stat().st_size > 0
