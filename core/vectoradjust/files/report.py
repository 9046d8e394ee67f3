"""``report.html``: one self-contained HTML report of an adjustment.

:func:`write_report` writes a single file with inline CSS and the figures embedded as
PNG data URIs (no scripts, no external links or resources), so it can be mailed,
archived or opened in QGIS's browser as it is. Sections: summary with the chi-square
verdict, the images' exterior orientation with sigmas, control and check points, the
road databases (and the truth comparison of simulations), accuracy statements
(:mod:`vectoradjust.accuracy.statements`), the precision of the adjusted points, the image
residuals and flagged observations, features, shape points, the QA verdict when given,
and warnings. :func:`write_compare_report` does the same for ``vectoradjust compare``
(each database adjusted alone): the comparison table, the RMSE chart across the
databases and one set of sections per database.

Figures (matplotlib, imported lazily, Agg canvas only, no pyplot, so a running QGIS
session is not disturbed): residual vectors over the road lines
(:func:`residual_vector_figure`), 90 % error ellipses (:func:`error_ellipse_figure`),
standardized image residuals (:func:`residual_histogram_figure`) and RMSE per
database (:func:`rmse_bar_figure`). For large runs the arrows and ellipses are a
random subsample (fixed seed) and the figure says so; the shape points table then
lists the largest residuals only (the full data are in ``adjusted.gpkg``).
"""

from __future__ import annotations

import base64
import datetime as _dt
import html
import io
import math
import os
import re
import tempfile
from collections.abc import Sequence
from contextlib import contextmanager
from contextvars import ContextVar
from pathlib import Path
from typing import Any, Optional

import numpy as np

from vectoradjust.errors import CancelledError, InputFileError

__all__ = [
    "write_report",
    "write_compare_report",
    "report_html",
    "compare_report_html",
    "residual_vector_figure",
    "error_ellipse_figure",
    "residual_histogram_figure",
    "rmse_bar_figure",
    "figure_png",
    "MAX_ARROWS",
    "MAX_ELLIPSES",
    "MAX_FULL_SHAPE_ROWS",
    "LARGEST_SHAPE_ROWS",
    "LARGEST_FEATURE_ROWS",
    "MAX_SEGMENTS",
]

#: Arrows per database panel of the residual figure (random subsample above).
MAX_ARROWS = 600
#: Above this many line segments per panel, lines are drawn thin and without
#: antialiasing (readable, and a PNG of reasonable size).
DENSE_SEGMENTS = 6000
#: Ellipses in the error-ellipse figure (random subsample above).
MAX_ELLIPSES = 800
#: Up to this many vertices (all databases) the shape points table lists every vertex.
MAX_FULL_SHAPE_ROWS = 1000
#: Otherwise it lists the vertices with the largest horizontal residuals.
LARGEST_SHAPE_ROWS = 200
#: Features tables longer than this show the features with the largest RMSE only.
MAX_FEATURE_ROWS = 1000
#: ... that many of them (the others are in the features layer).
LARGEST_FEATURE_ROWS = 200
#: Flagged observations listed in the report (largest |w| first; all in the CSV).
LARGEST_FLAGGED_ROWS = 200
#: Line segments drawn per database in a figure; above, whole features are sampled
#: (the report's size and time stay bounded whatever the run).
MAX_SEGMENTS = 200_000

_DPI = 100
_PALETTE = ["#1f77b4", "#2ca02c", "#9467bd", "#ff7f0e", "#17becf", "#8c564b", "#e377c2",
            "#bcbd22"]
_ARROW = "#d62728"
_STYLE = {
    "font.size": 9.0,
    "axes.titlesize": 10.0,
    "axes.labelsize": 9.0,
    "legend.fontsize": 8.0,
    "xtick.labelsize": 8.0,
    "ytick.labelsize": 8.0,
    "axes.grid": True,
    "grid.alpha": 0.3,
    "grid.linewidth": 0.6,
    "axes.spines.top": False,
    "axes.spines.right": False,
    "savefig.dpi": _DPI,
}
_CHI2_2_90 = -2.0 * math.log(0.1)  # chi-square quantile, 2 dof, p = 0.9


# =========================================================================== formatting
class _Raw(str):
    """HTML that is already escaped / built (not escaped again)."""


def _e(s: Any) -> str:
    return html.escape(str(s), quote=True)


def _fmt(v: Any, nd: int = 3) -> str:
    """Consistent number formatting: None/NaN -> '–', bool -> yes/no, int as is."""
    if v is None:
        return "\u2013"
    if isinstance(v, (bool, np.bool_)):
        return "yes" if v else "no"
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    if isinstance(v, (float, np.floating)):
        f = float(v)
        return f"{f:.{nd}f}" if math.isfinite(f) else "\u2013"
    return str(v)


def _fmt_col(values, nd: int = 3) -> list:
    """Format a column (array or list) of numbers quickly."""
    a = np.asarray(values)
    if a.dtype.kind == "f":
        out = np.char.mod(f"%.{nd}f", np.where(np.isfinite(a), a, 0.0)).astype(object)
        out[~np.isfinite(a)] = "\u2013"
        return out.tolist()
    if a.dtype.kind in "iu":
        return a.astype(str).tolist()
    return [_fmt(x, nd) if not isinstance(x, str) else x for x in a.tolist()]


_NUM_RE = re.compile(r"^[+\-\u2212]?\d[\d,]*(\.\d+)?( ?%)?$|^\u2013$")


def _cell(v: Any) -> str:
    if isinstance(v, _Raw):
        return str(v)
    return _e(v)


def _table(headers: Sequence[str], rows: Sequence[Sequence[Any]], *, cls: str = "",
           ident: Optional[str] = None, row_keys: Optional[Sequence[str]] = None,
           header_html: bool = False) -> str:
    """An HTML table; numeric columns right-aligned. Cells are escaped unless _Raw."""
    if not rows:
        return '<p class="note">(none)</p>'
    ncol = len(headers)
    numeric = []
    for j in range(ncol):
        col = [r[j] for r in rows[:200] if j < len(r)]
        numeric.append(bool(col) and all(isinstance(c, str) and not isinstance(c, _Raw)
                                         and _NUM_RE.match(c) for c in col))
    parts = [f'<table{f" id={_q(ident)}" if ident else ""} class="{_e(cls)}">', "<thead><tr>"]
    for h in headers:
        parts.append(f"<th>{h if header_html else _e(h)}</th>")
    parts.append("</tr></thead><tbody>")
    for i, r in enumerate(rows):
        key = f" data-key={_q(row_keys[i])}" if row_keys is not None else ""
        tds = "".join(
            f'<td class="num">{_cell(c)}</td>' if numeric[j] else f"<td>{_cell(c)}</td>"
            for j, c in enumerate(r))
        parts.append(f"<tr{key}>{tds}</tr>")
    parts.append("</tbody></table>")
    return "".join(parts)


def _q(s: str) -> str:
    return f'"{_e(s)}"'


def _kv_table(pairs: Sequence[tuple], ident: Optional[str] = None) -> str:
    """Two-column table of (label, value[, key]) pairs."""
    rows = [[p[0], p[1]] for p in pairs]
    keys = [p[2] if len(p) > 2 else re.sub(r"\W+", "_", str(p[0])).strip("_").lower()
            for p in pairs]
    return _table(["quantity", "value"], rows, cls="kv", ident=ident, row_keys=keys)


def _badge(passed: Optional[bool], yes: str = "passed", no: str = "FAILED",
           na: str = "not tested") -> _Raw:
    if passed is None:
        return _Raw(f'<span class="badge na">{_e(na)}</span>')
    return _Raw(f'<span class="badge {"pass" if passed else "fail"}">'
                f"{_e(yes if passed else no)}</span>")


def _note(text: str) -> str:
    return f'<p class="note">{_e(text)}</p>'


_CSS = """
body{font-family:-apple-system,"Segoe UI",Roboto,"Helvetica Neue",Arial,sans-serif;
 color:#222;margin:0;background:#f6f7f9;font-size:14px;line-height:1.45}
main{max-width:1180px;margin:0 auto;padding:24px 28px 60px;background:#fff}
h1{font-size:26px;margin:0 0 4px}
h2{font-size:20px;border-bottom:2px solid #1f77b4;padding-bottom:3px;margin-top:36px}
h3{font-size:16px;margin-top:24px}
h4{font-size:14px;margin:16px 0 6px}
.meta{color:#666;margin:0 0 16px}
nav ol{columns:3;font-size:13px;margin:8px 0 0;padding-left:20px}
nav li.sub{margin-left:14px;font-size:12px}
nav a,main a{color:#1f5fa0;text-decoration:none}
table{border-collapse:collapse;margin:8px 0 14px;font-size:12.5px}
th,td{border:1px solid #d8dce2;padding:3px 7px;vertical-align:top}
th{background:#eef2f7;text-align:left;position:sticky;top:0}
tbody tr:nth-child(even){background:#fafbfc}
td.num{text-align:right;font-variant-numeric:tabular-nums;white-space:nowrap}
table.kv td:first-child{color:#444}
.scroll{max-height:560px;overflow:auto;border:1px solid #e3e6ea;margin:8px 0 14px}
.scroll table{margin:0}
.badge{display:inline-block;padding:1px 8px;border-radius:10px;font-weight:600;
 font-size:12px}
.badge.pass{background:#dff3e4;color:#146c2e;border:1px solid #9fd5ae}
.badge.fail{background:#fde2e1;color:#a4161a;border:1px solid #f1a7a4}
.badge.na{background:#eee;color:#555;border:1px solid #ccc}
.verdict{font-size:15px;padding:8px 12px;border-radius:6px;margin:10px 0}
.verdict.pass{background:#eef9f1;border-left:5px solid #2e9e4f}
.verdict.fail{background:#fdf0ef;border-left:5px solid #d62728}
.verdict.na{background:#f3f3f3;border-left:5px solid #999}
.note{color:#555;font-size:12.5px}
.statement{background:#f4f8fc;border-left:4px solid #1f77b4;padding:6px 10px;
 margin:6px 0}
figure{margin:12px 0 20px}
figure img{max-width:100%;height:auto;border:1px solid #e3e6ea}
figcaption{font-size:12.5px;color:#444;margin-top:4px}
details summary{cursor:pointer;color:#1f5fa0}
ul.warnings li{color:#8a4b00}
footer{color:#888;font-size:12px;margin-top:40px}
"""


# =========================================================================== figures
def _mpl():
    """Import the matplotlib pieces lazily (no pyplot, no global backend switch)."""
    import matplotlib
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    return matplotlib, Figure, FigureCanvasAgg


def _new_figure(width: float, height: float, compressed: bool = False):
    """A figure on an Agg canvas with constrained layout ('compressed' for map panels
    where matplotlib has it, 3.6+)."""
    matplotlib, Figure, FigureCanvasAgg = _mpl()
    fig = None
    if compressed:
        try:
            fig = Figure(figsize=(width, height), dpi=_DPI, layout="compressed")
        except (TypeError, ValueError):
            fig = None
    if fig is None:
        fig = Figure(figsize=(width, height), dpi=_DPI, constrained_layout=True)
    FigureCanvasAgg(fig)
    return fig


def figure_png(fig, dpi: Optional[float] = None) -> bytes:
    """Render a matplotlib figure to PNG bytes with the Agg canvas.

    Parameters
    ----------
    fig : matplotlib.figure.Figure
    dpi : float, optional
        Default: the report's 100 dpi.

    Returns
    -------
    bytes
    """
    matplotlib, _, FigureCanvasAgg = _mpl()
    if not isinstance(fig.canvas, FigureCanvasAgg):
        FigureCanvasAgg(fig)
    buf = io.BytesIO()
    with matplotlib.rc_context(_STYLE):
        fig.savefig(buf, format="png", dpi=dpi or _DPI, facecolor="white",
                    metadata={"Software": "vectoradjust"})
    return buf.getvalue()


def _nice(x: float, mode: str = "floor") -> float:
    """A 1-2-5 number near ``x`` (``floor`` or ``round`` in log scale)."""
    if not (x > 0 and math.isfinite(x)):
        return 1.0
    e = math.floor(math.log10(x))
    cands = [m * 10.0 ** k for k in (e - 1, e, e + 1) for m in (1.0, 2.0, 5.0)]
    if mode == "floor":
        ok = [c for c in cands if c <= x * (1 + 1e-9)]
        return max(ok) if ok else min(cands)
    return min(cands, key=lambda c: abs(math.log(c / x)))


def _origin(xy: np.ndarray) -> tuple:
    """A round origin (multiple of 1000 m, or 100 m for small extents) below the data."""
    xy = xy[np.isfinite(xy).all(axis=1)]
    if not len(xy):
        return 0.0, 0.0
    lo = xy.min(axis=0)
    step = 1000.0 if np.ptp(xy, axis=0).max() > 200 else 100.0
    return float(math.floor(lo[0] / step) * step), float(math.floor(lo[1] / step) * step)


def _axis_labels(ax, origin: tuple) -> None:
    ox, oy = origin

    def lab(name, o):
        return f"{name} \u2212 {o:,.0f} (m)".replace(",", "\u2009") if o else f"{name} (m)"

    ax.set_xlabel(lab("Easting", ox))
    ax.set_ylabel(lab("Northing", oy))
    ax.set_aspect("equal", adjustable="box")


def _limits(xy: np.ndarray, pad: float = 0.04) -> tuple:
    """Padded (xmin, xmax, ymin, ymax) of the finite rows of ``xy``."""
    xy = xy[np.isfinite(xy).all(axis=1)]
    if not len(xy):
        return -1.0, 1.0, -1.0, 1.0
    lo, hi = xy.min(axis=0), xy.max(axis=0)
    p = pad * max(float((hi - lo).max()), 1.0)
    return lo[0] - p, hi[0] + p, lo[1] - p, hi[1] + p


def _segments(xyz: np.ndarray, feature: np.ndarray, part: np.ndarray,
              origin: tuple) -> np.ndarray:
    """(s, 2, 2) line segments between consecutive vertices of the same feature part."""
    xy = np.asarray(xyz, float)[:, :2] - np.asarray(origin)
    if len(xy) < 2:
        return np.zeros((0, 2, 2))
    same = (feature[1:] == feature[:-1]) & (part[1:] == part[:-1])
    same &= np.isfinite(xy[1:]).all(axis=1) & np.isfinite(xy[:-1]).all(axis=1)
    if same.sum() > MAX_SEGMENTS:  # a sample of whole features, the same for every call
        nf = int(feature.max()) + 1
        pick = np.zeros(nf, bool)
        pick[_subsample(nf, max(1, int(nf * MAX_SEGMENTS / same.sum())))] = True
        same &= pick[feature[:-1]]
    return np.stack([xy[:-1][same], xy[1:][same]], axis=1)


def _db_colors(names: Sequence[str], colors: Optional[dict] = None) -> dict:
    out = dict(colors or {})
    for n in names:
        if n not in out:
            out[n] = _PALETTE[len(out) % len(_PALETTE)]
    return out


def _subsample(n: int, k: int, seed: int = 0) -> np.ndarray:
    if n <= k:
        return np.arange(n)
    return np.sort(np.random.default_rng(seed).choice(n, size=k, replace=False))


def _control_xy(run) -> dict:
    """Control (used) and check (intersected) point positions, (n, 2) each."""
    cp = run.control_points or {}
    if not len(cp.get("point_id", [])):
        return {"control": np.zeros((0, 2)), "check": np.zeros((0, 2))}
    role = np.asarray(cp["role"])
    used = np.asarray(cp["Used"]) == 1
    xy = np.column_stack([cp["AdjX"], cp["AdjY"]]).astype(float)
    return {"control": xy[(role == "control") & used], "check": xy[(role == "check") & used]}


def _residual_arrows(dbs, origin: tuple) -> list:
    """Per database ``(xy, uv)``: one arrow per adjusted object point (shared vertices once)."""
    arrows = []
    for d in dbs:
        v = d.vertices
        adj = np.flatnonzero(v["Adjusted"] == 1)
        _, first = np.unique(d.vertex_point[adj], return_index=True)
        idx = adj[np.sort(first)]
        xy = np.column_stack([v["X"][idx], v["Y"][idx]]).astype(float) - origin
        uv = np.column_stack([v["Vx"][idx], v["Vy"][idx]]).astype(float)
        good = np.isfinite(xy).all(axis=1) & np.isfinite(uv).all(axis=1)
        arrows.append((xy[good], uv[good]))
    return arrows


def _arrow_scale(arrows: list, extent: float, max_arrows: int,
                 exaggeration: Optional[float]) -> tuple:
    """Arrow exaggeration ``k`` (default from the 95th percentile residual) and key length."""
    mags = np.concatenate([np.hypot(*uv.T) for _, uv in arrows]) if arrows else np.zeros(0)
    p95 = float(np.percentile(mags, 95)) if mags.size else 1.0
    if exaggeration is None:
        # long enough to read, short enough not to cross the neighbouring arrows
        n_shown = max(min(max(len(xy) for xy, _ in arrows), max_arrows), 1)
        spacing = extent / math.sqrt(n_shown)
        k_raw = min(0.08 * extent, 1.2 * spacing) / max(p95, 1e-6)
        exaggeration = 1.0 if 1.0 <= k_raw < 2.0 else _nice(k_raw, "floor")
    return float(exaggeration), _nice(p95, "round")


def _database_lines(ax, d, col: str, origin: tuple) -> None:
    """Database lines (grey) and adjusted lines (the database's colour) of one panel."""
    layer = d.shape.layer
    seg_db = _segments(layer.coords, layer.vertex_feature, layer.vertex_part, origin)
    seg_adj = _segments(d.adjusted_coords, layer.vertex_feature, layer.vertex_part, origin)
    dense = len(seg_db) > DENSE_SEGMENTS
    _draw_segments(ax, seg_db, color="#9a9a9a", linewidth=0.35 if dense else 0.9,
                   antialiased=not dense, zorder=1)
    _draw_segments(ax, seg_adj, color=col, linewidth=0.5 if dense else 1.3,
                   antialiased=not dense, zorder=2)


def _draw_segments(ax, seg: np.ndarray, **style) -> None:
    """Draw ``(s, 2, 2)`` segments as ONE path, NaN-separated (a LineCollection makes a
    Path object per segment: seconds for 10^5 segments)."""
    if not len(seg):
        return
    xy = np.concatenate([seg, np.full((len(seg), 1, 2), np.nan)], axis=1).reshape(-1, 2)
    ax.plot(xy[:, 0], xy[:, 1], scalex=False, scaley=False, solid_capstyle="butt", **style)


def _control_markers(ax, ctl: dict, origin: tuple) -> None:
    """Control points (black triangles) and check points (orange squares)."""
    for kind, mk, fc in (("control", "^", "black"), ("check", "s", "#ff7f0e")):
        pts = ctl[kind] - origin
        if len(pts):
            ax.scatter(pts[:, 0], pts[:, 1], marker=mk, s=22, c=fc,
                       edgecolors="white", linewidths=0.5, zorder=5)


def _arrow_key(ax, q, key_len: float, k: float) -> None:
    """The arrow scale key in a white box, lower right of the panel."""
    from matplotlib.patches import Rectangle

    ax.add_patch(Rectangle((0.72, 0.01), 0.27, 0.10, transform=ax.transAxes,
                           facecolor="white", edgecolor="#bbbbbb", lw=0.6,
                           alpha=0.92, zorder=6))
    qk = ax.quiverkey(q, X=0.855, Y=0.035, U=key_len * k, coordinates="axes",
                      label=(f"{key_len:g} m" + (f" (\u00d7{k:g})" if k != 1 else "")),
                      labelpos="N", fontproperties={"size": 8}, color=_ARROW)
    qk.set_zorder(7)


def _residual_panel(ax, d, col: str, arrows: tuple, ctl: dict, origin: tuple,
                    scale: tuple, max_arrows: int) -> None:
    """One database panel of :func:`residual_vector_figure` (``scale``: ``(k, key_len)``)."""
    k, key_len = scale
    _database_lines(ax, d, col, origin)
    xy, uv = arrows
    sel = _subsample(len(xy), max_arrows)
    q = ax.quiver(xy[sel, 0], xy[sel, 1], uv[sel, 0] * k, uv[sel, 1] * k,
                  angles="xy", scale_units="xy", scale=1.0, color=_ARROW,
                  width=0.0045, headwidth=3.5, headlength=4.5, headaxislength=4.0,
                  zorder=4)
    _control_markers(ax, ctl, origin)
    rm = np.hypot(*uv.T)
    rmse = float(np.sqrt(np.mean(rm**2))) if rm.size else float("nan")
    title = f"{d.name}: {len(xy)} residuals, RMSE$_h$ {rmse:.2f} m"
    if len(sel) < len(xy):
        title += f"\n({len(sel)} of {len(xy)} arrows shown, random subsample)"
    ax.set_title(title)
    _arrow_key(ax, q, key_len, k)
    _axis_labels(ax, origin)


def _residual_handles(n: int, col: str) -> list:
    """Legend handles of the residual figure (``col``: adjusted line colour for one panel)."""
    from matplotlib.lines import Line2D

    return [Line2D([], [], color="#9a9a9a", lw=1.2, label="database line"),
            Line2D([], [], color=col if n == 1 else "#444", lw=1.6,
                   label="adjusted line" + ("" if n == 1 else " (colour per database)")),
            Line2D([], [], color=_ARROW, lw=1.6, marker=">", markersize=5,
                   label="residual V"),
            Line2D([], [], ls="", marker="^", color="black", label="control point"),
            Line2D([], [], ls="", marker="s", color="#ff7f0e", label="check point")]


def residual_vector_figure(run, *, max_arrows: int = MAX_ARROWS,
                           exaggeration: Optional[float] = None,
                           colors: Optional[dict] = None, panel_width: float = 4.3):
    """Residual vectors ``V = adjusted - database`` over the road lines, one panel per database.

    Database lines grey, adjusted lines in the database's colour, arrows (red) at the
    database position of every adjusted object point, with one common scale for all
    panels (stated in each panel and shown by a key); control points (triangles) and
    check points (squares) for orientation.

    Parameters
    ----------
    run : vectoradjust.pipeline.AdjustmentRun
    max_arrows : int, optional
        Arrows per panel; above it a random subsample (seed 0) is drawn and the title
        says so.
    exaggeration : float, optional
        Arrow length / residual length. Default: a 1-2-5 value that makes the 95th
        percentile residual about 8 % of the map extent, and 1 (true scale: arrows end
        on the adjusted line) when the residuals are large enough.
    colors : dict, optional
        Database name -> colour.
    panel_width : float, optional
        Inches per panel.

    Returns
    -------
    matplotlib.figure.Figure or None
        None when the run has no adjusted shape point.
    """
    _, _, _ = _mpl()

    dbs = [d for d in run.databases if d.vertices and np.any(d.vertices["Adjusted"] == 1)]
    if not dbs:
        return None
    cmap = _db_colors([d.name for d in run.databases], colors)
    ctl = _control_xy(run)
    allxy = np.concatenate([d.shape.layer.coords[:, :2] for d in dbs]
                           + [d.adjusted_coords[:, :2] for d in dbs]
                           + [ctl["control"], ctl["check"]])
    origin = _origin(allxy)
    ok = np.isfinite(allxy).all(axis=1)
    span = np.ptp(allxy[ok], axis=0) if ok.any() else np.ones(2)
    extent = float(max(span.max(), 1.0))
    aspect = float(np.clip(1.14 * span[1] / max(span[0], 1e-9), 0.55, 1.5))
    arrows = _residual_arrows(dbs, origin)
    k, key_len = _arrow_scale(arrows, extent, max_arrows, exaggeration)
    n = len(dbs)
    ncols = min(n, 3)
    nrows = int(math.ceil(n / ncols))
    fig = _new_figure(panel_width * ncols, panel_width * aspect * nrows + 1.0, compressed=True)
    matplotlib = _mpl()[0]
    with matplotlib.rc_context(_STYLE):
        axes = fig.subplots(nrows, ncols, squeeze=False)
        x0, x1, y0, y1 = _limits(allxy - np.asarray(origin))
        y0 -= 0.14 * (y1 - y0)  # a free strip at the bottom for the arrow key
        for i, d in enumerate(dbs):
            ax = axes[i // ncols][i % ncols]
            _residual_panel(ax, d, cmap[d.name], arrows[i], ctl, origin, (k, key_len),
                            max_arrows)
            ax.set_xlim(x0, x1)
            ax.set_ylim(y0, y1)
        for j in range(n, nrows * ncols):
            axes[j // ncols][j % ncols].set_visible(False)
        scale_txt = ("arrows at true scale (they end on the adjusted line)" if k == 1 else
                     f"arrows exaggerated \u00d7{k:g}")
        # one narrow panel: the title on two lines and the legend in rows (not clipped)
        sep = "\n" if ncols == 1 else " "
        fig.suptitle(f"Residuals V = adjusted \u2212 database{sep}({scale_txt})", fontsize=11)
        _figure_legend(fig, axes[0][0], _residual_handles(n, cmap[dbs[0].name]),
                       ncol=3 if ncols == 1 else 5)
    return fig


def _conflation_arrows(d, origin: tuple) -> tuple:
    """Displacement arrows of a conflated database: measured and predicted object points."""
    v = d.vertices
    first = d.shape.object_vertex  # one arrow per object point
    xy = np.column_stack([v["X"][first], v["Y"][first]]).astype(float) - origin
    uv = np.column_stack([v["Vx"][first], v["Vy"][first]]).astype(float)
    good = np.isfinite(xy).all(axis=1) & np.isfinite(uv).all(axis=1)
    measured = (v["Adjusted"][first] == 1) & good
    return (xy[measured], uv[measured]), (xy[~measured & good], uv[~measured & good])


def _conflation_panel(fig, ax, d, origin: tuple, max_arrows: int) -> None:
    """One database: CE90 raster of the field, corrected lines, displacement arrows."""
    from matplotlib.collections import LineCollection

    from vectoradjust.accuracy.conflation import field_grid

    g = field_grid(d)
    ox, oy = origin
    ny, nx = g["ce90"].shape
    ext = [g["x0"] - ox, g["x0"] + nx * g["cell"] - ox, g["y0"] - ny * g["cell"] - oy,
           g["y0"] - oy]
    im = ax.imshow(g["ce90"], extent=ext, origin="upper", cmap="viridis", zorder=0,
                   interpolation="nearest")
    fig.colorbar(im, ax=ax, shrink=0.8, label="CE90 of the corrected position (m)")
    lay = d.shape.layer
    ax.add_collection(LineCollection(_segments(d.adjusted_coords, lay.vertex_feature,
                                               lay.vertex_part, origin),
                                     colors="white", linewidths=0.6, zorder=1))
    meas, pred = _conflation_arrows(d, origin)
    extent = float(max(ext[1] - ext[0], ext[3] - ext[2], 1.0))
    k, key_len = _arrow_scale([meas, pred], extent, max_arrows, None)
    q = None
    for (xy, uv), col in ((pred, "#ff7f0e"), (meas, "black")):
        sel = _subsample(len(xy), max_arrows // 2)
        if len(sel):
            q = ax.quiver(xy[sel, 0], xy[sel, 1], uv[sel, 0] * k, uv[sel, 1] * k,
                          angles="xy", scale_units="xy", scale=1.0, color=col, width=0.004,
                          headwidth=3.5, headlength=4.5, headaxislength=4.0, zorder=4)
    ax.set_title(f"{d.name}: {len(meas[0])} measured (black), {len(pred[0])} predicted "
                 f"(orange)\ndisplacement arrows \u00d7{k:g}", fontsize=9)
    if q is not None:
        _arrow_key(ax, q, key_len, k)
    ax.set_xlim(ext[0], ext[1])
    ax.set_ylim(ext[2], ext[3])
    _axis_labels(ax, origin)


def conflation_figure(run, *, max_arrows: int = MAX_ARROWS, panel_width: float = 5.0):
    """The displacement field of every conflated database: arrows and a CE90 raster.

    Displacement ``adjusted - database`` at the measured (black) and the predicted
    (orange) object points over the raster of the predicted position's CE90 (the
    field's uncertainty; small near measured points, growing away from them) and the
    corrected lines (white).

    Returns
    -------
    matplotlib.figure.Figure or None
        None when no database was conflated.
    """
    dbs = [d for d in run.databases if getattr(d, "conflation", None) is not None]
    if not dbs:
        return None
    origin = _origin(np.concatenate([d.shape.layer.coords[:, :2] for d in dbs]))
    ncols = min(len(dbs), 2)
    nrows = int(math.ceil(len(dbs) / ncols))
    fig = _new_figure(panel_width * ncols, panel_width * 0.9 * nrows, compressed=True)
    matplotlib = _mpl()[0]
    with matplotlib.rc_context(_STYLE):
        axes = fig.subplots(nrows, ncols, squeeze=False)
        for i, d in enumerate(dbs):
            _conflation_panel(fig, axes[i // ncols][i % ncols], d, origin, max_arrows)
        for j in range(len(dbs), nrows * ncols):
            axes[j // ncols][j % ncols].set_visible(False)
    return fig


def _figure_legend(fig, ax, handles, ncol: int) -> None:
    """A legend below the panels (matplotlib 3.7+), else inside the first panel."""
    if _has_outside():
        fig.legend(handles=handles, loc="outside lower center", ncol=ncol, frameon=False)
    else:
        ax.legend(handles=handles, loc="upper left", fontsize=7, framealpha=0.85)


def _has_outside() -> bool:
    """Whether this matplotlib knows legend locations 'outside ...' (3.7+)."""
    import matplotlib

    try:
        major, minor = (int(x) for x in matplotlib.__version__.split(".")[:2])
    except ValueError:
        return False
    return (major, minor) >= (3, 7)


def _ellipse_collection(ax, xy, a, b, angle_deg, color, lw=0.8):
    from matplotlib.collections import EllipseCollection

    kw = dict(widths=2 * a, heights=2 * b, angles=angle_deg, units="xy", offsets=xy,
              facecolors="none", edgecolors=color, linewidths=lw, zorder=3)
    try:
        coll = EllipseCollection(offset_transform=ax.transData, **kw)
    except TypeError:  # matplotlib < 3.6
        coll = EllipseCollection(transOffset=ax.transData, **kw)
    ax.add_collection(coll)
    return coll


def _ellipse_groups(run, cmap: dict) -> list:
    """``(label, colour, xy, cov)`` of shape points per database, control, tie, check points."""
    res = run.result
    kinds = np.asarray(run.point_kind)
    dbn = np.asarray(run.point_database)
    groups = []
    for d in run.databases:
        m = (kinds == "shape") & (dbn == d.name)
        if m.any():
            groups.append((f"{d.name} shape points", cmap[d.name], res.xyz[m, :2],
                           res.point_cov[m, :2, :2]))
    for kind, lab, col in (("control", "control points", "black"),
                           ("tie", "tie points", "#7f7f7f")):
        m = kinds == kind
        if m.any():
            groups.append((lab, col, res.xyz[m, :2], res.point_cov[m, :2, :2]))
    cp = run.control_points or {}
    if len(cp.get("point_id", [])):
        m = (np.asarray(cp["role"]) == "check") & (np.asarray(cp["Used"]) == 1)
        if m.any():
            cov = np.zeros((int(m.sum()), 2, 2))
            cov[:, 0, 0] = np.asarray(cp["SigmaX"], float)[m] ** 2
            cov[:, 1, 1] = np.asarray(cp["SigmaY"], float)[m] ** 2
            xy = np.column_stack([cp["AdjX"], cp["AdjY"]]).astype(float)[m]
            groups.append(("check points (axis-aligned)", "#ff7f0e", xy, cov))
    return groups


def _ellipse_axes(groups: list) -> list:
    """``(label, colour, xy, a, b, angle_deg)`` of the 90 % ellipses, non-empty groups only."""
    from vectoradjust.accuracy.stats import principal_axes

    prepared = []
    for lab, col, xy, cov in groups:
        smax, smin, ang = principal_axes(cov)
        c = math.sqrt(_CHI2_2_90)
        good = np.isfinite(xy).all(axis=1) & np.isfinite(smax) & np.isfinite(smin)
        prepared.append((lab, col, xy[good], c * np.asarray(smax)[good],
                         c * np.asarray(smin)[good], np.degrees(np.asarray(ang)[good])))
    return [p for p in prepared if len(p[2])]


def _ellipse_share(prepared: list, max_ellipses: int) -> tuple:
    """``(n_total, keep_share)``: the share of shape points drawn within ``max_ellipses``."""
    n_total = sum(len(p[2]) for p in prepared)
    # control, check and tie points are few: always all of them; shape points share the rest
    n_fixed = sum(len(p[2]) for p in prepared if "shape" not in p[0])
    n_shape = n_total - n_fixed
    return n_total, min(1.0, max(max_ellipses - n_fixed, 1) / max(n_shape, 1))


def _adjusted_lines(ax, run, origin: tuple) -> None:
    """The adjusted road lines in light grey, under the ellipses."""
    for d in run.databases:
        if d.adjusted_coords is None:
            continue
        lay = d.shape.layer
        seg = _segments(d.adjusted_coords, lay.vertex_feature, lay.vertex_part, origin)
        dense = len(seg) > DENSE_SEGMENTS
        _draw_segments(ax, seg, color="#d0d0d0", linewidth=0.3 if dense else 0.8,
                       antialiased=not dense, zorder=1)


def _draw_ellipses(ax, prepared: list, keep_share: float, origin: tuple, k: float) -> tuple:
    """Draw each group's (subsampled) ellipses; ``(shown, legend handles)``."""
    from matplotlib.lines import Line2D

    shown = 0
    handles = []
    for gi, (lab, col, xy, a, b, ang) in enumerate(prepared):
        want = (len(xy) if keep_share >= 1 or "shape" not in lab else
                max(1, int(round(len(xy) * keep_share))))
        sel = _subsample(len(xy), want, seed=gi)
        shown += len(sel)
        lw = 1.2 if "shape" not in lab else 0.8
        _ellipse_collection(ax, xy[sel] - origin, a[sel] * k, b[sel] * k, ang[sel], col, lw)
        handles.append(Line2D([], [], ls="", marker="o", markerfacecolor="none",
                              markeredgecolor=col, markersize=8,
                              label=f"{lab} (median {np.median(a):.3f} m semi-major)"))
    return shown, handles


def _circle_key(ax, r_key: float, k: float, limits: tuple) -> None:
    """Scale key: a circle of radius ``r_key`` (m, drawn ``x k``), lower left."""
    from matplotlib.patches import Circle

    x0, x1, y0, y1 = limits
    cx, cy = x0 + 0.06 * (x1 - x0) + r_key * k, y0 + 0.06 * (y1 - y0) + r_key * k
    ax.add_patch(Circle((cx, cy), r_key * k, fill=False, ec="#333", lw=1.0, zorder=6))
    ax.annotate(f"{r_key:g} m", (cx + r_key * k * 1.15, cy), va="center", fontsize=8,
                zorder=6, bbox={"boxstyle": "round,pad=0.2", "fc": "white", "ec": "none",
                                "alpha": 0.85})


def error_ellipse_figure(run, *, max_ellipses: int = MAX_ELLIPSES,
                         exaggeration: Optional[float] = None,
                         colors: Optional[dict] = None):
    """90 % confidence ellipses of the adjusted points (a posteriori), exaggerated.

    Semi-axes ``sqrt(chi2_2(0.9) l_i) = 2.1460 sqrt(l_i)`` from the eigenvalues of each
    point's horizontal 2x2 covariance (the region that holds the true position with
    90 % probability; its area differs from the CE90 circle's). Shape points per
    database colour, control points black, tie points grey (all from the bundle's
    full covariances) and check points orange (axis-aligned, from ``SigmaX``,
    ``SigmaY`` of the ``control_points`` table, which has no XY covariance).

    Parameters
    ----------
    run : vectoradjust.pipeline.AdjustmentRun
    max_ellipses : int, optional
        Above it a random subsample (seed 0) is drawn; the title says so.
    exaggeration : float, optional
        Default: a 1-2-5 value making the median ellipse about 1.2 % of the extent.
    colors : dict, optional
        Database name -> colour.

    Returns
    -------
    matplotlib.figure.Figure or None
        None when there is no point with a covariance.
    """
    _, _, _ = _mpl()  # matplotlib required even when there is nothing to draw
    cmap = _db_colors([d.name for d in run.databases], colors)
    prepared = _ellipse_axes(_ellipse_groups(run, cmap))
    if not prepared:
        return None
    allxy = np.concatenate([p[2] for p in prepared])
    line_xy = [d.adjusted_coords[:, :2] for d in run.databases if d.adjusted_coords is not None]
    origin = _origin(np.concatenate([allxy] + line_xy))
    span = np.ptp(np.concatenate([allxy] + line_xy), axis=0)
    extent = float(max(span.max(), 1.0))
    aspect = float(np.clip(span[1] / max(span[0], 1e-9), 0.55, 1.5))
    a_all = np.concatenate([p[3] for p in prepared])
    med = float(np.median(a_all[a_all > 0])) if np.any(a_all > 0) else 1.0
    if exaggeration is None:
        exaggeration = _nice(0.012 * extent / med, "floor")
    k = float(exaggeration)
    n_total, keep_share = _ellipse_share(prepared, max_ellipses)
    fig = _new_figure(8.0, 7.4 * aspect + 1.2, compressed=True)
    matplotlib = _mpl()[0]
    with matplotlib.rc_context(_STYLE):
        ax = fig.add_subplot(1, 1, 1)
        _adjusted_lines(ax, run, origin)
        shown, handles = _draw_ellipses(ax, prepared, keep_share, origin, k)
        limits = _limits(np.concatenate([allxy] + line_xy) - np.asarray(origin))
        ax.set_xlim(limits[0], limits[1])
        ax.set_ylim(limits[2], limits[3])
        _circle_key(ax, _nice(med, "round"), k, limits)
        _axis_labels(ax, origin)
        title = ("90 % confidence ellipses of the adjusted points (a posteriori), "
                 f"exaggerated \u00d7{k:g}")
        if shown < n_total:
            title += f"\n{shown} of {n_total} points shown (random subsample)"
        ax.set_title(title)
        _figure_legend(fig, ax, handles, ncol=2)
    return fig


def _w_values(reliability) -> tuple:
    """(w-test values, critical value) from a reliability object/dict, or (None, None)."""
    if reliability is None:
        return None, None

    def get(name):
        if isinstance(reliability, dict):
            return reliability.get(name)
        return getattr(reliability, name, None)

    w = get("w_image")
    if w is None:
        return None, None
    w = np.asarray(w, float).ravel()
    w = w[np.isfinite(w)]
    crit = get("critical")
    try:
        crit = float(crit) if crit is not None else 3.2905
    except (TypeError, ValueError):
        crit = 3.2905
    return (w if w.size else None), crit


def residual_histogram_figure(run, reliability=None):
    """Histogram of the standardized image residuals ``v / sigma`` with N(0, 1).

    ``v / sigma`` (x and y pooled) has variance ``sigma0^2 r_i`` (redundancy number
    ``r_i < 1``), so it is narrower than N(0, 1) where the geometry is weak; the w-test
    ``v / (sigma sqrt(q_vv))`` of the reliability analysis, shown in a second panel
    when given, is N(0, 1) under the null hypothesis.

    Parameters
    ----------
    run : vectoradjust.pipeline.AdjustmentRun
    reliability : object or dict, optional
        Anything with ``w_image`` (and optionally ``critical``).

    Returns
    -------
    matplotlib.figure.Figure or None
        None when there are no image residuals.
    """
    v = np.asarray(run.result.v_image, float)
    s = np.asarray(run.problem.obs_sigma, float)
    with np.errstate(invalid="ignore", divide="ignore"):
        z = (v / s).ravel()
    z = z[np.isfinite(z)]
    if not z.size:
        return None
    w, crit = _w_values(reliability)
    panels = [("v / \u03c3 (image x and y)", z, None)]
    if w is not None:
        panels.append(("Baarda w-test", w, crit))
    fig = _new_figure(5.2 * len(panels), 3.6)
    matplotlib = _mpl()[0]
    with matplotlib.rc_context(_STYLE):
        axes = fig.subplots(1, len(panels), squeeze=False)[0]
        for ax, (lab, vals, cr) in zip(axes, panels):
            lim = float(min(max(4.0, np.ceil(np.abs(vals).max() + 0.25)), 8.0))
            if cr is not None:
                lim = max(lim, math.ceil(cr + 0.5))
            nb = int(np.clip(np.sqrt(vals.size) * 1.2, 15, 80))
            outside = int(np.sum(np.abs(vals) > lim))
            ax.hist(np.clip(vals, -lim, lim), bins=nb, range=(-lim, lim), density=True,
                    color="#9ecae1", edgecolor="#3182bd", linewidth=0.5,
                    label=f"{lab}: n = {vals.size}, mean {vals.mean():.2f}, "
                          f"sd {vals.std(ddof=1) if vals.size > 1 else 0.0:.2f}")
            x = np.linspace(-lim, lim, 400)
            ax.plot(x, np.exp(-0.5 * x * x) / math.sqrt(2 * math.pi), color="#d62728",
                    lw=1.5, label="N(0, 1)")
            sd = float(vals.std(ddof=1)) if vals.size > 1 else 0.0
            if cr is None and sd > 0 and abs(sd - 1.0) > 0.05:
                ax.plot(x, np.exp(-0.5 * (x / sd) ** 2) / (sd * math.sqrt(2 * math.pi)),
                        color="#555", lw=1.0, ls="--", label=f"N(0, {sd:.2f}\u00b2) for comparison")
            if cr is not None:
                nflag = int(np.sum(np.abs(vals) > cr))
                for sgn in (-1, 1):
                    ax.axvline(sgn * cr, color="#444", ls="--", lw=1.0,
                               label=(f"critical \u00b1{cr:.4g} ({nflag} flagged)"
                                      if sgn > 0 else None))
            ax.set_xlim(-lim, lim)
            ax.set_xlabel(f"{lab} (dimensionless)")
            ax.set_ylabel("probability density")
            t = "Standardized image residuals" if cr is None else "w-tests of image coordinates"
            if outside:
                t += f"\n({outside} values beyond \u00b1{lim:g} in the end bins)"
            ax.set_title(t)
            ax.legend(loc="upper left", frameon=False)
            ymax = ax.get_ylim()[1]
            ax.set_ylim(0, ymax * 1.25)
    return fig


def rmse_bar_figure(entries: Sequence[dict], *, colors: Optional[dict] = None,
                    title: Optional[str] = None):
    """Bar chart of the horizontal RMSE per database.

    Bars: RMSE of the residuals V (the database's accuracy estimated by the
    adjustment) and, where the run carries truth (simulations), RMSE of database -
    truth (what V should recover) and of adjusted - truth (the accuracy of the
    adjusted positions). Every bar is labelled with its value.

    Parameters
    ----------
    entries : sequence of dict
        ``summary["databases"]`` entries: ``name``, ``residuals.rmse_horizontal`` and
        optionally ``truth`` (``rmse_database_truth_horizontal``,
        ``rmse_adjusted_truth_horizontal``).
    colors : dict, optional
        Unused colours are taken from the report palette.
    title : str, optional

    Returns
    -------
    matplotlib.figure.Figure or None
        None when there are no entries.
    """
    entries = [e for e in entries if (e.get("residuals") or {}).get("rmse_horizontal")
               is not None]
    if not entries:
        return None
    names = [str(e["name"]) for e in entries]

    def val(e, *path):
        x = e
        for p in path:
            x = (x or {}).get(p)
        return float(x) if x is not None else float("nan")

    series = [("residuals V", "#1f77b4",
               [val(e, "residuals", "rmse_horizontal") for e in entries])]
    if any(e.get("truth") for e in entries):
        series.append(("database \u2212 truth", "#9a9a9a",
                       [val(e, "truth", "rmse_database_truth_horizontal") for e in entries]))
        series.append(("adjusted \u2212 truth", "#2ca02c",
                       [val(e, "truth", "rmse_adjusted_truth_horizontal") for e in entries]))
    fig = _new_figure(max(4.8, 1.5 + 1.5 * len(names) * len(series) / 2.0), 3.6)
    matplotlib = _mpl()[0]
    with matplotlib.rc_context(_STYLE):
        ax = fig.add_subplot(1, 1, 1)
        x = np.arange(len(names))
        wdt = 0.8 / len(series)
        top = np.nanmax([np.nanmax(s[2]) if np.isfinite(s[2]).any() else 0 for s in series])
        for i, (lab, col, vals) in enumerate(series):
            pos = x - 0.4 + wdt * (i + 0.5)
            bars = ax.bar(pos, np.nan_to_num(vals), width=wdt * 0.92, color=col, label=lab)
            for rect, v in zip(bars, vals):
                if np.isfinite(v):
                    ax.annotate(f"{v:.2f}", (rect.get_x() + rect.get_width() / 2,
                                             rect.get_height()),
                                xytext=(0, 2), textcoords="offset points", ha="center",
                                va="bottom", fontsize=7.5)
        ax.set_xticks(x)
        ax.set_xticklabels(names)
        ax.set_ylabel("horizontal RMSE (m)")
        ax.set_ylim(0, (top if top > 0 else 1.0) * 1.15)
        ax.grid(axis="x", visible=False)
        ax.set_title(title or "Horizontal RMSE per road database")
        ax.legend(frameon=False, loc="upper left")
    return fig


def _img(fig, alt: str, caption: str) -> str:
    if fig is None:
        return _note(f"({alt}: nothing to plot)")
    data = base64.b64encode(figure_png(fig)).decode("ascii")
    return (f'<figure><img alt={_q(alt)} src="data:image/png;base64,{data}">'
            f"<figcaption>{_e(caption)}</figcaption></figure>")


# =========================================================================== sections
#: (progress, is_cancelled, sections done) while a report is written (see _reporting)
_HOOKS: ContextVar = ContextVar("vectoradjust_report_hooks", default=None)
_EXPECTED_SECTIONS = 16  # sections of a one-run report, for the progress fraction


@contextmanager
def _reporting(progress, is_cancelled):
    """Progress per finished section and cancel between sections while a report is built."""
    token = _HOOKS.set([progress, is_cancelled, 0])
    try:
        yield
    finally:
        _HOOKS.reset(token)


def _section_done(title: str) -> None:
    hooks = _HOOKS.get()
    if hooks is None:
        return
    progress, is_cancelled, n = hooks
    hooks[2] = n + 1
    if is_cancelled is not None and is_cancelled():
        raise CancelledError("Writing the report was cancelled", "Run it again when ready")
    if progress is not None:
        progress(min(0.95, (n + 1) / _EXPECTED_SECTIONS), f"report: {title}")


class _Doc:
    """Sections with headings, anchors and a table of contents."""

    def __init__(self) -> None:
        self.parts: list = []
        self.toc: list = []

    def section(self, ident: str, title: str, body: str, level: int = 2) -> None:
        if level <= 3:
            self.toc.append((level, ident, title))
        self.parts.append(f'<section id={_q(ident)}><h{level}>{_e(title)}</h{level}>'
                          f"{body}</section>")
        _section_done(title)

    def raw(self, text: str) -> None:
        self.parts.append(text)


def _summary_body(run, prefix: str = "") -> str:
    s = run.summary
    chi = s.get("chi_square") or {}
    obs = s.get("observations") or {}
    passed = chi.get("passed")
    if chi.get("lower") is not None:
        verdict_cls = "pass" if passed else "fail"
        verdict = (f"Global chi-square test (\u03b1 = {_fmt(chi.get('alpha'), 3)}): "
                   f"v\u1d40Pv = {_fmt(chi.get('statistic'), 2)} "
                   f"{'lies within' if passed else 'lies outside'} "
                   f"[{_fmt(chi.get('lower'), 2)}, {_fmt(chi.get('upper'), 2)}] "
                   f"for r = {s.get('degrees_of_freedom')} degrees of freedom.")
    else:
        verdict_cls = "na"
        verdict = "Global chi-square test: not possible without redundancy."
    out = [f'<div class="verdict {verdict_cls}">{_badge(passed)} {_e(verdict)}</div>']
    sp = s.get("shape_points") or {}
    ck = s.get("check_points") or {}
    co = s.get("control_points") or {}
    passes = s.get("passes") or []
    pairs = [
        ("project", s.get("project", ""), "project"),
        ("CRS", s.get("crs", ""), "crs"),
        ("reweighting", f"{s.get('reweight', 'none')} ({len(passes)} pass"
                        f"{'es' if len(passes) != 1 else ''})", "reweight"),
        ("converged", _fmt(s.get("converged")), "converged"),
        ("iterations", _fmt(s.get("iterations")), "iterations"),
        ("\u03c3\u2080\u00b2 (a-posteriori variance factor)", _fmt(s.get("sigma0_squared"), 4),
         "sigma0_squared"),
        ("\u03c3\u2080", _fmt(s.get("sigma0"), 4), "sigma0"),
        ("degrees of freedom r", _fmt(s.get("degrees_of_freedom")), "degrees_of_freedom"),
        ("v\u1d40Pv", _fmt(chi.get("statistic"), 2), "chi_square_statistic"),
        ("chi-square lower bound", _fmt(chi.get("lower"), 2), "chi_square_lower"),
        ("chi-square upper bound", _fmt(chi.get("upper"), 2), "chi_square_upper"),
        ("chi-square test", _badge(passed), "chi_square_passed"),
        ("observations (total)", _fmt(obs.get("total")), "observations_total"),
        ("image coordinates", _fmt(obs.get("image_coordinates")), "image_coordinates"),
        ("point coordinate priors", _fmt(obs.get("point_priors")), "point_priors"),
        ("EO priors", _fmt(obs.get("eo_priors")), "eo_priors"),
        ("unknowns", _fmt(obs.get("unknowns")), "unknowns"),
        ("control / shape / tie points",
         f"{_fmt(obs.get('control_points'))} / {_fmt(obs.get('shape_points'))} / "
         f"{_fmt(obs.get('tie_points'))}", "point_counts"),
        ("shape points: RMSE of residuals, horizontal (m)",
         _fmt(sp.get("rmse_horizontal"), 3), "shape_rmse_horizontal"),
        ("control points: RMSE horizontal (m)", _fmt(co.get("rmse_horizontal"), 3),
         "control_rmse_horizontal"),
        ("check points: RMSE horizontal / vertical (m)",
         f"{_fmt(ck.get('rmse_horizontal'), 3)} / {_fmt(ck.get('rmse_z'), 3)}",
         "check_rmse"),
        ("mean CE90 / LE90 of adjusted shape points (m)",
         f"{_fmt(s.get('mean_ce90'), 3)} / {_fmt(s.get('mean_le90'), 3)}", "mean_ce90_le90"),
    ]
    out.append(_kv_table(pairs, ident=f"{prefix}summary-table"))
    if len(passes) > 1:
        rows = []
        for p in passes:
            sig = p.get("sigma") or {}
            rows.append([_fmt(p.get("pass")), _fmt(p.get("sigma0_squared"), 4),
                         _fmt(p.get("iterations")),
                         "; ".join(f"{k}: " + ", ".join(_fmt(x, 3) for x in v)
                                   for k, v in sig.items())])
        out.append("<h4>Adjustment passes</h4>")
        out.append(_table(["pass", "\u03c3\u2080\u00b2", "iterations",
                           "prior \u03c3 of shape points X, Y, Z (m)"], rows))
    return "".join(out)


def _rpc_images_body(images: list, prefix: str) -> str:
    """The RPC images' estimated bias: values, sigmas, the significance test, the
    corrected RPC file."""
    rows = []
    for im in images:
        b, sd = im.get("bias") or {}, im.get("sigma_bias") or {}
        sig = im.get("significance") or {}
        rows.append([im.get("id", ""), im.get("bias_model", ""),
                     "; ".join(f"{k} = {_fmt(v, 3)} ± {_fmt(sd.get(k), 3)}"
                               for k, v in b.items()) or "–",
                     _fmt(sig.get("statistic"), 1), _fmt(sig.get("critical"), 2),
                     _fmt(sig.get("significant")),
                     (im.get("corrected_rpc") or {}).get("file", "–"),
                     _fmt((im.get("corrected_rpc") or {}).get("fold_misfit_px"), 6)])
    heads = ["image", "bias model", "bias (px)", "b′C⁻¹b", "χ² limit",
             "significant", "corrected RPC", "fold misfit (px)"]
    return (_note("RPC images: the image-space bias (column a0 + a1 u + a2 v, row b0 + b1 u "
                  "+ b2 v; u, v the normalised column and row) estimated with the adjustment, "
                  "its a-posteriori standard deviations, the joint test of the bias against "
                  "zero, and the RPC file with the bias folded in (next to the image, GDAL "
                  "uses it instead of the image's own RPCs).")
            + _table(heads, rows, ident=f"{prefix}rpc-images-table"))


def _images_body(run, prefix: str = "") -> str:
    rows = []
    everything = run.summary.get("images") or []
    rpc = [im for im in everything if im.get("model") == "rpc"]
    if rpc and len(rpc) == len(everything):
        return _rpc_images_body(rpc, prefix)
    for im in everything:
        if im.get("model") == "rpc":
            continue
        pos = im.get("position") or [None] * 3
        att = im.get("attitude") or [None] * 3
        sp = im.get("sigma_position") or [None] * 3
        sa = im.get("sigma_attitude") or [None] * 3
        rows.append([im.get("id", ""), im.get("date") or "\u2013",
                     *(_fmt(x, 3) for x in pos), *(_fmt(x, 3) for x in sp),
                     *(_fmt(x, 5) for x in att), *(_fmt(x, 5) for x in sa),
                     _fmt(bool(im.get("used", True)))])
    heads = ["image", "date", "X_L (m)", "Y_L (m)", "Z_L (m)", "\u03c3X (m)", "\u03c3Y (m)",
             "\u03c3Z (m)", "\u03c9 (\u00b0)", "\u03c6 (\u00b0)", "\u03ba (\u00b0)",
             "\u03c3\u03c9 (\u00b0)", "\u03c3\u03c6 (\u00b0)", "\u03c3\u03ba (\u00b0)",
             "adjusted"]
    return (_note("Adjusted exterior orientation and its a-posteriori standard deviations "
                  "(\u03c3\u2080\u00b2 N\u207b\u00b9). Images without measurements keep their "
                  "approximations and are marked as not adjusted.")
            + _table(heads, rows, ident=f"{prefix}images-table")
            + (_rpc_images_body(rpc, prefix) if rpc else ""))


_CP_COLS = [("point_id", "point", None), ("X", "X (m)", 3), ("Y", "Y (m)", 3),
            ("Z", "Z (m)", 3), ("Vx", "Vx (m)", 3), ("Vy", "Vy (m)", 3), ("Vz", "Vz (m)", 3),
            ("SigmaX", "\u03c3X (m)", 3), ("SigmaY", "\u03c3Y (m)", 3),
            ("SigmaZ", "\u03c3Z (m)", 3), ("CE90", "CE90 (m)", 3), ("LE90", "LE90 (m)", 3),
            ("NImages", "images", None), ("Used", "used", None)]


def _columns_table(cols: dict, spec, mask: np.ndarray, ident: Optional[str] = None,
                   order: Optional[np.ndarray] = None) -> str:
    idx = np.flatnonzero(mask) if order is None else order
    if not len(idx):
        return '<p class="note">(none)</p>'
    columns = []
    heads = []
    for key, head, nd in spec:
        if key not in cols:
            continue
        a = np.asarray(cols[key])[idx]
        if key == "Used" or key == "Adjusted":
            columns.append(["yes" if int(x) == 1 else "no" for x in a.tolist()])
        elif nd is None:
            columns.append(_fmt_col(a) if a.dtype.kind in "iuf" else [str(x) for x in a])
        else:
            columns.append(_fmt_col(a.astype(float), nd))
        heads.append(head)
    rows = [list(r) for r in zip(*columns)]
    return _table(heads, rows, ident=ident)


def _control_body(run, role: str, prefix: str = "") -> str:
    cp = run.control_points or {}
    if not len(cp.get("point_id", [])):
        return _note("(no control file points)")
    mask = np.asarray(cp["role"]) == role
    txt = ("Residuals V = adjusted \u2212 surveyed of the control points in the adjustment; "
           "\u03c3, CE90 and LE90 a posteriori." if role == "control" else
           "Check points are not in the adjustment: intersected from the adjusted images; "
           "V = intersected \u2212 surveyed (the independent accuracy of the block).")
    s = run.summary.get("check_points" if role == "check" else "control_points") or {}
    extra = ""
    if s.get("count"):
        extra = _note(f"RMSE over {s['count']} points: X {_fmt(s.get('rmse_x'))} m, Y "
                      f"{_fmt(s.get('rmse_y'))} m, Z {_fmt(s.get('rmse_z'))} m, horizontal "
                      f"{_fmt(s.get('rmse_horizontal'))} m.")
    return _note(txt) + extra + _columns_table(cp, _CP_COLS, mask, ident=f"{prefix}{role}-table")


def _databases_body(run, prefix: str, colors: dict, *, with_bars: bool = True) -> str:
    entries = run.summary.get("databases") or []
    if not entries:
        return _note("No road database in this run (plain aerial triangulation).")
    rows = []
    for e in entries:
        r = e.get("residuals") or {}
        sig = e.get("sigma_prior") or [None] * 3
        rows.append([e.get("name", ""), _fmt(e.get("vertices")),
                     _fmt(e.get("adjusted_vertices")), _fmt(e.get("points")),
                     _fmt(e.get("features")),
                     _fmt(e.get("unadjustable_features")),
                     ", ".join(_fmt(x, 2) for x in sig),
                     _fmt(r.get("rmse_x")), _fmt(r.get("rmse_y")), _fmt(r.get("rmse_z")),
                     _fmt(r.get("rmse_horizontal")), _fmt(e.get("mean_ce90")),
                     _fmt(e.get("mean_le90"))])
    out = [_note("Residuals V = adjusted \u2212 database at the measured (adjusted) vertices: "
                 "the RMSE of V estimates the database's positional accuracy. It counts "
                 "each object point once (points: an intersection shared by features is "
                 "one point)."),
           _table(["database", "vertices", "adjusted", "points", "features", "unadjustable",
                   "prior \u03c3 X, Y, Z (m)", "RMSE Vx (m)", "RMSE Vy (m)", "RMSE Vz (m)",
                   "RMSE V horiz. (m)", "mean CE90 (m)", "mean LE90 (m)"], rows,
                  ident=f"{prefix}databases-table")]
    truth = [e for e in entries if e.get("truth")]
    if truth:
        trows = []
        for e in truth:
            t = e["truth"]
            trows.append([e.get("name", ""), _fmt(t.get("count")),
                          _fmt(t.get("rmse_residuals_horizontal")),
                          _fmt(t.get("rmse_database_truth_horizontal")),
                          _fmt(t.get("recovery_rate")),
                          _fmt(t.get("rmse_adjusted_truth_horizontal")),
                          _fmt(t.get("rmse_adjusted_truth_z")),
                          _fmt(t.get("improvement")), _fmt(t.get("share_within_ce90")),
                          _fmt(t.get("share_within_le90"))])
        out.append("<h4>Comparison with the truth (simulation)</h4>")
        out.append(_note("recovery = RMSE(V) / RMSE(database \u2212 truth); improvement = 1 \u2212 "
                         "RMSE(adjusted \u2212 truth) / RMSE(database \u2212 truth); shares: "
                         "adjusted points whose true error is within their CE90 / LE90."))
        out.append(_table(["database", "points", "RMSE V (m)", "RMSE db\u2212truth (m)",
                           "recovery", "RMSE adj\u2212truth (m)", "RMSE adj\u2212truth Z (m)",
                           "improvement", "within CE90", "within LE90"], trows,
                          ident=f"{prefix}truth-table"))
    if with_bars:
        out.append(_img(rmse_bar_figure(entries, colors=colors), "RMSE per database",
                        "Horizontal RMSE per road database: of the residuals V"
                        + (", of database \u2212 truth and of adjusted \u2212 truth."
                           if truth else ".")))
    out.append(_img(residual_vector_figure(run, colors=colors), "residual vectors",
                    "Residual vectors V at the database positions over the database lines "
                    "(grey) and the adjusted lines (colour); one common arrow scale for all "
                    "panels, given by the key."))
    return "".join(out)


def _ager_rows(block: dict) -> list:
    ag = block.get("ager") or {}
    ns = block.get("nssda") or {}
    return [
        ["CE90 (horizontal, with bias)", _fmt(ag.get("ce90_formula")),
         _fmt(ag.get("ce90_exact")), ag.get("ce90_rule") or "\u2013"],
        ["LE90 (vertical, with bias)", _fmt(ag.get("le90_formula")),
         _fmt(ag.get("le90_exact")), ag.get("le90_rule") or "\u2013"],
        ["NSSDA horizontal 95 %", _fmt(ns.get("horizontal_95")),
         _fmt(ns.get("horizontal_95_exact")), ns.get("horizontal_method") or "\u2013"],
        ["NSSDA 1.7308 RMSE_r", _fmt(ns.get("horizontal_95_1_7308_rmse_r")), "\u2013",
         "the NSSDA formula for RMSE_x = RMSE_y"],
        ["NSSDA vertical 95 %", _fmt(ns.get("vertical_95")), "\u2013", "1.9600 RMSE_z"],
    ]


def _accuracy_block(block: dict, title: str) -> str:
    if not block:
        return ""
    mean = block.get("mean_error") or {}
    rb = block.get("residual_bias")
    rm = block.get("rmse") or {}
    ag = block.get("ager") or {}
    asp = block.get("asprs2023") or {}
    ns = block.get("nssda") or {}
    bias = block.get("bias") or {}
    out = [f"<h3>{_e(title)}</h3>",
           _note(f"Errors: {block.get('errors', '')}; reference: {block.get('reference', '')}; "
                 f"{block.get('count', 0)} points.")]
    if bias.get("statement"):
        out.append(f'<p class="statement">Bias: {_e(bias["statement"])}'
                   + (f", azimuth {_fmt(bias.get('azimuth'), 1)}\u00b0"
                      if bias.get("azimuth") is not None else "") + ".</p>")
    pairs = [("mean error x, y, z (m)", ", ".join(_fmt(mean.get(a)) for a in "xyz"))]
    if rb:
        pairs.append(("mean residual V x, y, z (m)",
                      ", ".join(_fmt(rb.get(a)) for a in ("vx", "vy", "vz"))))
    pairs += [
        ("RMSE x, y, z, horizontal (m)", ", ".join(_fmt(rm.get(a)) for a in
                                                  ("x", "y", "z", "horizontal"))),
        ("\u03bc = |mean horizontal error| (m)", _fmt(ag.get("mu"))),
        ("\u03c3_c = (\u221a\u03bb\u2081 + \u221a\u03bb\u2082) / 2 (m)", _fmt(ag.get("sigma_c"))),
        ("\u03c3_z (m)", _fmt(ag.get("sigma_z"))),
    ]
    out.append(_kv_table(pairs))
    out.append(_table(["statistic", "formula (m)", "exact (m)", "rule"], _ager_rows(block),
                      cls="acc"))
    for k in ("horizontal_statement", "vertical_statement"):
        if ns.get(k):
            out.append(f'<p class="statement">NSSDA: {_e(ns[k])}.</p>')
    ap = [("RMSE_H (m)", _fmt(asp.get("rmse_h"))), ("RMSE_V (m)", _fmt(asp.get("rmse_v"))),
          ("RMSE_3D (m)", _fmt(asp.get("rmse_3d"))),
          ("RMSE_H, RMSE_V of the data alone (m)",
           f"{_fmt(asp.get('rmse_h_data'))}, {_fmt(asp.get('rmse_v_data'))}"),
          ("reference (checkpoint) accuracy added, H / V (m)",
           f"{_fmt(asp.get('survey_rmse_h'))} / {_fmt(asp.get('survey_rmse_v'))}"),
          ("at least 30 checkpoints", _fmt(asp.get("min_checkpoints_met")))]
    out.append("<h4>ASPRS Positional Accuracy Standards, Edition 2 (2023)</h4>")
    out.append(_kv_table(ap))
    for k in ("statement_h", "statement_v", "statement_3d"):
        if asp.get(k):
            out.append(f'<p class="statement">{_e(asp[k])}</p>')
    t = block.get("truth")
    if t:
        out.append(_note(
            f"Against the truth (simulation), database \u2212 truth at the same {t.get('count')} "
            f"points: bias {t.get('bias_text', '')}, RMSE horizontal "
            f"{_fmt(t.get('rmse_horizontal'))} m, CE90 exact {_fmt(t.get('ce90_exact'))} m "
            f"(formula {_fmt(t.get('ce90_formula'))} m), LE90 exact "
            f"{_fmt(t.get('le90_exact'))} m."))
    return "".join(out)


def _accuracy_body(acc: Optional[dict]) -> str:
    if not acc:
        return _note("Accuracy statements: not computed.")
    out = [_note("CE90/LE90 with bias (Ager, NIMA): the piecewise formula value beside the "
                 "exact numeric value; NSSDA (FGDC-STD-007.3-1998) 95 % values; ASPRS 2023 "
                 "RMSE_H / RMSE_V / RMSE_3D. For a road database the errors are database "
                 "\u2212 adjusted (= \u2212V): the adjusted positions serve as checkpoints.")]
    for b in acc.get("databases") or []:
        out.append(_accuracy_block(b, f"Database {b.get('name', '')}"))
    if acc.get("check_points"):
        out.append(_accuracy_block(acc["check_points"], "Check points"))
    else:
        out.append(_note("Check points: none intersected."))
    return "".join(out)


_NAME_KEYS = ("name", "fullname", "full_name", "street", "st_name", "road_name", "label")
_TYPE_KEYS = ("highway", "fclass", "mtfcc", "road_class", "class", "type", "roadtype")


def _name_columns(attributes: dict) -> list:
    """Up to two attribute columns that name or classify the road."""
    low = {str(k).lower(): k for k in attributes}
    out = []
    for cands in (_NAME_KEYS, _TYPE_KEYS):
        hit = next((low[c] for c in cands if c in low), None)
        if hit is None and cands is _NAME_KEYS:
            hit = next((k for lk, k in low.items() if "name" in lk), None)
        if hit is not None and hit not in out:
            out.append(hit)
    return out


def _attr_text(v: Any) -> str:
    """An attribute value as text; None and NaN as '\u2013'."""
    if v is None or (isinstance(v, (float, np.floating)) and not math.isfinite(float(v))):
        return "\u2013"
    return str(v)


def _statement_rows(rows, fids: list) -> dict:
    """The per-feature statements of the features ``fids`` by feature id: only those
    rows are built from :class:`~vectoradjust.accuracy.statements.FeatureStatements`."""
    if hasattr(rows, "index_of"):
        at = rows.index_of(fids).tolist()
        return {f: rows[i] for f, i in zip(fids, at) if i >= 0}
    return {r["feature_id"]: r for r in rows}


def _features_body(run, acc: Optional[dict], prefix: str) -> str:
    parts = []
    feats_acc = (acc or {}).get("features") or {}
    for d in run.databases:
        f = d.features
        layer = d.shape.layer
        nf = layer.n_features
        if not nf:
            continue
        names = _name_columns(layer.attributes)
        order = np.arange(nf)
        note = ""
        if nf > MAX_FEATURE_ROWS:
            rm = np.nan_to_num(np.asarray(f["RMSE"], float), nan=-1.0)
            order = np.argsort(-rm, kind="stable")[:LARGEST_FEATURE_ROWS]
            note = _note(f"{nf} features: the {LARGEST_FEATURE_ROWS} with the largest RMSE are "
                         f"listed ({nf - LARGEST_FEATURE_ROWS} left out); all are in the "
                         "features layer of adjusted.gpkg and their accuracy statements in "
                         "feature_accuracy.csv.")
        cols = [layer.feature_ids[order].tolist()]
        heads = ["feature"]
        for k in names:
            vals = layer.attributes[k]
            cols.append([_attr_text(vals[i]) for i in order.tolist()])
            heads.append(str(k))
        for key, head, nd in (("NPts", "NPts", None), ("NAdj", "NAdj", None),
                              ("RMSE_X", "RMSE X (m)", 3), ("RMSE_Y", "RMSE Y (m)", 3),
                              ("RMSE_Z", "RMSE Z (m)", 3), ("RMSE", "RMSE horiz. (m)", 3),
                              ("Length", "length (m)", 1)):
            a = np.asarray(f[key])[order]
            cols.append(_fmt_col(a) if nd is None else _fmt_col(a.astype(float), nd))
            heads.append(head)
        fids = layer.feature_ids[order].tolist()
        arow = _statement_rows(feats_acc.get(d.name, []), fids)
        ce, ce_f, bias = [], [], []
        for fid in fids:
            r = arow.get(fid)
            ag = (r or {}).get("ager") or {}
            ce.append(_fmt(ag.get("ce90_exact")))
            ce_f.append(_fmt(ag.get("ce90_formula")))
            bias.append((r or {}).get("bias_text") or "\u2013")
        cols += [ce, ce_f, bias]
        heads += ["CE90 exact (m)", "CE90 Ager (m)", "bias (database \u2212 adjusted)"]
        for key, head in (("Images", "images"), ("Problem", "problem")):
            if key in f:
                cols.append([str(x) if x not in (None, "") else "\u2013"
                             for x in np.asarray(f[key], dtype=object)[order].tolist()])
                heads.append(head)
        rows = [list(r) for r in zip(*cols)]
        parts.append(f"<h3>{_e(d.name)}: {nf} features</h3>")
        parts.append(note)
        parts.append('<div class="scroll">' + _table(heads, rows,
                                                     ident=f"{prefix}features-{d.name}")
                     + "</div>")
    if not parts:
        return _note("(no features)")
    n_min = (acc or {}).get("min_feature_vertices")
    head = _note("RMSE of the residuals V over the adjusted vertices of each feature; CE90 "
                 "with bias (exact and Ager's formula) and bias of database \u2212 adjusted "
                 + (f"for features with at least {n_min} adjusted vertices." if n_min else "."))
    return head + "".join(parts)


_SHAPE_COLS = [("Database", "database", None), ("point_id", "point", None),
               ("feature_id", "feature", None), ("X", "X (m)", 3), ("Y", "Y (m)", 3),
               ("Z", "Z (m)", 3), ("Vx", "Vx (m)", 3), ("Vy", "Vy (m)", 3), ("Vz", "Vz (m)", 3),
               ("Vh", "|V| horiz. (m)", 3), ("SigmaX", "\u03c3X (m)", 3),
               ("SigmaY", "\u03c3Y (m)", 3), ("SigmaZ", "\u03c3Z (m)", 3),
               ("CE90", "CE90 (m)", 3), ("LE90", "LE90 (m)", 3), ("NImages", "images", None),
               ("Adjusted", "adjusted", None)]


def _shape_body(run, prefix: str) -> str:
    dbs = [d for d in run.databases if d.vertices]
    if not dbs:
        return _note("(no shape points)")
    def column(k):
        return np.concatenate([np.asarray(d.vertices[k], float) for d in dbs])

    vh = np.hypot(column("Vx"), column("Vy"))
    n = len(vh)
    n_adj = int(sum(np.sum(np.asarray(d.vertices["Adjusted"]) == 1) for d in dbs))
    if n <= MAX_FULL_SHAPE_ROWS:
        order = np.arange(n)
        note = _note(f"All {n} vertices ({n_adj} adjusted). V = adjusted \u2212 database; "
                     "unmeasured vertices are not adjusted (\u2013).")
    else:
        vh = np.where(np.isfinite(vh), vh, -1.0)
        k = min(LARGEST_SHAPE_ROWS, n)
        top = np.argpartition(-vh, k - 1)[:k]
        order = top[np.argsort(-vh[top], kind="stable")]
        note = _note(f"{n} vertices ({n_adj} adjusted): the {k} with the largest horizontal "
                     "residual are listed; every vertex is in the shape_points layer of "
                     "adjusted.gpkg.")
    # only the listed rows are gathered (not every column of a million vertices)
    ends = np.cumsum([len(d.vertices["X"]) for d in dbs])
    which = np.searchsorted(ends, order, side="right")
    local = order - np.concatenate([[0], ends[:-1]])[which]
    cols = {"Vh": np.where(vh[order] >= 0, vh[order], np.nan)}
    for k in (k for k, _, _ in _SHAPE_COLS if k != "Vh"):
        parts = [np.asarray(d.vertices[k])[local[which == i]] if k in d.vertices else
                 np.full(int(np.sum(which == i)), d.name, dtype=object)
                 for i, d in enumerate(dbs)]
        gathered = np.concatenate(parts)
        cols[k] = np.empty(len(order), gathered.dtype)
        cols[k][np.argsort(which, kind="stable")] = gathered
    m = len(order)
    return note + '<div class="scroll">' + _columns_table(
        cols, _SHAPE_COLS, np.ones(m, bool), ident=f"{prefix}shape-table",
        order=np.arange(m)) + "</div>"


def _flagged_list(run, reliability) -> Optional[list]:
    """Flagged observations from the reliability argument or the summary; None if absent."""
    if reliability is not None:
        if isinstance(reliability, (list, tuple)):
            return list(reliability)
        if isinstance(reliability, dict) and "flagged" in reliability:
            return list(reliability["flagged"] or [])
        fl = getattr(reliability, "flagged", None)
        if fl is not None and not callable(fl):
            return list(fl)
        if hasattr(reliability, "flag_image"):  # a vectoradjust.adjust.reliability.Reliability
            try:
                from vectoradjust.adjust.reliability import flagged_observations
            except ImportError:  # pragma: no cover - module not installed
                flagged_observations = None
            if flagged_observations is not None:
                return flagged_observations(reliability, run.result, run.point_ids,
                                            run.image_ids, run.point_kind)
    rel = (run.summary or {}).get("reliability")
    if isinstance(rel, dict):
        return list(rel.get("flagged") or [])
    return None


def _records_table(records: Sequence[dict], ident: Optional[str] = None) -> str:
    """A table of dicts (union of keys, first-seen order); nested values compacted."""
    keys: list = []
    for r in records:
        for k in r:
            if k not in keys:
                keys.append(k)
    rows = [[_compact(r.get(k)) for k in keys] for r in records]
    return _table([str(k) for k in keys], rows, ident=ident)


def _compact(v: Any, depth: int = 0):
    if isinstance(v, dict):
        if depth > 2:
            return f"{len(v)} entries"
        return _Raw(_generic(v, depth + 1))
    if isinstance(v, (list, tuple)):
        if v and all(isinstance(x, dict) for x in v):
            if depth > 2:
                return f"{len(v)} rows"
            return _Raw(f"<details><summary>{len(v)} row{'s' if len(v) != 1 else ''}</summary>"
                        f"{_records_table(v)}</details>")
        items = [_fmt(x, 4) if not isinstance(x, str) else x for x in v]
        text = ", ".join(items[:30]) + (f", \u2026 ({len(items)} in all)" if len(items) > 30
                                         else "")
        return text or "\u2013"
    if isinstance(v, (float, np.floating)):
        return _fmt(v, 4)
    if v is None:
        return "\u2013"
    if isinstance(v, str) and v.lower() in ("pass", "fail"):
        return _badge(v.lower() == "pass", "pass", "fail")
    return _fmt(v)


def _generic(obj: Any, depth: int = 0) -> str:
    """Render a JSON-like object as tables."""
    if isinstance(obj, dict):
        scal = [(k, v) for k, v in obj.items()
                if not isinstance(v, (dict, list, tuple))]
        rest = [(k, v) for k, v in obj.items() if isinstance(v, (dict, list, tuple))]
        out = []
        if scal:
            out.append(_table(["key", "value"], [[str(k), _compact(v, depth)] for k, v in scal],
                              cls="kv"))
        for k, v in rest:
            out.append(f"<h4>{_e(k)}</h4>")
            if isinstance(v, dict):
                out.append(_generic(v, depth + 1))
            elif v and all(isinstance(x, dict) for x in v):
                out.append(_records_table(v))
            else:
                out.append(f"<p>{_e(_compact(v, depth))}</p>")
        return "".join(out)
    if isinstance(obj, (list, tuple)) and obj and all(isinstance(x, dict) for x in obj):
        return _records_table(obj)
    return f"<p>{_e(_compact(obj, depth))}</p>"


def _residuals_body(run, reliability) -> str:
    out = [_img(residual_histogram_figure(run, reliability), "standardized residuals",
                "Image coordinate residuals v (adjusted \u2212 observed) divided by their a-priori "
                "\u03c3, x and y pooled, with the standard normal density; v/\u03c3 has variance "
                "\u03c3\u2080\u00b2 r\u1d62 (redundancy number r\u1d62 < 1), so it is narrower "
                "than N(0, 1). The w-tests (when computed) are N(0, 1) under the null hypothesis.")]
    v = np.asarray(run.result.v_image, float) * 1000.0
    if v.size:
        rms = np.sqrt(np.nanmean(v**2, axis=0))
        out.append(_note(f"RMS of the image residuals: x {rms[0]:.2f} \u00b5m, y "
                         f"{rms[1]:.2f} \u00b5m over {len(v)} measurements; largest |v| "
                         f"{np.nanmax(np.abs(v)):.2f} \u00b5m."))
    return "".join(out)


def _flagged_body(run, reliability, prefix: str = "") -> str:
    flagged = _flagged_list(run, reliability)
    if flagged is None:
        return _note("Reliability analysis (w-tests, flagged observations): not computed.")
    if not flagged:
        return _note("No observation is flagged by the w-test.")
    text = f"{len(flagged)} observation(s) flagged by the w-test, largest |w| first."
    if len(flagged) > LARGEST_FLAGGED_ROWS:  # bounded: all of them are in the CSV
        left = len(flagged) - LARGEST_FLAGGED_ROWS
        text += (f" The first {LARGEST_FLAGGED_ROWS} are listed ({left} left out); all are in "
                 "flagged_observations.csv.")
        flagged = flagged[:LARGEST_FLAGGED_ROWS]
    return (_note(text) + '<div class="scroll">'
            + _records_table(flagged, ident=f"{prefix}flagged-table") + "</div>")


def _qa_body(qa: Any) -> str:
    if hasattr(qa, "as_dict"):
        qa = qa.as_dict()
    if not isinstance(qa, dict):
        return _generic(qa)
    out = []
    passed = qa.get("passed")
    if passed is None and isinstance(qa.get("verdict"), str):
        passed = {"pass": True, "fail": False}.get(qa["verdict"].lower())
    if "passed" in qa or "verdict" in qa:
        cls = "na" if passed is None else ("pass" if passed else "fail")
        out.append(f'<div class="verdict {cls}">{_badge(passed, "accepted", "REJECTED")} '
                   f"QA verdict: {_e(qa.get('verdict', ''))}</div>")
    from vectoradjust.qa.verdict import production_rows

    # the production checks as compact tables (zones, inter-strip ties, free model);
    # their full detail (point ids per zone, overlap polygons) is in qa.json
    for title, rows in production_rows(qa):
        out.append(f"<h4>{_e(title)}</h4>" + _records_table(rows))
    skip = ("passed", "verdict", "tie_zones", "triplet_zones", "inter_strip", "free_model")
    out.append(_generic({k: v for k, v in qa.items() if k not in skip}))
    return "".join(out)


def _error_model_rows(s: dict) -> list:
    """One row per database: identification sigma (stated / estimated) and offset."""
    rows = []
    for db in s.get("databases") or []:
        ident = db.get("identification_sigma")
        est = "; ".join(f"{e['horizontal']:.2f} \u00b1 {e['horizontal_se']:.2f} m "
                        f"({e['source']}, n = {e['count']})"
                        for e in db.get("identification_estimates") or []
                        if e.get("horizontal") is not None)
        off = db.get("offset") or {}
        rows.append([db.get("name"),
                     "not given" if ident is None else f"{ident[0]:g} / {ident[1]:g} m",
                     est or "-", db.get("offset_model", "none"),
                     off.get("statement", "not estimated")])
    return rows


def _error_model_body(run) -> str:
    """Identification error, database offsets, roads versus control, group factors."""
    s = run.summary or {}
    parts = [_table(["database", "identification \u03c3 (h / v)",
                     "identification \u03c3 from the data", "offset model", "offset"],
                    _error_model_rows(s))]
    rc = s.get("roads_and_control")
    if rc:
        parts.append(_note(rc["text"]))
    vf = (s.get("variance_factors") or {}).get("groups") or {}
    if vf:
        parts.append(_table(["group", "v'Pv", "redundancy r", "v'Pv / r", "flagged"],
                            [[g, _fmt(e["vtpv"], 2), _fmt(e["redundancy"], 2),
                              _fmt(e["factor"], 3), "yes" if e["flagged"] else ""]
                             for g, e in vf.items()]))
        parts.append(_note(s["variance_factors"].get("explanation", "")))
    cs = s.get("covariance_scale")
    if cs:
        parts.append(_note(f"{cs['meaning']} (factor {cs['factor']:.4g})."))
    return "".join(parts)


def _conflation_rows(c: dict) -> list:
    """One row per database of summary.json ``conflation``."""
    rows = []
    for e in c.get("databases") or []:
        n = e.get("vertices") or {}
        cov = ((e.get("covariance") or {}).get("horizontal")) or {}
        cv = ((e.get("cross_validation") or {}).get("horizontal")) or {}
        tr = e.get("truth") or {}
        model = (f"{cov['model']}: C0 {cov['sill']:.3g} m\u00b2, L {cov['length']:.0f} m, "
                 f"database noise {cov['nugget']:.3g} m\u00b2" if cov else "-")
        truth = (f"{tr['rmse_database_truth_horizontal']:.2f} \u2192 "
                 f"{tr['rmse_conflated_truth_horizontal']:.2f} m, CE90 covers "
                 f"{tr['share_within_ce90']:.0%}" if tr else "-")
        rows.append([e["name"], e["status"], n.get("measured"), n.get("interpolated"),
                     n.get("extrapolated"), n.get("unchanged"), model,
                     _fmt(cv.get("rmse"), 2), _fmt(cv.get("share_within_90"), 2), truth])
    return rows


def _conflation_body(run) -> str:
    """Conflation: counts, covariance functions, cross-validation, the field's map."""
    c = (run.summary or {}).get("conflation")
    if not c:
        return _note("Conflation was not run.")
    parts = [_table(["database", "status", "measured", "interpolated", "extrapolated",
                     "unchanged", "horizontal covariance", "LOO RMSE (m)",
                     "LOO inside 90 %", "truth: RMSE before \u2192 after (predicted)"],
                    _conflation_rows(c))]
    parts.append(_note(
        "Every vertex not measured on the images is moved by the database's estimated "
        "offset plus the displacement field predicted by least-squares collocation from "
        f"its {c.get('k')} nearest measured points ([conflation], DESIGN section 10). "
        "LOO: each measured point predicted from the others (horizontal RMSE of the "
        "held-out displacement and the share inside its predicted 90 % radius); the "
        "covariance function and the database's own white noise are those whose held-out "
        "predictions score best. The features' LengthSD includes the predicted vertices' "
        "covariance; only vertices left at their database position count as fixed "
        "(LengthSDOf)."))
    parts.append(_img(conflation_figure(run), "conflation field",
                      "Displacement (adjusted \u2212 database) at measured and predicted "
                      "points over the CE90 of the predicted position."))
    return "".join(parts)


def _warnings_body(run) -> str:
    ws = list(dict.fromkeys(list(run.summary.get("warnings") or []) + list(run.warnings or [])))
    if not ws:
        return _note("No warnings.")
    return '<ul class="warnings">' + "".join(f"<li>{_e(w)}</li>" for w in ws) + "</ul>"


def _run_sections(doc: _Doc, run, *, acc: Optional[dict], qa: Any, reliability: Any,
                  prefix: str = "", level: int = 2, colors: Optional[dict] = None,
                  with_bars: bool = True) -> None:
    colors = _db_colors([d.name for d in run.databases], colors)
    sec = doc.section
    sec(f"{prefix}summary", "Summary", _summary_body(run, prefix), level)
    sec(f"{prefix}images", "Images: exterior orientation", _images_body(run, prefix), level)
    sec(f"{prefix}control-points", "Control points", _control_body(run, "control", prefix), level)
    sec(f"{prefix}check-points", "Check points", _control_body(run, "check", prefix), level)
    sec(f"{prefix}databases", "Road databases", _databases_body(run, prefix, colors,
                                                                 with_bars=with_bars), level)
    sec(f"{prefix}error-model", "Error model: identification, offsets, variance factors",
        _error_model_body(run), level)
    if (run.summary or {}).get("conflation"):
        sec(f"{prefix}conflation", "Conflation: every vertex corrected", _conflation_body(run),
            level)
    sec(f"{prefix}accuracy", "Accuracy statements", _accuracy_body(acc), level)
    sec(f"{prefix}precision", "Precision of the adjusted points",
        _img(error_ellipse_figure(run, colors=colors), "error ellipses",
             "90 % confidence ellipses (semi-axes 2.1460 \u221a\u03bb of the a-posteriori 2\u00d72 "
             "covariance) at the adjusted positions, exaggerated by the stated factor; the "
             "circle gives the scale."), level)
    sec(f"{prefix}residuals", "Image residuals", _residuals_body(run, reliability), level)
    sec(f"{prefix}flagged", "Flagged observations", _flagged_body(run, reliability, prefix), level)
    sec(f"{prefix}features", "Features", _features_body(run, acc, prefix), level)
    sec(f"{prefix}shape-points", "Shape points", _shape_body(run, prefix), level)
    interior = run.summary.get("interior_orientation")
    if interior:
        sec(f"{prefix}interior", "Interior orientation", _generic(interior), level)
    if qa is not None:
        sec(f"{prefix}qa", "Quality assurance", _qa_body(qa), level)
    sec(f"{prefix}warnings", "Warnings", _warnings_body(run), level)


def _page(title: str, doc: _Doc, subtitle: str) -> str:
    indent = ' class="sub"'
    toc = "".join(f'<li{indent if lvl > 2 else ""}><a href="#{_e(i)}">{_e(t)}</a></li>'
                  for lvl, i, t in doc.toc)
    from vectoradjust import __version__

    stamp = _dt.datetime.now().strftime("%Y-%m-%d %H:%M")
    return (
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
        "<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">"
        f"<title>{_e(title)}</title><style>{_CSS}</style></head><body><main>"
        f"<h1>{_e(title)}</h1><p class=\"meta\">{_e(subtitle)} \u00b7 vectoradjust "
        f"{_e(__version__)} \u00b7 {_e(stamp)}</p>"
        f"<nav><strong>Contents</strong><ol>{toc}</ol></nav>"
        + "".join(doc.parts)
        + "<footer>Self-contained report written by vectoradjust: figures are embedded; the "
          "full per-vertex data are in adjusted.gpkg and summary.json.</footer>"
        "</main></body></html>\n"
    )


def _accuracy_for(run, accuracy: Optional[dict]) -> Optional[dict]:
    if accuracy is not None:
        return accuracy
    acc = (run.summary or {}).get("accuracy")
    if isinstance(acc, dict):
        return acc
    from vectoradjust.accuracy.statements import accuracy_statements

    return accuracy_statements(run)


def _compare_table(rows: Sequence[dict]) -> str:
    if not rows:
        return _note("(no rows)")
    keys: list = []
    for r in rows:
        for k in r:
            if k not in keys:
                keys.append(k)
    labels = {"database": "database", "adjusted": "adjusted vertices", "rmse_x": "RMSE x (m)",
              "rmse_y": "RMSE y (m)", "rmse_z": "RMSE z (m)", "rmse_horizontal": "RMSE h (m)",
              "mean_ce90": "mean CE90 (m)", "mean_le90": "mean LE90 (m)",
              "sigma0_squared": "\u03c3\u2080\u00b2", "chi_square_passed": "chi-square test",
              "check_rmse_horizontal": "check points RMSE h (m)",
              "true_rmse": "RMSE db\u2212truth (m)", "recovery": "recovery",
              "adjusted_truth_rmse": "RMSE adj\u2212truth (m)", "improvement": "improvement"}
    body = []
    for r in rows:
        line = []
        for k in keys:
            v = r.get(k)
            if k == "chi_square_passed":
                line.append(_badge(v))
            elif k == "sigma0_squared":
                line.append(_fmt(v, 4))
            else:
                line.append(_fmt(v, 3))
        body.append(line)
    return _table([labels.get(k, k.replace("_", " ")) for k in keys], body,
                  ident="compare-table")


def _project_label(project: str) -> str:
    """``<directory>/<file>`` of a project path (``<simulated ...>`` labels as they are)."""
    if not project or project.startswith("<"):
        return project
    p = Path(project)
    return f"{p.parent.name}/{p.name}" if p.parent.name else p.name


# =========================================================================== public API
def report_html(run, *, title: Optional[str] = None, accuracy: Optional[dict] = None,
                compare_rows: Optional[Sequence[dict]] = None, qa: Any = None,
                reliability: Any = None) -> str:
    """The report of one adjustment as an HTML string (see :func:`write_report`)."""
    acc = _accuracy_for(run, accuracy)
    project = str((run.summary or {}).get("project", ""))
    title = title or f"vectoradjust report: {_project_label(project) or 'adjustment'}"
    doc = _Doc()
    if compare_rows:
        doc.section("comparison", "Database comparison", _compare_table(compare_rows))
    _run_sections(doc, run, acc=acc, qa=qa, reliability=reliability)
    return _page(title, doc, f"project {project}" if project else "adjustment")


def write_report(run, path, *, title: Optional[str] = None, accuracy: Optional[dict] = None,
                 compare_rows: Optional[Sequence[dict]] = None, qa: Any = None,
                 reliability: Any = None, progress=None, is_cancelled=None) -> Path:
    """Write ``report.html``: one self-contained HTML file of an adjustment.

    Parameters
    ----------
    run : vectoradjust.pipeline.AdjustmentRun
    path : str or os.PathLike
        Output file (its directory is created); written atomically.
    title : str, optional
        Default ``"vectoradjust report: <project file name>"``.
    accuracy : dict, optional
        :func:`vectoradjust.accuracy.statements.accuracy_statements` of the run (default:
        ``run.summary["accuracy"]`` if present, else computed here).
    compare_rows : list of dict, optional
        Rows of a database comparison to show first.
    qa : dict or object with ``as_dict()``, optional
        QA verdict (rendered generically: verdict, stages, non-conformities).
    reliability : optional
        Reliability result: an object or dict with ``w_image`` (and ``critical``) for
        the w-test histogram, and ``flagged`` (list of dicts), or the list of flagged
        observations itself. Default: ``run.summary["reliability"]["flagged"]`` when
        present, else the report says "not computed".
    progress : callable, optional
        ``progress(fraction, message)`` after each section (figures and tables).
    is_cancelled : callable, optional
        Polled after each section; true raises :class:`CancelledError`.

    Returns
    -------
    pathlib.Path
        The file written.

    Raises
    ------
    InputFileError
        If the file cannot be written.
    CancelledError
        If ``is_cancelled`` says so (nothing is written).
    """
    path = _prepare(Path(path))
    with _reporting(progress, is_cancelled):
        text = report_html(run, title=title, accuracy=accuracy, compare_rows=compare_rows,
                           qa=qa, reliability=reliability)
    if progress is not None:
        progress(1.0, "report written")
    return _write_text(path, text)


def compare_report_html(runs: Sequence, rows: Sequence[dict], *,
                        title: Optional[str] = None,
                        accuracies: Optional[Sequence[Optional[dict]]] = None) -> str:
    """The comparison report as an HTML string (see :func:`write_compare_report`)."""
    runs = list(runs)
    names = [d.name for r in runs for d in r.databases]
    colors = _db_colors(names)
    project = str((runs[0].summary or {}).get("project", "")) if runs else ""
    title = title or f"vectoradjust comparison: {_project_label(project) or 'databases'}"
    doc = _Doc()
    entries = [e for r in runs for e in (r.summary.get("databases") or [])]
    body = (_note("Each road database adjusted alone with the same control and images.")
            + _compare_table(rows)
            + _img(rmse_bar_figure(entries, colors=colors,
                                   title="Horizontal RMSE per road database (each adjusted "
                                         "alone)"),
                   "RMSE per database", "Horizontal RMSE per road database across the runs."))
    doc.section("comparison", "Database comparison", body)
    accs = list(accuracies) if accuracies is not None else [None] * len(runs)
    for i, r in enumerate(runs):
        label = ", ".join(d.name for d in r.databases) or f"run {i + 1}"
        ident = re.sub(r"[^A-Za-z0-9_-]+", "-", label) or f"run-{i + 1}"
        prefix = f"{ident}-"
        doc.section(f"{prefix}run", f"Database {label}", "", 2)
        _run_sections(doc, r, acc=_accuracy_for(r, accs[i] if i < len(accs) else None),
                      qa=None, reliability=None, prefix=prefix, level=3, colors=colors,
                      with_bars=False)
    return _page(title, doc, f"project {project}" if project else "comparison")


def write_compare_report(runs: Sequence, rows: Sequence[dict], path, *,
                         title: Optional[str] = None,
                         accuracies: Optional[Sequence[Optional[dict]]] = None, progress=None,
                         is_cancelled=None) -> Path:
    """Write the report of ``vectoradjust compare`` (each database adjusted alone).

    Parameters
    ----------
    runs : list of vectoradjust.pipeline.AdjustmentRun
        One run per database.
    rows : list of dict
        The comparison rows (``compare.csv``), shown as the first table.
    path : str or os.PathLike
    title : str, optional
    accuracies : list of dict, optional
        Accuracy statements per run (default: computed).
    progress, is_cancelled : callable, optional
        As in :func:`write_report`.

    Returns
    -------
    pathlib.Path

    Raises
    ------
    InputFileError
        If the file cannot be written.
    CancelledError
        If ``is_cancelled`` says so (nothing is written).
    """
    path = _prepare(Path(path))
    with _reporting(progress, is_cancelled):
        text = compare_report_html(runs, rows, title=title, accuracies=accuracies)
    if progress is not None:
        progress(1.0, "report written")
    return _write_text(path, text)


def _prepare(path: Path) -> Path:
    """Create the report's directory up front (fail before the work, not after)."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputFileError(f"Cannot create the directory of the report {str(path)!r} ({exc})",
                             "Choose a writable output directory", path=str(path)) from exc
    if path.is_dir():
        raise InputFileError(f"The report path {str(path)!r} is a directory",
                             "Give a file name such as report.html", path=str(path))
    return path


def _new_file_mode() -> int:
    """The mode ``open()`` gives a new file: 0666 less the process's umask (e.g. 0644)."""
    mask = os.umask(0o022)
    os.umask(mask)
    return 0o666 & ~mask


def _write_text(path: Path, text: str) -> Path:
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=".report-", suffix=".html", dir=path.parent)
        try:
            with os.fdopen(fd, "w", encoding="utf-8") as fh:
                fh.write(text)
            # mkstemp makes the file 0600; the report gets a new file's usual mode
            os.chmod(tmp, _new_file_mode())
            os.replace(tmp, path)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise
    except OSError as exc:
        raise InputFileError(f"Cannot write the report {str(path)!r} ({exc})",
                             "Choose a writable output directory", path=str(path)) from exc
    return path
