"""``vectoradjust study``: the dissertation's experiments as commands.

- ``vectoradjust study gcp PROJECT.toml --out DIR [--numbers 24,12,6,3] [--config 3-North
  --config 3-East --config 3-SW] [--random 3,6,12 --repeats 10 --seed 1]`` - the project
  adjusted with subsets of its control points; the held-out ones are check points.
  Writes ``gcp_study.csv`` (one row per run), ``gcp_summary.csv`` (mean, sd, min, max
  per configuration), ``gcp_map.png``, ``gcp_rmse.png``, ``report.html``.
- ``vectoradjust study shift PROJECT.toml --out DIR --dx 15 --dy 15 [--vectors NAME]`` -
  each database adjusted as read and translated; ``shift_study.csv``, ``shift.png``,
  ``report.html`` and the per-point truth tables of both runs.
- ``vectoradjust study identification --out DIR --errors 0,0.5,1,2 [--seed 35]
  [--repeats 1]`` - the simulator re-run with each identification error;
  ``identification_study.csv``, ``identification.png``, ``report.html``.

The work is :mod:`vectoradjust.files.study`; figures :mod:`vectoradjust.files.study_report`.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from vectoradjust.cli import options
from vectoradjust.cli.progress import ProgressBar
from vectoradjust.errors import ProjectError
from vectoradjust.runner.project_run import truth_tables

__all__ = ["add_parser", "cmd_gcp", "cmd_shift", "cmd_identification", "truth_tables",
           "parse_numbers", "write_common_points"]


def parse_numbers(text, what: str, integer: bool = False) -> list:
    """``"24,12,6,3"`` -> ``[24, 12, 6, 3]`` (a clear error for anything else)."""
    if text is None:
        return []
    try:
        vals = [float(t) for t in str(text).replace(";", ",").split(",") if t.strip()]
    except ValueError as exc:
        raise ProjectError(f"{what} {text!r} is not a list of numbers",
                           f"Write e.g. {'24,12,6,3' if integer else '0,0.5,1,2'}") from exc
    if integer:
        if any(v != int(v) or v < 1 for v in vals):
            raise ProjectError(f"{what} {text!r} must be whole numbers >= 1",
                               "Write e.g. 24,12,6,3")
        return [int(v) for v in vals]
    if any(v < 0 for v in vals):
        raise ProjectError(f"{what} {text!r} must be >= 0", "Write e.g. 0,0.5,1,2")
    return vals


def write_common_points(runs, out_dir):
    """``common_points.csv`` of ``compare`` (points measured for more than one database,
    e.g. through ``[adjustment] reuse_tolerance``); None when there are none."""
    from vectoradjust.files.study import common_points, write_csv

    rows = common_points(runs)
    return write_csv(rows, Path(out_dir) / "common_points.csv") if rows else None


def _load(project):
    from vectoradjust.files.project import load_project
    from vectoradjust.files.readers import load_project_data

    spec = load_project(project)
    return spec, load_project_data(spec)


def cmd_gcp(args) -> int:
    """Run ``vectoradjust study gcp``."""
    from vectoradjust.files import study_report as sr
    from vectoradjust.files.study import gcp_plan, gcp_study, gcp_summary, write_csv

    spec, data = _load(args.project)
    numbers = parse_numbers(args.numbers, "--numbers", integer=True) if args.numbers else None
    rand = parse_numbers(args.random, "--random", integer=True)
    if numbers is None and (args.config or rand):
        numbers = []
    plan = gcp_plan(data, numbers, args.config or [], rand, args.repeats, args.seed)
    rows = gcp_study(data, plan, vectors=args.vectors,
                     progress=ProgressBar("gcp study", enabled=not args.quiet))
    summ = gcp_summary(rows)
    out = Path(args.out)
    write_csv(rows, out / "gcp_study.csv")
    write_csv(summ, out / "gcp_summary.csv")
    names = [s.name for s in spec.vectors if not args.vectors or s.name in args.vectors]
    has_truth = any(r.get(f"{n}_adj_truth") is not None for r in rows for n in names)
    fmap = sr.gcp_map_figure(data.control.xyz, data.control.role, plan)
    frm = sr.gcp_rmse_figure(summ, databases=names if has_truth else ())
    sr.write_png(fmap, out / "gcp_map.png")
    sr.write_png(frm, out / "gcp_rmse.png")
    cols = ["label", "n_control", "runs", "failed", "check_rmse_h_mean", "check_rmse_h_sd",
            "check_rmse_h_min", "check_rmse_h_max", "held_out_rmse_h_mean"] + [
        f"{n}_{c}_mean" for n in names for c in ("rmse", "adj_truth")]
    sr.write_study_report(out / "report.html", f"GCP study: {args.project}", [
        ("gcp", "Control point study", sr.table_html(summ, cols), [
            (fmap, "GCP configurations", "Control points kept (triangles), held out and "
             "scored as check points (circles), the project's check points (crosses)."),
            (frm, "RMSE against the number of GCPs", "Mean over the runs of each "
             "configuration; bars from the smallest to the largest run.")]),
        ("runs", "Every run", sr.table_html(rows), [])])
    if not args.quiet:
        print(f"vectoradjust study gcp: {args.project} ({len(rows)} runs)")
        for r in summ:
            print(f"  {r['label']:>14s}  n = {r['n_control']:3d}  check RMSE h "
                  f"{_f(r.get('check_rmse_h_mean'))} m  (min {_f(r.get('check_rmse_h_min'))}, "
                  f"max {_f(r.get('check_rmse_h_max'))}, {r['runs']} run(s))")
        print(f"  wrote {out / 'gcp_study.csv'}, {out / 'gcp_summary.csv'}, "
              f"{out / 'report.html'}")
    return 0


def _f(v) -> str:
    return "-" if v is None else f"{v:.3f}"


def cmd_shift(args) -> int:
    """Run ``vectoradjust study shift``."""
    from vectoradjust.cli.buffer import project_truth, truth_buffer
    from vectoradjust.files import study_report as sr
    from vectoradjust.files.study import shift_study, write_csv

    spec, data = _load(args.project)
    out = Path(args.out)
    lines = project_truth(spec)
    written = {}

    def after(run, label):
        if lines is not None:
            truth_buffer(run, *lines)
        written.update(truth_tables(run, spec, out / label.replace(" ", "_"), f"{label} "))

    rows, runs = shift_study(data, args.dx, args.dy, args.vectors,
                             progress=ProgressBar("shift study", enabled=not args.quiet),
                             after_run=after)
    write_csv(rows, out / "shift_study.csv")
    fig = sr.shift_figure(runs)
    sr.write_png(fig, out / "shift.png")
    sr.write_study_report(out / "report.html", f"Shift study: {args.project}", [
        ("shift", f"Databases shifted by {args.dx:g} m east, {args.dy:g} m north",
         sr.table_html(rows), [(fig, "residuals before and after the shift",
                                "Residuals V = adjusted - database of every adjusted vertex: "
                                "the shifted cloud is the unshifted one moved by -(dx, dy).")])])
    if not args.quiet:
        print(f"vectoradjust study shift: {args.project} (dx = {args.dx:g} m, dy = {args.dy:g} m)")
        for r in rows:
            print(f"  {r['database']:>8s}  RMSE V {_f(r['rmse_unshifted'])} -> "
                  f"{_f(r['rmse_shifted'])} m, true {_f(r['true_rmse_shifted'])} m, "
                  f"recovered shift ({_f(r['recovered_dx'])}, {_f(r['recovered_dy'])}) m, "
                  f"adjusted points moved at most {_f(r['adjusted_moved_max'])} m")
        print(f"  wrote {out / 'shift_study.csv'}, {out / 'report.html'}")
    return 0


def cmd_identification(args) -> int:
    """Run ``vectoradjust study identification``."""
    from vectoradjust.files import study_report as sr
    from vectoradjust.files.study import identification_study, write_csv

    errors = parse_numbers(args.errors, "--errors")
    if not errors:
        raise ProjectError("--errors is empty", "Write e.g. --errors 0,0.5,1,2")
    dbs = [d.strip() for d in args.databases.split(",") if d.strip()]
    rows = identification_study(errors, seed=args.seed, repeats=args.repeats, databases=dbs,
                                reweight=args.reweight, state_sigma=not args.no_stated_sigma,
                                progress=ProgressBar("identification", enabled=not args.quiet))
    out = Path(args.out)
    write_csv(rows, out / "identification_study.csv")
    fig = sr.identification_figure(rows)
    sr.write_png(fig, out / "identification.png")
    sr.write_study_report(out / "report.html", "Identification error study", [
        ("identification", "Simulated identification errors", sr.table_html(rows), [
            (fig, "accuracy against the identification error",
             "RMSE of adjusted - truth per database (mean over the repeats).")])])
    if not args.quiet:
        print("vectoradjust study identification")
        for r in rows:
            print(f"  {r['identification_error']:5.2f} m  seed {r['seed']}  "
                  f"{r['database']:>6s}  adjusted-truth {_f(r['adj_truth_rmse'])} m  "
                  f"closer {_f(r['moved_closer'])}")
        print(f"  wrote {out / 'identification_study.csv'}, {out / 'report.html'}")
    return 0


def add_parser(sub) -> argparse.ArgumentParser:
    """Register ``vectoradjust study gcp|shift|identification``; the ``study`` parser."""
    s = options.add_command(sub, "study", None, "the dissertation's experiments: GCP "
                            "number/location, shifted database, identification error")
    ss = s.add_subparsers(dest="study", metavar="STUDY")
    ss.required = True
    g = options.add_project_command(ss, "gcp", cmd_gcp, "adjust with subsets of the control "
                                    "points; the held-out ones are scored as check points")
    g.add_argument("--numbers", help="number sweep with well-spread subsets, e.g. 24,12,6,3 "
                   "(default: all, half, quarter ... down to 3, unless --config/--random)")
    g.add_argument("--config", action="append", metavar="NAME",
                   help="named configuration COUNT-PART (3-North, 3-East, 3-SW, 4-Center, "
                        "6-Spread) or NAME=ID1,ID2,ID3 (repeatable)")
    g.add_argument("--random", help="numbers of control points drawn at random, e.g. 3,6,12")
    options.add_repeats(g, 10, help="random subsets per number")
    options.add_seed(g, 0, help="seed of the random subsets")
    options.add_vectors(g)
    options.add_quiet(g, help="no progress bar or table")
    h = options.add_project_command(ss, "shift", cmd_shift,
                                    "translate a database, adjust, compare with unshifted")
    h.add_argument("--dx", type=float, default=15.0, help="shift east in m")
    h.add_argument("--dy", type=float, default=15.0, help="shift north in m")
    options.add_vectors(h, help="shift this [[vectors]] entry (repeatable) (default: all, each "
                                "alone)")
    options.add_quiet(h, help="no progress bar or table")
    _identification_parser(ss)
    return s


def _identification_parser(ss) -> argparse.ArgumentParser:
    """``study identification``'s parser."""
    i = options.add_command(ss, "identification", cmd_identification,
                            "simulate with a list of identification errors")
    options.add_out(i)
    i.add_argument("--errors", default="0,0.5,1,2", help="identification errors per axis (m)")
    options.add_seed(i, 35, help="simulation seed (the sample's is 35)")
    options.add_repeats(i, 1, help="scenarios per error (seed, seed+1, ...)")
    i.add_argument("--databases", default="OSM,TNM,TIGER", help="simulated databases")
    i.add_argument("--reweight", choices=("none", "two-pass", "vce"), default="two-pass",
                   help="[adjustment] reweight of the runs (two-pass: as the sample)")
    i.add_argument("--no-stated-sigma", action="store_true",
                   help="do not state identification_sigma = the simulated error (the "
                        "runs then estimate it from the data, or use the default)")
    options.add_quiet(i, help="no progress bar or table")
    return i
