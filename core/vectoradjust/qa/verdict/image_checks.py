"""Checks on images and image pairs: observation pairs and their vertical parallax, triplet
discrepancies and the interior orientation stages.
"""

from __future__ import annotations

import math
from typing import Any, Optional

import numpy as np

from vectoradjust.adjust.bundle import intersect
from vectoradjust.qa.tolerances import (
    check_stage,
    interior_orientation_tolerance,
    model_discrepancies,
    vertical_parallax,
)
from vectoradjust.qa.verdict.spec import (
    PAIR_MODES,
    _first,
    _fit_pixel,
    _fit_report,
    _interior_entries,
    _na_stage,
)

__all__ = ["observation_pairs", "pair_parallax", "triplet_discrepancies", "interior_stages"]


def observation_pairs(obs_point, obs_image) -> tuple:
    """Every pair of observations of the same point on two different images.

    Parameters
    ----------
    obs_point, obs_image : array_like of int, shape (k,)

    Returns
    -------
    (first, second) : numpy.ndarray of int
        Observation indices; ``obs_image[first] < obs_image[second]``.
    """
    op = np.asarray(obs_point, np.int64)
    oi = np.asarray(obs_image, np.int64)
    order = np.lexsort((oi, op))
    p, im = op[order], oi[order]
    first, second = [], []
    d = 1
    while d < len(p):
        same = p[d:] == p[:-d]
        if not same.any():
            break  # groups are contiguous: none is larger than d
        i = np.flatnonzero(same & (im[d:] != im[:-d]))
        first.append(order[i])
        second.append(order[i + d])
        d += 1
    if not first:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    return np.concatenate(first), np.concatenate(second)


def _problem(run):
    return run.result.problem if run.result.problem is not None else run.problem


def pair_parallax(run, pairs: str = "consecutive", min_points: int = 6) -> tuple:
    """Vertical parallax of every stereo pair after the adjustment.

    Parameters
    ----------
    run : AdjustmentRun
    pairs : {"consecutive", "all"}
        Consecutive images (in ``run.image_ids`` order) or every image pair.
    min_points : int
        Common points needed to call two images a stereo pair.

    Returns
    -------
    (pairs, skipped) : (list of dict, list of dict)
        Per stereo pair: ``left``, ``right`` (image ids), ``point_ids`` (numpy array of
        str), ``py_mm`` (numpy array, observed photo coordinates and adjusted EO,
        epipolar-normalised frame); ``skipped`` lists the candidate pairs with too few
        common points (``left``, ``right``, ``n``).
    """
    if pairs not in PAIR_MODES:
        raise ValueError(f"pairs must be one of {PAIR_MODES}, got {pairs!r}")
    prob = _problem(run)
    eo = run.result.eo
    a, b = observation_pairs(prob.obs_point, prob.obs_image)
    ia, ib = prob.obs_image[a], prob.obs_image[b]
    n_img = eo.shape[0]
    if pairs == "consecutive":
        keep = ib - ia == 1
        a, b, ia, ib = a[keep], b[keep], ia[keep], ib[keep]
    py = vertical_parallax(prob.obs_xy[a], prob.obs_xy[b], eo[ia], eo[ib],
                           prob.focal_length, tuple(prob.principal_point))
    key = ia * n_img + ib
    keys, inv, counts = np.unique(key, return_inverse=True, return_counts=True)
    inv = np.asarray(inv).reshape(-1)
    order = np.argsort(inv, kind="stable")
    bounds = np.concatenate([[0], np.cumsum(counts)])
    ids = np.asarray(run.point_ids).astype(str)
    found, skipped = [], []
    for g, k in enumerate(keys.tolist()):
        sel = order[bounds[g]:bounds[g + 1]]
        left, right = run.image_ids[k // n_img], run.image_ids[k % n_img]
        if counts[g] < min_points:
            skipped.append({"left": left, "right": right, "n": int(counts[g])})
            continue
        pts = prob.obs_point[a[sel]]
        srt = np.argsort(pts, kind="stable")
        found.append({"left": left, "right": right, "point_ids": ids[pts[srt]],
                      "py_mm": py[sel][srt]})
    if pairs == "consecutive":
        have = {(d["left"], d["right"]) for d in found} | {(d["left"], d["right"])
                                                           for d in skipped}
        for j in range(n_img - 1):
            pair = (run.image_ids[j], run.image_ids[j + 1])
            if pair not in have:
                skipped.append({"left": pair[0], "right": pair[1], "n": 0})
    return found, skipped


# ----------------------------------------------------------------------- triplets
def triplet_discrepancies(run, min_points: int = 3) -> tuple:
    """Discrepancies of points between the adjacent models of every triplet.

    A triplet is three consecutive images ``(1, 2, 3)`` of ``run.image_ids``. Each point
    measured on all three is intersected from its rays in model (1, 2) and in model
    (2, 3) with the adjusted exterior orientation held fixed.

    Parameters
    ----------
    run : AdjustmentRun
    min_points : int
        Points on all three images needed to judge a triplet.

    Returns
    -------
    (triplets, skipped) : (list of dict, list of dict)
        Per triplet: ``images`` (3 ids), ``point_ids``, ``xyz_12``, ``xyz_23`` (m),
        ``scale`` (photo-scale denominator ``m = H / f`` per point), ``e_xy_mm``,
        ``e_z_mm`` (image scale), ``base_m`` (mean air base of the two models),
        ``base_mm`` (photo base at the mean image scale). ``skipped``: triplets with
        too few common points (``images``, ``n``).
    """
    prob = _problem(run)
    eo = run.result.eo
    n_img = eo.shape[0]
    if n_img < 3:
        return [], []
    op, oi = prob.obs_point, prob.obs_image
    order = np.lexsort((oi, op))
    p, im = op[order], oi[order]
    if len(p) >= 3:
        hit = ((p[2:] == p[:-2]) & (p[1:-1] == p[:-2])
               & (im[1:-1] == im[:-2] + 1) & (im[2:] == im[:-2] + 2))
        i = np.flatnonzero(hit)
    else:
        i = np.zeros(0, np.int64)
    o1, o2, o3 = order[i], order[i + 1], order[i + 2]
    first = oi[o1]
    f = float(prob.focal_length)
    pp = tuple(prob.principal_point)
    n = len(i)
    rows = np.arange(n)
    # every (point, triplet) row is one "point" of each intersection
    xyz12, _ = intersect(eo, np.concatenate([rows, rows]), np.concatenate([oi[o1], oi[o2]]),
                         np.concatenate([prob.obs_xy[o1], prob.obs_xy[o2]]),
                         np.concatenate([prob.obs_sigma[o1], prob.obs_sigma[o2]]), n, f, pp)
    xyz23, _ = intersect(eo, np.concatenate([rows, rows]), np.concatenate([oi[o2], oi[o3]]),
                         np.concatenate([prob.obs_xy[o2], prob.obs_xy[o3]]),
                         np.concatenate([prob.obs_sigma[o2], prob.obs_sigma[o3]]), n, f, pp)
    mid = eo[first + 1]
    height = mid[:, 2] - 0.5 * (xyz12[:, 2] + xyz23[:, 2])
    scale = height * 1e3 / f
    e_xy, e_z = model_discrepancies(xyz12, xyz23, scale)
    ids = np.asarray(run.point_ids).astype(str)
    found, skipped = [], []
    for j in range(n_img - 2):
        sel = np.flatnonzero(first == j)
        names = [run.image_ids[j], run.image_ids[j + 1], run.image_ids[j + 2]]
        if len(sel) < min_points:
            skipped.append({"images": names, "n": int(len(sel))})
            continue
        base = 0.5 * (np.linalg.norm(eo[j + 1, :3] - eo[j, :3])
                      + np.linalg.norm(eo[j + 2, :3] - eo[j + 1, :3]))
        m_mean = float(np.mean(scale[sel]))
        found.append({
            "images": names, "point_ids": ids[op[o1[sel]]], "xyz_12": xyz12[sel],
            "xyz_23": xyz23[sel], "scale": scale[sel], "e_xy_mm": e_xy[sel],
            "e_z_mm": e_z[sel], "base_m": float(base), "base_mm": float(base / m_mean * 1e3),
        })
    return found, skipped


# ----------------------------------------------------------- interior orientation
def interior_stages(interior: Any, pixel: Optional[float]) -> tuple:
    """Interior orientation stages (max fiducial residual <= 1 pixel) per image.

    Parameters
    ----------
    interior : dict
        ``ProjectData.interior`` (:func:`vectoradjust.sensor.interior.refine_measurements`
        report): per image under ``"images"`` the fiducial affine report with the
        residual of every fiducial (``v_um`` or ``vx_um, vy_um``), ``max_um``,
        ``redundancy`` (0: an exact fit checks nothing) and the pixel size it used.
    pixel : float or None
        Pixel size (mm) when the report does not give one.

    Returns
    -------
    (stages, notes) : (list of StageResult, list of str)
        One stage per image with a fiducial fit, per-fiducial rows ``"<image>:<id>"``.
    """
    stages, notes, without = [], [], []
    for img, e in _interior_entries(interior):
        fit = _fit_report(e)
        if fit is None:
            without.append(img)
            continue
        name = f"interior orientation {img}: max fiducial residual"
        fid = fit.get("fiducials")
        if isinstance(fid, dict) and fid and all(isinstance(v, dict) for v in fid.values()):
            ids = [f"{img}:{k}" for k in fid]
            um = np.array([float(v["v_um"]) if v.get("v_um") is not None else
                           math.hypot(float(v.get("vx_um") or 0.0), float(v.get("vy_um") or 0.0))
                           for v in fid.values()])
        else:
            ids, um = [img], np.array([float(_first(fit, "max_um", "max_residual_um"))])
        p = _fit_pixel(fit) or pixel
        if fit.get("redundancy") == 0:
            notes.append(f"interior orientation of {img}: 3 fiducials leave no redundancy; "
                         "nothing is checked")
            stages.append(_na_stage(name, um / 1e3 / p if p else um, ids, "max",
                                    "px" if p else "um"))
        elif p is None:
            stages.append(_na_stage(name, um, ids, "max", "um"))
        else:
            tol = interior_orientation_tolerance(p)
            stages.append(check_stage(name, um / 1e3 / p, ids, tol.max_px, "max", unit="px"))
    if stages and without:
        notes.append(f"interior orientation: no fiducial fit for image(s) {', '.join(without)}")
    return stages, notes

