"""The mesh of `acq mesh` and the cloud of `acq colorize` seen from three viewpoints along
the simulated street, against the truth seen from the same poses.

Data: ``acq.sim.drive_log.write_drive_log`` — ``--seconds`` (30) of the synthetic street at
20 km/h with the two-camera rig (left and right fisheyes). Meshed (:func:`acq.mesh.drive.
prepare_mesh`, as `acq mesh -o mesh.glb --tile-m` longer than the drive: one file) and
coloured (:func:`acq.cloud.colorize.run`, as `acq colorize -o cloud.ply`) in the world
frame with the log's calibration (the true one) and the TRUE trajectory (as
`--trajectory` would take it), so both lie in the street's frame and the comparison is of
the colours and the surfaces, not of dead reckoning's drift. The ``.glb`` and ``.ply``
are read back from their files.

Three viewpoints (:func:`acq.sim.mesh_views.street_views`: left facades at 35 % of the
drive, right facades at 50 %, oblique at 65 %; 320 x 240 px, 75 degrees): the mesh
rasterised with its vertex colours, the cloud splatted (each point a square as wide as
the spacing between profiles, 0.14 m at 20 km/h), the truth ray-cast. One JSON line, per
view and pooled over the three: ``street_px`` (pixels where the truth hits a surface),
``covered`` (the share of them the render covers), ``within_24`` (of those covered, the
share within 24/255 in every channel; target >= 90 % for the mesh) and ``psnr_db``; and
the times of each step. ``ceiling``: the truth cast at the fisheyes' resolution at their
axis (px per radian, the best they see the street), resampled to the view and compared
with the truth (:func:`acq.sim.mesh_views.resolution_ceiling`): what no texture sampled
from those frames can pass, per view and pooled. ``--picture PNG`` saves the views beside
the truth (a PNG of 256 colours).
``--texture`` also meshes the drive textured (as `acq mesh --texture`, cells of the
default texels) into a second ``.glb``, reads it back with its texture, renders it from
the same views (:func:`acq.mesh.render.render_textured`) and reports it as ``textured``
beside the vertex-coloured mesh and the cloud (per view and pooled; in the picture a
panel per view).

Run as a script:
``python bench/mesh_render.py [--seconds S] [--work DIR] [--texture] [--picture PNG]``.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=30.0)
    ap.add_argument(
        "--work", type=Path, default=None, help="folder for the drive (default: a temporary one)"
    )
    ap.add_argument("--picture", type=Path, default=None, help="PNG of the views and the truth")
    ap.add_argument(
        "--texture", action="store_true",
        help="also the textured mesh (acq mesh --texture), rendered and compared beside the others",
    )  # fmt: skip
    args = ap.parse_args()
    from acq.cli.mesh import TEXELS
    from acq.cloud import PLY_DTYPE
    from acq.cloud.colorize import run as colorize
    from acq.mesh.drive import prepare_mesh
    from acq.sim.drive_log import write_drive_log
    from acq.sim.mesh_views import (
        compare,
        picture,
        read_mesh,
        read_textured_mesh,
        resolution_ceiling,
        street_views,
    )
    from acq.sim.world import default_rig

    row: dict[str, Any] = {"bench": "mesh_render", "seconds": args.seconds}
    times: dict[str, float] = {}
    with tempfile.TemporaryDirectory() as tmp:
        work = args.work or Path(tmp)
        t0 = time.perf_counter()
        truth = write_drive_log(work / "drive", args.seconds, rig=default_rig(cameras=2))
        times["drive_log"] = time.perf_counter() - t0
        trajectory = truth.host_trajectory()

        t0 = time.perf_counter()
        glb = work / "mesh.glb"
        mj = prepare_mesh(truth.files, truth.calibration, glb, trajectory=trajectory,
                          tile_m=math.inf)  # fmt: skip
        rep = mj.run()
        times["mesh"] = time.perf_counter() - t0
        if args.texture:
            t0 = time.perf_counter()
            textured_glb = work / "textured.glb"
            tj = prepare_mesh(truth.files, truth.calibration, textured_glb,
                              trajectory=trajectory, tile_m=math.inf, texels=TEXELS)  # fmt: skip
            trep = tj.run()
            times["mesh_texture"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        ply = work / "cloud.ply"
        colorize(truth.files, truth.calibration, ply, trajectory=trajectory)
        times["colorize"] = time.perf_counter() - t0

        t0 = time.perf_counter()
        mesh = read_mesh(glb)
        textured = read_textured_mesh(textured_glb) if args.texture else None
        if args.texture:
            row["glb_bytes"] = {"mesh": glb.stat().st_size, "textured": textured_glb.stat().st_size}
        data = ply.read_bytes()
        v = np.frombuffer(data, PLY_DTYPE, offset=data.index(b"end_header\n") + 11)
        cloud = (np.stack([v["x"], v["y"], v["z"]], axis=1),
                 np.stack([v["red"], v["green"], v["blue"]], axis=1))  # fmt: skip
        times["read"] = time.perf_counter() - t0

        t0 = time.perf_counter()
        views = street_views(truth.trajectory, [f * args.seconds for f in (0.35, 0.5, 0.65)])
        splat_m = truth.config["speed_kmh"] / 3.6 * truth.rig.scan_period
        result = compare(truth.street, views, mesh, cloud, splat_m, textured=textured)
        times["render_and_compare"] = time.perf_counter() - t0
        # the best any texture from these frames can do: the truth seen at the fisheyes'
        # resolution at their axis (they see less off it), against the truth
        lens_px_per_rad = max(float(c.lens.fx) for c in truth.rig.cameras)
        ceiling, ceiling_all = resolution_ceiling(truth.street, views, lens_px_per_rad)

    row["facets"], row["vertices"], row["points"] = rep.facets, rep.vertices, cloud[0].shape[0]
    row["splat_m"] = round(splat_m, 3)
    if textured is not None:
        row["texels"], row["textured_facets"] = TEXELS, trep.textured
        row["atlas_px"] = list(textured.image.shape[:2])

    def figures(lk: Any) -> dict[str, Any]:
        return {"street_px": lk.street, "covered": round(lk.covered, 4),
                "within_24": round(lk.within, 4), "psnr_db": round(lk.psnr_db, 2)}  # fmt: skip

    row["views"] = {
        name: {"mesh": figures(m), "cloud": figures(c)}
        for name, (m, c) in zip(result.names, result.per_view, strict=True)
    }
    for name, (_, t) in zip(result.names, result.textured_views, strict=False):
        row["views"][name]["textured"] = figures(t)
    for name, lk in ceiling.items():
        row["views"][name]["ceiling"] = figures(lk)
    row["mesh"], row["cloud"] = figures(result.mesh), figures(result.cloud)
    row["ceiling"] = figures(ceiling_all) | {"lens_px_per_rad": round(lens_px_per_rad, 1)}
    if result.textured is not None:
        row["textured"] = figures(result.textured)
    row["seconds_per_step"] = {k: round(s, 2) for k, s in times.items()}
    row["load_average"] = round(os.getloadavg()[0], 2)
    if args.picture is not None:
        title = (f"acq mesh (vertex colours) and acq colorize, {args.seconds:g} s drive, beside "
                 f"the true street: mesh {result.mesh.text()}")  # fmt: skip
        if result.textured is not None:
            title = (f"acq mesh (vertex colours, then --texture) and acq colorize, "
                     f"{args.seconds:g} s drive, beside the true street: textured "
                     f"{result.textured.text()}")  # fmt: skip
        # a palette of 256 colours: a third of the bytes of full colour, for the README
        Image.fromarray(picture(result, title)).quantize(256).save(args.picture, optimize=True)
    print(json.dumps(row))


if __name__ == "__main__":
    main()
