"""``vectoradjust demo``: the embedded sample project end to end - all road databases
adjusted together, each alone (``compare``), then the satellite triplet with RPCs.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from vectoradjust.cli import options
from vectoradjust.cli.adjust import cmd_adjust
from vectoradjust.cli.compare import compare
from vectoradjust.cli.printing import compare_row, print_table

__all__ = ["add_parser", "cmd_demo", "sample_project_dir"]


def sample_project_dir() -> Path:
    """Directory of the embedded sample project
    (:func:`vectoradjust.runner.project_run.sample_project_dir`)."""
    from vectoradjust.runner.project_run import sample_project_dir as sample

    return sample()


def cmd_demo(args) -> int:
    """Run ``vectoradjust demo`` into ``args.out`` (``all/``, ``compare/``,
    ``satellite/``)."""
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


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Add ``vectoradjust demo`` to ``subparsers``; its parser."""
    d = options.add_command(subparsers, "demo", cmd_demo,
                            "run the embedded sample project end to end")
    options.add_out(d, required=False, default="vectoradjust-demo")
    options.add_format(d)
    options.add_quiet(d, help="no progress bar or summary")
    return d
