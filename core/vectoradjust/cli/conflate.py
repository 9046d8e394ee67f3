"""``vectoradjust conflate``: smart conflation of adjusted road databases.

``vectoradjust conflate SOURCE_A [SOURCE_B ...] -o DIR [--databases OSM TNM]
[--max-distance M] [--min-overlap F] [--by ce90|rmse] [--quiet]`` reads the adjusted
features of each SOURCE (an output folder of ``vectoradjust adjust``, all its databases
or those named by ``--databases``, or a vector file of adjusted features), matches them
feature by feature (:mod:`vectoradjust.conflation.smart`), keeps the more accurate feature
of each match and every unmatched one, and writes ``DIR/conflated.gpkg`` (layer
``conflated``), ``DIR/conflated.csv`` and ``DIR/summary.json``.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Optional

from vectoradjust.cli import options
from vectoradjust.cli.tools import run_alone
from vectoradjust.errors import ProjectError

__all__ = ["add_parser", "cmd_conflate", "main"]


def _check(args) -> None:
    if args.max_distance is not None and not args.max_distance > 0:
        raise ProjectError(f"--max-distance {args.max_distance:g} must be positive",
                           "Give the largest distance of two matching lines in metres, "
                           "or leave it out (2 x the larger CE90, at least 5 m)")
    if not 0.0 < args.min_overlap <= 1.0:
        raise ProjectError(f"--min-overlap {args.min_overlap:g} must be in (0, 1]",
                           "Give the least share of a line along its match, e.g. 0.5")
    out = Path(args.out).resolve()
    for s in args.sources:
        if Path(s).resolve() == out:
            raise ProjectError(f"-o {args.out} is the SOURCE folder {s}: its summary.json "
                               "would be overwritten", "Give another output folder")


def cmd_conflate(args) -> int:
    """Run ``vectoradjust conflate`` (see :func:`add_parser` for the arguments)."""
    from vectoradjust.conflation.smart import smart_conflate, summarise
    from vectoradjust.files.smart_outputs import (
        conflated_frame,
        feature_sets,
        read_sources,
        summary_table,
        write_smart,
    )

    t0 = time.perf_counter()
    _check(args)
    sources = read_sources(args.sources, args.databases)
    sets = feature_sets(sources)
    result, steps = smart_conflate(sets, args.max_distance, args.min_overlap, args.by)
    frame = conflated_frame(sources, result)
    summary = summarise(result)
    summary.update({
        "sources": [str(s) for s in args.sources], "by": args.by,
        "max_distance": args.max_distance, "min_overlap": args.min_overlap,
        "steps": [{"matched": int(len(m.a)), "candidates": int(m.candidates),
                   "against": sets[k + 1].name} for k, m in enumerate(steps)],
        "seconds": time.perf_counter() - t0})
    paths = write_smart(frame, summary, args.out)
    if not args.quiet:
        names = ", ".join(s.name for s in sets)
        print(f"vectoradjust conflate: {names}: {summary['features']} features, "
              f"{summary['matched']} matched (by {args.by})")
        print(summary_table(summary))
        for key in ("gpkg", "csv", "summary"):
            print(f"  wrote {paths[key]}")
    return 0


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Add the ``conflate`` subcommand; its parser."""
    c = options.add_command(
        subparsers, "conflate", cmd_conflate,
        "smart conflation: the more accurate feature of each match of two or more adjusted "
        "road databases",
        "match the adjusted features of two or more road databases by geometry (names and "
        "classes as a bonus), keep per match the one with the smaller CE90 (tie: smaller "
        "RMSE), carry unmatched features through; write conflated.gpkg (layer conflated), "
        "conflated.csv and summary.json")
    c.add_argument("sources", nargs="+", metavar="SOURCE",
                   help="output folder of 'vectoradjust adjust' or vector file of "
                        "adjusted features (with CE90)")
    options.add_out(c)
    c.add_argument("--databases", nargs="+", metavar="NAME",
                   help="only these databases of the sources, in this order (default: all)")
    c.add_argument("--max-distance", type=float, default=None, metavar="M",
                   help="largest distance of two matching lines in m (default: per pair "
                        "2 x the larger CE90, at least 5 m)")
    c.add_argument("--min-overlap", type=float, default=0.5, metavar="F",
                   help="least share of each line within the distance of the other")
    c.add_argument("--by", choices=("ce90", "rmse"), default="ce90",
                   help="which uncertainty decides: ce90 (tie: RMSE) or rmse (the mean "
                        "adjusted displacement; tie: CE90)")
    options.add_quiet(c, help="print nothing")
    return c


def main(argv: Optional[Sequence[str]] = None) -> int:
    """Run ``vectoradjust conflate`` alone (``python -m vectoradjust.cli.conflate``)."""
    return run_alone(add_parser, "conflate", argv)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
