"""A mesh's file, by its suffix (:func:`write`): binary PLY, glTF 2.0 binary (``.glb``)
or OBJ, each with per-vertex colour and acq's mark (:mod:`acq.provenance`), written whole
or not at all (a temporary beside it, renamed).

- PLY: x y z double (m), red green blue uchar, faces; the mark a header comment.
- glb (pygltflib, the vertices in the order given): positions float32 relative to the
  file's first vertex, that offset and the turn from the world's z up to glTF's +y up in
  the node's matrix (JSON doubles: a CRS's coordinates keep their millimetres); COLOR_0
  per vertex, linear as glTF defines it (:func:`gltf_colours`; 16 bits: sRGB's 8 come
  back exactly, :func:`glb_colours`); the mark ``asset.generator``, the comments in
  ``asset.extras.acq``. Textured (:class:`acq.mesh.texture.Atlas`): a vertex per facet
  corner with its TEXCOORD_0, the atlas a JPEG baseColorTexture, no COLOR_0.
- OBJ: ``v x y z r g b`` (the vertex-colour extension that Blender, MeshLab,
  CloudCompare and trimesh read; colours 0..1), 1-based ``f a b c``; the mark and the
  comments ``#`` lines at the top. Textured: ``v x y z``, ``vt u v`` per facet corner,
  ``f a/i b/j c/k``, with ``mtllib OUT.mtl`` (marked as the OBJ) naming ``OUT.jpg`` (a
  JPEG comment its mark).
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, TextIO

import numpy as np

from acq.atomic_write import atomic
from acq.cloud import ply
from acq.extras import needs
from acq.output_suffix import suffix_format
from acq.provenance import SOFTWARE, marked_image

if TYPE_CHECKING:
    from acq.mesh.texture import Atlas

__all__ = [
    "SUFFIXES",
    "Y_UP",
    "format_of",
    "glb_colours",
    "gltf_colours",
    "srgb_of_gltf",
    "texture_files",
    "write",
]

SUFFIXES = (".ply", ".glb", ".obj")
# a glb's atlas, as the OBJ's (at 75: 0.5 points less like the truth, 8 % smaller)
GLB_JPEG_QUALITY = 95
# the world's (x, y, z), z up, as glTF's (x, y, z), +y up
Y_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])


def format_of(output: Path, option: str = "-o") -> str:
    """The format ``output``'s suffix names ("ply", "glb", "obj"); InputValueError naming
    ``option`` and the accepted suffixes for any other."""
    return suffix_format(output, SUFFIXES, "mesh", option)


def write(
    path: Path, xyz: np.ndarray, rgb: np.ndarray, faces: np.ndarray,
    comments: Sequence[str] = (), texture: Atlas | None = None,
) -> int:  # fmt: skip
    """Write the triangles ``faces`` (F,3) int of the vertices ``xyz`` (V,3) m coloured
    ``rgb`` (V,3) uint8 to ``path`` in the format of its suffix, marked as acq's, with
    ``comments`` (one line each); the bytes written. ``texture`` (glb or OBJ): the
    facets' atlas instead of the vertex colours (an OBJ's in OUT.mtl and OUT.jpg
    beside it, :func:`texture_files`)."""
    kind = format_of(path)
    lines = [f"{SOFTWARE} facets: x y z metres", *comments]
    if texture is not None and kind == "ply":
        raise ValueError(f"{path}: a PLY file holds vertex colours, not a texture")
    if kind == "ply":
        return ply.write_mesh(path, xyz, rgb, faces, lines)
    if kind == "glb":
        return _write_glb(path, xyz, rgb, faces, lines, texture)
    if texture is None:
        return _write_obj(path, xyz, rgb, faces, lines)
    return _write_textured_obj(path, xyz, faces, lines, texture)


def gltf_colours(rgb: np.ndarray) -> np.ndarray:
    """(V,4) uint16: sRGB colours ``rgb`` (V,3) uint8 as glTF's COLOR_0 holds them, linear
    (normalised to 0..65535), opaque: a viewer shows the colours given, not paler ones."""
    c = np.asarray(rgb, np.float64) / 255.0
    linear = np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)
    out = np.full((len(c), 4), 65535, np.uint16)
    out[:, :3] = np.round(linear * 65535.0)
    return out


def srgb_of_gltf(values: np.ndarray) -> np.ndarray:
    """(V,3) uint8 sRGB of COLOR_0 ``values`` (V,3|4) uint16 normalised linear: the
    inverse of :func:`gltf_colours`, exact on what it wrote."""
    c = np.asarray(values, np.float64)[:, :3] / 65535.0
    s = np.where(c <= 0.0031308, 12.92 * c, 1.055 * c ** (1 / 2.4) - 0.055)
    out: np.ndarray = np.clip(np.round(s * 255.0), 0, 255).astype(np.uint8)
    return out


def glb_colours(path: Path) -> np.ndarray:
    """(V,3) uint8 sRGB: the vertex colours (COLOR_0) of the one mesh of a glb that acq
    wrote (uint16 normalised, linear); ValueError if it has none or another kind."""
    import pygltflib as gl

    g = gl.GLTF2().load(str(path))
    k = g.meshes[0].primitives[0].attributes.COLOR_0
    if k is None:
        raise ValueError(f"{path}: no vertex colours (COLOR_0)")
    acc = g.accessors[k]
    if acc.componentType != gl.UNSIGNED_SHORT or acc.type not in (gl.VEC3, gl.VEC4):
        raise ValueError(f"{path}: COLOR_0 not of 16-bit normalised values")
    view = g.bufferViews[acc.bufferView]
    start = (view.byteOffset or 0) + (acc.byteOffset or 0)
    width = 3 if acc.type == gl.VEC3 else 4
    raw = np.frombuffer(g.binary_blob(), np.uint16, acc.count * width, start)
    return srgb_of_gltf(raw.reshape(acc.count, width))


def texture_files(path: Path) -> tuple[Path, Path]:
    """The material (.mtl) and the image (.jpg) beside a textured OBJ ``path``."""
    return path.with_suffix(".mtl"), path.with_suffix(".jpg")


def _write_glb(
    path: Path, xyz: np.ndarray, rgb: np.ndarray, faces: np.ndarray, lines: Sequence[str],
    texture: Atlas | None,
) -> int:  # fmt: skip
    with needs("mesh", f"{path}: glTF output"):
        import pygltflib as gl

    offset = xyz[0].copy() if len(xyz) else np.zeros(3)
    parts = _GlbBuffer()
    if texture is None:
        attributes = gl.Attributes(
            POSITION=parts.positions(xyz - offset, None),
            COLOR_0=parts.accessor(gltf_colours(rgb), gl.UNSIGNED_SHORT, gl.VEC4, normalized=True),
        )
        indices = parts.accessor(faces.reshape(-1).astype(np.uint32), gl.UNSIGNED_INT, gl.SCALAR)
        primitive = gl.Primitive(attributes=attributes, indices=indices)
        extra: dict[str, Any] = {}
    else:
        # a vertex per facet corner, in order (no indices): each facet has its own place
        # in the atlas; glTF's v runs down; no COLOR_0 (glTF multiplies it into the texture)
        uv = texture.uv.reshape(-1, 2).copy()
        uv[:, 1] = 1.0 - uv[:, 1]
        attributes = gl.Attributes(
            POSITION=parts.positions(xyz - offset, faces),
            TEXCOORD_0=parts.accessor(uv, gl.FLOAT, gl.VEC2),
        )
        primitive = gl.Primitive(attributes=attributes, material=0)
        image = gl.Image(bufferView=parts.view(_jpeg(texture.bgr)), mimeType="image/jpeg")
        # matte: glTF's default material is a metal
        pbr = gl.PbrMetallicRoughness(
            baseColorTexture=gl.TextureInfo(index=0), metallicFactor=0.0, roughnessFactor=1.0
        )
        # no mipmaps: a coarser level would mix each facet's texels with its neighbours'
        # in the atlas (another place on the street)
        sampler = gl.Sampler(magFilter=gl.LINEAR, minFilter=gl.LINEAR,
                             wrapS=gl.CLAMP_TO_EDGE, wrapT=gl.CLAMP_TO_EDGE)  # fmt: skip
        extra = {
            "images": [image], "samplers": [sampler], "textures": [gl.Texture(source=0, sampler=0)],
            "materials": [gl.Material(pbrMetallicRoughness=pbr)],
        }  # fmt: skip
    node = np.eye(4)
    node[:3, :3] = Y_UP
    node[:3, 3] = Y_UP @ offset
    glb = gl.GLTF2(
        asset=gl.Asset(generator=SOFTWARE, version="2.0", extras={"acq": list(lines)}),
        scene=0, scenes=[gl.Scene(nodes=[0])],
        nodes=[gl.Node(name="facets", mesh=0, matrix=node.T.reshape(-1).tolist())],
        meshes=[gl.Mesh(name="facets", primitives=[primitive])],
        accessors=parts.accessors, bufferViews=parts.views,
        buffers=[gl.Buffer(byteLength=parts.size)], **extra,
    )  # fmt: skip
    glb.set_binary_blob(parts.blob())
    with atomic(path) as tmp, open(tmp, "wb") as out:
        for chunk in glb.save_to_bytes():
            out.write(chunk)
    return path.stat().st_size


class _GlbBuffer:
    """A glb's binary chunk being assembled: its buffer views (each on 4 bytes, as glTF
    wants them) and accessors (pygltflib's)."""

    def __init__(self) -> None:
        self.chunks: list[bytes] = []
        self.views: list[Any] = []
        self.accessors: list[Any] = []
        self.size = 0

    def view(self, data: bytes) -> int:
        """A buffer view of ``data``; its number."""
        import pygltflib as gl

        self.views.append(gl.BufferView(buffer=0, byteOffset=self.size, byteLength=len(data)))
        pad = -len(data) % 4
        self.chunks += [data, b"\0" * pad]
        self.size += len(data) + pad
        return len(self.views) - 1

    def accessor(
        self, values: np.ndarray, component: int, kind: str, *, normalized: bool = False,
        bounds: tuple[list[float], list[float]] | None = None,
    ) -> int:  # fmt: skip
        """An accessor of ``values`` (N,) or (N,k) in a view of their own, with their
        ``bounds`` (min, max) when given; its number."""
        import pygltflib as gl

        lo, hi = bounds or (None, None)
        self.accessors.append(
            gl.Accessor(
                bufferView=self.view(np.ascontiguousarray(values).tobytes()),
                componentType=component, count=len(values), type=kind,
                normalized=normalized or None, min=lo, max=hi,
            )
        )  # fmt: skip
        return len(self.accessors) - 1

    def positions(self, xyz: np.ndarray, faces: np.ndarray | None) -> int:
        """An accessor of the positions ``xyz`` (V,3) m as float32 (``faces`` (F,3): a
        vertex per facet corner), with the min and max glTF wants (the vertices')."""
        import pygltflib as gl

        v = xyz.astype(np.float32)
        bounds = (v.min(axis=0).tolist(), v.max(axis=0).tolist()) if len(v) else None
        corners = v if faces is None else v[faces].reshape(-1, 3)
        return self.accessor(corners, gl.FLOAT, gl.VEC3, bounds=bounds)

    def blob(self) -> bytes:
        return b"".join(self.chunks)


def _jpeg(bgr: np.ndarray) -> bytes:
    """``bgr`` (H,W,3) uint8 as a JPEG marked as acq's (:data:`GLB_JPEG_QUALITY`)."""
    import cv2

    ok, buf = cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, GLB_JPEG_QUALITY])
    if not ok:
        raise ValueError(f"cannot encode an atlas of {bgr.shape} as JPEG")
    return marked_image(buf.tobytes())


def _write_obj(
    path: Path, xyz: np.ndarray, rgb: np.ndarray, faces: np.ndarray, lines: Sequence[str]
) -> int:
    if not all(c.isprintable() for c in lines):  # a line break would end the comment
        raise ValueError(f"an OBJ comment is one line of printable text: {list(lines)}")
    with atomic(path) as tmp, open(tmp, "w", encoding="ascii") as out:
        out.write("".join(f"# {c}\n" for c in lines))
        # four decimals: every colour byte comes back as round(255 * c)
        _rows(out, "v %.4f %.4f %.4f %.4f %.4f %.4f\n", np.hstack([xyz, rgb / 255.0]))
        _rows(out, "f %d %d %d\n", np.asarray(faces, dtype=np.int64) + 1)
    return os.path.getsize(path)


def _write_textured_obj(
    path: Path, xyz: np.ndarray, faces: np.ndarray, lines: Sequence[str], texture: Atlas
) -> int:
    """The OBJ (its vertices shared, a texture coordinate per facet corner), then its
    .mtl and .jpg beside it, written first: an OBJ never names a missing file."""
    from acq.provenance import write_image

    if not all(c.isprintable() for c in lines):
        raise ValueError(f"an OBJ comment is one line of printable text: {list(lines)}")
    mtl, jpg = texture_files(path)
    write_image(jpg, texture.bgr)
    with atomic(mtl) as tmp, open(tmp, "w", encoding="utf-8") as out:
        out.write(f"# {lines[0]}\nnewmtl facets\nKa 1 1 1\nKd 1 1 1\nKs 0 0 0\n"
                  f"illum 1\nmap_Kd {jpg.name}\n")  # fmt: skip
    with atomic(path) as tmp, open(tmp, "w", encoding="utf-8") as out:
        out.write("".join(f"# {c}\n" for c in lines))
        out.write(f"mtllib {mtl.name}\nusemtl facets\n")
        _rows(out, "v %.4f %.4f %.4f\n", xyz)
        _rows(out, "vt %.7f %.7f\n", texture.uv.reshape(-1, 2).astype(np.float64))
        corner = np.arange(faces.size, dtype=np.int64).reshape(-1, 3) + 1
        both = np.stack([np.asarray(faces, dtype=np.int64) + 1, corner], axis=2)
        _rows(out, "f %d/%d %d/%d %d/%d\n", both.reshape(-1, 6))
    return sum(os.path.getsize(p) for p in (path, mtl, jpg))


def _rows(out: TextIO, line: str, values: np.ndarray, block: int = 65536) -> None:
    """Each row of ``values`` as ``line`` formats it, a block of rows at a time (one
    string formatting per block: three times numpy's savetxt, which formats row by row)."""
    for k in range(0, values.shape[0], block):
        part = values[k : k + block]
        out.write((line * part.shape[0]) % tuple(part.ravel().tolist()))
