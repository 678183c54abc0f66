"""The drive's mesh and cloud seen from virtual viewpoints along the street, beside the truth.

Three viewpoints at three places along the drive (:func:`street_views`): the left
facades and the right facades seen from the road at 1.5 m, and an oblique view from 5 m
up, 5 m behind, looking ahead over the left side of the street. From each, the mesh is
rasterised (:func:`acq.mesh.render.render_mesh`, per-vertex colours; a textured mesh
of `acq mesh --texture` with :func:`acq.mesh.render.render_textured`), the cloud splatted
(:func:`acq.mesh.render.splat`) and the TRUE street ray-cast (:func:`acq.sim.raycast.cast`,
the simulator's own surface colours) through the same pinhole. :func:`likeness` compares
a render with the truth where the street is visible (the truth hits a surface, not the
sky) and the render covers it: the share of those pixels within ``TOLERANCE`` (0-255) in
every channel, and the PSNR (dB). :func:`picture` lays the views out side by side.

Metres in the street's frame (x along the street, y left, z up); seconds of the
simulator's clock; images RGB uint8.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from acq.camera.camera_models import Pinhole
from acq.mesh.files import Y_UP, glb_colours
from acq.mesh.render import View, look_at, render_mesh, render_textured, splat
from acq.mesh.texture import MAX_SIDE
from acq.sim.raycast import cast
from acq.sim.world import Material, Street, Trajectory

__all__ = [
    "TOLERANCE",
    "Likeness",
    "TexturedMesh",
    "ViewsResult",
    "compare",
    "likeness",
    "picture",
    "read_mesh",
    "read_textured_mesh",
    "resolution_ceiling",
    "street_views",
    "truth_image",
]

TOLERANCE = 24  # a pixel agrees when every channel is within this of the truth (0-255)
EYE_M = 1.5  # the facade views' height above the road, m
WIDTH, HEIGHT, FOV_DEG = 320, 240, 75.0  # each view's size (px) and horizontal field


@dataclass(frozen=True)
class Likeness:
    """A render against the truth: ``street`` pixels where the truth hits a surface,
    ``covered`` the share of them the render covers, ``within`` the share of those
    covered that agree within ``TOLERANCE`` in every channel, ``psnr_db`` over them."""

    street: int
    covered: float
    within: float
    psnr_db: float

    def text(self) -> str:
        return (
            f"{100 * self.within:.1f} % within {TOLERANCE}/255, {self.psnr_db:.1f} dB, "
            f"covers {100 * self.covered:.0f} %"
        )


def street_views(
    trajectory: Trajectory, times_s: Sequence[float], width: int = WIDTH, height: int = HEIGHT,
    fov_deg: float = FOV_DEG,
) -> dict[str, View]:  # fmt: skip
    """Three views (module docstring) at the vehicle's places at ``times_s`` (three s):
    ``left`` at the first, ``right`` at the second, ``oblique`` at the third."""
    if len(times_s) != 3:
        raise ValueError(f"three times, one a view: got {len(times_s)}")
    f = 0.5 * width / math.tan(math.radians(fov_deg) / 2)
    camera = Pinhole(width, height, f, f, (width - 1) / 2, (height - 1) / 2)
    R, p = trajectory.poses(np.asarray(times_s, np.float64))
    views: dict[str, View] = {}
    for name, Rk, pk in zip(("left", "right", "oblique"), R, p, strict=True):
        ahead = np.array([Rk[0, 0], Rk[1, 0], 0.0])
        ahead /= np.linalg.norm(ahead)
        left = np.array([-ahead[1], ahead[0], 0.0])
        road = np.array([pk[0], pk[1], 0.0])
        up = np.array([0.0, 0.0, 1.0])
        eye = road + EYE_M * up
        if name == "oblique":
            pose = look_at(road - 5.0 * ahead + 5.0 * up, road + 10.0 * ahead + 4.0 * left)
        else:
            pose = look_at(eye, eye + (10.0 if name == "left" else -10.0) * left)
        views[name] = View(camera, pose)
    return views


def truth_image(street: Street, view: View) -> tuple[np.ndarray, np.ndarray]:
    """The true street through ``view``: (H,W,3) uint8 RGB and (H,W) bool where a ray
    hits a surface (not the sky)."""
    origin, dirs = view.rays()
    hit = cast(street, origin, dirs)
    H, W = view.shape
    seen = np.isfinite(hit.distance) & (hit.material != Material.SKY)
    rgb = hit.colour[:, ::-1].reshape(H, W, 3)
    return np.ascontiguousarray(rgb), seen.reshape(H, W)


def likeness(
    render: np.ndarray, covered: np.ndarray, truth: np.ndarray, street: np.ndarray
) -> Likeness:
    """``render`` (H,W,3) uint8 with ``covered`` (H,W) bool against ``truth`` (H,W,3)
    where ``street`` (H,W) bool (:class:`Likeness`; NaN shares where there is nothing to
    compare, PSNR +inf for identical pixels)."""
    both = covered & street
    n = int(street.sum())
    k = int(both.sum())
    if k == 0:
        return Likeness(n, 0.0 if n else math.nan, math.nan, math.nan)
    d = render[both].astype(np.int32) - truth[both].astype(np.int32)
    within = float((np.abs(d) <= TOLERANCE).all(axis=1).mean())
    mse = float(np.mean(d.astype(np.float64) ** 2))
    psnr = math.inf if mse == 0 else 10.0 * math.log10(255.0**2 / mse)
    return Likeness(n, k / n, within, psnr)


@dataclass(frozen=True)
class TexturedMesh:
    """A textured mesh: vertices ``xyz`` (V,3) m, ``faces`` (F,3), each facet corner's
    texture coordinates ``uv`` (F,3,2) (v up) in ``image`` (h,w,3) uint8 RGB."""

    xyz: np.ndarray
    faces: np.ndarray
    uv: np.ndarray
    image: np.ndarray


@dataclass(frozen=True)
class ViewsResult:
    """Per view (in order): its name, the truth, the mesh's and the cloud's renders, and
    each render's likeness to the truth; ``mesh`` and ``cloud`` over all views pooled;
    with a textured mesh, its render per view and likeness in ``textured_views`` (else
    empty) and pooled in ``textured``."""

    names: list[str]
    images: list[tuple[np.ndarray, np.ndarray, np.ndarray]]  # truth, mesh, cloud (RGB)
    per_view: list[tuple[Likeness, Likeness]]  # mesh, cloud
    mesh: Likeness
    cloud: Likeness
    textured_views: list[tuple[np.ndarray, Likeness]] = field(default_factory=list)
    textured: Likeness | None = None


def compare(
    street: Street,
    views: dict[str, View],
    mesh: tuple[np.ndarray, np.ndarray, np.ndarray],
    cloud: tuple[np.ndarray, np.ndarray],
    splat_m: float,
    textured: TexturedMesh | None = None,
) -> ViewsResult:
    """Render ``mesh`` (vertices (V,3) m, faces (F,3), RGB (V,3) uint8) and splat ``cloud``
    (points (N,3) m, RGB (N,3) uint8; squares of ``splat_m`` m) from each view, and the
    ``textured`` mesh if given; compare each with the truth."""
    images, per_view, textured_views = [], [], []
    pooled: dict[str, list[np.ndarray]] = {"truth": [], "street": [], "mesh": [], "mesh_in": [],
                                           "cloud": [], "cloud_in": [], "tex": [],
                                           "tex_in": []}  # fmt: skip
    for view in views.values():
        truth, seen = truth_image(street, view)
        m_img, m_in = render_mesh(view, *mesh)
        c_img, c_in = splat(view, cloud[0], cloud[1], splat_m)
        images.append((truth, m_img, c_img))
        per_view.append((likeness(m_img, m_in, truth, seen), likeness(c_img, c_in, truth, seen)))
        drawn = [truth, seen, m_img, m_in, c_img, c_in]
        if textured is not None:
            t = textured
            t_img, t_in = render_textured(view, t.xyz, t.faces, t.uv, t.image)
            textured_views.append((t_img, likeness(t_img, t_in, truth, seen)))
            drawn += [t_img, t_in]
        for key, a in zip(pooled, drawn, strict=False):
            pooled[key].append(a)
    cat = {k: np.concatenate(v) for k, v in pooled.items() if v}
    return ViewsResult(
        list(views), images, per_view,
        likeness(cat["mesh"], cat["mesh_in"], cat["truth"], cat["street"]),
        likeness(cat["cloud"], cat["cloud_in"], cat["truth"], cat["street"]),
        textured_views,
        None if textured is None
        else likeness(cat["tex"], cat["tex_in"], cat["truth"], cat["street"]),
    )  # fmt: skip


def resolution_ceiling(
    street: Street, views: dict[str, View], px_per_rad: float
) -> tuple[dict[str, Likeness], Likeness]:
    """What a texture seen at ``px_per_rad`` (a camera's resolution on the surface, px per
    radian at its axis) can reach at best: per view the TRUE street cast at that
    resolution (the view's pose and field, its size scaled), resampled bilinearly to the
    view's size and compared with the truth at the view's own; (per view by name, pooled
    over ``views``): what is lost at edges between colours by seeing them coarser,
    whatever the texture's geometry, view or colours."""
    got, truth_px, street_px, each = [], [], [], {}
    for name, view in views.items():
        cam = view.camera
        s = px_per_rad / cam.fx
        W, H = max(2, round(cam.width * s)), max(2, round(cam.height * s))
        fx, fy = cam.fx * W / cam.width, cam.fy * H / cam.height
        coarse_cam = Pinhole(width=W, height=H, fx=fx, fy=fy, cx=(W - 1) / 2, cy=(H - 1) / 2)
        coarse, _ = truth_image(street, View(coarse_cam, view.world_to_camera))
        truth, seen = truth_image(street, view)
        up = cv2.resize(coarse, (cam.width, cam.height), interpolation=cv2.INTER_LINEAR)
        each[name] = likeness(up, np.ones_like(seen), truth, seen)
        got.append(up)
        truth_px.append(truth)
        street_px.append(seen)
    every = np.concatenate(street_px)
    pooled = likeness(np.concatenate(got), np.ones_like(every), np.concatenate(truth_px), every)
    return each, pooled


def picture(result: ViewsResult, title: str) -> np.ndarray:
    """(H,W,3) uint8 RGB: a row per view (truth, mesh, cloud, and the textured mesh if
    ``result`` has it), each panel captioned with its figures, ``title`` on top."""
    band = 16
    font, scale = cv2.FONT_HERSHEY_SIMPLEX, 0.36

    def captioned(img: np.ndarray, text: str) -> np.ndarray:
        top = np.full((band, img.shape[1], 3), 255, np.uint8)
        cv2.putText(top, text, (3, band - 5), font, scale, (0, 0, 0), 1, cv2.LINE_AA)
        return np.vstack([top, img])

    rows = []
    for k, (name, (truth, m_img, c_img), (m, c)) in enumerate(
        zip(result.names, result.images, result.per_view, strict=True)
    ):
        panels = [
            captioned(truth, f"{name}: the true street"),
            captioned(m_img, f"mesh: {m.text()}"),
            captioned(c_img, f"cloud: {c.text()}"),
        ]
        if result.textured_views:
            t_img, t = result.textured_views[k]
            panels.insert(2, captioned(t_img, f"textured: {t.text()}"))
        rows.append(np.hstack(panels))
    body = np.vstack(rows)
    head = np.full((band + 4, body.shape[1], 3), 255, np.uint8)
    cv2.putText(head, title, (3, band - 1), font, scale + 0.06, (0, 0, 0), 1, cv2.LINE_AA)
    return np.vstack([head, body])


def read_mesh(glb: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A ``.glb`` of `acq mesh` read back through trimesh: vertices (V,3) m in the world
    frame (the node's matrix applied, glTF's +y up turned back to z up), faces (F,3) and
    vertex colours (V,3) uint8 sRGB (its linear COLOR_0 through
    :func:`acq.mesh.files.glb_colours`: trimesh takes it as it is)."""
    g = _triangles(glb)
    rgb = glb_colours(glb)
    if len(rgb) != len(g.vertices):
        raise ValueError(f"{glb}: {len(rgb)} vertex colours for {len(g.vertices)} vertices")
    return np.asarray(g.vertices) @ Y_UP, np.asarray(g.faces), rgb


def read_textured_mesh(glb: Path) -> TexturedMesh:
    """A ``.glb`` of `acq mesh --texture` read back through trimesh (as :func:`read_mesh`):
    its TEXCOORD_0 (trimesh turns glTF's v down to v up) and its embedded base colour
    texture."""
    from PIL import Image
    from trimesh.visual import TextureVisuals

    # Pillow warns of (and past twice its limit refuses) images over 89 Mpx; an atlas
    # of acq mesh may be up to MAX_SIDE a side
    limit = Image.MAX_IMAGE_PIXELS
    Image.MAX_IMAGE_PIXELS = max(limit or 0, MAX_SIDE**2)
    try:
        g = _triangles(glb)
    finally:
        Image.MAX_IMAGE_PIXELS = limit
    visual = g.visual
    texture = getattr(getattr(visual, "material", None), "baseColorTexture", None)
    if not isinstance(visual, TextureVisuals) or visual.uv is None or texture is None:
        raise ValueError(f"{glb}: not a triangle mesh with a texture")
    faces = np.asarray(g.faces)
    uv = np.asarray(visual.uv, np.float32)[faces]
    image = np.ascontiguousarray(np.asarray(texture.convert("RGB"), np.uint8))
    return TexturedMesh(np.asarray(g.vertices) @ Y_UP, faces, uv, image)


def _triangles(glb: Path) -> Any:
    """The one triangle mesh of ``glb`` (trimesh), its node's matrix applied."""
    import trimesh

    g = trimesh.load_scene(glb).to_geometry()
    if not isinstance(g, trimesh.Trimesh):
        raise ValueError(f"{glb}: not a triangle mesh")
    return g
