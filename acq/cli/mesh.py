"""`acq mesh`: a drive's facets with per-vertex colour (PLY, glTF binary or OBJ), or
textured (glTF binary or OBJ)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from acq.cli import output_files
from acq.cli.camera_option import add_camera_option
from acq.cli.colorize import CHUNK_S, add_placing_options, check_crs_option
from acq.cli.option_types import integer, real
from acq.cli.output_files import Output
from acq.errors import InputValueError
from acq.extras import require

TEXELS = 8  # texels a side of an atlas cell, by default: see the README's "Facets"
HELP = "facets of a drive's laser profiles, coloured from its cameras (glTF, OBJ or PLY)"


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    from acq.mesh.organized import FacetRules

    rules = FacetRules()
    m = sub.add_parser(
        "mesh",
        help=HELP,
        description="Join the laser points of LOG (the split files of one session, or "
        "their folder) into triangles along the scan grid (scan x step: neighbouring "
        "returns of a profile and of the next profile), each vertex placed and coloured "
        "as `acq colorize` places and colours the point (every camera of CALIB, the best "
        "view of each point, exposure and white balance evened out). A vertex carries its "
        "point's colour; with --texture (.glb, .obj) each facet is textured from the fisheye "
        "frame that sees it whole and sharpest, its neighbours' where that costs little. "
        "Long drives are split into "
        "tiles along the track (--tile-m), each a file of its own. OUT replaces what acq "
        "wrote before; an input, a file of another kind or anyone else's is refused "
        "(--force replaces the last). Exit status: 0 written, 2 bad input, 3 the disk "
        "full, 1 another failure.",
    )
    m.add_argument("logs", nargs="+", type=Path, metavar="LOG", help="MCAP files or a folder")
    m.add_argument("--calib", type=Path, required=True, help="calib.yaml (camera and laser)")
    m.add_argument(
        "-o", "--output", type=Path, required=True, metavar="OUT",
        help="the format from the suffix: OUT.glb (glTF 2.0 binary, +y up as glTF has it: "
        "the world's z up turned, the first vertex's coordinates in the node's matrix), "
        "OUT.obj (vertex colours as 'v x y z r g b'; with --texture its OUT.mtl and "
        "OUT.jpg) or OUT.ply (binary, x y z double, red green blue); a drive longer than "
        "one tile gives OUT_000.SUFFIX, OUT_001.SUFFIX... beside OUT, in the order driven "
        "(an earlier run's files cut otherwise are kept, and named)",
    )  # fmt: skip
    add_camera_option(
        m, "colour from this camera (each vertex takes the camera whose view of its point "
        "is best)", several=True,
    )  # fmt: skip
    add_placing_options(
        m,
        "as a comment (PLY, OBJ) or in asset.extras (glb)",
        "meshes",
        laser_note=" (refused: a moving rig's profiles lie on top of each other there)",
    )
    m.add_argument(
        "--tile-m", type=real(1, 1e6, what="metres"), default=50.0, metavar="M",
        help="length of track per file, metres (default 50); a facet goes to the tile of its "
        "first profile; the last tile holds the rest, a rest under a quarter tile joins it",
    )  # fmt: skip
    m.add_argument(
        "--max-grazing-deg", type=real(0, 90, hi_open=True, what="degrees"),
        default=rules.max_grazing_deg, metavar="DEG",
        help="refuse an edge within this angle of the viewing ray from its profile's own "
        f"sensor position (a range jump), degrees (default {rules.max_grazing_deg:g})",
    )  # fmt: skip
    m.add_argument(
        "--edge-a-m", type=real(0, 100, what="metres"), default=None, metavar="M",
        help=f"refuse an edge longer than A + B x range: A, metres (default {rules.edge_a_m:g})",
    )  # fmt: skip
    m.add_argument(
        "--edge-b", type=real(0, 10, what="a ratio"), default=None, metavar="B",
        help="refuse an edge longer than A + B x range: B, metres per metre of range "
        f"(default {rules.edge_b:g})",
    )  # fmt: skip
    m.add_argument(
        "--chunk", type=CHUNK_S, default=None, metavar="S",
        help=f"seconds of scans per chunk, {CHUNK_S.range_text()} (default 15), as `acq "
        "colorize --chunk`; the facets are the same for any value",
    )  # fmt: skip
    m.add_argument(
        "--texture", action="store_true",
        help="texture the facets (.glb, or .obj with OUT.mtl and OUT.jpg beside it): each "
        "facet takes, of every camera's frames around its scan time, one where no corner is "
        "off the sensor or hidden by nearer laser points, weighing its size in pixels, "
        "nearness in time and angle to the axis against its neighbours' views (fewer "
        "seams); its texels are "
        "resampled from that fisheye frame, balanced as the vertex colours are, into one "
        "JPEG atlas per tile (a glb has a vertex per facet corner: files about 3 times "
        "larger, about 2.4 times the time; off by default)",
    )  # fmt: skip
    m.add_argument(
        "--texels", type=integer(4, 64, what="texels"), default=None, metavar="N",
        help="with --texture: texels a side of an atlas cell, which holds two facets "
        f"(default {TEXELS}: about the camera's own pixels on a facet at 20 km/h)",
    )  # fmt: skip
    m.add_argument(
        "--simplify", type=real(0, 0.5, lo_open=True, what="metres"), default=None,
        metavar="M",
        help="merge near-coplanar facets while the surface moves by at most about M metres "
        "(e.g. 0.02): a flat road or facade keeps a few large facets, edges and steps stay; "
        "each tile's border is kept, so tiles still meet; vertex colours only (a merged "
        "facet's colour is its corners': detail painted on a flat surface is lost)",
    )  # fmt: skip
    m.add_argument("--force", action="store_true", help=output_files.FORCE_HELP)
    m.set_defaults(handler=run, stops_cleanly=True)


def run(args: argparse.Namespace) -> int:
    from dataclasses import replace

    from acq.camera import calibfile
    from acq.mesh import FacetRules
    from acq.mesh.drive import prepare_mesh
    from acq.mesh.files import format_of, texture_files

    kind = format_of(args.output, "-o")
    if kind == "glb":
        require("mesh", f"-o {args.output}: glTF output")
    if args.simplify is not None:
        require("mesh", "--simplify")
    textured_obj = kind == "obj" and args.texture
    if args.texels is not None and not args.texture:
        raise InputValueError("--texels: only with --texture")
    check_crs_option(args.crs, args.frame)
    rules = FacetRules(max_grazing_deg=args.max_grazing_deg)
    if args.edge_a_m is not None:
        rules = replace(rules, edge_a_m=args.edge_a_m)
    if args.edge_b is not None:
        rules = replace(rules, edge_b=args.edge_b)
    inputs = [("--calib", args.calib), *(("LOG", p) for p in args.logs)]
    if args.trajectory is not None:
        inputs.append(("--trajectory", args.trajectory))
    output_files.check(inputs, [Output("-o", args.output, "mesh")], force=args.force)
    calib = calibfile.load(args.calib)
    mj = prepare_mesh(
        args.logs, calib, args.output, camera=args.camera, frame=args.frame,
        trajectory=args.trajectory, crs=args.crs, rules=rules, tile_m=args.tile_m,
        chunk_s=args.chunk, texels=(args.texels or TEXELS) if args.texture else None,
        simplify_m=args.simplify,
    )  # fmt: skip
    if mj.paths != [args.output] or textured_obj:  # now that the tiles are known
        outputs = [Output("-o", p, "mesh") for p in mj.paths]
        if textured_obj:
            outputs += [
                o
                for p in mj.paths
                for mtl, jpg in [texture_files(p)]
                for o in (Output("-o", mtl, "mesh"), Output("-o", jpg, "image"))
            ]
        output_files.check(inputs, outputs, force=args.force)
    report = mj.run(progress=args.progress or sys.stderr.isatty())
    print("\n".join(report.lines()))
    return 0
