"""`acq mesh`: a drive's facets with per-vertex colour or textured, in tiles along the track.

The points are placed and coloured by `acq colorize`'s pipeline (:func:`acq.cloud.job.prepare`,
the chunks of :mod:`acq.cloud.chunks` run by :func:`acq.cloud.colorize.run_chunks`); each
chunk's points, with the last scan of the chunk before it (so that no facet between two
chunks is lost, and none is made twice), are joined into triangles by
:func:`acq.mesh.grid_facets`. A facet belongs to the tile of its first scan: tiles of
``tile_m`` metres along the laser's track, the last one holding the rest (a rest shorter
than a quarter of a tile joins the tile before it); each tile is written as soon as the
chunks have passed its end (:mod:`acq.mesh.files`; its atlas made and its file written
on a writer thread while the next chunks are joined), with the vertices its facets use;
with a texture (``texels``), with its atlas (:mod:`acq.mesh.texture`): the vertices keep
their frame and pixel (the job's ``want_uv``), the frames' gains are kept by session
frame, and a tile's texels are sampled from the parts of the frames the colouring kept
(:class:`acq.cloud.views.Crop`; a frame whose part misses a pixel is decoded again), its
seams between views levelled (:mod:`acq.mesh.seams`).

Metres; times host monotonic ns.
"""

from __future__ import annotations

import copy
import math
import os
import time
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from acq.camera.calibfile import Calibration
from acq.camera.jpeg import decoded_frames
from acq.cloud.balance import Gains
from acq.cloud.chunks import Chunk, ChunkResult, laser_positions, plan
from acq.cloud.colorize import CHUNK_S, READ_ONCE_BYTES, run_chunks
from acq.cloud.job import Job, prepare
from acq.cloud.report import Report
from acq.cloud.views import Crop, point_size
from acq.disk_space import full_disk_error
from acq.errors import InputValueError
from acq.log.drive_log import DriveLog, read_log
from acq.log.inputs import session_files
from acq.mesh import files, seams, simplify, texture, view_selection
from acq.mesh.organized import FacetRules, grid_facets
from acq.motion import Trajectory

__all__ = ["MeshJob", "MeshReport", "TileViews", "prepare_mesh", "tile_names", "tiles_of"]

# tiles made (views, atlas) and written at once on their own threads, beside the colouring:
# two keep both cores busy where one tile's atlas takes longer than the chunks that follow
WRITERS = 2


@dataclass
class MeshReport:
    """What `acq mesh` did: the files written, its counts and the pipeline's notes."""

    output: str
    files: list[str] = field(default_factory=list)
    vertices: int = 0
    facets: int = 0
    points: int = 0
    coloured: int = 0
    textured: int | None = None  # facets with a texture sampled from a frame (None: none made)
    joined: int | None = None  # facets joined before --simplify merged them (None: not asked)
    scans: int = 0
    track_m: float = 0.0
    frame: str = "world"
    trajectory: str = ""
    bytes: int = 0
    seconds: float = 0.0
    notes: list[str] = field(default_factory=list)

    def lines(self) -> list[str]:
        share = self.coloured / self.points if self.points else 0.0
        out = [
            f"{self.facets:,} facets on {self.vertices:,} vertices from {self.points:,} "
            f"points of {self.scans:,} scans ({100 * share:.1f} % of the points coloured), "
            f"{self.track_m:.1f} m of track",
            f"frame: {self.frame}; trajectory: {self.trajectory or 'none'}",
            *(
                [
                    f"simplified from {self.joined:,} facets ("
                    f"{100 * self.facets / max(1, self.joined):.1f} % kept)"
                ]
                if self.joined is not None
                else []
            ),
            *(
                [
                    f"{self.textured:,} facets textured from a frame, the others filled with "
                    "their vertices' colour"
                ]
                if self.textured is not None
                else []
            ),
            f"wrote {len(self.files)} file(s), {self.bytes / 1e6:.1f} MB in "
            f"{self.seconds:.1f} s: " + ", ".join(self.files),
        ]
        return out + [f"note: {n}" for n in self.notes]


def tiles_of(track_m: np.ndarray, tile_m: float) -> np.ndarray:
    """The tile (S,) int of each scan, from its distance ``track_m`` (S,) m along the
    track (nondecreasing): tiles of ``tile_m``, the last one holding the rest, a rest
    shorter than a quarter of a tile joined to the tile before it."""
    total = float(track_m[-1]) if track_m.size else 0.0
    n = max(1, math.ceil(total / tile_m - 0.25))
    return np.minimum(np.floor(track_m / tile_m).astype(np.int64), n - 1)


def tile_names(output: Path, tiles: int) -> list[Path]:
    """The files of ``tiles`` tiles: ``output`` itself for one, else OUT_000.SUFFIX,
    OUT_001.SUFFIX... beside it."""
    if tiles <= 1:
        return [output]
    width = max(3, len(str(tiles - 1)))
    return [output.with_name(f"{output.stem}_{k:0{width}d}{output.suffix}") for k in range(tiles)]


@dataclass(frozen=True)
class TileViews:
    """A textured tile's facets as :class:`MeshJob` textures them, for checks against a
    truth: per vertex its session ``scan`` and ``step`` (V,) int64 and the view it was
    coloured from, ``camera`` (V,) uint8 (``NO_CAMERA``: none) and session ``frame``
    (V,) int64; ``faces`` (F,3) into them; each facet's view ``view_cam``, ``view_frame``
    (F,) (-1: none) and its corners' pixels in it ``corner_px`` (F,3,2) px (NaN: none)."""

    scan: np.ndarray
    step: np.ndarray
    camera: np.ndarray
    frame: np.ndarray
    faces: np.ndarray
    view_cam: np.ndarray
    view_frame: np.ndarray
    corner_px: np.ndarray


@dataclass
class MeshJob:
    """A drive read and planned (:func:`prepare_mesh`): its colouring job, chunks, each
    session scan's sensor position and tile, and the files it will write."""

    job: Job
    index: DriveLog
    chunks: list[Chunk]
    origin: np.ndarray  # (S,3) m, the laser at each session scan's point 0
    tile: np.ndarray  # (S,) int
    paths: list[Path]
    rules: FacetRules
    once: bool
    report: MeshReport
    comments: list[str]
    texels: int | None = None  # texels a side of an atlas cell; None: vertex colours
    on_views: Callable[[TileViews], None] | None = None  # given each textured tile's views
    simplify_m: float | None = None  # merge near-coplanar facets within this, m; None: not

    def run(self, progress: bool = False) -> MeshReport:
        """Colour the chunks, join them into facets and write the tiles; OSError naming
        the file that cannot be written (a full disk: DiskFullError)."""
        t0 = time.perf_counter()
        tiles = _Tiles(self)
        try:
            run_chunks(self.job, self.chunks, 1, None, progress, tiles.add,
                       self.index if self.once else None)  # fmt: skip
            tiles.finish()
        finally:
            tiles.close()
        rep = self.report
        if not rep.files:
            raise InputValueError(
                f"LOG {self.job.files[0]}: no two neighbouring laser returns to join into a "
                "facet; nothing written"
            )
        stale = _other_tiles(Path(rep.output), self.paths)
        if stale:
            rep.notes.append(
                "files of an earlier run with other tiles are still there, not replaced: "
                + ", ".join(p.name for p in stale[:3])
                + (f" and {len(stale) - 3} more" if len(stale) > 3 else "")
            )
        rep.seconds += time.perf_counter() - t0
        return rep


def _other_tiles(output: Path, written: Sequence[Path]) -> list[Path]:
    """The files beside ``output`` named as itself or as its tiles (OUT_000...) that acq
    wrote and this run did not: an earlier run's, cut otherwise."""
    from acq.provenance import made_by_acq

    found = [output, *output.parent.glob(f"{output.stem}_*{output.suffix}")]
    tiles = [p for p in found if p == output or p.stem[len(output.stem) + 1 :].isdigit()]
    return sorted(p for p in tiles if p not in written and p.is_file() and made_by_acq(p))


def prepare_mesh(
    logs: Sequence[Path],
    calib: Calibration,
    output: Path,
    *,
    camera: str | Sequence[str] | None = None,
    frame: str | None = None,
    trajectory: Path | Trajectory | None = None,
    crs: str | None = None,
    rules: FacetRules | None = None,
    tile_m: float = 50.0,
    chunk_s: float | None = None,
    texels: int | None = None,
    simplify_m: float | None = None,
) -> MeshJob:
    """Read ``logs`` and plan the mesh (:class:`MeshJob`; its ``paths``: the files it
    will write, for the caller to check before :meth:`MeshJob.run`); options as `acq
    colorize` takes them; ``rules``: default
    :class:`FacetRules`; ``chunk_s``: default colorize's; ``texels``: texture the facets
    (:mod:`acq.mesh.texture`; glb or OBJ) with cells of that many texels a side;
    ``simplify_m``: merge near-coplanar facets of each tile while the surface moves by
    at most about that many metres (:mod:`acq.mesh.simplify`; vertex colours only).
    InputError for bad input, named."""
    t0 = time.perf_counter()
    if files.format_of(output) == "ply" and texels is not None:
        raise InputValueError(
            f"--texture: -o {output}: a PLY file holds vertex colours, not a texture; use "
            ".glb or .obj"
        )
    if simplify_m is not None and not 0 < simplify_m < math.inf:
        raise InputValueError(f"--simplify {simplify_m}: expected metres above 0")
    if simplify_m is not None and texels is not None:
        raise InputValueError(
            "--simplify: not with --texture (a merged facet would span several frames' "
            "texels); simplify a mesh with vertex colours"
        )
    logs = session_files(logs)
    once = sum(f.stat().st_size for f in logs if f.is_file()) <= READ_ONCE_BYTES
    cloud = Report(output=str(output))
    job, index = prepare(
        logs, calib, cloud, camera=camera, frame=frame, trajectory=trajectory, jpegs=once,
        threads=os.cpu_count() or 1, crs=crs,
    )  # fmt: skip
    if index.n_scans == 0:
        raise InputValueError(f"LOG {logs[0]}: no laser scans; nothing to join into facets")
    if texels is not None:
        # each vertex's pixel in its frame, and the frames' parts around them
        job = replace(job, want_uv=True, want_crops=True)
    if not job.frame_world:
        # a moving rig's profiles lie on top of each other in the laser frame: its grid
        # joins nothing that is a surface
        raise InputValueError(
            "--frame laser: facets join neighbouring profiles where the rig placed them; "
            "use --frame world"
            if job.trajectory is not None
            else "facets need the rig's motion: CAN odometry or GNSS fixes in the log, or "
            "--trajectory CSV"
        )
    scan_new = np.sort(job.scan_new)
    origin = np.zeros((scan_new.size, 3))
    track = np.zeros(scan_new.size)
    if job.frame_world:
        ok = job.trajectory.covers(scan_new)
        if ok.any():
            origin[ok] = laser_positions(job, scan_new[ok])
            steps = np.linalg.norm(np.diff(origin[ok], axis=0), axis=1)
            along = np.concatenate([[0.0], np.cumsum(steps)])
            # scans without a pose have no points: the distance of the scan before them
            track = np.interp(np.arange(scan_new.size), np.flatnonzero(ok), along)
    tile = tiles_of(track, tile_m)
    report = MeshReport(
        output=str(output), scans=int(scan_new.size), track_m=float(track[-1]),
        frame=cloud.frame, trajectory=cloud.trajectory, notes=list(cloud.notes),
        seconds=time.perf_counter() - t0,
    )  # fmt: skip
    comments = [f"frame {cloud.frame}", *([f"crs {crs}"] if crs else [])]
    if simplify_m is not None:
        comments.append(f"near-coplanar facets merged within {simplify_m:g} m")
    return MeshJob(
        job, index, plan(scan_new, chunk_s or CHUNK_S), origin, tile,
        tile_names(output, int(tile[-1]) + 1), rules or FacetRules(), once, report, comments,
        texels, simplify_m=simplify_m,
    )  # fmt: skip


class _Tiles:
    """The vertices and facets not yet written, chunk by chunk: vertices numbered in
    the session from 0 (``base``: the number of the first one held), facets by tile."""

    def __init__(self, mj: MeshJob) -> None:
        self.mj = mj
        self.base = 0
        self.xyz = np.zeros((0, 3))
        self.rgb = np.zeros((0, 3), np.uint8)
        self.scan = np.zeros(0, np.int64)
        self.step = np.zeros(0, np.int64)
        self.faces = np.zeros((0, 3), np.int64)  # session vertex numbers
        self.next_tile = 0  # the first tile not written
        # with a texture: each vertex's view and pixel in it, each frame's colour gains
        self.camera = np.zeros(0, np.uint8)
        self.frame = np.zeros(0, np.int64)
        self.uv = np.zeros((0, 2), np.float32)
        self.gains: Gains | None = None
        # the colouring's crops of decoded frames, per camera by session frame
        self.crops: list[dict[int, Crop]] = [{} for _ in mj.job.cameras]
        # the tiles being written on the writer threads: path, facets before simplifying, task
        self._writer: ThreadPoolExecutor | None = None
        self._pending: list[tuple[Path, int, Future[tuple[int, int, int, int | None]]]] = []

    def add(self, r: ChunkResult) -> None:
        mj, rep = self.mj, self.mj.report
        rep.points += int(r.scan.size)
        rep.coloured += int(np.count_nonzero(r.coloured))
        # the held scans' last one joins this chunk's first
        last = self.scan[-1] if self.scan.size else -1
        carry = np.flatnonzero(self.scan == last)
        scan = np.concatenate([self.scan[carry], r.scan.astype(np.int64)])
        step = np.concatenate([self.step[carry], r.step.astype(np.int64)])
        xyz = np.concatenate([self.xyz[carry], r.xyz])
        tri = grid_facets(scan, step, xyz, mj.origin[scan], mj.rules)
        tri = tri[(tri >= carry.size).any(axis=1)]  # one made with the last chunk already
        ids = np.concatenate(
            [self.base + carry, self.base + self.scan.size + np.arange(r.scan.size)]
        )
        self.faces = np.concatenate([self.faces, ids[tri]])
        self.xyz = np.concatenate([self.xyz, r.xyz])
        self.rgb = np.concatenate([self.rgb, r.rgb])
        self.scan = np.concatenate([self.scan, r.scan.astype(np.int64)])
        self.step = np.concatenate([self.step, r.step.astype(np.int64)])
        if mj.texels is not None:
            assert r.uv is not None  # the job wants them
            self.camera = np.concatenate([self.camera, r.camera])
            self.frame = np.concatenate([self.frame, r.frame.astype(np.int64)])
            self.uv = np.concatenate([self.uv, r.uv])
            self._add_gains(r)
            for held, crops in zip(self.crops, r.crops, strict=True):
                held.update(crops)
        if self.scan.size:  # tiles whose last scan is before the held last one are whole
            self._write_until(int(mj.tile[self.scan[-1]]))

    def finish(self) -> None:
        self._write_until(len(self.mj.paths))
        while self._pending:
            self._collect()

    def close(self) -> None:
        """Wait for the tiles being written, if any (on an error: their outcome unasked)."""
        if self._writer is not None:
            self._writer.shutdown(wait=True)

    def _write(self, path: Path, at: np.ndarray, tri: np.ndarray) -> None:
        """Make the tile of the facets ``tri`` of the held vertices ``at`` (its atlas) and
        write it on a writer thread, while this one goes on with the next chunks; at most
        ``WRITERS`` tiles in flight (the oldest collected first)."""
        if len(self._pending) >= WRITERS:
            self._collect()
        if self._writer is None:
            self._writer = ThreadPoolExecutor(max_workers=WRITERS,
                                              thread_name_prefix="acq-mesh-write")  # fmt: skip
        # what the tile needs as it is now: the held arrays are replaced, not changed in
        # place, as chunks come; the gains and crops are changed in place
        held = copy.copy(self)
        held.crops = [dict(c) for c in self.crops]
        if self.gains is not None:
            held.gains = replace(self.gains, log_gain=[g.copy() for g in self.gains.log_gain])

        before = self._pending[-1][2] if self._pending else None

        def make() -> tuple[int, int, int, int | None]:
            """The tile written: (bytes, vertices, facets, textured facets) of its file
            (None: no texture); the report is the main thread's. Files are written in
            order, none after one that failed."""
            mj = self.mj
            atlas = held._atlas(at, tri) if mj.texels is not None else None
            xyz, rgb, faces = held.xyz[at], held.rgb[at], tri
            if mj.simplify_m is not None:
                xyz, rgb, faces = simplify.simplify(xyz, rgb, faces, mj.simplify_m)
            if before is not None:
                before.result()  # raises what the tile before raised: this one not written
            size = files.write(path, xyz, rgb, faces, mj.comments, atlas)
            textured = None if atlas is None else int(np.count_nonzero(atlas.textured))
            return size, xyz.shape[0], faces.shape[0], textured

        self._pending.append((path, tri.shape[0], self._writer.submit(make)))

    def _collect(self) -> None:
        """Wait for the oldest tile being written; its file and counts into the report (a
        full disk: DiskFullError naming it)."""
        if not self._pending:
            return
        path, joined, task = self._pending.pop(0)
        rep = self.mj.report
        try:
            size, n_vertices, n_facets, textured = task.result()
        except Exception as e:
            full = full_disk_error(path, e)
            if full is None:
                raise
            raise full from e
        rep.bytes += size
        rep.files.append(str(path))
        rep.vertices += n_vertices
        rep.facets += n_facets
        if textured is not None:
            rep.textured = (rep.textured or 0) + textured
        if self.mj.simplify_m is not None:
            rep.joined = (rep.joined or 0) + joined

    def _write_until(self, end: int) -> None:
        """Write the tiles before ``end`` and drop what only they used."""
        mj, rep = self.mj, self.mj.report
        if end <= self.next_tile:
            return
        first_scan = self.scan[self.faces.min(axis=1) - self.base] if self.faces.size else None
        face_tile = mj.tile[first_scan] if first_scan is not None else np.zeros(0, np.int64)
        for t in range(self.next_tile, end):
            mine = self.faces[face_tile == t]
            if not mine.size:
                rep.notes.append(f"{mj.paths[t].name}: no facets in that stretch; not written")
                continue
            used, tri = np.unique(mine, return_inverse=True)
            at = used - self.base
            tri = tri.reshape(-1, 3)
            path = mj.paths[t]
            if mj.texels is not None:
                h, w = texture.atlas_shape(tri.shape[0], mj.texels)
                if max(h, w) > texture.MAX_SIDE:
                    raise InputValueError(
                        f"--texture: {path.name}: {tri.shape[0]:,} facets need an atlas of "
                        f"{w:,} x {h:,} texels, over the {texture.MAX_SIDE:,} a side that "
                        "viewers take; use a shorter --tile-m or fewer --texels"
                    )
            self._write(path, at, tri)
        self.faces = self.faces[face_tile >= end]
        self.next_tile = end
        # a later tile's facets start at its own first scan: what is before is done
        if end < len(mj.paths):
            keep = mj.tile[self.scan] >= end
            keep |= self.scan == self.scan[-1]
            drop = int(np.argmax(keep)) if keep.any() else self.scan.size
            self.base += drop
            self.xyz, self.rgb = self.xyz[drop:], self.rgb[drop:]
            self.scan, self.step = self.scan[drop:], self.step[drop:]
            if mj.texels is not None:
                self.camera, self.frame = self.camera[drop:], self.frame[drop:]
                self.uv = self.uv[drop:]
                self._drop_crops()

    def _add_gains(self, r: ChunkResult) -> None:
        """Keep the chunk's gains by session frame (a frame two chunks share: the later's)."""
        if r.gains is None:
            return
        if self.gains is None:
            self.gains = Gains([np.zeros((c.frame_old.size, 3)) for c in self.mj.job.cameras], 0, 0)
        for table, rows, g in zip(self.gains.log_gain, r.session_frames, r.gains.log_gain,
                                  strict=True):  # fmt: skip
            if g.size:
                table[rows] = g

    def _atlas(self, at: np.ndarray, tri: np.ndarray) -> texture.Atlas:
        """The atlas of the facets ``tri`` (F,3) of the held vertices ``at``."""
        mj = self.mj
        assert mj.texels is not None
        camera, frame = self.camera[at], self.frame[at]
        job = mj.job
        # every held point may hide a facet (each at its scan's time, as the colouring's)
        scan_ns = np.sort(job.scan_new)[self.scan]
        ranges = np.linalg.norm(self.xyz - mj.origin[self.scan], axis=1)
        size = point_size(ranges, mj.index.angle_increment, job.travel_m)
        occluders = view_selection.Occluders(self.xyz, scan_ns, size)
        view_cam, view_frame = view_selection.select_views(
            job, self.xyz[at], scan_ns[at], tri, camera, frame, occluders
        )
        px = texture.corner_pixels(mj.job, self.xyz[at], camera, frame, self.uv[at], tri,
                                   view_cam, view_frame)  # fmt: skip
        self._tell(at, tri, view_cam, view_frame, px)
        fill = self.rgb[at][tri].mean(axis=1).round().astype(np.uint8)
        atlas = texture.build_atlas(px, view_cam, view_frame,
                                    self._images_for(px, view_cam, view_frame), self.gains,
                                    fill, mj.texels)  # fmt: skip
        seams.level_seams(atlas, tri, view_cam, view_frame, mj.texels)
        return atlas

    def _tell(
        self, at: np.ndarray, tri: np.ndarray, view_cam: np.ndarray, view_frame: np.ndarray,
        px: np.ndarray,
    ) -> None:  # fmt: skip
        """Give :attr:`MeshJob.on_views` (if any) the tile's facets, views and pixels."""
        if self.mj.on_views is not None:
            self.mj.on_views(TileViews(self.scan[at], self.step[at], self.camera[at],
                                       self.frame[at], tri, view_cam, view_frame, px))  # fmt: skip

    def _drop_crops(self) -> None:
        """Drop the crops of the frames before those the held vertices were coloured
        from (the tiles after are made of later scans)."""
        for c, crops in enumerate(self.crops):
            mine = self.frame[(self.camera == c) & (self.frame >= 0)]
            first = int(mine.min()) if mine.size else None
            for f in [f for f in crops if first is None or f < first]:
                del crops[f]

    def _images_for(
        self, px: np.ndarray, view_cam: np.ndarray, view_frame: np.ndarray
    ) -> texture.FrameImages:
        """The frames of the facets whose corners are at ``px`` (F,3,2) in their view
        (``view_cam``, ``view_frame`` (F,)), as :func:`texture.build_atlas` asks for them:
        the crop the colouring kept of a frame when it holds every pixel the facets'
        texels are sampled from (in a buffer of the frame's size, valid until the next
        one is asked for), else the frame decoded again (:meth:`_images`)."""
        assert self.mj.texels is not None
        ok = np.flatnonzero((view_cam >= 0) & np.isfinite(px).all(axis=(1, 2)))
        key = (view_cam[ok] << 32) | view_frame[ok]
        by_view = np.argsort(key, kind="stable")
        keys, first = np.unique(key[by_view], return_index=True)
        p = px[ok[by_view]]
        lo = np.minimum(np.minimum(p[:, 0], p[:, 1]), p[:, 2])
        hi = np.maximum(np.maximum(p[:, 0], p[:, 1]), p[:, 2])
        # a half cell's texels reach past its triangle by a texel (1/(texels - 3) of it
        # at most), and bilinear sampling a pixel beyond
        pad = (hi - lo).max(axis=1, keepdims=True) / (self.mj.texels - 3) + 2
        need_lo = np.minimum.reduceat(lo - pad, first) if ok.size else lo
        need_hi = np.maximum.reduceat(hi + pad, first) if ok.size else hi

        def held(camera: int, frame: int, row: int) -> Crop | None:
            crop = self.crops[camera].get(frame)
            if crop is None:
                return None
            w, h = crop.size  # beyond the frame, BORDER_REPLICATE reads its edge
            x0, y0 = np.clip(np.floor(need_lo[row]).astype(int), 0, [w - 1, h - 1])
            x1, y1 = np.clip(np.ceil(need_hi[row]).astype(int) + 1, 1, [w, h])
            return crop if crop.holds(int(x0), int(y0), int(x1), int(y1)) else None

        def images(camera: int, frames: np.ndarray) -> Iterator[np.ndarray | None]:
            rows = np.searchsorted(keys, (camera << 32) | frames)
            crops = [
                held(camera, f, r) for f, r in zip(frames.tolist(), rows.tolist(), strict=True)
            ]
            again = frames[[c is None for c in crops]]
            decoded = self._images(camera, again) if again.size else iter(())
            buffer = np.zeros((0, 0, 3), np.uint8)
            for crop in crops:
                if crop is None:
                    yield next(decoded)
                    continue
                w, h = crop.size
                if buffer.shape[:2] != (h, w):
                    buffer = np.empty((h, w, 3), np.uint8)
                ch, cw = crop.pixels.shape[:2]
                buffer[crop.y0 : crop.y0 + ch, crop.x0 : crop.x0 + cw] = crop.pixels
                yield buffer

        return images

    def _images(self, camera: int, frames: np.ndarray) -> Iterator[np.ndarray | None]:
        """Camera ``camera``'s session ``frames`` (sorted), decoded in order."""
        mj = self.mj
        cj = mj.job.cameras[camera]
        stamps = cj.frame_old[frames]
        if mj.once:
            held = mj.index.cameras[cj.name]
        else:  # read the part of the log with those frames (receipt times: a second wider)
            part = read_log(
                list(mj.job.files), laser=mj.job.laser, cameras=[cj.name], returns=False,
                start_ns=int(stamps[0]) - 2 * 10**9, end_ns=int(stamps[-1]) + 2 * 10**9,
            )  # fmt: skip
            held = part.cameras[cj.name]
        order = np.argsort(held.frame_ns, kind="stable")
        k = np.clip(np.searchsorted(held.frame_ns[order], stamps), 0, max(0, order.size - 1))
        found = held.frame_ns[order][k] == stamps if order.size else np.zeros(0, bool)
        jpegs = [held.jpegs[int(order[j])] if ok else b"" for j, ok in zip(k, found, strict=True)]
        return decoded_frames(jpegs, np.arange(len(jpegs)), mj.job.threads)
