"""What the ``adjust``, ``compare`` and ``demo`` commands print: the adjustment summary,
the side-by-side comparison table and the notes of the output folder's commit."""

from __future__ import annotations

import sys

__all__ = ["compare_row", "compare_columns", "fmt", "print_summary", "print_table",
           "say_notes"]


def compare_row(summary: dict) -> dict:
    """:func:`vectoradjust.accuracy.summary.compare_row` (imported when first used: the
    command line starts reading its inputs without loading the statistics)."""
    from vectoradjust.accuracy.summary import compare_row as row

    return row(summary)


def compare_columns(rows: list) -> list:
    """:func:`vectoradjust.accuracy.summary.compare_columns` (imported when used)."""
    from vectoradjust.accuracy.summary import compare_columns as cols

    return cols(rows)


def fmt(v, nd: int = 3) -> str:
    """``v`` as a table cell: ``-`` for None, yes/no for a bool, ``nd`` decimals for a
    number, else ``str(v)``."""
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


def print_summary(summary: dict, out=None) -> None:
    """Print the adjustment's ``summary`` (sigma0, chi-square test, RMSEs, CE90/LE90,
    interior orientation, warnings) to ``out`` (default stdout)."""
    out = out or sys.stdout
    chi = summary["chi_square"]
    print(f"  sigma0^2 = {fmt(summary['sigma0_squared'], 4)} with {summary['degrees_of_freedom']}"
          f" degrees of freedom, {summary['iterations']} iterations", file=out)
    if chi.get("lower") is not None:
        print(f"  chi-square test (alpha = {chi['alpha']}): v'Pv = {fmt(chi['statistic'], 2)} in "
              f"[{fmt(chi['lower'], 2)}, {fmt(chi['upper'], 2)}]: "
              f"{'passed' if chi['passed'] else 'FAILED'}", file=out)
    for key, label in (("shape_points", "shape points (residuals)"),
                       ("control_points", "control points"),
                       ("check_points", "check points")):
        s = summary.get(key) or {}
        if s.get("count"):
            print(f"  {label:26s} n = {s['count']:5d}  RMSE x {fmt(s['rmse_x'])}  y "
                  f"{fmt(s['rmse_y'])}  z {fmt(s['rmse_z'])}  horizontal "
                  f"{fmt(s['rmse_horizontal'])} m", file=out)
    if summary.get("mean_ce90") is not None:
        print(f"  mean CE90 {fmt(summary['mean_ce90'])} m, mean LE90 "
              f"{fmt(summary['mean_le90'])} m", file=out)
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
    cells = [[fmt(r.get(k)) if k != "database" else str(r.get(k)) for k, _ in cols]
             for r in rows]
    widths = [max(len(h), *(len(c[i]) for c in cells)) for i, h in enumerate(heads)]
    print("  ".join(h.rjust(w) for h, w in zip(heads, widths)), file=out)
    for c in cells:
        print("  ".join(v.rjust(w) for v, w in zip(c, widths)), file=out)


def say_notes(notes, quiet: bool) -> None:
    """What the commit of the output folder said (``notes``, or a RunFolder's): the
    previous run's files removed (unless quiet), files of earlier runs left in place
    (always, on stderr)."""
    for kind, text in getattr(notes, "notes", notes):
        if kind == "warning":
            print(f"vectoradjust: warning: {text}", file=sys.stderr)
        elif not quiet:
            print(f"  note: {text}")
