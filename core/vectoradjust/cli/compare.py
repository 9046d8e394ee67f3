"""``vectoradjust compare``: adjust each road database of a project alone and tabulate
the results side by side (``compare.csv``, ``compare.json``, ``report.html``).
"""

from __future__ import annotations

import argparse
import csv
import json
import shutil
import sys
from pathlib import Path

from vectoradjust.cli import options
from vectoradjust.cli.adjust import StageBars, output_folder
from vectoradjust.cli.printing import compare_columns, compare_row, print_table, say_notes
from vectoradjust.cli.progress import ProgressBar
from vectoradjust.errors import NothingAdjustedError, VectorAdjustError

__all__ = ["add_parser", "cmd_compare", "compare"]


def compare(project, out_dir, fmt: str = "gpkg", quiet: bool = False) -> list:
    """Adjust every ``[[vectors]]`` entry alone and tabulate the results.

    A database that cannot be adjusted (no measured shape point, a DEM hole at a measured
    vertex, ...) gets a row with the reason in ``error``; the others are compared. All
    files are written into a staging folder and moved into ``out_dir`` at the end
    (:class:`~vectoradjust.files.outputs.RunFolder`).

    Returns
    -------
    list of dict
        One row per database (the columns of ``compare.csv``).

    Raises
    ------
    VectorAdjustError
        The project cannot be read, ``out_dir`` cannot be written or is locked by
        another run, or no database could be adjusted (each one's reason is named).
    """
    with output_folder(out_dir, "compare") as folder:
        rows, _ = _compare_into(project, folder, fmt, quiet)
    return rows


def _compare_into(project, folder, fmt: str, quiet: bool, adjusted=None) -> tuple:
    """:func:`compare` into an open RunFolder; (rows, names of the databases that failed
    with an error, not merely for want of measurements).

    Each database's report is drawn by another process while the next database is
    adjusted (with its part of the comparison report, the figures they share drawn
    once); ``adjusted()`` (optional) is called once every database is adjusted, before
    their reports are waited for (``demo`` finishes its first folder there)."""
    from vectoradjust.files.project import load_project
    from vectoradjust.files.readers import load_project_data
    from vectoradjust.files.report.figures import database_colors
    from vectoradjust.runner.project_run import close_reports

    spec = load_project(project)
    if not spec.vectors:
        raise VectorAdjustError(f"{project}: there are no [[vectors]] entries to compare",
                                "Add [[vectors]] entries (one per road database)")
    data = load_project_data(spec)
    colors = database_colors([v.name for v in spec.vectors])  # one colour per database
    pending: list = []  # the databases' reports, drawn while the next one is adjusted
    try:
        runs, rows, failed = _compare_each(spec, data, folder, (fmt, quiet, colors), pending)
        errors = [r["database"] for r in failed if r.pop("_error", False)]
        if not runs:
            if errors:
                raise VectorAdjustError(
                    f"{project}: no road database could be adjusted: "
                    + "; ".join(r["error"] for r in failed),
                    "Mend the inputs named above (the previous result in the output folder "
                    "is left as it was)")
            raise NothingAdjustedError(
                f"{project}: no road database has a measured shape point",
                "See the messages above: set id_field, or measure the shape points")
        if adjusted is not None:
            adjusted()
        _compare_report(folder.stage, runs, rows, colors, pending, quiet)
    finally:
        close_reports(pending)
    rows = rows + failed  # the databases that could not be adjusted, with the reason
    stage = folder.stage
    with open(stage / "compare.csv", "w", newline="", encoding="utf-8") as fh:
        cols = compare_columns(rows)
        w = csv.DictWriter(fh, fieldnames=[k for k, _ in cols])
        w.writeheader()
        for r in rows:
            w.writerow({k: ("" if r.get(k) is None else r.get(k)) for k, _ in cols})
    with open(stage / "compare.json", "w", encoding="utf-8") as fh:
        json.dump(rows, fh, indent=2)
    folder.commit()
    return rows, errors


def _compare_report(stage, runs: list, rows: list, colors: dict, pending: list,
                    quiet: bool) -> None:
    """The databases' reports waited for (their bars shown in turn), then the points
    used by several databases and the comparison report (its parts about the runs
    drawn beside their reports) written into ``stage``."""
    from vectoradjust.cli import study as cli_study
    from vectoradjust.files.report import write_compare_report
    from vectoradjust.runner.project_run import finish_reports

    finish_reports(pending)
    sections = {id(p.job.run): p.section for p in pending}
    cli_study.write_common_points(runs, stage)  # points used by several databases
    write_compare_report(runs, rows, stage / "report.html",
                         progress=ProgressBar("  report", enabled=not quiet), colors=colors,
                         sections=[sections.get(id(r)) for r in runs])


def _compare_each(spec, data, folder, how: tuple, pending: list) -> tuple:
    """Each database run alone into ``folder``/<name> (:func:`vectoradjust.runner.
    project_run.run_into`, as ``adjust --vectors NAME`` would); (runs, rows, failed rows).
    ``how``: (format, quiet, the databases' colours); the reports still being drawn are
    appended to ``pending``.

    A database that fails (any :class:`VectorAdjustError` but a cancel or a full disk) is
    reported and left out; the others go on. A failed row has ``_error`` true unless
    the database merely had no measured shape point."""
    from vectoradjust.errors import CancelledError
    from vectoradjust.files.outputs import is_disk_full
    from vectoradjust.runner.project_run import Project, RunOptions, run_into

    fmt, quiet, colors = how
    project = Project(spec, data)  # read once for all databases
    runs, rows, failed = [], [], []
    for i, v in enumerate(spec.vectors):
        target = folder.path / v.name
        bars = StageBars(quiet, f"{v.name:>8s} ",
                         {"adjust": f"{v.name:>8s} ({i + 1}/{len(spec.vectors)})"})
        try:
            result, _, _ = run_into(project, folder, target, RunOptions(
                fmt=fmt, vectors=[v.name], quiet=quiet, command="compare",
                compare_colors=colors), bars, reports=pending)
        except CancelledError:
            raise
        except VectorAdjustError as exc:  # this database only: the others go on
            if is_disk_full(exc):
                raise
            shutil.rmtree(folder.staged(target), ignore_errors=True)  # nothing half of it
            print(f"\nvectoradjust compare: {v.name}: {exc}", file=sys.stderr)
            failed.append({"database": v.name, "adjusted": 0, "error": str(exc),
                           "_error": not isinstance(exc, NothingAdjustedError)})
            continue
        rows.append(compare_row(result.summary))
        runs.append(result)
    return runs, rows, failed


def cmd_compare(args) -> int:
    """Run ``vectoradjust compare``: exit status 1 when a database failed with an error
    (the others are written and tabulated)."""
    with output_folder(args.out, "compare") as folder:
        rows, errors = _compare_into(args.project, folder, args.format, args.quiet)
    print(f"vectoradjust compare: {args.project} (each database adjusted alone)")
    print_table(rows)
    for r in rows:
        if r.get("error"):
            print(f"  {r['database']}: not adjusted (see compare.csv, column error)")
    print(f"  wrote {Path(args.out) / 'compare.csv'} and {Path(args.out) / 'report.html'}")
    say_notes(folder, args.quiet)
    if errors:  # finished what it could; the exit status says that some failed
        print(f"vectoradjust compare: {len(errors)} of {len(rows)} databases failed: "
              f"{', '.join(errors)} (the reasons are above and in compare.csv)",
              file=sys.stderr)
        return 1
    return 0


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Add ``vectoradjust compare`` to ``subparsers``; its parser."""
    c = options.add_project_command(subparsers, "compare", cmd_compare,
                                    "adjust each road database alone and compare")
    options.add_format(c)
    options.add_quiet(c, help="no progress bar or summary")
    return c
