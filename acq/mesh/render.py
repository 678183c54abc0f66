"""A small software rasteriser: a triangle mesh or a point cloud seen by a virtual pinhole.

:func:`rasterise` draws the triangles into a depth buffer (numba, one pass over the
facets, no back-face culling: a street is seen from both sides) and keeps per pixel the
nearest facet and its perspective-correct barycentric weights (a visibility buffer);
shading is a separate step on those weights: :func:`vertex_colours` interpolates
per-vertex colours; :func:`texture_colours` interpolates a textured mesh's texture
coordinates per facet corner with the same weights and samples its image (bilinear).
:func:`splat` draws a coloured cloud into the same camera: each point a square whose side
is ``size_m`` metres at its depth (at least one pixel), z-buffered.

Cameras are :class:`acq.camera.camera_models.Pinhole` without distortion and a pose
``world_to_camera`` (:class:`acq.geometry.transforms.Rigid`: x right, y down, z forward);
pixel centres are at integers, metres in the world frame. Facets with a corner nearer
than ``NEAR_M`` (or behind the camera) are not drawn: the meshes are of small facets.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numba
import numpy as np

from acq.camera.camera_models import Pinhole
from acq.geometry.transforms import Rigid

__all__ = [
    "NEAR_M",
    "Raster",
    "View",
    "look_at",
    "rasterise",
    "render_mesh",
    "render_textured",
    "splat",
    "texture_colours",
    "vertex_colours",
]

NEAR_M = 0.05  # nearest depth drawn, m


@dataclass(frozen=True)
class View:
    """A virtual pinhole camera (no distortion) at pose ``world_to_camera``."""

    camera: Pinhole
    world_to_camera: Rigid

    def __post_init__(self) -> None:
        if any(self.camera.dist):
            raise ValueError("the rasteriser draws through undistorted pinholes only")

    @property
    def shape(self) -> tuple[int, int]:
        """(height, width) px."""
        return self.camera.height, self.camera.width

    def pixels(self, xyz: np.ndarray) -> np.ndarray:
        """(N,3) world points, m -> (N,3) (u px, v px, depth m) in this camera; depth is
        the camera-frame z (u, v are not finite where it is 0)."""
        P = self.world_to_camera.apply(np.asarray(xyz, np.float64).reshape(-1, 3))
        c = self.camera
        out = np.empty_like(P)
        with np.errstate(divide="ignore", invalid="ignore"):
            out[:, 0] = c.fx * P[:, 0] / P[:, 2] + c.cx
            out[:, 1] = c.fy * P[:, 1] / P[:, 2] + c.cy
        out[:, 2] = P[:, 2]
        return out

    def rays(self) -> tuple[np.ndarray, np.ndarray]:
        """The camera centre (3,) and (H*W,3) unit world directions of its pixels' rays,
        row by row."""
        c = self.camera
        v, u = np.mgrid[0 : c.height, 0 : c.width].astype(np.float64)
        d = np.stack([(u.ravel() - c.cx) / c.fx, (v.ravel() - c.cy) / c.fy,
                      np.ones(u.size)], axis=1)  # fmt: skip
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        to_world = self.world_to_camera.inverse()
        return to_world.translation.copy(), d @ to_world.rotation.T


def look_at(eye: np.ndarray, target: np.ndarray, up: np.ndarray | None = None) -> Rigid:
    """The world -> camera pose of a camera at ``eye`` looking at ``target`` (world m),
    image up towards ``up`` (default +z). ValueError if the view is along ``up``."""
    eye, target = np.asarray(eye, np.float64), np.asarray(target, np.float64)
    up = np.array([0.0, 0.0, 1.0]) if up is None else np.asarray(up, np.float64)
    z = target - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, up)
    n = np.linalg.norm(x)
    if not n > 1e-9:
        raise ValueError("look_at: the view direction is along 'up'")
    x /= n
    y = np.cross(z, x)
    R = np.stack([x, y, z])  # rows: the camera's axes in the world
    return Rigid(R, -R @ eye)


@dataclass(frozen=True)
class Raster:
    """Per pixel (H,W): ``face`` the nearest facet (-1 none), ``weights`` (H,W,3) its
    corners' perspective-correct barycentric weights, ``depth`` m (+inf none)."""

    face: np.ndarray
    weights: np.ndarray
    depth: np.ndarray

    @property
    def mask(self) -> np.ndarray:
        """(H,W) bool: pixels a facet covers."""
        covered: np.ndarray = self.face >= 0
        return covered


@numba.njit(cache=True, error_model="numpy")
def _raster(uvz, faces, near, depth, face, weights):  # type: ignore[no-untyped-def]
    """Draw triangles ``faces`` (F,3) of projected vertices ``uvz`` (V,3) into the
    buffers (H,W) in place; a pixel is inside when its centre is (edges included)."""
    H, W = depth.shape
    for f in range(faces.shape[0]):
        a, b, c = faces[f, 0], faces[f, 1], faces[f, 2]
        za, zb, zc = uvz[a, 2], uvz[b, 2], uvz[c, 2]
        if not (za > near and zb > near and zc > near):  # also False for NaN
            continue
        ua, va = uvz[a, 0], uvz[a, 1]
        ub, vb = uvz[b, 0], uvz[b, 1]
        uc, vc = uvz[c, 0], uvz[c, 1]
        area = (ub - ua) * (vc - va) - (vb - va) * (uc - ua)
        if not abs(area) > 1e-12:
            continue
        # clamped as floats: a corner just past the near plane projects far off-screen
        x0 = int(max(0.0, np.ceil(min(ua, ub, uc))))
        x1 = int(min(W - 1.0, np.floor(max(ua, ub, uc))))
        y0 = int(max(0.0, np.ceil(min(va, vb, vc))))
        y1 = int(min(H - 1.0, np.floor(max(va, vb, vc))))
        ia, ib, ic = 1.0 / za, 1.0 / zb, 1.0 / zc
        for y in range(y0, y1 + 1):
            for x in range(x0, x1 + 1):
                wa = ((ub - x) * (vc - y) - (vb - y) * (uc - x)) / area
                wb = ((uc - x) * (va - y) - (vc - y) * (ua - x)) / area
                wc = 1.0 - wa - wb
                if wa < 0.0 or wb < 0.0 or wc < 0.0:
                    continue
                inv = wa * ia + wb * ib + wc * ic  # 1/z is linear on the screen
                z = 1.0 / inv
                if z < depth[y, x]:
                    depth[y, x] = z
                    face[y, x] = f
                    weights[y, x, 0] = wa * ia * z
                    weights[y, x, 1] = wb * ib * z
                    weights[y, x, 2] = wc * ic * z


def rasterise(view: View, xyz: np.ndarray, faces: np.ndarray) -> Raster:
    """The facets ``faces`` (F,3) int of vertices ``xyz`` (V,3) world m as ``view`` sees
    them."""
    H, W = view.shape
    depth = np.full((H, W), np.inf)
    face = np.full((H, W), -1, np.int64)
    weights = np.zeros((H, W, 3), np.float32)
    uvz = np.ascontiguousarray(view.pixels(xyz))
    _raster(uvz, np.ascontiguousarray(faces, np.int64), NEAR_M, depth, face, weights)
    return Raster(face, weights, depth)


def vertex_colours(raster: Raster, faces: np.ndarray, rgb: np.ndarray) -> np.ndarray:
    """(H,W,3) uint8: the per-vertex colours ``rgb`` (V,3) uint8 interpolated over each
    pixel's facet; black where none."""
    H, W = raster.face.shape
    out = np.zeros((H, W, 3), np.uint8)
    hit = raster.mask
    corners = np.asarray(faces)[raster.face[hit]]  # (K,3) vertex indices
    c = np.asarray(rgb, np.float32)[corners]  # (K,3 corners,3 channels)
    mixed = np.einsum("kj,kjc->kc", raster.weights[hit], c)
    out[hit] = np.clip(np.rint(mixed), 0, 255).astype(np.uint8)
    return out


def render_mesh(
    view: View, xyz: np.ndarray, faces: np.ndarray, rgb: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The mesh with per-vertex colours ``rgb`` (V,3) uint8 as ``view`` sees it: (H,W,3)
    uint8 image (black where empty) and (H,W) bool mask of covered pixels."""
    raster = rasterise(view, xyz, faces)
    return vertex_colours(raster, faces, rgb), raster.mask


def texture_colours(raster: Raster, uv: np.ndarray, image: np.ndarray) -> np.ndarray:
    """(H,W,3) uint8: the texture ``image`` (h,w,3) uint8 sampled (bilinear, edges
    replicated) at each pixel's texture coordinates, its facet's corners' ``uv`` (F,3,2)
    interpolated; black where no facet. Texture coordinates in [0, 1] from the image's
    bottom-left corner (v up, as OBJ and trimesh have them; glTF's v runs down)."""
    H, W = raster.face.shape
    hit = raster.mask
    at = np.einsum("kj,kjc->kc", raster.weights[hit], np.asarray(uv, np.float32)[raster.face[hit]])
    h, w = image.shape[:2]
    # texture coordinates measure from the image's edges, remap's pixels from texel centres
    mx = np.full((H, W), -1.0, np.float32)
    my = np.full((H, W), -1.0, np.float32)
    mx[hit] = at[:, 0] * w - 0.5
    my[hit] = (1.0 - at[:, 1]) * h - 0.5
    got = cv2.remap(np.ascontiguousarray(image), mx, my, cv2.INTER_LINEAR,
                    borderMode=cv2.BORDER_REPLICATE)  # fmt: skip
    got[~hit] = 0
    out: np.ndarray = got
    return out


def render_textured(
    view: View, xyz: np.ndarray, faces: np.ndarray, uv: np.ndarray, image: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The mesh textured with ``image`` at its facet corners' ``uv`` (F,3,2)
    (:func:`texture_colours`) as ``view`` sees it: (H,W,3) uint8 image (black where empty)
    and (H,W) bool mask of covered pixels."""
    raster = rasterise(view, xyz, faces)
    return texture_colours(raster, uv, image), raster.mask


@numba.njit(cache=True, error_model="numpy")
def _splat(uvz, half, near, depth, index):  # type: ignore[no-untyped-def]
    """Draw each point as a square of half side ``half[i]`` px around its pixel into
    the buffers (H,W) in place, nearest first."""
    H, W = depth.shape
    for i in range(uvz.shape[0]):
        z = uvz[i, 2]
        if not z > near:
            continue
        u, v = uvz[i, 0], uvz[i, 1]
        h = half[i]
        x0 = int(max(0.0, np.ceil(u - h)))
        x1 = int(min(W - 1.0, np.floor(u + h)))
        y0 = int(max(0.0, np.ceil(v - h)))
        y1 = int(min(H - 1.0, np.floor(v + h)))
        for y in range(y0, y1 + 1):
            for x in range(x0, x1 + 1):
                if z < depth[y, x]:
                    depth[y, x] = z
                    index[y, x] = i


def splat(
    view: View, xyz: np.ndarray, rgb: np.ndarray, size_m: float
) -> tuple[np.ndarray, np.ndarray]:
    """The points ``xyz`` (N,3) world m coloured ``rgb`` (N,3) uint8 as ``view`` sees them,
    each a square ``size_m`` metres wide at its depth (at least one pixel): (H,W,3) uint8
    image and (H,W) bool mask of covered pixels."""
    if not size_m > 0:
        raise ValueError(f"splat size {size_m} m: expected > 0")
    H, W = view.shape
    uvz = np.ascontiguousarray(view.pixels(xyz))
    f = 0.5 * (view.camera.fx + view.camera.fy)
    with np.errstate(divide="ignore", invalid="ignore"):
        half = np.maximum(0.5 * size_m * f / uvz[:, 2], 0.5)
    depth = np.full((H, W), np.inf)
    index = np.full((H, W), -1, np.int64)
    _splat(uvz, np.ascontiguousarray(half), NEAR_M, depth, index)
    mask: np.ndarray = index >= 0
    out = np.zeros((H, W, 3), np.uint8)
    out[mask] = np.asarray(rgb, np.uint8)[index[mask]]
    return out, mask
