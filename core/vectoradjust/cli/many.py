"""``vectoradjust adjust-many``: many independent projects on Dask.

``vectoradjust adjust-many P1.toml P2.toml ... --out DIR [--scheduler ADDRESS]
[--workers N] [--memory-limit SIZE] [--no-merge]`` adjusts every project as ``adjust``
does, each into ``DIR/<project name>/``, on a local Dask cluster of worker processes (or
the distributed scheduler at ADDRESS), and writes ``DIR/many_summary.csv``,
``DIR/many_summary.json`` and ``DIR/merged_<database>.gpkg`` (every project's
shape_points and features, with a ``project`` column). A project
that fails is listed with its error (and again at the end, on stderr, with its
project file); the others go on. The exit status is 0 when every project was adjusted, 1
when one or more failed. Python API:
:func:`vectoradjust.files.many.adjust_many`.
"""

from __future__ import annotations

import argparse
import sys

from vectoradjust.cli import options
from vectoradjust.cli.progress import ProgressBar

__all__ = ["add_parser", "cmd_adjust_many"]


def cmd_adjust_many(args) -> int:
    """Run ``vectoradjust adjust-many`` (see :func:`add_parser`)."""
    from vectoradjust.files.many import adjust_many

    bar = ProgressBar("adjust-many", enabled=not args.quiet)
    bar(0.0, f"{len(args.projects)} projects on "
        f"{args.scheduler or 'a local cluster'}")
    rows = adjust_many(args.projects, args.out, scheduler=args.scheduler, workers=args.workers,
                       fmt=args.format, bands=not args.no_bands, report=not args.no_report,
                       merge=not args.no_merge, memory_limit=args.memory_limit, progress=bar)
    failed = [r for r in rows if r.get("status") != "ok"]
    if not args.quiet:
        print(f"vectoradjust adjust-many: {len(rows) - len(failed)} of {len(rows)} projects "
              f"adjusted into {args.out}")
        for r in rows:
            s0 = r.get("sigma0_squared")
            what = (f"sigma0^2 {s0:.4f}, check RMSE h {r.get('check_rmse_horizontal')}"
                    if r.get("status") == "ok" and s0 is not None else r.get("error"))
            print(f"  {r['name']:24s} {r['status']:6s} {what}")
        print(f"  wrote {args.out}/many_summary.csv and many_summary.json"
              + ("" if args.no_merge else ", merged_<database>.gpkg"))
    if failed:  # always said, also with --quiet: the exit status alone names nobody
        print(f"vectoradjust adjust-many: {len(failed)} of {len(rows)} projects failed "
              f"(many_summary.json, failures):", file=sys.stderr)
        for r in failed:
            print(f"  {r['name']} ({r['project']}): {r.get('error')}", file=sys.stderr)
    return 1 if failed else 0


def add_parser(sub) -> argparse.ArgumentParser:
    """Register ``vectoradjust adjust-many``; its parser."""
    m = options.add_command(sub, "adjust-many", cmd_adjust_many,
                            "adjust many independent projects on Dask (local processes or a "
                            "distributed scheduler) with one combined summary")
    m.add_argument("projects", nargs="+", help="project files (TOML)")
    options.add_out(m, help="output directory: DIR/<project name>/ each, and "
                            "many_summary.csv/.json")
    m.add_argument("--scheduler", metavar="ADDRESS",
                   help="address of a dask.distributed scheduler (tcp://host:8786), or "
                        "processes/threads/sync for Dask's local schedulers (default: a "
                        "LocalCluster of worker processes)")
    m.add_argument("--workers", type=int, help="worker processes of the local cluster or "
                   "scheduler (default: the number of cores)")
    m.add_argument("--memory-limit", metavar="SIZE", help="memory of each local-cluster "
                   "worker, e.g. 1GB (default: Dask's, the machine's memory shared)")
    m.add_argument("--no-merge", action="store_true", help="no merged_<database>.gpkg "
                   "(every project's shape_points and features with a project column)")
    options.add_format(m)
    options.add_no_bands(m)
    m.add_argument("--no-report", action="store_true", help="no report.html per project")
    options.add_quiet(m, help="no progress or table")
    return m
