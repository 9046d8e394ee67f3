"""Subcommands for derived quantities: ``propagate``, ``equal-error`` and ``two-step``.

* ``vectoradjust propagate PROJECT.toml --out DIR (--distance ID_A ID_B [--3d] |
  --length ID ID ... | --mean-height ID ... | --profile FEATURE_ID [--database NAME])``
  adjusts the project and prints the derived quantity with its sigma with and without
  the covariances between the points; writes ``DIR/propagate.json``.
* ``vectoradjust equal-error PROJECT.toml --out DIR [--spacing 10] [--images A B]``
  writes the equal-error map ``DIR/equal_error.tif`` (sigma X, Y, Z of a point
  intersected from the stereo pair) and ``DIR/equal_error.json``, and prints its range.
* ``vectoradjust two-step PROJECT.toml --out DIR [--images A B]`` compares the
  two-step orientation (relative + absolute) of a stereo pair with the bundle
  adjustment; prints a table and writes ``DIR/two_step.json``.

The console script registers them with :func:`add_parsers`; ``python -m
vectoradjust.cli.propagate`` runs them alone.
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
from vectoradjust.cli.tools import fmt_number, run_command, write_json

__all__ = ["add_parsers", "cmd_propagate", "cmd_equal_error", "cmd_two_step", "main"]


def _adjust(project: str, quiet: bool):
    """Load and adjust a project (with a progress bar unless quiet)."""
    from vectoradjust.files.readers import load_project_data
    from vectoradjust.pipeline import run

    progress = None
    if not quiet:
        from vectoradjust.cli.progress import ProgressBar

        progress = ProgressBar("adjust")
    data = load_project_data(project)
    return run(data, progress=progress)


def _f(v, nd: int = 4) -> str:
    return fmt_number(v, nd)


# ------------------------------------------------------------------------- propagate
def cmd_propagate(args) -> int:
    """Run ``vectoradjust propagate``."""
    from vectoradjust.accuracy import derived

    t0 = time.perf_counter()
    r = _adjust(args.project, args.quiet)
    payload: dict = {"project": str(args.project), "sigma0_squared": r.result.sigma0_squared}
    print(f"vectoradjust propagate: {args.project}")
    if args.profile is not None:
        pr = derived.profile(r, args.profile, args.database)
        payload["profile"] = pr.to_dict()
        print(f"  height profile of feature {pr.feature_id} ({pr.database}): "
              f"{len(pr.z)} vertices, {int(pr.adjusted.sum())} adjusted")
        print(f"  {'point_id':>16s} {'part':>4s} {'chainage':>10s} {'sd chain':>9s} "
              f"{'sd nocov':>9s} {'Z':>10s} {'sd Z':>8s}")
        for i in range(len(pr.z)):
            print(f"  {str(pr.vertex_ids[i]):>16s} {int(pr.part[i]):4d} "
                  f"{_f(pr.chainage[i], 3):>10s} {_f(pr.sigma_chainage[i]):>9s} "
                  f"{_f(pr.sigma_chainage_no_cov[i]):>9s} {_f(pr.z[i], 3):>10s} "
                  f"{_f(pr.sigma_z[i]):>8s}")
        results = [v for v in (pr.mean_height, pr.rise) if v is not None]
    else:
        if args.distance is not None:
            res = derived.distance_between(r, args.distance[0], args.distance[1],
                                           dims=3 if args.three_d else 2)
        elif args.length is not None:
            res = derived.length_between(r, args.length, dims=3 if args.three_d else 2)
        else:
            res = derived.mean_height_between(r, args.mean_height)
        results = [res]
    for v in results:
        ratio = v.sigma / v.sigma_no_cov if v.sigma_no_cov > 0 else float("nan")
        print(f"  {v.quantity}: {v.value:.4f} m   sigma {v.sigma:.4f} m with covariances, "
              f"{v.sigma_no_cov:.4f} m without (ratio {_f(ratio, 3)})")
    payload["results"] = [v.to_dict() for v in results]
    payload["seconds"] = time.perf_counter() - t0
    path = write_json(args.out, "propagate.json", payload)
    print(f"  wrote {path}")
    return 0


# ----------------------------------------------------------------------- equal error
def _dem_sampler(r):
    """``z(X, Y)`` from the first DEM of the project's road databases, or None."""
    from vectoradjust.files.readers import sample_dem

    dems = [d.spec.dem for d in r.databases if getattr(d.spec, "dem", None)]
    if not dems:
        return None, None
    path = dems[0]

    def z(x, y):
        xy = np.column_stack([np.ravel(x), np.ravel(y)])
        return sample_dem(path, xy, r.data.crs).reshape(np.shape(x))

    return z, path


def cmd_equal_error(args) -> int:
    """Run ``vectoradjust equal-error``."""
    from vectoradjust.accuracy import derived
    from vectoradjust.files.derived_outputs import write_equal_error_map

    t0 = time.perf_counter()
    r = _adjust(args.project, args.quiet)
    z, dem = (None, None) if args.flat else _dem_sampler(r)
    grid = derived.equal_error_grid(r, args.spacing, args.images, z)
    rng = derived.equal_error_range(grid)
    out = Path(args.out)
    tif = write_equal_error_map(grid, out / "equal_error.tif", r.data.crs)
    pair = args.images or r.image_ids[:2]
    payload = {"project": str(args.project), "images": list(pair), "heights": dem or "mean",
               "transform": list(grid.transform), "shape": list(grid.X.shape), **rng,
               "seconds": time.perf_counter() - t0}
    path = write_json(out, "equal_error.json", payload)
    print(f"vectoradjust equal-error: {args.project}, images {pair[0]} and {pair[1]}, "
          f"{rng['nodes']} nodes at {args.spacing:g} m, heights from {dem or 'the mean terrain'}")
    for name in ("sigma_x", "sigma_y", "sigma_h", "sigma_z"):
        s = rng[name]
        print(f"  {name:8s} min {_f(s['min'])}  max {_f(s['max'])}  mean {_f(s['mean'])} m")
    print(f"  wrote {tif}\n  wrote {path}")
    return 0


# -------------------------------------------------------------------------- two-step
def format_two_step(c: dict) -> str:
    """The comparison table of :func:`vectoradjust.accuracy.derived.compare_two_step`."""
    lines = [
        f"  two-step orientation of {c['images'][0]} / {c['images'][1]} ({c['method']}): "
        f"{c['n_points']} points ({c['control_points']} control, {c['shape_points']} shape, "
        f"{c['tie_points']} tie)",
        f"  relative orientation s0 {_f(c['relative_s0'], 3)}, absolute orientation s0 "
        f"{_f(c['absolute_s0'], 3)}; bundle s0^2 {_f(c['bundle_sigma0_squared'], 3)}",
        "  |two-step - bundle| (m)        mean      max",
    ]
    d = c["difference"]
    for key, label in (("xy", "shape points XY"), ("z", "shape points Z"),
                       ("tie_xy", "tie points XY"), ("tie_z", "tie points Z"),
                       ("control_xy", "control points XY"), ("control_z", "control points Z")):
        lines.append(f"    {label:26s} {_f(d[key]['mean']):>8s} {_f(d[key]['max']):>8s}")
    lines.append("  sigma two-step / sigma bundle (median; same a-priori footing)")
    lines.append(f"    {'':26s} {'x':>8s} {'y':>8s} {'z':>8s}")
    for grp, label in (("sigma_ratio", "shape"), ("tie_sigma_ratio", "tie"),
                       ("control_sigma_ratio", "control")):
        for cov in ("rigorous", "classical"):
            s = c[grp][cov]
            lines.append(f"    {label + ', ' + cov:26s} " + " ".join(
                f"{_f(s[ax]['median'], 3):>8s}" for ax in "xyz"))
    return "\n".join(lines)


def cmd_two_step(args) -> int:
    """Run ``vectoradjust two-step``."""
    from vectoradjust.accuracy import derived

    t0 = time.perf_counter()
    r = _adjust(args.project, args.quiet)
    c = derived.compare_two_step(r, args.images, method=args.method)
    c["project"] = str(args.project)
    c["seconds"] = time.perf_counter() - t0
    print(f"vectoradjust two-step: {args.project}")
    print(format_two_step(c))
    path = write_json(args.out, "two_step.json", c)
    print(f"  wrote {path}")
    return 0


# ---------------------------------------------------------------------------- parsers
def _pair_command(subparsers, name: str, func, help: str, description: str):
    """A subcommand on a project's stereo pair: ``project``, ``-o``, ``--images A B``,
    ``-q`` (``equal-error``, ``two-step``)."""
    p = options.add_project_command(subparsers, name, func, help, description,
                                    f"output directory ({name.replace('-', '_')}.json)")
    options.add_pair(p)
    options.add_quiet(p)
    return p


def add_parsers(subparsers) -> dict:
    """Add the ``propagate``, ``equal-error`` and ``two-step`` subcommands.

    Parameters
    ----------
    subparsers : argparse._SubParsersAction
        From ``ArgumentParser.add_subparsers()``.

    Returns
    -------
    dict of str to argparse.ArgumentParser
        The three parsers by name (each has its ``func`` default).
    """
    p = options.add_project_command(
        subparsers, "propagate", cmd_propagate,
        "a derived quantity (distance, length, mean height, profile) with its sigma with and "
        "without covariances",
        "adjust the project and propagate the a-posteriori covariance of the adjusted points "
        "(covariances between points included) to a distance, a length, a mean height or a "
        "height profile; write propagate.json", out_help="output directory (propagate.json)")
    g = p.add_mutually_exclusive_group(required=True)
    g.add_argument("--distance", nargs=2, metavar=("ID_A", "ID_B"),
                   help="distance between two points (control, tie or shape point ids)")
    g.add_argument("--length", nargs="+", metavar="ID",
                   help="length of the polyline through these points, in order")
    g.add_argument("--mean-height", nargs="+", metavar="ID", help="average height of points")
    g.add_argument("--profile", metavar="FEATURE_ID",
                   help="height profile along a road feature (sigma per vertex)")
    p.add_argument("--3d", dest="three_d", action="store_true",
                   help="spatial instead of horizontal distance / length")
    p.add_argument("--database", metavar="NAME",
                   help="road database of --profile (when the id is in several)")
    options.add_quiet(p)

    e = _pair_command(
        subparsers, "equal-error", cmd_equal_error,
        "equal-error map of a stereo pair (GeoTIFF of sigma X, Y, Z)",
        "adjust the project and write the sigma X, Y, Z of a point intersected from the "
        "stereo pair, on a grid over the overlap (equal_error.tif, equal_error.json)")
    e.add_argument("--spacing", type=float, default=10.0, help="grid spacing in m")
    e.add_argument("--flat", action="store_true",
                   help="use the mean terrain height, not the project's DEM")

    t = _pair_command(
        subparsers, "two-step", cmd_two_step,
        "two-step orientation (relative + absolute) vs the bundle adjustment",
        "orient a stereo pair in two steps (relative orientation, 3D similarity to the "
        "control) and compare its points and sigmas with the bundle adjustment's; write "
        "two_step.json")
    t.add_argument("--method", choices=("collinearity", "coplanarity"), default="collinearity",
                   help="relative orientation formulation")
    return {"propagate": p, "equal-error": e, "two-step": t}


def main(argv: Optional[Sequence[str]] = None) -> int:
    """Run one of the subcommands alone (``python -m vectoradjust.cli.propagate``)."""
    parser = argparse.ArgumentParser(prog="vectoradjust")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    add_parsers(sub)
    args = parser.parse_args(argv)
    return run_command(args)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
