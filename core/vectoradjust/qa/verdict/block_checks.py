"""Checks on the block: tie-point zones, strips and inter-strip ties, the free-model stage
and the production checks.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Optional

import numpy as np

from vectoradjust.errors import ProjectError
from vectoradjust.formatting import float_or_none as _num
from vectoradjust.qa import zones as _zones
from vectoradjust.qa.free_model import FREE_MODEL_MAX_IMAGES, free_model, free_model_stages
from vectoradjust.qa.tolerances import (
    StageResult,
    check_stage,
    relative_orientation_tolerance,
)
from vectoradjust.qa.verdict.image_checks import _problem
from vectoradjust.qa.verdict.spec import _na_stage, _stats_um

__all__ = ["block_view", "zone_stages", "inter_strip_stages", "strips_from_project"]


def block_view(run, frame: Optional[tuple] = None) -> _zones.BlockView:
    """The adjusted block of a run as a :class:`vectoradjust.qa.zones.BlockView`.

    Parameters
    ----------
    run : AdjustmentRun
    frame : (float, float), optional
        Frame width and height (mm); default from the camera
        (:func:`vectoradjust.qa.zones.frame_size`).
    """
    prob = _problem(run)
    w, h, _src = _zones.frame_size(run.data.camera, prob.obs_xy, prob.principal_point, frame)
    return _zones.BlockView(
        image_ids=list(run.image_ids), eo=np.asarray(run.result.eo, float),
        xyz=np.asarray(run.result.xyz, float),
        point_ids=np.asarray(run.point_ids).astype(str),
        point_kind=np.asarray(run.point_kind).astype(str), obs_point=prob.obs_point,
        obs_image=prob.obs_image, obs_xy=prob.obs_xy, focal_length=float(prob.focal_length),
        principal_point=np.asarray(prob.principal_point, float), frame=(w, h))


def _count_stage(name: str, counts: dict, action: str) -> StageResult:
    """A coverage stage: every zone (or image) needs 2 points, 3 for a clean pass."""
    ids = list(counts)
    vals = [float(counts[i]) for i in ids]
    rows = [{"id": i, "value": v, "tolerance": float(_zones.ZONE_WARN),
             "passed": bool(v >= _zones.ZONE_WARN)} for i, v in zip(ids, vals)]
    warn = [i for i, v in zip(ids, vals) if _zones.ZONE_WARN <= v < _zones.ZONE_PASS]
    measured = min(vals) if vals else float("nan")
    return StageResult(name=name, tolerance=float(_zones.ZONE_PASS), measured=measured,
                       statistic="min", point_tolerance=float(_zones.ZONE_WARN),
                       passed=(bool(measured >= _zones.ZONE_WARN) if vals else None),
                       unit="points", rows=rows, warnings=warn, action=action)


def _zone_json(entry: dict) -> dict:
    """A zone entry for ``qa.json`` (floats rounded to what is meaningful)."""
    out = dict(entry)
    out["overlap_mm"] = [[round(x, 3), round(y, 3)] for x, y in entry["overlap_mm"]]
    if "zone_corners_mm" in entry:
        out["zone_corners_mm"] = [[[round(v, 3) for v in c] for c in z]
                                  for z in entry["zone_corners_mm"]]
    out["reference_height_m"] = _num(entry["reference_height_m"])
    if "overlap_area_mm2" in entry:
        out["overlap_area_mm2"] = _num(entry["overlap_area_mm2"])
    return out


def zone_stages(view: _zones.BlockView, strips, columns: int = 2) -> tuple:
    """Tie-point zone stages of every stereo pair and triplet of consecutive images.

    Parameters
    ----------
    view : vectoradjust.qa.zones.BlockView
    strips : array_like of int, shape (n,)
        Strip of every image: pairs and triplets never cross a strip change.
    columns : {2, 3}
        Zone columns along the base (2: the 6 von Gruber zones).

    Returns
    -------
    (stages, notes, pairs, triplets)
        ``pairs`` / ``triplets``: the zone entries
        (:func:`vectoradjust.qa.zones.pair_zones`) for ``qa.json``.
    """
    strips = np.asarray(strips, np.int64)
    counted, label = _zones.counted_kinds(view.point_kind)
    stages, pairs, trips = [], [], []
    n = len(view.image_ids)
    for j in range(n - 1):
        if strips[j + 1] != strips[j]:
            continue
        e = _zones.pair_zones(view, j, j + 1, columns, counted)
        name = "-".join(e["images"])
        stages.append(_count_stage(f"tie-point zones {name}",
                                   {f"{name}:{z['zone']}": z["count"] for z in e["zones"]}
                                   or {f"{name}:overlap": 0}, "add tie points"))
        pairs.append(_zone_json(e))
        if j + 2 < n and strips[j + 2] == strips[j]:
            t = _zones.triplet_zones(view, j, counted)
            tname = "-".join(t["images"])
            stages.append(_count_stage(f"triplet zones {tname}",
                                       {f"{tname}:{z['zone']}": z["count"] for z in t["zones"]}
                                       or {f"{tname}:overlap": 0}, "add tie points"))
            trips.append(_zone_json(t))
    notes = [f"tie-point zones: {label} counted per zone of each overlap (3 rows x {columns} "
             f"columns, frame {view.frame[0]:.1f} x {view.frame[1]:.1f} mm); at least "
             f"{_zones.ZONE_PASS} per zone pass, {_zones.ZONE_WARN} is a warning"]
    warned = [w for s in stages for w in s.warnings]
    if warned:
        notes.append(f"tie-point zones with only {_zones.ZONE_WARN} points (warning): "
                     + ", ".join(warned[:20]) + (" ..." if len(warned) > 20 else ""))
    if not pairs:
        stages.append(_na_stage("tie-point zones", unit="points"))
    return stages, notes, pairs, trips


def _strip_names(strips: np.ndarray, labels: Optional[Sequence]) -> list:
    """Display name of every strip number: the given label, else its number from 1."""
    if labels is None:
        return [str(k + 1) for k in range(int(strips.max(initial=-1)) + 1)]
    names: dict = {}
    for k, lab in zip(strips.tolist(), labels):
        names.setdefault(k, str(lab))
    return [names[k] for k in sorted(names)]


def inter_strip_stages(view: _zones.BlockView, strips, pixel: Optional[float],
                       labels: Optional[Sequence] = None) -> tuple:
    """Inter-strip tie counts and vertical parallax per pair of adjacent strips.

    Parameters
    ----------
    view : vectoradjust.qa.zones.BlockView
    strips : array_like of int, shape (n,)
    pixel : float or None
        Pixel size (mm): the parallax is judged with the relative orientation tolerance.
    labels : sequence, optional
        Given strip labels per image (for names).

    Returns
    -------
    (stages, notes, entries)
        With one strip: one ``n/a`` stage ("n/a: one strip"), never a pass.
    """
    strips = np.asarray(strips, np.int64)
    names = _strip_names(strips, labels)
    if len(names) < 2:
        return ([_na_stage("inter-strip ties", unit="points")],
                ["inter-strip ties: n/a: one strip"], [])
    stages, entries = [], []
    for t in _zones.inter_strip_ties(view, strips):
        a, b = (names[k] for k in t["strips"])
        name = f"inter-strip {a}-{b}"
        stages.append(_count_stage(f"{name}: tie points per image", t["per_image"],
                                   "add tie points between the strips"))
        rp = t["ray_pairs"]
        py = np.asarray(rp["py_mm"], float)
        if pixel is not None and py.size:
            tol = relative_orientation_tolerance(pixel)
            stages.append(check_stage(f"{name}: mean |py|", py / pixel, rp["point_ids"],
                                      tol.mean_px, "mean", point_tolerance=tol.max_px, unit="px"))
            stages.append(check_stage(f"{name}: max |py|", py / pixel, rp["point_ids"],
                                      tol.max_px, "max", unit="px"))
        else:
            stages.append(_na_stage(f"{name}: mean |py|", py * 1e3, rp["point_ids"], "mean",
                                    "um"))
        entries.append({"strips": [a, b], "images": t["images"], "n_points": t["n_points"],
                        "n_counted": t["n_counted"], "per_image": t["per_image"],
                        "min_per_image": t["min_per_image"], "ray_pairs": int(py.size),
                        "parallax": _stats_um(py, pixel), "point_ids": t["point_ids"]})
    return stages, [], entries


def _strips_of(run, view: _zones.BlockView, strips: Optional[Sequence]) -> tuple:
    """Strip numbers, their labels (or None) and where they came from."""
    if strips is not None:
        if isinstance(strips, dict):
            labels = [strips.get(i) for i in view.image_ids]
        else:
            labels = list(strips)
        if len(labels) != len(view.image_ids) or any(x is None for x in labels):
            raise ProjectError(
                f"{getattr(run.data, 'source', '<project>')}: strip labels are given for "
                f"{sum(x is not None for x in labels)} of {len(view.image_ids)} images",
                "Give strip = ... in every [[images]] entry, or in none (the strips are then "
                "found from the flight)")
        return _zones.image_strips(view.eo, labels), labels, "[[images]] strip"
    return _zones.image_strips(view.eo), None, "flight (positions and heading)"


def strips_from_project(raw: dict) -> Optional[dict]:
    """``{image id: strip}`` from the project's ``[[images]] strip`` keys, or None.

    Parameters
    ----------
    raw : dict
        The parsed project file (``ProjectSpec.raw``).

    Returns
    -------
    dict or None
        None when no image gives a strip (the strips are then found from the flight).
    """
    images = raw.get("images") or []
    found = {str(im.get("id")): im["strip"] for im in images
             if isinstance(im, dict) and im.get("strip") is not None}
    return found or None


def _free_model_part(run, pixel: Optional[float], mode) -> tuple:
    """``(stages, entry, notes)`` of the free model, or a note why it was left out."""
    n_img = len(run.image_ids)
    if mode is None or mode == "auto":
        mode = n_img <= FREE_MODEL_MAX_IMAGES
        if not mode:
            return [], {"skipped": f"{n_img} images > {FREE_MODEL_MAX_IMAGES}"}, [
                f"free model: not run for {n_img} images (more than {FREE_MODEL_MAX_IMAGES}; "
                "ask for it with --free-model)"]
    if not mode:
        return [], {"skipped": "--no-free-model"}, ["free model: not run (--no-free-model)"]
    fm = free_model(_problem(run), run.result.eo, run.result.xyz)
    return free_model_stages(fm, run.point_ids, pixel)


def _production_checks(run, pixel: Optional[float], *, frame, strips, zone_columns,
                       free_model_mode) -> tuple:
    """Zones, inter-strip ties and the free model: ``(stages, notes, parts)``."""
    view = block_view(run, frame)
    numbers, labels, source = _strips_of(run, view, strips)
    stages, notes, pairs, trips = zone_stages(view, numbers, zone_columns)
    is_stages, is_notes, inter = inter_strip_stages(view, numbers, pixel, labels)
    fm_stages, fm_entry, fm_notes = _free_model_part(run, pixel, free_model_mode)
    names = _strip_names(numbers, labels)
    parts = {
        "tie_zones": pairs, "triplet_zones": trips, "inter_strip": inter,
        "strips": {"source": source, "frame_mm": list(view.frame),
                   "strips": [{"strip": names[k], "images": [view.image_ids[i] for i in
                                                             np.flatnonzero(numbers == k)]}
                              for k in range(len(names))]},
        "free_model": fm_entry,
    }
    return stages + is_stages + fm_stages, notes + is_notes + fm_notes, parts

