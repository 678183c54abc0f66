"""The page's parser of packed points (acq/view/page/points.js, in headless Chromium) against
the server's packing (acq.view.points_payload): a payload, and each of its two parts (the
first frame's positions and colours, the attributes after), parses to the values packed, and
any payload or part damaged (cut, its header's bytes changed, bytes added) either parses to arrays
that fit its buffer or is refused with an Error saying why, never a RangeError of a typed
array nor a hang (hypothesis)."""

from __future__ import annotations

import base64
import json
from collections.abc import Iterator

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from acq.view.points_payload import payload, split_payload
from acq.view.server import ViewServer
from tests.browser import Browser
from tests.view.layer_files import cloud, unpack

# window.parsed(b64): what parsePoints makes of the bytes, or the Error it throws
PARSE = """window.parsed = async (b64) => {
  const { parsePoints } = await import('/static/points.js');
  const buffer = Uint8Array.from(atob(b64), (c) => c.charCodeAt(0)).buffer;
  try {
    const p = parsePoints(buffer);
    const lengths = Object.fromEntries(Object.entries(p.attributes).map(([k, v]) => [k, v.length]));
    return { count: p.count, start: p.start, stop: p.stop, rows: p.rows, origin: p.origin,
      time0: p.time0, cameras: p.cameras, part: p.part, has: p.has,
      positions: Array.from(p.positions?.slice(0, 6) ?? []), npositions: p.positions?.length ?? 0,
      lengths,
      scan: Array.from(p.attributes.scan?.slice(0, 5) ?? []) };
  } catch (error) {
    return { error: error.constructor.name, message: error.message };
  }
};"""


@pytest.fixture(scope="module")
def page(browser: Browser, tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict[str, bytes]]:
    """The page open on a small cloud, ``window.parsed`` defined; the cloud's payload
    ("whole") and its two parts ("points", "attributes")."""
    path = cloud(tmp_path_factory.mktemp("parser") / "c.ply", n=40)
    with ViewServer([path]) as server:
        browser.open(server.url)
        browser.evaluate(PARSE)
        split = split_payload(path, 30)
        yield {
            "whole": bytes(payload(path, 30, 3, 39)),
            "points": bytes(split.points),
            "attributes": bytes(split.attributes),
        }


def _parse(browser: Browser, data: bytes) -> dict[str, object]:
    result = browser.evaluate(f"window.parsed({json.dumps(base64.b64encode(data).decode())})")
    assert isinstance(result, dict)
    return result


def test_a_payload_parses_to_the_values_packed(browser: Browser, page: dict[str, bytes]) -> None:
    want = unpack(page["whole"])
    got = _parse(browser, page["whole"])
    assert got["part"] == "whole"
    assert (got["count"], got["start"], got["stop"], got["rows"]) == (30, 3, 39, 40)
    assert got["origin"] == list(want["origin"]) and got["time0"] == want["time0"]
    assert got["cameras"] == ["left"]
    assert np.allclose(got["positions"], (want["xyz"][:2] - want["origin"]).ravel(), atol=1e-6)
    assert got["npositions"] == 90 and got["scan"] == want["scan"][:5].tolist()
    widths = {"time": 1, "scan": 1, "intensity": 1, "rgb": 3, "coloured": 1, "camera": 1}
    assert got["lengths"] == {k: 30 * w for k, w in widths.items()}


def test_the_parts_parse_to_the_values_packed(browser: Browser, page: dict[str, bytes]) -> None:
    want = unpack(page["points"], page["attributes"])
    points, attributes = _parse(browser, page["points"]), _parse(browser, page["attributes"])
    every = ["time", "scan", "intensity", "rgb", "coloured", "camera"]
    assert points["part"] == "points" and attributes["part"] == "attributes"
    assert points["has"] == attributes["has"] == every  # the modes to enable
    assert points["lengths"] == {"rgb": 90} and points["npositions"] == 90
    assert np.allclose(points["positions"], (want["xyz"][:2] - want["origin"]).ravel(), atol=1e-6)
    assert attributes["npositions"] == 0 and attributes["scan"] == want["scan"][:5].tolist()
    assert attributes["lengths"] == {k: 30 for k in every if k != "rgb"}
    keys = ("count", "start", "stop", "rows", "origin", "time0", "cameras")
    assert [points[k] for k in keys] == [attributes[k] for k in keys]


@settings(max_examples=80, deadline=None)
@given(
    which=st.sampled_from(["whole", "points", "attributes"]),
    cut=st.integers(0, 2000),
    changes=st.lists(st.tuples(st.integers(0, 79), st.integers(0, 255)), max_size=4),
    tail=st.binary(max_size=8),
)
def test_a_damaged_payload_is_refused_or_fits(
    browser: Browser, page: dict[str, bytes], which: str, cut: int,
    changes: list[tuple[int, int]], tail: bytes,
) -> None:  # fmt: skip
    whole = page[which]
    data = bytearray(whole[: len(whole) - cut] if cut < len(whole) else b"")
    for at, value in changes:
        if at < len(data):
            data[at] = value
    data += tail
    got = _parse(browser, bytes(data))
    if "error" in got:
        assert got["error"] == "Error" and got["message"], got
    else:  # what parsed fits the buffer it came in
        n = got["count"]
        assert isinstance(n, int) and n > 0
        assert got["npositions"] == (0 if got["part"] == "attributes" else 3 * n)
        assert all(v == (3 if k == "rgb" else 1) * n for k, v in got["lengths"].items())
        assert got["start"] < got["stop"] <= got["rows"]
