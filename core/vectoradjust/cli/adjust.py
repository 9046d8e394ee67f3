"""``vectoradjust adjust``: adjust the road vectors of a project (:func:`vectoradjust.
run_project`), print the summary; and what ``compare`` and ``demo`` share with it (the
run options from the flags, the progress bars per stage, the output folder).
"""

from __future__ import annotations

import argparse
from typing import Optional

from vectoradjust.cli import options
from vectoradjust.cli.printing import print_summary, say_notes
from vectoradjust.cli.progress import ProgressBar

__all__ = ["add_parser", "cmd_adjust", "run_options", "StageBars", "output_folder"]


class StageBars:
    """The command line's progress bars for :func:`vectoradjust.run_project`: one
    :class:`ProgressBar` per stage of the run (``adjust``, ``truth``, ``truth tables``,
    ``write``, ``report``), labelled ``labels.get(stage, prefix + stage)``."""

    def __init__(self, quiet: bool = False, prefix: str = "",
                 labels: Optional[dict] = None) -> None:
        self.quiet, self.prefix, self.labels = quiet, prefix, labels or {}

    def stage(self, name: str) -> ProgressBar:
        """The bar of stage ``name`` (its clock starts now)."""
        return ProgressBar(self.labels.get(name, self.prefix + name), enabled=not self.quiet)


def output_folder(path, command: str = "adjust"):
    """``--out`` as a :class:`~vectoradjust.files.outputs.RunFolder`: entered before the
    work, it creates the folder and takes its lock (a folder that cannot be written, or
    that another run is writing into, is a clear error before the work, not after it);
    the run writes into its staging folder, and its commit moves the files into place."""
    from vectoradjust.files.outputs import RunFolder

    return RunFolder(path, command=command)


def run_options(args, **more):
    """The :class:`~vectoradjust.runner.project_run.RunOptions` the flags of ``args``
    set (``--format``, ``--vectors``, ``--no-bands``, ``--datum``,
    ``--conflation-raster``, ``-q``), with ``more`` on top."""
    from vectoradjust.runner.project_run import RunOptions

    return RunOptions(fmt=args.format, vectors=getattr(args, "vectors", None),
                      bands=not getattr(args, "no_bands", False),
                      datum=getattr(args, "datum", None),
                      conflation_raster=getattr(args, "conflation_raster", False),
                      quiet=args.quiet, **more)


def cmd_adjust(args) -> int:
    """Run ``vectoradjust adjust`` (:func:`vectoradjust.run_project`)."""
    from vectoradjust.runner.project_run import run_project

    # the folder is made and locked before the work; everything is written into its
    # staging folder and moved into place at the end: an interrupted or failed run
    # leaves the previous result as it was
    done = run_project(args.project, args.out, run_options(args),
                       progress=StageBars(args.quiet))
    if not args.quiet:
        print(f"vectoradjust adjust: {args.project}")
        print_summary(done.summary)
        for name in done.written.values():
            print(f"  wrote {name}")
    say_notes(done.notes, args.quiet)
    return 0


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Add ``vectoradjust adjust`` to ``subparsers``; its parser."""
    a = options.add_project_command(subparsers, "adjust", cmd_adjust,
                                    "adjust the road vectors of a project")
    options.add_vectors(a)
    options.add_no_bands(a)
    a.add_argument("--datum", choices=("auto", "free"), default=None,
                   help="auto: the datum from control points, camera priors and control "
                        "databases (checked before the solve); free: a free network (no "
                        "priors, inner constraints), relative precision only (default: the "
                        "project's [adjustment] datum, else auto)")
    a.add_argument("--conflation-raster", action="store_true",
                   help="also write each database's conflation field as a GeoTIFF "
                        "(conflation_<name>.tif: dX, dY, dZ, CE90, LE90)")
    options.add_format(a)
    options.add_quiet(a, help="no progress bar or summary")
    return a
