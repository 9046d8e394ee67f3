"""``vectoradjust dtm``: DTM and contour accuracy of an adjusted project.

``vectoradjust dtm PROJECT.toml -o DIR [--cell 5] [--interpolation tin|bilinear|bicubic]
[--source points|dem] [--node-sigma S] [--correlation-length L] [--contour-interval 1]
[--profile X Y X Y ...] [--volume X Y X Y ...] [--reference-height Z] [--quiet]``
adjusts the project, builds the DTM (from the adjusted points with their full
covariance, or from the project's DEM with a stated node sigma), and writes
``DIR/dtm_accuracy.tif`` (height, sigma Z, LE90, ...), ``DIR/dtm_contours.gpkg``
(contours with their horizontal uncertainty buffers) and ``DIR/dtm.json`` (summary,
profile, volume).
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Optional

import numpy as np

from vectoradjust.cli import options
from vectoradjust.cli.tools import fmt_number, run_alone, write_json
from vectoradjust.errors import ProjectError

__all__ = ["add_parser", "cmd_dtm", "main"]


def _pairs(values, flag: str, least: int) -> np.ndarray:
    v = np.asarray(values, float)
    if v.size % 2 or v.size < 2 * least:
        raise ProjectError(f"{flag} {' '.join(f'{x:g}' for x in v)}: {v.size} numbers",
                           f"Give at least {least} X Y pairs: {flag} X1 Y1 X2 Y2 ...")
    return v.reshape(-1, 2)


def _dem_model(r, args):
    """The project's DEM (in the project CRS) with its node sigma, or a ProjectError."""
    from vectoradjust.accuracy.dtm import run_dem_model

    model = run_dem_model(r, args.node_sigma, args.correlation_length)
    if model is None:
        raise ProjectError("--source dem: the project has no DEM in its CRS",
                           "Give dem = \"...\" in a [[vectors]] entry, or use --source points")
    return model


def _model(r, args):
    from vectoradjust.accuracy.dtm import run_points_model

    if args.source == "dem":
        if args.interpolation == "tin":
            raise ProjectError("--source dem --interpolation tin: a DEM is a grid",
                               "Use --interpolation bilinear or bicubic with --source dem")
        return _dem_model(r, args)
    return run_points_model(r)


def _extras(product, args) -> dict:
    """Profile and volume entries of dtm.json (when asked for)."""
    from vectoradjust.accuracy.dtm import profile_accuracy, volume_accuracy

    out: dict = {}
    if args.profile is not None:
        pr = profile_accuracy(product, _pairs(args.profile, "--profile", 2))
        out["profile"] = pr.to_dict()
        print(f"  profile: {len(pr.h)} samples, {pr.chainage[-1]:.1f} m; rise sigma "
              f"{fmt_number(pr.sigma_rise)} m with covariances, "
              f"{fmt_number(pr.sigma_rise_no_cov)} m without")
    if args.volume is not None:
        poly = _pairs(args.volume, "--volume", 3)
        ref = args.reference_height
        if ref is None:
            from vectoradjust.accuracy.dtm import points_in_polygon

            inside = points_in_polygon(product.centres(), poly)
            ref = float(np.nanmin(np.where(inside, product.height.ravel(), np.nan)))
        v = volume_accuracy(product, poly, ref)
        out["volume"] = v.to_dict()
        print(f"  volume above {ref:.3f} m: {v.volume:.1f} m3 over {v.area:.0f} m2, sigma "
              f"{fmt_number(v.sigma)} m3 ({fmt_number(v.sigma_no_cov)} without covariances)")
    return out


def cmd_dtm(args) -> int:
    """Run ``vectoradjust dtm`` (see :func:`add_parser` for the arguments)."""
    from vectoradjust.accuracy.dtm import contour_segments, dtm_product, run_flying_height
    from vectoradjust.cli import propagate
    from vectoradjust.files.dtm_outputs import write_contours, write_dtm_raster

    t0 = time.perf_counter()
    if not args.cell > 0 or not args.contour_interval > 0:
        raise ProjectError(f"--cell {args.cell:g} / --contour-interval "
                           f"{args.contour_interval:g} must be positive",
                           "Give a positive cell size and contour interval in metres")
    r = propagate._adjust(args.project, args.quiet)
    t1 = time.perf_counter()
    model = _model(r, args)
    product = dtm_product(model, args.cell, args.interpolation,
                          flying_height=run_flying_height(r))
    seg = contour_segments(product, args.contour_interval)
    out = Path(args.out)
    tif = write_dtm_raster(product, out / "dtm_accuracy.tif", r.data.crs)
    gpkg = write_contours(seg, out / "dtm_contours.gpkg", r.data.crs)
    s = product.summary
    print(f"vectoradjust dtm: {args.project}: {s['method']} from the {s['source']}, "
          f"{s['cells']} cells of {args.cell:g} m")
    for key in ("sigma_interpolation", "sigma", "le90"):
        st = s[key]
        print(f"  {key:20s} min {fmt_number(st['min'])}  median {fmt_number(st['median'])}  "
              f"max {fmt_number(st['max'])} m")
    print(f"  added: sampling {fmt_number(product.sigma_sampling)} m "
          f"({s['sampling']['per_mille']:.2f} per mille of H), terrain "
          f"{fmt_number(product.sigma_terrain)} m (mean slope {s['mean_slope_percent']:.1f} %)")
    payload = {"project": str(args.project), "summary": s,
               "contours": {"interval": args.contour_interval, "segments": int(len(seg.level)),
                            "median_sigma_xy": (float(np.median(seg.sigma_xy))
                                                if len(seg.level) else None)},
               **_extras(product, args)}
    payload["seconds"] = {"adjust": t1 - t0, "dtm": time.perf_counter() - t1}
    path = write_json(out, "dtm.json", payload)
    print(f"  {len(seg.level)} contour segments at {args.contour_interval:g} m")
    print(f"  wrote {tif}\n  wrote {gpkg}\n  wrote {path}")
    return 0


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Add the ``dtm`` subcommand; its parser."""
    d = options.add_project_command(
        subparsers, "dtm", cmd_dtm,
        "DTM accuracy: sigma Z / LE90 per cell, contours with their uncertainty",
        "adjust the project and propagate the full covariance of the adjusted points (or a "
        "DEM's stated node sigma) through the DTM interpolation, add the sampling "
        "(Torlegard) and terrain (Li) terms; write dtm_accuracy.tif, dtm_contours.gpkg and "
        "dtm.json")
    d.add_argument("--cell", type=float, default=5.0, help="cell size in m")
    d.add_argument("--interpolation", choices=("tin", "bilinear", "bicubic"), default="tin",
                   help="TIN (linear in triangles), bilinear or bicubic")
    d.add_argument("--source", choices=("points", "dem"), default="points",
                   help="the adjusted points or the project's DEM")
    d.add_argument("--node-sigma", type=float, metavar="S",
                   help="sigma of a DEM node in m (--source dem) (default: the database's Z "
                        "sigma)")
    d.add_argument("--correlation-length", type=float, default=0.0, metavar="L",
                   help="correlation length of the DEM nodes' errors in m")
    options.add_contour_interval(d, default=1.0)
    d.add_argument("--profile", type=float, nargs="+", metavar="XY",
                   help="profile along the polyline X1 Y1 X2 Y2 ...")
    d.add_argument("--volume", type=float, nargs="+", metavar="XY",
                   help="volume over the polygon X1 Y1 X2 Y2 X3 Y3 ...")
    d.add_argument("--reference-height", type=float, metavar="Z",
                   help="reference plane of --volume (default: the lowest cell inside)")
    options.add_quiet(d)
    return d


def main(argv: Optional[Sequence[str]] = None) -> int:
    """Run ``vectoradjust dtm`` alone (``python -m vectoradjust.cli.dtm``)."""
    return run_alone(add_parser, "dtm", argv)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
