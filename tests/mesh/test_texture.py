"""acq mesh --texture: one view per facet (chosen as tests/mesh/test_view_selection.py
checks), its texels resampled from that fisheye frame into the tile's atlas, read back
from the glb.

The atlas is checked against synthetic frames (a linear gradient, which bilinear
sampling reproduces exactly) and on the short simulated drive (a real MCAP log) against
the frames decoded here on their own; the glb through pygltflib and trimesh."""

from __future__ import annotations

import io
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import pygltflib
import pytest
import trimesh
from PIL import Image
from plyfile import PlyData

from acq.camera import calibfile, jpeg
from acq.camera.jpeg import decode_jpeg
from acq.cli import main as acq_main
from acq.cloud.balance import Gains
from acq.cloud.chunks import NO_CAMERA
from acq.cloud.views import Crop
from acq.log.drive_log import read_log
from acq.mesh import drive, texture, view_selection
from acq.mesh.drive import prepare_mesh
from acq.mesh.files import Y_UP
from acq.provenance import SOFTWARE, made_by_acq
from acq.sim.drive_log import DriveTruth

Drive = tuple[DriveTruth, Path]
T = 8


def _gradient(h: int = 120, w: int = 160) -> np.ndarray:
    """A BGR image whose channels are linear in (u, v): B = u, G = v, R = 200 - u/2."""
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    return np.stack([u, v, 200 - u / 2], axis=-1).astype(np.uint8)


def _frames(*images: np.ndarray | None) -> texture.FrameImages:
    asked: list[tuple[int, list[int]]] = []

    def images_of(camera: int, frames: np.ndarray) -> Any:
        asked.append((camera, frames.tolist()))
        return iter(images[f] for f in frames.tolist())

    images_of.asked = asked  # type: ignore[attr-defined]
    return images_of


def test_facet_views_take_the_agreeing_or_the_majority_frame() -> None:
    camera = np.array([0, 0, 0, 1, NO_CAMERA, 1], dtype=np.uint8)
    frame = np.array([5, 5, 6, 5, -1, 5], dtype=np.int64)
    faces = np.array([[0, 1, 0], [0, 1, 2], [2, 3, 0], [4, 4, 3], [4, 4, 4], [3, 5, 0]])
    cam, fr = texture.facet_views(camera, frame, faces)
    # all three agree; two of three; none agree (the first vertex's); two without a view
    # (the one with); none with a view; two of three across cameras
    assert cam.tolist() == [0, 0, 0, 1, -1, 1]
    assert fr.tolist() == [5, 5, 6, 5, -1, 5]


def test_atlas_texels_are_the_frame_at_the_facets_pixels_and_cells_do_not_mix() -> None:
    img = _gradient()
    # four facets, two cells: corners in px (u, v); facet 1 is filled (no view), facet 3
    # has a corner off the sensor (NaN)
    px = np.array(
        [
            [[10.0, 10.0], [40.0, 12.0], [14.0, 50.0]],
            [[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]],
            [[100.5, 80.25], [130.0, 60.0], [90.0, 100.0]],
            [[10.0, 10.0], [np.nan, 12.0], [14.0, 50.0]],
        ],
        dtype=np.float32,
    )
    view_cam = np.array([0, -1, 0, 0])
    view_frame = np.array([0, -1, 1, 1])
    fill = np.array([[1, 2, 3], [7, 8, 9], [0, 0, 0], [4, 5, 6]], dtype=np.uint8)
    images = _frames(img, img[::-1, ::-1].copy())  # frame 1: the image turned half round
    gains = Gains([np.log(np.array([[1.0, 1.0, 1.0], [2.0, 1.0, 0.5]]))], 0, 0)
    atlas = texture.build_atlas(px, view_cam, view_frame, images, gains, fill, T)
    assert images.asked == [(0, [0, 1])]  # type: ignore[attr-defined]  # each frame once
    assert atlas.textured.tolist() == [True, False, True, False]
    # places in the order sampled (by camera, frame), then those filled
    assert atlas.slot.tolist() == [0, 2, 1, 3]
    assert atlas.image.shape == (T, 2 * T, 3)  # two cells side by side
    corners = texture.cell_corners(T)
    for f, gain in ((0, np.ones(3)), (2, np.array([2, 1, 0.5]))):
        s = atlas.slot[f]
        cx, cy = (s // 2) % 2, (s // 2) // 2
        q = corners[s % 2]
        half = texture.half_texels(T)[s % 2]
        for x, y in zip(*half, strict=True):
            # barycentric coordinates of the texel in the cell's triangle, the same in the frame
            A = np.vstack([q.T, np.ones(3)])
            w = np.linalg.solve(A, [x, y, 1.0])
            u, v = w @ px[f].astype(np.float64)
            u, v = np.clip(u, 0, 159), np.clip(v, 0, 119)
            want_bgr = (
                np.array([u, v, 200 - u / 2])
                if f == 0
                else np.array([159 - u, 119 - v, 200 - (159 - u) / 2])
            )
            want_rgb = np.clip(want_bgr[::-1] / gain, 0, 255)
            got = atlas.image[cy * T + y, cx * T + x].astype(np.float64)
            assert np.abs(got - want_rgb).max() <= 1.51, (f, x, y, got, want_rgb)
    # the facets without a texture hold their fill colour, every texel of their half
    for f in (1, 3):
        s = atlas.slot[f]
        cx, cy = (s // 2) % 2, (s // 2) // 2
        xs, ys = texture.half_texels(T)[s % 2]
        assert (atlas.image[cy * T + ys, cx * T + xs] == fill[f]).all()
    # every corner's texture coordinate in its own cell, on a texel of its own half
    at = np.stack([atlas.uv[..., 0] * 2 * T, (1 - atlas.uv[..., 1]) * T], axis=-1) - 0.5
    for f in range(4):
        s = atlas.slot[f]
        cx, cy = (s // 2) % 2, (s // 2) // 2
        local = at[f] - [cx * T, cy * T]
        assert np.allclose(local, corners[s % 2], atol=1e-4)
    # bilinear filtering at any point of a triangle reads its own half only: the upper
    # left's texels have x + y < T, its points x + y <= T - 2; the lower right's >= T, T + 1
    assert corners[0].sum(axis=1).max() == T - 2 and corners[1].sum(axis=1).min() == T + 1


def test_atlas_is_the_same_however_many_facets_a_remap_takes_and_a_lost_frame_is_filled(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Many facets of both halves in three frames, the middle one not decoding: the
    atlas sampled a facet per cv2.remap call is the one sampled a frame's half at a
    time; the lost frame's facets hold their fill, the others their frame's texels."""
    rng = np.random.default_rng(3)
    n = 301
    base = rng.uniform([5, 5], [150, 110], (n, 1, 2))
    px = (base + rng.uniform(-4, 4, (n, 3, 2))).astype(np.float32)
    view_cam = np.zeros(n, dtype=np.int64)
    view_frame = rng.integers(0, 3, n)
    fill = rng.integers(0, 256, (n, 3), dtype=np.uint8)
    img = _gradient()
    gains = Gains([np.log(np.array([[1.0, 1.0, 1.0], [1.0, 1.0, 1.0], [1.5, 1.0, 0.8]]))], 0, 0)
    whole = texture.build_atlas(px, view_cam, view_frame, _frames(img, None, img[::-1].copy()),
                                gains, fill, T)  # fmt: skip
    monkeypatch.setattr(texture, "_ROWS", 1)
    one = texture.build_atlas(px, view_cam, view_frame, _frames(img, None, img[::-1].copy()),
                              gains, fill, T)  # fmt: skip
    assert np.array_equal(one.bgr, whole.bgr) and np.array_equal(one.uv, whole.uv)
    assert whole.textured.tolist() == (view_frame != 1).tolist()
    cols = whole.bgr.shape[1] // T
    frames = _frames(img, None, img[::-1].copy())
    for f in range(n):  # each facet's texels as an atlas of that facet alone has them
        s = whole.slot[f]
        xs, ys = texture.half_texels(T)[s % 2]
        texels = whole.bgr[(s // 2) // cols * T + ys, (s // 2) % cols * T + xs]
        k = [f] * (1 + s % 2)  # the facet (twice for the lower right half: the second)
        alone = texture.build_atlas(px[k], view_cam[k], view_frame[k], frames, gains,
                                    fill[k], T)  # fmt: skip
        assert alone.slot[-1] == s % 2
        assert np.array_equal(texels, alone.bgr[ys, xs]), f
        if view_frame[f] == 1:
            assert (texels == fill[f, ::-1]).all()


@dataclass
class Captured:
    """What acq mesh --texture gave build_atlas for the short drive, and what it made."""

    job: Any
    args: tuple[Any, ...]
    atlas: texture.Atlas
    asked: list[tuple[int, list[int]]]
    xyz: np.ndarray
    tri: np.ndarray
    camera: np.ndarray
    frame: np.ndarray
    uv: np.ndarray


def _run(
    short_drive: Drive, out: Path, monkeypatch: pytest.MonkeyPatch, chunk_s: float | None = None
) -> Captured:
    """acq mesh --texture of the short drive through the library, observing (not
    replacing) the atlas it builds and the frames it asks for."""
    truth, calib_path = short_drive
    seen: dict[str, Any] = {"asked": []}
    build, views = texture.build_atlas, view_selection.select_views

    def select_views(job: Any, xyz: np.ndarray, time_ns: np.ndarray, tri: np.ndarray,
                     camera: np.ndarray, frame: np.ndarray, *rest: Any) -> Any:  # fmt: skip
        seen.update(camera=camera, frame=frame, tri=tri)
        return views(job, xyz, time_ns, tri, camera, frame, *rest)

    def build_atlas(px: np.ndarray, vc: np.ndarray, vf: np.ndarray, images: Any,
                    *rest: Any) -> texture.Atlas:  # fmt: skip
        def counted(c: int, frames: np.ndarray) -> Any:
            seen["asked"].append((c, frames.tolist()))
            return images(c, frames)

        seen["args"] = (px, vc, vf, *rest)
        atlas = build(px, vc, vf, counted, *rest)
        seen["atlas"] = replace(atlas, bgr=atlas.bgr.copy())  # as sampled: seams levelled after
        return atlas

    corner = texture.corner_pixels

    def corner_pixels(job: Any, xyz: np.ndarray, camera: np.ndarray, frame: np.ndarray,
                      uv: np.ndarray, *rest: Any) -> np.ndarray:  # fmt: skip
        seen.update(job=job, xyz=xyz, uv=uv)
        return corner(job, xyz, camera, frame, uv, *rest)

    monkeypatch.setattr(texture, "build_atlas", build_atlas)
    monkeypatch.setattr(view_selection, "select_views", select_views)
    monkeypatch.setattr(texture, "corner_pixels", corner_pixels)
    mj = prepare_mesh(truth.files, calibfile.load(calib_path), out, texels=T, chunk_s=chunk_s)
    mj.run()
    return Captured(seen["job"], seen["args"], seen["atlas"], seen["asked"], seen["xyz"],
                    seen["tri"], seen["camera"], seen["frame"], seen["uv"])  # fmt: skip


@pytest.fixture(scope="module")
def textured(short_drive: Drive, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Captured]:
    out = tmp_path_factory.mktemp("texture") / "t.glb"
    with pytest.MonkeyPatch.context() as mp:
        return out, _run(short_drive, out, mp)


def _session_images_of(files: list[Path], camera: str) -> tuple[np.ndarray, list[bytes]]:
    """Camera ``camera``'s frames' stamps and bytes, in the order of their stamps."""
    log = read_log(list(files), cameras=[camera])
    frames = log.cameras[camera]
    order = np.argsort(frames.frame_ns, kind="stable")
    return frames.frame_ns[order], [frames.jpegs[int(k)] for k in order]


def _texels_checked(cap: Captured, files: list[Path], n: int) -> dict[int, int]:
    """Check ``n`` texels of textured facets, one each (the facets drawn at random), against
    the frame decoded here, bilinearly sampled at the texel's point in the facet's
    projection, balanced by the frame's gains: within 2 levels. The texels checked, by
    camera."""
    px, view_cam, view_frame, gains = cap.args[:4]
    atlas = cap.atlas
    jpegs = {c: _session_images_of(files, cj.name)[1] for c, cj in enumerate(cap.job.cameras)}
    cols = atlas.image.shape[1] // T
    rng = np.random.default_rng(3)
    checked: dict[int, int] = {}
    for f in rng.choice(np.flatnonzero(atlas.textured), n, replace=False):
        c = int(view_cam[f])
        frame = decode_jpeg(jpegs[c][int(view_frame[f])])
        assert frame is not None
        s = atlas.slot[f]
        cx, cy = (s // 2) % cols, (s // 2) // cols
        q = texture.cell_corners(T)[s % 2]
        xs, ys = texture.half_texels(T)[s % 2]
        k = rng.integers(xs.size)
        w = np.linalg.solve(np.vstack([q.T, np.ones(3)]), [xs[k], ys[k], 1.0])
        u, v = w @ px[f].astype(np.float64)  # the texel's point in the frame
        h, wd = frame.shape[:2]
        u, v = np.clip(u, 0, wd - 1), np.clip(v, 0, h - 1)
        u0, v0 = min(int(u), wd - 2), min(int(v), h - 2)
        a, b = u - u0, v - v0
        patch = frame[v0 : v0 + 2, u0 : u0 + 2].astype(np.float64)
        bgr = (1 - b) * ((1 - a) * patch[0, 0] + a * patch[0, 1]) + b * (
            (1 - a) * patch[1, 0] + a * patch[1, 1]
        )
        want = np.clip(bgr[::-1] * np.exp(-gains.log_gain[c][view_frame[f]]), 0, 255)
        got = atlas.image[cy * T + ys[k], cx * T + xs[k]].astype(np.float64)
        assert np.abs(got - want).max() <= 2.0, (f, got, want)
        checked[c] = checked.get(c, 0) + 1
    return checked


def test_texels_are_the_decoded_frames_pixels_at_the_facets_projection(
    textured: tuple[Path, Captured], short_drive: Drive
) -> None:
    out, cap = textured
    px, view_cam, view_frame, _, fill, texels = cap.args
    atlas = cap.atlas
    assert texels == T
    seen = np.isfinite(px).all(axis=(1, 2))
    assert np.array_equal(atlas.textured, (view_cam >= 0) & seen)
    assert atlas.textured[view_cam >= 0].mean() > 0.95  # the camera sees one side only
    # each frame asked once; as many as the facets' distinct views
    pairs = [(c, f) for c, frames in cap.asked for f in frames]
    assert len(pairs) == len(set(pairs))
    used = view_cam >= 0
    assert set(pairs) == set(zip(view_cam[used].tolist(), view_frame[used].tolist(), strict=True))
    assert _texels_checked(cap, short_drive[0].files, 300) == {0: 300}
    # end to end, read back from the glb: the texture at each facet's middle is the
    # colour of its vertices, balanced alike (they were sampled at its corners)
    mesh = next(iter(trimesh.load(str(out)).geometry.values()))
    mid = mesh.visual.uv.reshape(-1, 3, 2).mean(axis=1)
    stored = np.asarray(mesh.visual.material.baseColorTexture.convert("RGB"))
    h, w = stored.shape[:2]
    x = np.clip((mid[:, 0] * w).astype(int), 0, w - 1)
    y = np.clip(((1 - mid[:, 1]) * h).astype(int), 0, h - 1)
    diff = np.abs(stored[y, x].astype(int) - fill.astype(int))[atlas.textured]
    assert np.median(diff) <= 6, np.percentile(diff, [50, 90])


def test_views_join_fewer_seams_than_the_vertices_own(textured: tuple[Path, Captured]) -> None:
    """On the short drive the views chosen (view_selection) leave fewer edges between two
    views than the frames most of each facet's vertices were coloured from."""
    _, cap = textured
    view_cam, view_frame = cap.args[1:3]
    own_cam, own_frame = texture.facet_views(cap.camera, cap.frame, cap.tri)
    a, b = view_selection.neighbours(cap.tri)

    def seams(cam: np.ndarray, frame: np.ndarray) -> float:
        key = (cam << 32) | frame
        return float(np.mean(key[a] != key[b]))

    chosen, own = seams(view_cam, view_frame), seams(own_cam, own_frame)
    assert chosen < 0.5 * own, (chosen, own)  # 4.7 % and 13.4 % when written
    assert 0.1 < np.mean((view_cam != own_cam) | (view_frame != own_frame)) < 0.5


def test_corners_are_where_the_colouring_saw_them(textured: tuple[Path, Captured]) -> None:
    """A corner coloured from its facet's frame keeps the colouring's pixel; the others
    are projected as the colouring projects: forced to project every vertex into its own
    frame, the pixels are the colouring's to a thousandth of a pixel."""
    _, cap = textured
    px, view_cam, view_frame = cap.args[:3]
    key = (cap.camera.astype(np.int64) << 32) | cap.frame
    own = (key[cap.tri] == ((view_cam << 32) | view_frame)[:, None]) & (view_cam >= 0)[:, None]
    assert np.array_equal(px[own], cap.uv[cap.tri][own])
    projected = 1 - own[view_cam >= 0].mean()
    # some corners projected: a facet's view need not be any of its vertices'
    assert 0.01 < projected < 0.9, projected
    ok = (cap.camera != NO_CAMERA) & (cap.frame >= 0)
    v = np.flatnonzero(ok)
    faces = v[:, None].repeat(3, axis=1)  # a "facet" per vertex, in its own frame
    none = np.full(cap.camera.size, NO_CAMERA, dtype=np.uint8)  # hide the colouring's uv
    got = texture.corner_pixels(cap.job, cap.xyz, none, cap.frame, cap.uv, faces,
                                cap.camera[v].astype(np.int64), cap.frame[v])  # fmt: skip
    assert np.nanmax(np.abs(got[:, 0] - cap.uv[v])) < 1e-3


def test_glb_has_its_texture_and_each_facets_uvs_lie_in_its_cell(
    textured: tuple[Path, Captured], short_drive: Drive, tmp_path: Path
) -> None:
    out, cap = textured
    assert made_by_acq(out)
    g = pygltflib.GLTF2().load(str(out))
    assert g.images[0].mimeType == "image/jpeg"
    # sampled without mipmaps: a coarser level would mix neighbouring facets' cells
    sampler = g.samplers[g.textures[0].sampler]
    assert (sampler.minFilter, sampler.magFilter) == (pygltflib.LINEAR, pygltflib.LINEAR)
    assert (sampler.wrapS, sampler.wrapT) == (pygltflib.CLAMP_TO_EDGE, pygltflib.CLAMP_TO_EDGE)
    pbr = g.materials[g.meshes[0].primitives[0].material].pbrMetallicRoughness
    assert pbr.baseColorTexture.index == 0
    assert g.meshes[0].primitives[0].attributes.COLOR_0 is None  # it would tint the texture
    # matte and untinted (glTF's default material is a metal)
    assert pbr.metallicFactor == 0 and pbr.roughnessFactor == 1
    assert pbr.baseColorFactor in (None, [1.0, 1.0, 1.0, 1.0])
    # a vertex per facet corner, drawn in order: no index buffer
    assert g.meshes[0].primitives[0].indices is None
    assert g.accessors[g.meshes[0].primitives[0].attributes.POSITION].count == cap.tri.size
    blob = g.binary_blob()
    view = g.bufferViews[g.images[0].bufferView]
    assert SOFTWARE.encode() in blob[view.byteOffset : view.byteOffset + 64]  # marked
    jpeg = Image.open(io.BytesIO(blob[view.byteOffset : view.byteOffset + view.byteLength]))
    stored = np.asarray(jpeg.convert("RGB")).astype(np.int16)
    assert stored.shape == cap.atlas.image.shape
    assert np.abs(stored - cap.atlas.image).mean() < 4  # JPEG's loss only
    mesh = next(iter(trimesh.load(str(out)).geometry.values()))
    assert isinstance(mesh.visual, trimesh.visual.TextureVisuals)
    uv = mesh.visual.uv.reshape(-1, 3, 2)
    assert mesh.faces.shape[0] == cap.tri.shape[0] == uv.shape[0]
    assert (uv >= 0).all() and (uv <= 1).all()
    h, w = cap.atlas.image.shape[:2]
    cols = w // T
    s = cap.atlas.slot
    assert np.array_equal(np.sort(s), np.arange(s.size))  # a half cell each, none shared
    cx, cy = (s // 2) % cols, (s // 2) // cols
    x, y = uv[..., 0] * w, (1 - uv[..., 1]) * h
    inside = (x > (cx * T)[:, None]) & (x < ((cx + 1) * T)[:, None])
    inside &= (y > (cy * T)[:, None]) & (y < ((cy + 1) * T)[:, None])
    assert inside.all()
    # the same facets as without a texture: each facet's corners its vertices
    plain = tmp_path / "p.ply"
    truth, calib = short_drive
    assert acq_main(["mesh", *map(str, truth.files), "--calib", str(calib), "-o",
                     str(plain)]) == 0  # fmt: skip
    data = PlyData.read(str(plain))
    v = data["vertex"].data
    xyz = np.stack([v["x"], v["y"], v["z"]], axis=1)
    faces = np.stack(data["face"].data["vertex_indices"]).astype(np.int64)
    world = trimesh.load(str(out)).to_geometry()  # the node's offset and turn applied
    glb_corners = np.asarray(world.vertices).reshape(-1, 3, 3) @ Y_UP  # back to z up
    assert mesh.vertices.shape[0] == 3 * faces.shape[0]
    assert np.abs(glb_corners - xyz[faces]).max() < 1e-3  # the same facets, in order
    # memory: the atlas is the facets' cells and at most one spare row
    cells = (cap.tri.shape[0] + 1) // 2
    assert cells * T * T <= h * w < (cells + cols) * T * T


def test_frames_read_from_the_log_per_tile_give_the_same_atlas(
    textured: tuple[Path, Captured], short_drive: Drive, tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
) -> None:  # fmt: skip
    """A log too big to hold: each tile reads its frames from the files."""
    _, cap = textured
    monkeypatch.setattr(drive, "READ_ONCE_BYTES", 0)
    again = _run(short_drive, tmp_path / "big.glb", monkeypatch)
    assert np.array_equal(again.atlas.image, cap.atlas.image)


def test_frames_are_decoded_once_the_atlas_sampling_what_the_colouring_kept(
    short_drive: Drive, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The colouring keeps each frame's pixels around its points (views.Crop); the atlas
    samples those, decoding again only a frame whose kept part misses a pixel its facets
    need: the same atlas as with every frame decoded again."""
    decodes: list[int] = []
    real = jpeg.decode_jpeg

    def counted(data: bytes) -> np.ndarray | None:
        decodes.append(len(data))
        return real(data)

    monkeypatch.setattr(jpeg, "decode_jpeg", counted)  # the atlas's decoder (the colouring's
    # decodes into its thread's buffer, without it)
    kept = _run(short_drive, tmp_path / "kept.glb", monkeypatch)
    asked = sum(len(frames) for _, frames in kept.asked)
    assert asked > 20 and len(decodes) <= asked // 20, (len(decodes), asked)
    decodes.clear()
    monkeypatch.setattr(Crop, "holds", lambda self, *pixels: False)
    again = _run(short_drive, tmp_path / "again.glb", monkeypatch)
    assert len(decodes) == asked  # each frame the facets use, decoded again
    assert np.array_equal(again.atlas.bgr, kept.atlas.bgr)
    assert np.array_equal(again.atlas.uv, kept.atlas.uv)


@pytest.mark.parametrize(
    ("suffix", "argv", "expect"),
    [
        (".ply", ["--texture"], "a PLY file holds vertex colours, not a texture"),
        (".glb", ["--texels", "8"], "--texels: only with --texture"),
        (".glb", ["--texture", "--texels", "3"], "--texels: expected texels in [4, 64]"),
    ],
)
def test_texture_options_refused_in_one_line(
    short_drive: Drive, tmp_path: Path, capsys: pytest.CaptureFixture[str],
    suffix: str, argv: list[str], expect: str,
) -> None:  # fmt: skip
    truth, calib = short_drive
    out = tmp_path / f"m{suffix}"
    assert acq_main(["mesh", *map(str, truth.files), "--calib", str(calib), "-o", str(out),
                     *argv]) == 2  # fmt: skip
    err = capsys.readouterr().err
    assert expect in err and err.count("\n") == 1 and err.startswith("acq mesh"), err
    assert list(tmp_path.iterdir()) == []


def test_an_atlas_too_large_for_viewers_is_refused_in_one_line(
    short_drive: Drive, tmp_path: Path, capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:  # fmt: skip
    """(The limit lowered: the short drive's one tile needs over 3,000 texels a side at 16.)"""
    monkeypatch.setattr(texture, "MAX_SIDE", 2048)
    truth, calib = short_drive
    out = tmp_path / "m.glb"
    assert acq_main(["mesh", *map(str, truth.files), "--calib", str(calib), "-o", str(out),
                     "--texture", "--texels", "16"]) == 2  # fmt: skip
    err = capsys.readouterr().err
    assert "--texture: m.glb: " in err and "use a shorter --tile-m" in err, err
    assert err.count("\n") == 1 and list(tmp_path.iterdir()) == []


def test_obj_with_its_mtl_and_jpeg_reads_back_as_the_glb(
    textured: tuple[Path, Captured], short_drive: Drive, tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:  # fmt: skip
    glb, cap = textured
    truth, calib = short_drive
    out = tmp_path / "t.obj"
    argv = ["mesh", *map(str, truth.files), "--calib", str(calib), "-o", str(out), "--texture",
            "--texels", str(T)]  # fmt: skip
    assert acq_main(argv) == 0
    capsys.readouterr()
    mtl, jpg = tmp_path / "t.mtl", tmp_path / "t.jpg"
    assert all(made_by_acq(p) for p in (out, mtl, jpg))
    assert f"map_Kd {jpg.name}" in mtl.read_text()
    obj = trimesh.load(str(out), process=False)
    assert isinstance(obj.visual, trimesh.visual.TextureVisuals)
    image = np.asarray(obj.visual.material.image.convert("RGB")).astype(np.int16)
    assert image.shape == cap.atlas.image.shape
    assert np.abs(image - cap.atlas.image).mean() < 3  # JPEG's loss only
    glb_mesh = next(iter(trimesh.load(str(glb)).geometry.values()))
    uv_obj = obj.visual.uv[obj.faces]
    assert uv_obj.shape[0] == cap.tri.shape[0]
    assert np.abs(uv_obj - glb_mesh.visual.uv.reshape(-1, 3, 2)).max() < 1e-6
    # its positions shared: one "v" line a vertex, one "vt" a facet corner
    text = out.read_text()
    assert text.count("\nvt ") == 3 * cap.tri.shape[0]
    assert text.count("\nv ") == np.unique(cap.tri).size
    # a JPEG of someone else's where the texture would go: refused, kept, nothing written
    other = tmp_path / "o"
    other.mkdir()
    foreign = other / "t.jpg"
    foreign.write_bytes(jpg.read_bytes()[:2] + jpg.read_bytes()[2:].replace(b"acq ", b"xyz ", 1))
    assert not made_by_acq(foreign)
    argv[argv.index(str(out))] = str(other / "t.obj")
    assert acq_main(argv) == 2
    err = capsys.readouterr().err
    assert "t.jpg" in err and "not written by acq" in err and err.count("\n") == 1, err
    assert sorted(p.name for p in other.iterdir()) == ["t.jpg"]


def test_chunks_give_the_same_facets_and_texture(
    textured: tuple[Path, Captured], short_drive: Drive, tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
) -> None:  # fmt: skip
    """In chunks of 1 s, each with its own colour balance, kept by session frame: the
    same views, and texels that differ only by the chunks' balance."""
    _, cap = textured
    again = _run(short_drive, tmp_path / "c.glb", monkeypatch, chunk_s=1.0)

    def by_facet(c: Captured) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(facets, views, texel at each facet's middle) in the order of their vertices."""
        tri = np.sort(c.tri, axis=1)
        order = np.lexsort(tri.T[::-1])
        mid = c.atlas.uv.mean(axis=1)
        h, w = c.atlas.image.shape[:2]
        x = (mid[:, 0] * w).astype(int)
        y = ((1 - mid[:, 1]) * h).astype(int)
        views = np.stack([c.args[1], c.args[2]], axis=1)
        return tri[order], views[order], c.atlas.image[y, x][order].astype(int)

    tri, views, texel = by_facet(cap)
    tri_c, views_c, texel_c = by_facet(again)
    assert np.array_equal(tri_c, tri) and np.array_equal(views_c, views)
    gains = again.args[3]
    assert gains is not None and np.count_nonzero(gains.log_gain[0]) > 0
    diff = np.abs(texel_c - texel)
    assert np.median(diff) <= 2 and diff.mean() < 4, (np.median(diff), diff.mean())


def test_two_cameras_each_texture_their_facets(
    tmp_path_factory: pytest.TempPathFactory, monkeypatch: pytest.MonkeyPatch
) -> None:
    from acq.sim.drive_log import write_drive_log
    from acq.sim.world import default_rig

    d = tmp_path_factory.mktemp("two")
    truth = write_drive_log(d, 0.6, rig=default_rig(cameras=2))
    calib = d / "calib.yaml"
    calibfile.save(truth.calibration, calib)
    cap = _run((truth, calib), d / "t.glb", monkeypatch)
    view_cam = cap.args[1]
    assert set(np.unique(view_cam).tolist()) == {0, 1}
    assert cap.atlas.textured[view_cam >= 0].mean() > 0.95
    checked = _texels_checked(cap, truth.files, 200)
    assert checked.get(0, 0) > 20 and checked.get(1, 0) > 20, checked
