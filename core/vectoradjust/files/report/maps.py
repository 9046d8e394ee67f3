"""The report's map figures: residual vectors, the conflation field, error ellipses.

:func:`residual_vector_figure` (residuals V over the road lines, one panel per
database), :func:`conflation_figure` (displacement arrows over the CE90 raster of the
conflated databases) and :func:`error_ellipse_figure` (90 % confidence ellipses of the
adjusted points). For large runs the arrows and ellipses are a random subsample
(fixed seed) and the figure says so.
"""

from __future__ import annotations

import math
from typing import Optional

import numpy as np

from vectoradjust.files.report.figures import (
    _ARROW,
    _STYLE,
    _axis_labels,
    _db_colors,
    _limits,
    _mpl,
    _new_figure,
    _nice,
    _origin,
    _segments,
    _subsample,
)

__all__ = [
    "residual_vector_figure",
    "error_ellipse_figure",
    "conflation_figure",
    "MAX_ARROWS",
    "MAX_ELLIPSES",
    "DENSE_SEGMENTS",
]


#: Arrows per database panel of the residual figure (random subsample above).
MAX_ARROWS = 600
#: Above this many line segments per panel, lines are drawn thin and without
#: antialiasing (readable, and a PNG of reasonable size).
DENSE_SEGMENTS = 6000
#: Ellipses in the error-ellipse figure (random subsample above).
MAX_ELLIPSES = 800
#: Cells of the conflation figure's CE90 raster per database (at most; the field is
#: smooth: a 10 000-cell grid shows it at a quarter of the prediction's cost)
FIELD_CELLS = 10_000


_CHI2_2_90 = -2.0 * math.log(0.1)  # chi-square quantile, 2 dof, p = 0.9


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

    from vectoradjust.conflation import field_grid

    g = field_grid(d, max_cells=FIELD_CELLS)
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
