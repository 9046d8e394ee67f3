"""The report's sections about the adjustment, from the summary to the warnings.

Summary, images, control and check points, road databases, accuracy statements, error
model, conflation and warnings; also the document (:class:`_Doc`: headings, anchors,
table of contents) and the progress and cancel hooks called after each finished section
while a report is written.
"""

from __future__ import annotations

from contextlib import contextmanager
from contextvars import ContextVar
from typing import Optional

import numpy as np

from vectoradjust.errors import CancelledError
from vectoradjust.files.report.figures import _img, _Later, _run_key, rmse_bar_figure
from vectoradjust.files.report.maps import conflation_figure, residual_vector_figure
from vectoradjust.files.report.markup import (
    _badge,
    _columns_table,
    _e,
    _fmt,
    _kv_table,
    _note,
    _q,
    _table,
)

__all__: list = []  # helpers of the package's other modules


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
    out.append(_img(_Later(_run_key("residual vectors", run, colors),
                           lambda: residual_vector_figure(run, colors=colors)), "residual vectors",
                    "Residual vectors V at the database positions over the database lines "
                    "(grey) and the adjusted lines (colour); one common arrow scale for "
                    "all panels, given by the key."))
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
        f"its {c.get('k')} nearest measured points ([conflation], docs/method.md section 10). "
        "LOO: each measured point predicted from the others (horizontal RMSE of the "
        "held-out displacement and the share inside its predicted 90 % radius); the "
        "covariance function and the database's own white noise are those whose held-out "
        "predictions score best. The features' LengthSD includes the predicted vertices' "
        "covariance; only vertices left at their database position count as fixed "
        "(LengthSDOf)."))
    parts.append(_img(_Later(_run_key("conflation", run), lambda: conflation_figure(run)),
                      "conflation field",
                      "Displacement (adjusted \u2212 database) at measured and predicted "
                      "points over the CE90 of the predicted position."))
    return "".join(parts)


def _warnings_body(run) -> str:
    ws = list(dict.fromkeys(list(run.summary.get("warnings") or []) + list(run.warnings or [])))
    if not ws:
        return _note("No warnings.")
    return '<ul class="warnings">' + "".join(f"<li>{_e(w)}</li>" for w in ws) + "</ul>"
