"""Self-calibration: the camera's focal length, principal point and radial distortion
estimated with the bundle (a drone camera whose calibration is only nominal).

The interior parameters ``theta`` (``f``, ``x0``, ``y0`` in mm; ``k1``, ``k2`` in mm at the
normalising radius ``R``) enter every frame observation: the camera's focal length and
principal point become ``f0 + df``, ``pp0 + (dx0, dy0)``, and the (already corrected)
observation ``x`` is corrected once more for the radial distortion
``(xb / R) (k1 rho^2 + k2 rho^4)`` with ``xb = x - pp``, ``rho = |xb| / R`` (so ``k1``,
``k2`` are the distortion in mm at the radius ``R``). Like the databases' offsets
(:mod:`vectoradjust.adjust.offsets`) they are solved by Newton steps on their reduced
normal equations at the bundle's solution,

``N_red = W - B' Q B``, ``W = sum A' P A``, ``B = [sum_i a_e' P A; sum_j a_p' P A]``,
``B' Q B = sum_j B_j' D_j B_j + Y' S^-1 Y``, ``Y = B_e - sum N_ep D B_p``,

(``A`` the partials of the image residuals by ``theta``, by central differences; ``Q`` the
bundle's inverse from its kept factorisation, linear in the number of points), jointly
with the offsets where a project has both (:func:`joint_normals`). The covariances then
include the calibration's uncertainty, ``Q_x += (QB) Q_tt (QB)'``. Parameters the block
does not determine (e.g. the focal length against the flying height without height
control or camera height priors) are reported and left at the camera's values.
Numpy only.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Optional

import numpy as np

from vectoradjust.adjust.bundle import BundleProblem, BundleResult, _block_sum
from vectoradjust.sensor.collinearity import project

__all__ = ["SELF_CALIBRATION_PARAMETERS", "InteriorModel", "interior_partials",
           "interior_normals", "determined_parameters"]

#: the interior parameters that can be self-calibrated
SELF_CALIBRATION_PARAMETERS = ("f", "x0", "y0", "k1", "k2")
_STEP = {"f": 1e-4, "x0": 1e-4, "y0": 1e-4, "k1": 1e-5, "k2": 1e-5}


@dataclass
class InteriorModel:
    """Which interior parameters are estimated, and the observations they correct.

    Attributes
    ----------
    names : tuple of str
        A subset of :data:`SELF_CALIBRATION_PARAMETERS`, in that order.
    focal_length : float
        The camera's focal length (mm) before self-calibration.
    principal_point : numpy.ndarray, shape (2,)
        Its principal point (mm).
    obs_xy : numpy.ndarray, shape (k, 2)
        The image observations (mm) before self-calibration.
    radius : float
        Normalising radius ``R`` of the distortion terms (mm): the largest distance of an
        observation from the principal point.
    """

    names: tuple
    focal_length: float
    principal_point: np.ndarray
    obs_xy: np.ndarray
    radius: float

    @classmethod
    def build(cls, names, prob: BundleProblem) -> InteriorModel:
        """The model of ``names`` for the frame observations of ``prob``."""
        names = tuple(n for n in SELF_CALIBRATION_PARAMETERS if n in set(names))
        pp = np.asarray(prob.principal_point, float)
        r = np.sqrt(((prob.obs_xy - pp) ** 2).sum(axis=1))
        return cls(names, float(prob.focal_length), pp.copy(), prob.obs_xy.copy(),
                   float(max(r.max(initial=0.0), 1e-3)))

    @property
    def n_params(self) -> int:
        """Number of interior parameters."""
        return len(self.names)

    def _get(self, theta: np.ndarray, name: str) -> float:
        return float(theta[self.names.index(name)]) if name in self.names else 0.0

    def camera(self, theta: np.ndarray):
        """Focal length, principal point and corrected observations for ``theta``."""
        theta = np.asarray(theta, float)
        f = self.focal_length + self._get(theta, "f")
        pp = self.principal_point + np.array([self._get(theta, "x0"), self._get(theta, "y0")])
        xb = self.obs_xy - pp
        rho2 = (xb ** 2).sum(axis=1) / self.radius ** 2
        k1, k2 = self._get(theta, "k1"), self._get(theta, "k2")
        obs = self.obs_xy - xb / self.radius * (k1 * rho2 + k2 * rho2 ** 2)[:, None]
        return f, pp, obs

    def problem(self, base: BundleProblem, theta: np.ndarray, **kw) -> BundleProblem:
        """``base`` with the camera and the observations of ``theta``."""
        f, pp, obs = self.camera(theta)
        return replace(base, focal_length=f, principal_point=pp, obs_xy=obs, **kw)

    def values(self, theta: np.ndarray) -> dict:
        """The calibrated values: focal length, principal point (mm), k1, k2 (mm at R)."""
        f, pp, _ = self.camera(theta)
        return {"f": f, "x0": float(pp[0]), "y0": float(pp[1]),
                "k1": self._get(theta, "k1"), "k2": self._get(theta, "k2"),
                "radius_mm": self.radius}


def _residuals(model: InteriorModel, theta, eo, xyz, prob: BundleProblem) -> np.ndarray:
    """Image residuals (computed minus observed, mm) for ``theta`` at ``eo``, ``xyz``."""
    f, pp, obs = model.camera(theta)
    pred = project(eo[prob.obs_image], xyz[prob.obs_point], f, pp)
    return pred - obs


def interior_partials(model: InteriorModel, theta: np.ndarray,
                      result: BundleResult) -> np.ndarray:
    """Partials of the image residuals by the interior parameters, ``(k, 2, c)``
    (central differences at the bundle's solution)."""
    prob = result.problem
    out = np.empty((len(prob.obs_point), 2, model.n_params))
    for c, name in enumerate(model.names):
        h = _STEP[name]
        tp, tm = np.array(theta, float), np.array(theta, float)
        tp[c] += h
        tm[c] -= h
        out[:, :, c] = (_residuals(model, tp, result.eo, result.xyz, prob)
                        - _residuals(model, tm, result.eo, result.xyz, prob)) / (2.0 * h)
    return out


def _per_image(obs_image: np.ndarray, values: np.ndarray, n: int) -> np.ndarray:
    return _block_sum(obs_image, values, n)


def interior_normals(result: BundleResult, model: InteriorModel, theta: np.ndarray):
    """Reduced normal matrix, misclosure and ``Q B`` of the interior parameters.

    Returns
    -------
    n_red : numpy.ndarray, shape (c, c)
    g : numpy.ndarray, shape (c,)
        ``-A' P v``: the step is ``n_red^-1 g``.
    qb_p : numpy.ndarray, shape (m, 3, c)
        ``(Q B)`` of the points.
    qb_e : numpy.ndarray, shape (6n, c)
        ``(Q B)`` of the exterior orientation.
    a : numpy.ndarray, shape (k, 2, c)
        The partials.
    """
    prob = result.problem
    n, m = prob.n_images, prob.n_points
    a = interior_partials(model, theta, result)
    p = 1.0 / prob.obs_sigma ** 2
    pa = a * p[:, :, None]
    w = np.einsum("kri,krj->ij", a, pa)
    v = result.v_image
    g = -np.einsum("kri,kr->i", pa, v)
    b_e = _per_image(prob.obs_image, np.einsum("kri,krc->kic", result.a_eo, pa), n)
    b_p = _block_sum(prob.obs_point, np.einsum("kri,krc->kic", result.a_pt, pa), m)
    d = result.npp_inv
    db = np.matmul(d, b_p)  # D B_p (m, 3, c)
    zdb = _per_image(prob.obs_image, np.matmul(result.nep_obs, db[prob.obs_point]), n)
    y = (b_e - zdb).reshape(6 * n, -1)
    sy = result.s_inv @ y
    bqb = np.einsum("mic,mid->cd", b_p, db) + y.T @ sy
    back = np.matmul(np.swapaxes(result.nep_obs, 1, 2), sy.reshape(n, 6, -1)[prob.obs_image])
    qb_p = db - np.matmul(np.swapaxes(d, 1, 2), _block_sum(prob.obs_point, back, m))
    n_red = w - bqb
    return 0.5 * (n_red + n_red.T), g, qb_p, sy, a


def determined_parameters(n_red: np.ndarray, limit: float = 1e8) -> np.ndarray:
    """Which parameters the block determines, ``(c,)`` bool.

    The normal matrix is scaled to unit diagonal (a correlation-like matrix); while its
    condition number exceeds ``limit`` the parameter with the largest variance inflation
    (the diagonal of the inverse) is left out. A parameter with no information at all
    (zero diagonal) is left out first.
    """
    keep = np.diag(n_red) > 0
    while keep.sum() > 0:
        sel = np.flatnonzero(keep)
        sub = n_red[np.ix_(sel, sel)]
        sc = np.sqrt(np.diag(sub))
        corr = sub / np.outer(sc, sc)
        lam = np.linalg.eigvalsh(corr)
        if lam.min() > 0 and lam.max() / lam.min() < limit:
            break
        vif = np.diag(np.linalg.inv(corr + 1e-12 * np.eye(len(sel))))
        keep[sel[int(np.argmax(vif))]] = False
    return keep


def summary_record(model: InteriorModel, theta: np.ndarray, cof: np.ndarray,
                   variance_factor: float, dropped: Optional[list] = None) -> dict:
    """For summary.json: calibrated values, sigmas and correlations."""
    sig = np.sqrt(np.maximum(np.diag(cof) * variance_factor, 0.0))
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cof / np.outer(np.sqrt(np.diag(cof)), np.sqrt(np.diag(cof)))
    vals = model.values(theta)
    return {
        "parameters": list(model.names),
        "values": {k: vals[k] for k in model.names},
        "corrections": {k: float(t) for k, t in zip(model.names, theta)},
        "sigma": {k: float(s) for k, s in zip(model.names, sig)},
        "correlation": np.round(np.nan_to_num(corr), 4).tolist(),
        "radius_mm": model.radius,
        "units": "f, x0, y0 in mm; k1, k2: radial distortion in mm at radius_mm",
        "not_determined": list(dropped or []),
    }
