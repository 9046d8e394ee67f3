"""The report's figure machinery and its charts (matplotlib, imported lazily).

Agg canvas only, no pyplot (a running QGIS session is not disturbed): the figure style,
PNG rendering (:func:`figure_png`) and embedding as a data URI, the helpers shared by
the map figures (origin, limits, line segments, database colours, subsampling), the
histogram of the standardized image residuals (:func:`residual_histogram_figure`) and
the RMSE per database (:func:`rmse_bar_figure`).
"""

from __future__ import annotations

import base64
import io
import math
from collections.abc import Sequence
from contextlib import contextmanager
from contextvars import ContextVar
from typing import Callable, Optional

import numpy as np

from vectoradjust.files.report.markup import _e, _note, _q

__all__ = [
    "residual_histogram_figure",
    "rmse_bar_figure",
    "figure_png",
    "figure_memo",
    "database_colors",
    "MAX_SEGMENTS",
]


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
        # zlib level 3: about 15 % less time than Pillow's default 6 for 4 % more bytes
        fig.savefig(buf, format="png", dpi=dpi or _DPI, facecolor="white",
                    metadata={"Software": "vectoradjust"}, pil_kwargs={"compress_level": 3})
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


def database_colors(names: Sequence[str]) -> dict:
    """The colour of each road database in the report's figures, in the order given
    (``compare`` fixes them for all its reports: a database has one colour throughout)."""
    return _db_colors(names)


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
            # one filled outline, not a rectangle per bin (a tenth of the drawing's cost)
            ax.hist(np.clip(vals, -lim, lim), bins=nb, range=(-lim, lim), density=True,
                    histtype="stepfilled", facecolor="#9ecae1", edgecolor="#3182bd",
                    linewidth=0.5,
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


#: the figures drawn while :func:`figure_memo` is active, by key (None: not active)
_MEMO: ContextVar = ContextVar("vectoradjust_report_figures", default=None)


@contextmanager
def figure_memo():
    """Inside, a figure asked for again with the same key is not drawn again.

    One process writes a run's report and its section of the comparison report
    (``vectoradjust compare``) inside one memo: the figures the two share (the same run,
    the same colours) are drawn once. The memo ends with the block, so keys that name
    objects by ``id`` stay unambiguous.
    """
    token = _MEMO.set({})
    try:
        yield
    finally:
        _MEMO.reset(token)


class _Later:
    """A figure not drawn yet: ``make()`` draws it; ``key`` names it in the active
    :func:`figure_memo` (:func:`_img` draws it only when the memo lacks it)."""

    def __init__(self, key: tuple, make: Callable) -> None:
        self.key, self.make = key, make


def _run_key(name: str, run, colors: Optional[dict] = None) -> tuple:
    """Memo key of figure ``name`` of ``run`` drawn with ``colors`` (its databases')."""
    names = tuple(d.name for d in run.databases)
    return (name, id(run), tuple((n, (colors or {}).get(n)) for n in names))


def _img(fig, alt: str, caption: str) -> str:
    """The figure ``fig`` (a Figure, a :class:`_Later` or None) as an HTML ``<figure>``."""
    if isinstance(fig, _Later):
        memo = _MEMO.get()
        key = (*fig.key, alt, caption)
        if memo is not None and key in memo:
            return memo[key]
        html = _img(fig.make(), alt, caption)
        if memo is not None:
            memo[key] = html
        return html
    if fig is None:
        return _note(f"({alt}: nothing to plot)")
    data = base64.b64encode(figure_png(fig)).decode("ascii")
    return (f'<figure><img alt={_q(alt)} src="data:image/png;base64,{data}">'
            f"<figcaption>{_e(caption)}</figcaption></figure>")
