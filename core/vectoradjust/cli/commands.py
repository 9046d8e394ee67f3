"""The ``vectoradjust`` command line.

Subcommands (``docs/method.md`` section 9): ``demo``, ``adjust``, ``compare``. User errors
print one clear message and exit with status 1; usage errors exit with 2; an
interrupted run exits with 130.
"""

from __future__ import annotations

import argparse
import csv
import json
import shutil
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Optional

from vectoradjust import __version__
from vectoradjust.cli import buffer as cli_buffer
from vectoradjust.cli import conflate as cli_conflate
from vectoradjust.cli import drone as cli_drone
from vectoradjust.cli import dtm as cli_dtm
from vectoradjust.cli import many as cli_many
from vectoradjust.cli import measure as cli_measure
from vectoradjust.cli import propagate as cli_propagate
from vectoradjust.cli import qa as cli_qa
from vectoradjust.cli import study as cli_study
from vectoradjust.cli.progress import ProgressBar
from vectoradjust.cli.tools import run_command
from vectoradjust.errors import NothingAdjustedError, VectorAdjustError

__all__ = ["main", "ProgressBar", "StageBars", "sample_project_dir", "compare", "compare_row",
           "print_table", "run_options"]


def compare_row(summary: dict) -> dict:
    """:func:`vectoradjust.accuracy.summary.compare_row` (imported when first used: the
    command line starts reading its inputs without loading the statistics)."""
    from vectoradjust.accuracy.summary import compare_row as row

    return row(summary)


def compare_columns(rows: list) -> list:
    """:func:`vectoradjust.accuracy.summary.compare_columns` (imported when used)."""
    from vectoradjust.accuracy.summary import compare_columns as cols

    return cols(rows)


def sample_project_dir() -> Path:
    """Directory of the embedded sample project
    (:func:`vectoradjust.runner.project_run.sample_project_dir`)."""
    from vectoradjust.runner.project_run import sample_project_dir as sample

    return sample()


def _fmt(v, nd=3) -> str:
    if v is None:
        return "-"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, (int,)):
        return str(v)
    try:
        return f"{float(v):.{nd}f}"
    except (TypeError, ValueError):
        return str(v)


def _print_summary(summary: dict, out=None) -> None:
    out = out or sys.stdout
    chi = summary["chi_square"]
    print(f"  sigma0^2 = {_fmt(summary['sigma0_squared'], 4)} with {summary['degrees_of_freedom']}"
          f" degrees of freedom, {summary['iterations']} iterations", file=out)
    if chi.get("lower") is not None:
        print(f"  chi-square test (alpha = {chi['alpha']}): v'Pv = {_fmt(chi['statistic'], 2)} in "
              f"[{_fmt(chi['lower'], 2)}, {_fmt(chi['upper'], 2)}]: "
              f"{'passed' if chi['passed'] else 'FAILED'}", file=out)
    for key, label in (("shape_points", "shape points (residuals)"),
                       ("control_points", "control points"),
                       ("check_points", "check points")):
        s = summary.get(key) or {}
        if s.get("count"):
            print(f"  {label:26s} n = {s['count']:5d}  RMSE x {_fmt(s['rmse_x'])}  y "
                  f"{_fmt(s['rmse_y'])}  z {_fmt(s['rmse_z'])}  horizontal "
                  f"{_fmt(s['rmse_horizontal'])} m", file=out)
    if summary.get("mean_ce90") is not None:
        print(f"  mean CE90 {_fmt(summary['mean_ce90'])} m, mean LE90 "
              f"{_fmt(summary['mean_le90'])} m", file=out)
    interior = summary.get("interior_orientation")
    if interior:
        from vectoradjust.sensor.interior import describe_interior

        for line in describe_interior(interior):
            print(f"  {line}", file=out)
    for w in summary.get("warnings", []):
        print(f"  warning: {w}", file=out)


def print_table(rows: list, out=None) -> None:
    """Print the side-by-side comparison table."""
    out = out or sys.stdout
    cols = [(k, h) for k, h in compare_columns(rows) if k != "error"]
    heads = [h for _, h in cols]
    cells = [[_fmt(r.get(k)) if k != "database" else str(r.get(k)) for k, _ in cols]
             for r in rows]
    widths = [max(len(h), *(len(c[i]) for c in cells)) for i, h in enumerate(heads)]
    print("  ".join(h.rjust(w) for h, w in zip(heads, widths)), file=out)
    for c in cells:
        print("  ".join(v.rjust(w) for v, w in zip(c, widths)), file=out)


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


def _output_folder(path, command: str = "adjust"):
    """``--out`` as a :class:`~vectoradjust.files.outputs.RunFolder`: entered before the
    work, it creates the folder and takes its lock (a folder that cannot be written, or
    that another run is writing into, is a clear error before the work, not after it);
    the run writes into its staging folder, and its commit moves the files into place."""
    from vectoradjust.files.outputs import RunFolder

    return RunFolder(path, command=command)


def _say_notes(notes, quiet: bool) -> None:
    """What the commit of the output folder said (``notes``, or a RunFolder's): the
    previous run's files removed (unless quiet), files of earlier runs left in place
    (always, on stderr)."""
    for kind, text in getattr(notes, "notes", notes):
        if kind == "warning":
            print(f"vectoradjust: warning: {text}", file=sys.stderr)
        elif not quiet:
            print(f"  note: {text}")


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
        _print_summary(done.summary)
        for name in done.written.values():
            print(f"  wrote {name}")
    _say_notes(done.notes, args.quiet)
    return 0



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
    with _output_folder(out_dir, "compare") as folder:
        rows, _ = _compare_into(project, folder, fmt, quiet)
    return rows


def _compare_into(project, folder, fmt: str, quiet: bool) -> tuple:
    """:func:`compare` into an open RunFolder; (rows, names of the databases that failed
    with an error, not merely for want of measurements)."""
    from vectoradjust.files.project import load_project
    from vectoradjust.files.readers import load_project_data

    spec = load_project(project)
    if not spec.vectors:
        raise VectorAdjustError(f"{project}: there are no [[vectors]] entries to compare",
                                "Add [[vectors]] entries (one per road database)")
    from vectoradjust.files.report import write_compare_report

    data = load_project_data(spec)
    runs, rows, failed = _compare_each(spec, data, folder, fmt, quiet)
    errors = [r["database"] for r in failed if r.pop("_error", False)]
    if not runs:
        if errors:
            raise VectorAdjustError(
                f"{project}: no road database could be adjusted: "
                + "; ".join(r["error"] for r in failed),
                "Mend the inputs named above (the previous result in the output folder is "
                "left as it was)")
        raise NothingAdjustedError(
            f"{project}: no road database has a measured shape point",
            "See the messages above: set id_field, or measure the shape points")
    stage = folder.stage
    cli_study.write_common_points(runs, stage)  # points used by several databases
    write_compare_report(runs, rows, stage / "report.html",
                         progress=ProgressBar("  report", enabled=not quiet))
    rows = rows + failed  # the databases that could not be adjusted, with the reason
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


def _compare_each(spec, data, folder, fmt: str, quiet: bool) -> tuple:
    """Each database run alone into ``folder``/<name> (:func:`vectoradjust.runner.
    project_run.run_into`, as ``adjust --vectors NAME`` would); (runs, rows, failed rows).

    A database that fails (any :class:`VectorAdjustError` but a cancel or a full disk) is
    reported and left out; the others go on. A failed row has ``_error`` true unless
    the database merely had no measured shape point."""
    from vectoradjust.errors import CancelledError
    from vectoradjust.files.outputs import is_disk_full
    from vectoradjust.runner.project_run import Project, RunOptions, run_into

    project = Project(spec, data)  # read once for all databases
    runs, rows, failed = [], [], []
    for i, v in enumerate(spec.vectors):
        target = folder.path / v.name
        bars = StageBars(quiet, f"{v.name:>8s} ",
                         {"adjust": f"{v.name:>8s} ({i + 1}/{len(spec.vectors)})"})
        try:
            result, _, _ = run_into(project, folder, target, RunOptions(
                fmt=fmt, vectors=[v.name], quiet=quiet, command="compare"), bars)
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
    with _output_folder(args.out, "compare") as folder:
        rows, errors = _compare_into(args.project, folder, args.format, args.quiet)
    print(f"vectoradjust compare: {args.project} (each database adjusted alone)")
    print_table(rows)
    for r in rows:
        if r.get("error"):
            print(f"  {r['database']}: not adjusted (see compare.csv, column error)")
    print(f"  wrote {Path(args.out) / 'compare.csv'} and {Path(args.out) / 'report.html'}")
    _say_notes(folder, args.quiet)
    if errors:  # finished what it could; the exit status says that some failed
        print(f"vectoradjust compare: {len(errors)} of {len(rows)} databases failed: "
              f"{', '.join(errors)} (the reasons are above and in compare.csv)",
              file=sys.stderr)
        return 1
    return 0


def cmd_demo(args) -> int:
    project = sample_project_dir() / "project.toml"
    out = Path(args.out)
    print(f"vectoradjust demo: sample project {project}")
    print("  all road databases adjusted together ->", out / "all")
    ns = argparse.Namespace(project=str(project), out=str(out / "all"), format=args.format,
                            vectors=None, quiet=args.quiet)
    cmd_adjust(ns)
    print("\n  each database alone (compare) ->", out / "compare")
    rows = compare(project, out / "compare", fmt=args.format, quiet=args.quiet)
    print_table(rows)
    print("\n  (RMSE x/y/z/h: of the residuals V = adjusted - database; recovery = the smaller "
          "of RMSE(V) and RMSE(database - truth) over the larger; improvement = 1 - "
          "RMSE(adjusted - truth) / RMSE(database - truth))")
    print(f"  reports: {out / 'all' / 'report.html'}, {out / 'compare' / 'report.html'}")
    _demo_satellite(sample_project_dir() / "satellite", out / "satellite", args)
    return 0


def _demo_satellite(folder: Path, out: Path, args) -> None:
    """The demo's second part: the satellite sample (RPC triplet) adjusted, its bias and
    its OSM row printed."""
    import csv
    import json

    print(f"\n  satellite triplet with RPCs ({folder / 'project.toml'}) ->", out)
    ns = argparse.Namespace(project=str(folder / "project.toml"), out=str(out),
                            format=args.format, vectors=None, quiet=True)
    cmd_adjust(ns)
    summary = json.loads((out / "summary.json").read_text(encoding="utf-8"))
    with open(folder / "truth_bias.csv", newline="", encoding="utf-8") as fh:
        truth = {r["image_id"]: r for r in csv.DictReader(fh)}
    print("  image   bias  a0 (columns)      b0 (rows)  px   true a0     b0   corrected RPC")
    for e in summary["images"]:
        b, sd, t = e["bias"], e["sigma_bias"], truth.get(e["id"], {})
        print(f"  {e['id']:>5s}  {b['a0']:7.3f} +-{sd['a0']:.3f}  {b['b0']:7.3f} +-{sd['b0']:.3f}"
              f"     {float(t.get('a0', 'nan')):7.3f} {float(t.get('b0', 'nan')):7.3f}   "
              f"{e.get('corrected_rpc', {}).get('file', '-')}")
    print_table([compare_row(summary)])
    print(f"  report: {out / 'report.html'}")


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of the ``vectoradjust`` command."""
    p = argparse.ArgumentParser(
        prog="vectoradjust",
        description="Photogrammetric adjustment of road vectors: how far each vertex is from "
                    "the truth, where it belongs, and how sure that is.",
    )
    p.add_argument("--version", action="version", version=f"vectoradjust {__version__}")
    sub = p.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True

    def common(sp):
        sp.add_argument("--format", choices=("gpkg", "shp"), default="gpkg",
                        help="output format (default gpkg)")
        sp.add_argument("-q", "--quiet", action="store_true", help="no progress bar or summary")

    d = sub.add_parser("demo", help="run the embedded sample project end to end")
    d.add_argument("-o", "--out", default="vectoradjust-demo", help="output directory "
                   "(default ./vectoradjust-demo)")
    common(d)
    d.set_defaults(func=cmd_demo)

    a = sub.add_parser("adjust", help="adjust the road vectors of a project")
    a.add_argument("project", help="project file (TOML)")
    a.add_argument("-o", "--out", required=True, help="output directory")
    a.add_argument("--vectors", action="append", metavar="NAME",
                   help="adjust only this [[vectors]] entry (repeatable)")
    a.add_argument("--no-bands", action="store_true",
                   help="do not write the uncertainty_bands layer (saves time on large runs)")
    a.add_argument("--datum", choices=("auto", "free"), default=None,
                   help="auto: the datum from control points, camera priors and control "
                        "databases (checked before the solve); free: a free network (no "
                        "priors, inner constraints), relative precision only (default: the "
                        "project's [adjustment] datum, else auto)")
    a.add_argument("--conflation-raster", action="store_true",
                   help="also write each database's conflation field as a GeoTIFF "
                        "(conflation_<name>.tif: dX, dY, dZ, CE90, LE90)")
    common(a)
    a.set_defaults(func=cmd_adjust)

    c = sub.add_parser("compare", help="adjust each road database alone and compare")
    c.add_argument("project", help="project file (TOML)")
    c.add_argument("-o", "--out", required=True, help="output directory")
    common(c)
    c.set_defaults(func=cmd_compare)

    cli_qa.add_parser(sub)
    cli_propagate.add_parsers(sub)
    cli_buffer.add_parser(sub)
    cli_study.add_parser(sub)
    cli_many.add_parser(sub)
    cli_measure.add_parser(sub)
    cli_drone.add_parser(sub)
    cli_dtm.add_parser(sub)
    cli_conflate.add_parser(sub)
    return p


def main(argv: Optional[Sequence[str]] = None) -> int:
    """Entry point of the ``vectoradjust`` console script."""
    parser = build_parser()
    args = parser.parse_args(argv)
    return run_command(args)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
