"""The free-model stage of the accuracy control (``docs/method.md`` section 7.5).

Before control pulls on the block, the PHOTOMOD sequence adjusts the free model: the
image measurements alone, the datum fixed by inner constraints. Its variance factor and
image residuals show whether the measurements agree with each other (and with their
stated sigmas) before any control point, road database or camera prior can hide or
spread a blunder.

:func:`free_model` re-uses a finished run's bundle problem: every point measured on at
least two images becomes a tie point (its coordinate prior dropped), every camera prior
is dropped (``eo_sigma = inf``), points on one image only are left out, and the network
is solved with inner constraints over the cameras (``free_datum``,
:func:`vectoradjust.adjust.datum.free_network_correction`), starting from the run's
adjusted orientation and points (so it converges in a few iterations).

* ``sigma0 = sqrt(v'Pv / r)``, ``r = 2 k - (6 n + 3 m - 7)`` (``k`` image observations,
  ``n`` images, ``m`` points). With image sigmas that are right, ``sigma0^2 r`` is
  chi-square with ``r`` degrees of freedom: the stage passes when ``sigma0 <=
  sqrt(chi2_{0.99}(r) / r)`` (one-sided test at 1 %).
* Image residual RMS ``sqrt(mean(v_x^2 + v_y^2) / 2)`` (x and y pooled), in pixels,
  against the relative orientation tolerance (0.5 px); every point's largest residual
  component against the relative orientation maximum (1 px): what a relative orientation
  leaves is what the free model leaves.

A "heart" module: numpy, scipy and other vectoradjust heart modules only; no file I/O.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Optional

import numpy as np

from vectoradjust.adjust.bundle import BundleProblem, adjust
from vectoradjust.adjust.reliability import subset_problem
from vectoradjust.errors import VectorAdjustError
from vectoradjust.formatting import float_or_none as _num
from vectoradjust.qa.tolerances import StageResult, relative_orientation_tolerance

__all__ = ["FREE_MODEL_MAX_IMAGES", "free_problem", "free_model", "sigma0_bound",
           "free_model_stages"]

#: ``free_model="auto"`` runs the free model up to this many images (a second bundle
#: adjustment of the block; larger runs ask for it with ``--free-model``)
FREE_MODEL_MAX_IMAGES = 200


def free_problem(problem: BundleProblem, eo, xyz) -> tuple:
    """The free network of a run's bundle problem, started at its adjusted values.

    Parameters
    ----------
    problem : BundleProblem
        The run's problem (``run.result.problem``).
    eo : array_like, shape (n, 6)
        Adjusted exterior orientation.
    xyz : array_like, shape (m, 3)
        Adjusted points.

    Returns
    -------
    (free, obs_index, point_index)
        The free problem, and the original indices of its observations and points.
    """
    rays = np.bincount(problem.obs_point, minlength=problem.n_points)
    keep = rays >= 2
    eo = np.asarray(eo, float)
    start = replace(problem, eo0=eo.copy(), eo_start=None, xyz0=np.asarray(xyz, float).copy(),
                    eo_sigma=np.full(problem.eo_sigma.shape, np.inf),
                    prior_weight=np.zeros_like(problem.prior_weight), free_datum=True)
    return subset_problem(start, keep[problem.obs_point], keep)


def sigma0_bound(dof: int, alpha: float = 0.01) -> float:
    """Upper limit of ``sigma0`` when the stated sigmas are right: ``sqrt(chi2_{1-a}(r)/r)``."""
    from scipy.special import gammaincinv

    if dof <= 0:
        return float("nan")
    # the chi-square quantile: chi2_p(r) = 2 P^-1(r / 2, p) (regularised gamma)
    return math.sqrt(2.0 * float(gammaincinv(0.5 * dof, 1.0 - alpha)) / dof)


def free_model(problem: BundleProblem, eo, xyz, *, max_iterations: int = 20) -> dict:
    """Adjust the free model of a run (module notes).

    Parameters
    ----------
    problem : BundleProblem
    eo, xyz : array_like
        The run's adjusted orientation and points (the start).
    max_iterations : int

    Returns
    -------
    dict
        ``sigma0``, ``dof``, ``n_observations``, ``n_points``, ``n_images``,
        ``iterations``, ``rms_x_mm``, ``rms_y_mm``, ``rms_mm`` (pooled), ``v_mm`` (k, 2
        residuals), ``obs_index``, ``point_index``; or ``error`` (str) when the free
        network cannot be solved (RPC images, too few points, no convergence).
    """
    if problem.sensors is not None and problem.is_rpc.any():
        return {"error": "RPC images: their sensor model fixes the datum, there is no free "
                         "model"}
    free, obs_index, point_index = free_problem(problem, eo, xyz)
    if len(obs_index) == 0:
        return {"error": "no point is measured on two images"}
    try:
        res = adjust(free, max_iterations=max_iterations, compute_covariance=False)
    except VectorAdjustError as exc:
        return {"error": f"the free network could not be solved: {exc.what}"}
    v = np.asarray(res.v_image, float)
    return {
        "sigma0": math.sqrt(max(res.sigma0_squared, 0.0)) if res.dof > 0 else float("nan"),
        "dof": int(res.dof), "n_observations": int(len(v)), "n_points": int(free.n_points),
        "n_images": int(free.n_images), "iterations": int(res.iterations),
        "rms_x_mm": float(np.sqrt(np.mean(v[:, 0] ** 2))),
        "rms_y_mm": float(np.sqrt(np.mean(v[:, 1] ** 2))),
        "rms_mm": float(np.sqrt(np.mean(v**2))), "v_mm": v, "obs_index": obs_index,
        "point_index": point_index, "obs_point": free.obs_point,
    }


def _residual_stage(fm: dict, point_ids, pixel: Optional[float]) -> StageResult:
    """Image residual RMS (px) against 0.5 px; each point's largest |v| against 1 px."""
    v = np.abs(fm["v_mm"])
    worst = np.zeros(fm["n_points"])
    np.maximum.at(worst, fm["obs_point"], v.max(axis=1))
    ids = np.asarray(point_ids).astype(str)[fm["point_index"]].tolist()
    name = "free model: image residual RMS"
    if pixel is None:
        rows = [{"id": i, "value": float(x * 1e3), "tolerance": float("nan"), "passed": None}
                for i, x in zip(ids, worst.tolist())]
        return StageResult(name, float("nan"), fm["rms_mm"] * 1e3, "rms", float("nan"), None,
                           "um", rows)
    tol = relative_orientation_tolerance(pixel)
    px = worst / pixel
    ok = px <= tol.max_px
    rows = [{"id": i, "value": float(x), "tolerance": tol.max_px, "passed": bool(o)}
            for i, x, o in zip(ids, px.tolist(), ok.tolist())]
    rms_px = fm["rms_mm"] / pixel
    return StageResult(name, tol.mean_px, rms_px, "rms", tol.max_px,
                       bool(rms_px <= tol.mean_px and ok.all()), "px", rows)


def free_model_stages(fm: dict, point_ids, pixel: Optional[float]) -> tuple:
    """The free-model stages and the ``free_model`` entry of ``qa.json``.

    Parameters
    ----------
    fm : dict
        :func:`free_model`.
    point_ids : sequence of str
        The run's point ids (indexed by the problem's points).
    pixel : float or None
        Pixel size (mm); without it the residual stage is not evaluated.

    Returns
    -------
    (stages, entry, notes) : (list of StageResult, dict, list of str)
    """
    if "error" in fm:
        stage = StageResult("free model", float("nan"), float("nan"), "max", float("nan"),
                            None, "")
        return [stage], {"error": fm["error"]}, [f"free model: not evaluated ({fm['error']})"]
    bound = sigma0_bound(fm["dof"])
    s0 = fm["sigma0"]
    sig = StageResult("free model: sigma0", bound, s0, "max", bound,
                      None if not np.isfinite(s0) else bool(s0 <= bound), "",
                      [{"id": "sigma0", "value": s0, "tolerance": bound,
                        "passed": None if not np.isfinite(s0) else bool(s0 <= bound)}])
    sig.action = "check the image measurements"
    res = _residual_stage(fm, point_ids, pixel)
    entry = {k: (_num(fm[k]) if isinstance(fm[k], float) else fm[k])
             for k in ("sigma0", "dof", "n_observations", "n_points", "n_images",
                       "iterations")}
    entry["sigma0_bound"] = _num(bound)
    for k in ("rms_x", "rms_y", "rms"):
        entry[f"{k}_um"] = _num(fm[f"{k}_mm"] * 1e3)
        entry[f"{k}_px"] = _num(fm[f"{k}_mm"] / pixel) if pixel else None
    notes = [f"free model: sigma0 = {s0:.3f} over {fm['dof']} degrees of freedom (limit "
             f"{bound:.3f}, chi-square at 1 %), image residual RMS "
             f"{fm['rms_mm'] * 1e3:.2f} um; the image measurements alone, before control"]
    return [sig, res], entry, notes
