"""``vectoradjust demo``: the embedded sample project end to end - all road databases
adjusted together, each alone (``compare``), then the satellite triplet with RPCs.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from vectoradjust.cli import options
from vectoradjust.cli.printing import compare_row, print_summary, print_table, say_notes

__all__ = ["add_parser", "cmd_demo", "sample_project_dir"]


def sample_project_dir() -> Path:
    """Directory of the embedded sample project
    (:func:`vectoradjust.runner.project_run.sample_project_dir`)."""
    from vectoradjust.runner.project_run import sample_project_dir as sample

    return sample()


def cmd_demo(args) -> int:
    """Run ``vectoradjust demo`` into ``args.out`` (``all/``, ``compare/``,
    ``satellite/``).

    The parts overlap where a second core can take one: the report of ``all/`` is drawn
    while the databases of ``compare/`` are adjusted, and the satellite triplet is run
    by a forked process meanwhile (started once ``all/`` is adjusted, so that it finds
    the modules loaded; its tables are printed at the end, as before); every folder is
    still complete or left as it was."""
    project = sample_project_dir() / "project.toml"
    out = Path(args.out)
    print(f"vectoradjust demo: sample project {project}")
    satellite: list = []  # its process, once started
    try:
        print("  all road databases adjusted together ->", out / "all")
        rows = _demo_all_and_compare(project, out, args, satellite)
        print_table(rows)
        print("\n  (RMSE x/y/z/h: of the residuals V = adjusted - database; recovery = the "
              "smaller of RMSE(V) and RMSE(database - truth) over the larger; improvement = "
              "1 - RMSE(adjusted - truth) / RMSE(database - truth))")
        print(f"  reports: {out / 'all' / 'report.html'}, {out / 'compare' / 'report.html'}")
        _demo_satellite(sample_project_dir() / "satellite", out / "satellite", satellite[0])
    finally:
        for job in satellite:
            job.close()
    return 0


def _demo_all_and_compare(project: Path, out: Path, args, satellite: list) -> list:
    """``all/`` (every database together) and ``compare/`` (each alone; its rows).

    The report of ``all/`` is drawn by another process while the databases are adjusted
    one by one; ``all/`` is committed once they are (or when the comparison fails: it
    is complete by then). The satellite sample's process is started in between (into
    ``satellite``)."""
    from vectoradjust.cli.adjust import StageBars, output_folder, run_options
    from vectoradjust.cli.compare import _compare_into
    from vectoradjust.runner.project_run import close_reports, finish_reports, run_into

    ns = argparse.Namespace(format=args.format, vectors=None, quiet=args.quiet)
    pending: list = []
    with output_folder(out / "all") as folder:
        try:
            result, written, _ = run_into(str(project), folder, folder.path,
                                          run_options(ns), StageBars(args.quiet),
                                          reports=pending)
            satellite.append(_satellite_alongside(sample_project_dir() / "satellite",
                                                  out / "satellite", args.format))
            if not args.quiet:
                print(f"vectoradjust adjust: {project}")
                print_summary(result.summary)
                for name in written.values():
                    print(f"  wrote {name}")

            def finish_all() -> None:
                if pending:
                    finish_reports(pending)
                    pending.clear()
                    folder.commit()
                    say_notes(folder, args.quiet)

            print("\n  each database alone (compare) ->", out / "compare")
            try:
                with output_folder(out / "compare", "compare") as cfolder:
                    rows, _ = _compare_into(str(project), cfolder, args.format, args.quiet,
                                            adjusted=finish_all)
            except Exception:
                finish_all()  # all/ is complete: kept, as when it was written first
                raise
            say_notes(cfolder, args.quiet)
        finally:
            close_reports(pending)
    return rows


def _satellite_alongside(folder: Path, out: Path, fmt: str):
    """The satellite sample run into ``out`` by a forked process (beside the frame
    sample's work; in this process when it waits for it, where there is no fork)."""
    import os

    from vectoradjust.runner.background import Background

    return Background(_run_satellite, str(folder / "project.toml"), str(out), fmt,
                      os.getpid())


def _run_satellite(project: str, out: str, fmt: str, parent: int, progress=None) -> list:
    """``vectoradjust adjust PROJECT --out OUT -q``; the folder's notes. In a forked
    process (not ``parent``) everything runs in it (it may not fork again)."""
    import os

    from vectoradjust.runner.project_run import RunOptions, run_project

    done = run_project(project, out, RunOptions(fmt=fmt, quiet=True,
                                                background=os.getpid() == parent))
    return [tuple(n) for n in done.notes]


def _demo_satellite(folder: Path, out: Path, job) -> None:
    """The demo's second part: the satellite sample (RPC triplet) adjusted (by ``job``,
    :func:`_satellite_alongside`), its bias and its OSM row printed."""
    import csv
    import json

    print(f"\n  satellite triplet with RPCs ({folder / 'project.toml'}) ->", out)
    say_notes(job.result(), True)
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


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Add ``vectoradjust demo`` to ``subparsers``; its parser."""
    d = options.add_command(subparsers, "demo", cmd_demo,
                            "run the embedded sample project end to end")
    options.add_out(d, required=False, default="vectoradjust-demo")
    options.add_format(d)
    options.add_quiet(d, help="no progress bar or summary")
    return d
