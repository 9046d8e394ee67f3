"""One vector adjustment on in-memory data, as a sequence of named stages.

:func:`run` takes a :class:`~vectoradjust.model.ProjectData` (read by
:mod:`vectoradjust.files`, made by the simulator or by the QGIS plugin) and calls

1. classify - :func:`vectoradjust.adjust.classify.classify_measurements`: control, check,
   shape and tie points, and the checks that make an adjustment possible; around it the
   plausibility checks of :mod:`vectoradjust.adjust.plausibility` name a gross mistake
   (units, axes, CRS, approximate orientation, DEM) before it becomes a symptom;
2. set up - :func:`vectoradjust.adjust.classify.build_problem`: the bundle problem;
3. adjust - :func:`vectoradjust.adjust.passes.solve`: the bundle adjustment, with
   two-pass reweighting, variance components or data snooping as the project asks;
4. statistics - :mod:`vectoradjust.accuracy.tables`: control/check points, shape points
   and features in the contract's fields;
5. derived - :func:`vectoradjust.accuracy.derived.feature_length_sigma`: the sigma of
   each adjusted road's length;
6. summary - :mod:`vectoradjust.accuracy.summary`, the accuracy control field
   (:mod:`vectoradjust.qa.verdict`) and the accuracy statements
   (:mod:`vectoradjust.accuracy.statements`).

Writing the outputs is the caller's (:mod:`vectoradjust.files.outputs`, the CLI, the QGIS
plugin). No file I/O here; numpy and scipy only, so the QGIS plugin calls it directly.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import replace
from typing import Callable, Optional

import numpy as np

from vectoradjust.accuracy.consistency import roads_versus_control
from vectoradjust.accuracy.derived import feature_length_sigma
from vectoradjust.accuracy.identification import identification_estimates
from vectoradjust.accuracy.summary import (
    group_factors,
    offset_entry,
    reliability_summary,
    run_summary,
)
from vectoradjust.accuracy.tables import LE90_FACTOR, tabulate_control, tabulate_database
from vectoradjust.adjust.classify import build_problem, classify_measurements, reading_info
from vectoradjust.adjust.passes import free_network, solve
from vectoradjust.adjust.plausibility import check_classified, check_inputs
from vectoradjust.errors import ProjectError
from vectoradjust.model import ProjectData
from vectoradjust.results import AdjustmentRun, DatabaseResult

__all__ = ["AdjustmentRun", "DatabaseResult", "run", "distinct_warnings", "LE90_FACTOR"]

Progress = Callable[[float, str], None]


def _selected_databases(data: ProjectData, vectors: Optional[list]) -> set:
    """Names of the databases to adjust (all when ``vectors`` is empty)."""
    all_names = [spec.name for spec, _ in data.vectors]
    if vectors:
        unknown = [v for v in vectors if v not in all_names]
        if unknown:
            raise ProjectError(
                f"{data.source}: no [[vectors]] entry named {', '.join(map(repr, unknown))}",
                f"Use one of: {', '.join(all_names) or '(none defined)'}",
            )
    return set(vectors) if vectors else set(all_names)


def _derived(out: AdjustmentRun) -> None:
    """Sigma of each adjusted road's length, with and without the point covariances."""
    for d in out.databases:
        sd, sd_nc = feature_length_sigma(out, d)
        d.features["LengthSD"] = np.asarray(sd, float)
        d.features["LengthSDnc"] = np.asarray(sd_nc, float)


_SCALE_MEANING = {
    "a-posteriori": "covariances are the cofactors times sigma0^2 (a posteriori)",
    "a-priori": "covariances are the cofactors (a priori: the stated sigmas are trusted)",
    "groups": ("covariances are the cofactors with the reweighted sigmas, times the variance "
               "factor of the groups whose sigma is known or was estimated"),
}


def _covariance_scale_record(result, solution) -> dict:
    """summary.json ``covariance_scale``: which scale, its factor, what it means."""
    rec = {"scale": result.covariance_scale, "factor": result.variance_factor,
           "meaning": _SCALE_MEANING[result.covariance_scale]}
    kept = list(getattr(solution, "kept_groups", []) or [])
    if result.covariance_scale == "groups":
        rec["groups_left_out"] = kept
        reweighted = solution.vce is not None or len(solution.passes) > 1
        if not reweighted:
            rec["meaning"] = ("covariances are the cofactors times the variance factor of the "
                              "groups whose stated sigma is not larger than their residuals say")
        if kept:
            why = ("kept at a stated sigma the data could not check" if reweighted else
                   "stated sigma larger than the residuals say: the images fix these points")
            rec["meaning"] += f" (left out: {', '.join(kept)}, {why})"
    return rec


def _summarise(out: AdjustmentRun, solution, report=None) -> None:
    """summary.json's content, the QA field of the control points, accuracy statements
    (``report(fraction, message)`` before each of the long parts)."""
    say = report or (lambda fraction, message: None)
    data = out.data
    if data.qa:
        # production accuracy control: pass/fail of every control/check point
        from vectoradjust.qa.verdict import control_qa_field, spec_from_table

        spec = spec_from_table(data.qa, source=data.source)
        out.control_points["QA"] = np.asarray(control_qa_field(out, spec), dtype=object)
    out.summary = run_summary(out)
    say(0.83, "reliability: redundancy numbers and w-tests")
    out.summary["reliability"] = reliability_summary(out, data.settings)
    say(0.85, "variance factors of the observation groups")
    out.summary["variance_factors"] = group_factors(out)
    out.summary["covariance_scale"] = _covariance_scale_record(out.result, solution)
    chi = out.summary["chi_square"]
    if chi.get("passed") is False:
        note = (f"chi-square test failed (sigma0^2 = {out.summary['sigma0_squared']:.3f}): "
                + out.summary["variance_factors"]["explanation"])
        out.warnings.append(note)
        out.summary["warnings"].append(note)
    if solution.datum is not None:
        out.summary["datum"] = solution.datum
    if solution.self_calibration is not None:
        out.summary["self_calibration"] = solution.self_calibration
    if solution.vce is not None:
        out.summary["variance_components"] = solution.vce
    if solution.snooping is not None:
        out.summary["data_snooping"] = solution.snooping
    _database_error_model(out, solution)
    from vectoradjust.accuracy.statements import accuracy_statements

    say(0.87, "accuracy statements of every road feature")
    out.summary["accuracy"] = accuracy_statements(out)


def _warn(out: AdjustmentRun, note: str) -> None:
    out.warnings.append(note)
    out.summary["warnings"].append(note)


def _identification(out: AdjustmentRun, d, entry: dict, estimates: dict) -> None:
    """The stated identification sigma, the data's estimates, and what to say about them."""
    ident = d.spec.identification_sigma
    entry["identification_sigma"] = list(map(float, ident)) if ident is not None else None
    found = [e for e in [estimates["databases"].get(d.name)] if e] + [
        e for e in estimates["pairs"] if d.name in e["source"].split(" ", 2)[-1].split("/")]
    entry["identification_estimates"] = found
    said = "; ".join(f"{e['horizontal']:.2f} +- {e['horizontal_se']:.2f} m horizontal from "
                     f"{e['source']} (n = {e['count']})" for e in found
                     if e["horizontal"] is not None)
    if ident is None and entry["adjusted_vertices"]:
        _warn(out, f"{d.name}: identification_sigma is not given, so CE90/LE90 describe the "
              "measured point only, not the real road vertex (set identification_sigma in "
              "its [[vectors]] entry; README: identification error)"
              + (f"; the data suggest {said}" if said else ""))
    elif ident is not None:
        for e in found:
            if e["horizontal"] is None:
                continue
            if abs(e["horizontal"] - ident[0]) > 3 * e["horizontal_se"] + 0.05:
                _warn(out, f"{d.name}: identification_sigma = {ident[0]:g} m (horizontal) "
                      f"disagrees with {e['horizontal']:.2f} +- {e['horizontal_se']:.2f} m "
                      f"estimated from {e['source']}")


def _database_error_model(out: AdjustmentRun, solution) -> None:
    """Offsets and identification error per database in the summary (docs/method.md section 10)."""
    alpha = out.data.settings.alpha
    estimates = identification_estimates(out)
    out.summary["identification_estimates"] = estimates
    for d, entry in zip(out.databases, out.summary["databases"]):
        _identification(out, d, entry, estimates)
        entry["offset_model"] = d.spec.offset
        if solution.offsets and d.name in solution.offsets:
            entry["offset"] = offset_entry(solution.offsets[d.name], d.name, alpha)


def _inputs(out: AdjustmentRun) -> None:
    """How each database was read (layer, ``where`` filter, features kept, CRS
    transformations) as summary.json ``databases[].input``; an inaccurate transformation
    is a warning."""
    for d, entry in zip(out.databases, out.summary["databases"]):
        info = reading_info(d.shape.layer)
        if not info:
            continue
        entry["input"] = {k: v for k, v in info.items() if k != "excluded_feature_ids"}
        for what, crs in (("layer", info.get("crs")), ("DEM", (info.get("dem") or {}).get("crs"))):
            if crs and crs.get("warning"):
                _warn(out, f"{d.name}: the transformation of its {what} {crs['warning']}")
    for w in getattr(out.data, "reading_warnings", None) or []:
        _warn(out, w)
    reading = getattr(out.data.control, "reading", None)
    if reading:  # how the control points were read ([control] crs / vertical_crs)
        out.summary["control_input"] = reading
        crs = reading.get("crs") or {}
        if crs.get("warning"):
            _warn(out, f"control points: the transformation {crs['warning']}")
        if reading.get("warning"):
            _warn(out, f"control points: {reading['warning']}")


def _conflation(out: AdjustmentRun, solution, report, is_cancelled) -> None:
    """Correct every unmeasured vertex from the measured ones (least-squares collocation,
    docs/method.md section 10; ``[conflation]``), after the statistics of the measured points."""
    from vectoradjust.conflation import conflate_run, settings_from_table

    settings = settings_from_table(out.data.conflation, out.data.source)
    rec = conflate_run(out, solution.offsets, settings,
                       lambda f, m: report(0.9 + 0.09 * f, m), is_cancelled)
    out.summary["conflation"] = rec
    for e in rec["databases"]:
        if e["status"].startswith("not done"):
            _warn(out, f"{e['name']}: conflation {e['status']}; its unmeasured vertices keep "
                  "their database position")


def distinct_warnings(warnings: list, databases=()) -> list:
    """Each warning once: the same text of several databases (``"OSM: ..."``,
    ``"TNM: ..."``) as one (``"OSM, TNM: ..."``), a repeated one with its count."""
    counts = Counter(warnings)
    groups: dict = {}
    for w in counts:
        name = next((n for n in databases if w.startswith(f"{n}: ")), None)
        key = w[len(name) + 2:] if name else w
        groups.setdefault((name is not None, key), []).append((name, counts[w]))
    out = []
    for (per_db, key), members in groups.items():
        n = max(c for _, c in members)
        text = f"{', '.join(m for m, _ in members)}: {key}" if per_db else key
        out.append(text + (f" ({n} times)" if n > 1 else ""))
    return out


def _roads_and_control(out: AdjustmentRun, cls, setup) -> None:
    """Do the databases agree with the control? (the same run without shape points)."""
    if not (setup.point_kind == "control").any():  # no control points: nothing to compare
        out.summary["roads_and_control"] = {
            "harm": False, "text": "not done: no control points are measured (the datum "
            "comes from camera priors or a control road database)"}
        return
    rows = np.flatnonzero(cls.is_check & (setup.imap[cls.img_of_obs] >= 0))
    check_obs = ((rows, cls.ctrl_of_obs[rows], setup.imap[cls.img_of_obs[rows]])
                 if rows.size else None)
    s = out.data.settings
    rec = roads_versus_control(out, check_obs, alpha=s.alpha, adjust_kwargs={
        "max_iterations": s.max_iterations, "tolerance_position": s.tolerance_position,
        "tolerance_angle": s.tolerance_angle})
    if rec is None:
        return
    out.summary["roads_and_control"] = rec
    if rec["harm"]:
        out.warnings.append(rec["text"])
        out.summary["warnings"].append(rec["text"])


def run(
    data: ProjectData,
    *,
    vectors: Optional[list] = None,
    progress: Optional[Progress] = None,
    is_cancelled: Optional[Callable[[], bool]] = None,
    on_adjusted: Optional[Callable[[AdjustmentRun], None]] = None,
) -> AdjustmentRun:
    """Adjust the road vectors of a project.

    A database whose ``identification_sigma`` is not given gets one that no user has to
    guess: a first adjustment estimates it where the data allow (truth, common
    intersections of two databases: :func:`vectoradjust.accuracy.identification.
    choose_identification`), else the conservative default of ten pixels on the ground;
    the run is then made with it, and summary.json says which was used and why.

    Parameters
    ----------
    data : ProjectData
        Inputs as arrays (from :func:`vectoradjust.files.readers.load_project_data`, the
        simulator or QGIS).
    vectors : list of str, optional
        Names of the ``[[vectors]]`` entries to adjust (default: all). Measurements of
        the other databases' shape points are left out (not turned into tie points).
    progress : callable, optional
        ``progress(fraction, message)``.
    is_cancelled : callable, optional
        Polled between iterations.
    on_adjusted : callable, optional
        ``on_adjusted(run)`` as soon as the adjustment is final: before the control
        points' and the vertices' tables, the statistics, the control-only run and the
        conflation. The command line starts the uncertainty bands (which need no more)
        in other processes there. ``run.summary`` is still empty at that point, and
        ``run.control_points`` and the databases' ``vertices``, ``features`` and
        ``truth`` are not filled in yet.

    Returns
    -------
    AdjustmentRun

    Raises
    ------
    VectorAdjustError
        For every inconsistency of the input (named file, line, feature or point).
    """
    selected = _selected_databases(data, vectors)
    unstated = [spec.name for spec, _ in data.vectors
                if spec.name in selected and spec.identification_sigma is None]
    if not unstated or data.settings.datum == "free":
        return _run_once(data, vectors=vectors, progress=progress, is_cancelled=is_cancelled,
                         on_adjusted=on_adjusted)

    def first(frac, msg):
        if progress is not None:
            progress(0.2 * frac, f"identification error: {msg}")

    chosen = _identification_pass(data, vectors, first, is_cancelled, unstated)
    stated = replace(data, vectors=[
        (replace(spec, identification_sigma=(chosen[spec.name]["horizontal"],
                                             chosen[spec.name]["vertical"]))
         if spec.name in chosen else spec, layer) for spec, layer in data.vectors])

    def second(frac, msg):
        if progress is not None:
            progress(0.2 + 0.8 * frac, msg)

    out = _run_once(stated, vectors=vectors, progress=second, is_cancelled=is_cancelled,
                    on_adjusted=on_adjusted)
    _identification_used(out, chosen)
    return out


def _identification_pass(data: ProjectData, vectors, report, is_cancelled,
                         unstated: list) -> dict:
    """The adjustment alone (no statistics, no conflation), its identification
    estimates, and per unstated database the sigma to use (estimate or default)."""
    from vectoradjust.accuracy.identification import (
        choose_identification,
        default_identification,
    )

    warnings: list = []
    selected = _selected_databases(data, vectors)
    cls = classify_measurements(data, selected, warnings)
    setup = build_problem(data, cls, selected, warnings)
    solution = solve(setup, data.settings, image_ids=cls.image_ids[setup.img_used],
                     meas=data.measurements, warnings=warnings, progress=report,
                     is_cancelled=is_cancelled)
    out = AdjustmentRun(
        data=data, problem=solution.problem, result=solution.result,
        point_ids=setup.point_ids, point_kind=setup.point_kind,
        point_database=setup.point_database,
        image_ids=cls.image_ids[setup.img_used].tolist(), obs_rows=setup.obs_rows,
        databases=setup.databases, control_points={}, summary={}, warnings=warnings,
        passes=solution.passes)
    for d in out.databases:
        tabulate_database(out, d)
    estimates = identification_estimates(out)
    default = default_identification(_pixel_on_ground(out))
    chosen = {}
    for name in unstated:
        c = choose_identification(name, estimates)
        chosen[name] = c if c is not None else dict(default)
    return chosen


def _pixel_on_ground(out: AdjustmentRun) -> Optional[float]:
    """A pixel's size on the ground (m) of the frame images: the camera's pixel size
    (else the median stated measurement sigma) times the image scale (the flying height
    above the median shape point over the focal length); None for RPC images."""
    prob, data = out.problem, out.data
    if prob.sensors is not None and prob.is_rpc.any():
        return None
    cal = getattr(data.camera, "calibration", None)
    px = getattr(cal, "pixel_size", None) if cal is not None else None
    pixel = float(np.mean(px)) if px is not None else float(np.median(data.measurements.sigma))
    shape = out.point_kind == "shape"
    ground = float(np.median(out.result.xyz[shape, 2])) if shape.any() else \
        float(np.median(out.result.xyz[:, 2]))
    height = float(np.median(out.result.eo[:, 2])) - ground
    if not (height > 0 and prob.focal_length > 0):
        return None
    return pixel * height / float(prob.focal_length)


def _identification_used(out: AdjustmentRun, chosen: dict) -> None:
    """summary.json: the identification sigma used for each unstated database, and why."""
    for d, entry in zip(out.databases, out.summary["databases"]):
        c = chosen.get(d.name)
        if c is None:
            continue
        entry["identification_sigma"] = None  # not given in the project ...
        entry["identification_sigma_used"] = {  # ... this was used
            "horizontal": c["horizontal"], "vertical": c["vertical"], "source": c["source"],
            **{k: c[k] for k in ("estimate", "se", "count") if k in c}}
        said = (f"estimated from {c['source']}: {c['estimate']:.2f} +- {c['se']:.2f} m "
                f"(n = {c['count']})" + ("" if c["source"] == "truth" else
                                         " plus one standard error") if "estimate" in c
                else f"the data do not determine it; the conservative {c['source']}")
        note = (f"{d.name}: identification_sigma is not given; "
                f"[{c['horizontal']:.2f}, {c['vertical']:.2f}] m was used ({said}); state "
                "it in the [[vectors]] entry if you know it (README: identification error)")
        own = f"{d.name}: identification_sigma = "  # a 'disagrees' note of our own value
        out.warnings = [w for w in out.warnings if not w.startswith(own)] + [note]
        out.summary["warnings"] = list(out.warnings)


def _run_once(
    data: ProjectData,
    *,
    vectors: Optional[list] = None,
    progress: Optional[Progress] = None,
    is_cancelled: Optional[Callable[[], bool]] = None,
    on_adjusted: Optional[Callable[[AdjustmentRun], None]] = None,
) -> AdjustmentRun:
    """One run of :func:`run` (same parameters, returns, raises) with the
    identification sigmas as given."""
    def report(frac, msg):
        if progress is not None:
            progress(frac, msg)

    warnings: list = []
    selected = _selected_databases(data, vectors)
    report(0.02, "classifying measurements")
    check_inputs(data, selected, warnings)  # the gross mistakes, named before their symptoms
    cls = classify_measurements(data, selected, warnings)
    check_classified(data, cls, selected, warnings)
    report(0.06, "assembling the bundle problem")
    setup = build_problem(data, cls, selected, warnings)
    if data.settings.datum == "free":
        free_network(setup, warnings)
    image_ids = cls.image_ids[setup.img_used]
    solution = solve(setup, data.settings, image_ids=image_ids, meas=data.measurements,
                     warnings=warnings, progress=report, is_cancelled=is_cancelled)
    report(0.75, "intersecting check points and computing statistics")
    out = AdjustmentRun(
        data=data, problem=solution.problem, result=solution.result, point_ids=setup.point_ids,
        point_kind=setup.point_kind, point_database=setup.point_database,
        image_ids=image_ids.tolist(), obs_rows=setup.obs_rows, databases=setup.databases,
        control_points={}, summary={}, warnings=warnings, passes=solution.passes,
    )
    if on_adjusted is not None:
        on_adjusted(out)
    tabulate_control(out, cls.ctrl_of_obs, cls.is_check, cls.img_of_obs, setup.imap)
    for d in out.databases:
        tabulate_database(out, d)
    report(0.78, "feature length accuracy")
    _derived(out)
    report(0.81, "statistics, reliability and accuracy statements")
    _summarise(out, solution, report)
    _inputs(out)
    if setup.problem.free_datum:  # nothing to compare with, nothing to move
        warnings.append("free network: the roads are not compared with the control and their "
                        "unmeasured vertices are not conflated (no datum to move them into)")
    else:
        report(0.9, "roads against the control")
        _roads_and_control(out, cls, setup)
        _conflation(out, solution, report, is_cancelled)
    from vectoradjust.accuracy.derived import feature_accuracy

    for d in out.databases:  # CE90/LE90 per feature, conflated vertices' LengthSD, Problem
        feature_accuracy(out, d)
    names = [spec.name for spec, _ in data.vectors]
    out.warnings = distinct_warnings(out.warnings, names)
    out.summary["warnings"] = list(out.warnings)
    report(1.0, "done")
    return out
