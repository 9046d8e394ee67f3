"""Figures and ``report.html`` of ``vectoradjust study`` (built on :mod:`.report`).

:func:`gcp_map_figure` (the control configurations on the block),
:func:`gcp_rmse_figure` (check point RMSE against the number of control points, with the
spread of repeated random subsets), :func:`shift_figure` (residuals of a database before
and after it was shifted) and :func:`identification_figure` (accuracy against the
identification error); :func:`write_study_report` puts tables and figures into one
self-contained HTML page and :func:`write_png` writes a figure next to the tables.
matplotlib is used through :mod:`vectoradjust.files.report` (Agg canvas, no pyplot).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Optional

import numpy as np

from vectoradjust.files import report as _r

__all__ = ["gcp_map_figure", "gcp_rmse_figure", "shift_figure", "identification_figure",
           "write_png", "table_html", "write_study_report"]

#: panels of the configuration map at most
MAX_MAP_PANELS = 12


def _fmt_cell(v) -> str:
    if isinstance(v, float):
        return _r._fmt(v, 3)
    return _r._fmt(v)


def table_html(rows: Sequence[dict], columns: Optional[Sequence[str]] = None) -> str:
    """An HTML table of dict rows (numbers with 3 decimals)."""
    cols = list(columns) if columns else list(dict.fromkeys(k for r in rows for k in r))
    return _r._table(cols, [[_fmt_cell(r.get(c)) for c in cols] for r in rows])


def gcp_map_figure(control_xyz: np.ndarray, role: np.ndarray, plan: Sequence[dict]):
    """One map panel per configuration: control points kept, held out, check points.

    Parameters
    ----------
    control_xyz : numpy.ndarray, shape (n, 3)
    role : numpy.ndarray of str
        The roles as read (``control`` / ``check``).
    plan : sequence of dict
        Entries of :func:`vectoradjust.files.study.gcp_plan` (``label``, ``rows``); of
        repeated random subsets only the first is drawn.
    """
    items, seen = [], set()
    for p in plan:
        if p["label"] not in seen:
            seen.add(p["label"])
            items.append(p)
    items = items[:MAX_MAP_PANELS]
    if not items:
        return None
    ncol = min(4, len(items))
    nrow = int(np.ceil(len(items) / ncol))
    fig = _r._new_figure(3.0 * ncol, 3.0 * nrow + 0.4)
    origin = _r._origin(control_xyz[:, :2])
    xy = control_xyz[:, :2] - np.asarray(origin)
    is_ctrl = np.asarray(role) == "control"
    for k, p in enumerate(items):
        ax = fig.add_subplot(nrow, ncol, k + 1)
        kept = np.zeros(len(xy), bool)
        kept[p["rows"]] = True
        held = is_ctrl & ~kept
        ax.scatter(*xy[~is_ctrl].T, marker="x", color="#555555", s=22, label="check point")
        ax.scatter(*xy[held].T, facecolors="none", edgecolors="#1f77b4", s=26,
                   label="held out (check)")
        ax.scatter(*xy[kept].T, marker="^", color="#d62728", s=60, label="control kept")
        ax.set_title(f"{p['label']} ({int(kept.sum())} GCPs)", fontsize=10)
        ax.set_aspect("equal")
        ax.tick_params(labelsize=7)
        if k == 0:
            ax.legend(fontsize=7, loc="best", frameon=False)
    return fig


def gcp_rmse_figure(summary: Sequence[dict], column: str = "check_rmse_h",
                    databases: Sequence[str] = ()):
    """RMSE against the number of control points; error bars = min-max over repeats.

    Parameters
    ----------
    summary : sequence of dict
        :func:`vectoradjust.files.study.gcp_summary` rows.
    column : str
        The RMSE column (``check_rmse_h``, ``held_out_rmse_h``, ...).
    databases : sequence of str
        Also plot ``<db>_adj_truth`` (adjusted - truth RMSE) of these databases.
    """
    if not summary:
        return None
    fig = _r._new_figure(7.0, 4.2)
    ax = fig.add_subplot(1, 1, 1)
    series = [(column, "check points (horizontal)", "#d62728")] + [
        (f"{db}_adj_truth", f"{db} adjusted \u2212 truth", _r._PALETTE[i % len(_r._PALETTE)])
        for i, db in enumerate(databases)]
    labelled: set = set()
    for group, marker in (("number", "o-"), ("random", "s--"), ("configuration", "D")):
        rows = sorted((r for r in summary if r["group"] == group), key=lambda r: r["n_control"])
        for col, label, color in series:
            pts = [(r["n_control"], r.get(f"{col}_mean"), r.get(f"{col}_min"),
                    r.get(f"{col}_max"), r["label"]) for r in rows
                   if r.get(f"{col}_mean") is not None]
            if not pts:
                continue
            n, m, lo, hi, lab = (np.array(a, dtype=object) for a in zip(*pts))
            m, lo, hi = (np.asarray(a, float) for a in (m, lo, hi))
            ax.errorbar(np.asarray(n, float), m, yerr=[m - lo, hi - m], fmt=marker,
                        color=color, capsize=3, ms=5,
                        label="_nolegend_" if col in labelled else label,
                        linestyle="none" if group == "configuration" else None)
            labelled.add(col)
            if group == "configuration" and col == column:
                for x, y, t in zip(n, m, lab):
                    ax.annotate(str(t), (float(x), float(y)), fontsize=7,
                                xytext=(4, 4), textcoords="offset points")
    ax.set_xlabel("number of ground control points")
    ax.set_ylabel("RMSE (m)")
    ax.set_ylim(bottom=0)
    ax.set_title("Accuracy against the number of control points\n(circles: well-spread "
                 "sweep, squares: random subsets, diamonds: named configurations)", fontsize=10)
    ax.legend(fontsize=7, frameon=False)
    return fig


def shift_figure(runs: Sequence[tuple]):
    """Per database: residuals V (horizontal) of the unshifted and the shifted run."""
    if not runs:
        return None
    fig = _r._new_figure(3.6 * len(runs), 3.8)
    for k, (base, moved) in enumerate(runs):
        ax = fig.add_subplot(1, len(runs), k + 1)
        for run, color, label in ((base, "#1f77b4", "unshifted"), (moved, "#d62728", "shifted")):
            d = run.databases[0]
            m = d.vertices["Adjusted"] == 1
            ax.scatter(d.vertices["Vx"][m], d.vertices["Vy"][m], s=8, color=color, alpha=0.6,
                       label=label)
        ax.axhline(0, color="#999999", lw=0.6)
        ax.axvline(0, color="#999999", lw=0.6)
        ax.set_aspect("equal")
        ax.set_xlabel("Vx (m)")
        ax.set_ylabel("Vy (m)")
        ax.set_title(base.databases[0].name, fontsize=10)
        ax.legend(fontsize=7, frameon=False)
    return fig


def identification_figure(rows: Sequence[dict]):
    """Adjusted - truth RMSE per database against the identification error."""
    if not rows:
        return None
    fig = _r._new_figure(6.5, 4.0)
    ax = fig.add_subplot(1, 1, 1)
    names = list(dict.fromkeys(r["database"] for r in rows))
    for i, name in enumerate(names):
        sel = [r for r in rows if r["database"] == name and r.get("adj_truth_rmse") is not None]
        errs = sorted({r["identification_error"] for r in sel})
        mean = [np.mean([r["adj_truth_rmse"] for r in sel if r["identification_error"] == e])
                for e in errs]
        ax.plot(errs, mean, "o-", color=_r._PALETTE[i % len(_r._PALETTE)], label=name)
    e = np.array(sorted({r["identification_error"] for r in rows}), float)
    ax.plot(e, np.sqrt(2.0) * e, ":", color="#777777", label="\u221a2 \u00d7 error (2 axes)")
    ax.set_xlabel("identification error per axis (m)")
    ax.set_ylabel("RMSE adjusted \u2212 truth, horizontal (m)")
    ax.set_ylim(bottom=0)
    ax.legend(fontsize=8, frameon=False)
    return fig


def write_png(fig, path) -> Optional[Path]:
    """Write a figure as PNG (nothing for None)."""
    if fig is None:
        return None
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(_r.figure_png(fig))
    return path


def write_study_report(path, title: str, sections: Sequence[tuple],
                       subtitle: str = "") -> Path:
    """Write ``report.html``: ``sections`` are ``(ident, title, body_html, figures)`` with
    ``figures`` a list of ``(figure, alt, caption)``."""
    path = _r._prepare(Path(path))
    doc = _r._Doc()
    for ident, heading, body, figures in sections:
        figs = "".join(_r._img(f, alt, cap) for f, alt, cap in figures)
        doc.section(ident, heading, body + figs)
    return _r._write_text(path, _r._page(title, doc, subtitle or "vectoradjust study"))
