"""Weighted least-squares bundle adjustment over the reduced camera system.

Unknowns are the exterior orientation (6 per image) and the ground coordinates of
every object point (3 per point). Observations are image coordinates, optional priors
on object points (control points heavy, road shape points light, tie points none) and
optional priors on the exterior orientation. Gauss-Newton iterates on the normal
equations ``N dx = t`` with ``N = [[N_ee, N_ep], [N_pe, N_pp]]``; the point blocks are
eliminated (Schur complement) so that only the small reduced camera system
``S = N_ee - N_ep N_pp^-1 N_pe`` is solved (``DESIGN.md`` section 3).

Nothing here loops over points. Points seen by the same set of ``c`` images form a
group, cut into blocks (:data:`_CHUNK_OBS` observations) whose arrays are
laid out ``(c, ..., g)``: the rotation matrix of an image and its derivatives are
computed once per image and broadcast over the block's points (no matrix per
observation), a point's sums over its images are sums over the first axis (no
``np.add.at``), an image's sums over its points are matrix products, the 3x3 point
blocks are inverted (and Cholesky-factored) in closed form, and a block's share of the
reduced system is one symmetric product ``U U'`` with ``U = N_ep L``, ``L L' = N_pp^-1``.
The exact point covariances are the 3x3 blocks of ``N^-1``,
``N_pp^-1 + N_pp^-1 N_pe S^-1 N_ep N_pp^-1``, from ``S^-1`` restricted to each block's
images (no dense matrix over the points). The adjustment runs with one OpenBLAS thread
(:func:`_single_blas_thread`). ``benchmarks/run.py`` times it; ``tests/test_solver_dense.py``
checks it against a dense Gauss-Newton.
"""

from __future__ import annotations

import ctypes
import os
import sys
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from typing import Callable, Optional

import numpy as np
import scipy.linalg

from vectoradjust.adjust.datum import free_network_correction
from vectoradjust.adjust.intersection import (  # noqa: F401 (inv3x3, ray_intersection: API)
    _block_sum,
    approximate_points,
    inv3x3,
    ray_intersection,
)
from vectoradjust.errors import CancelledError, NonConvergenceError, SingularityError
from vectoradjust.sensor.collinearity import (
    partials,
    project,
    rotation_derivatives,
    rotation_matrix,
)
from vectoradjust.sensor.models import SensorSet, observe_rpc

__all__ = [
    "BundleProblem",
    "BundleResult",
    "adjust",
    "intersect",
    "ray_intersection",
    "inv3x3",
]

ProgressCallback = Callable[[float, str], None]


#: (set, get) symbol pairs of the OpenBLAS builds numpy and scipy ship or link
_BLAS_THREAD_SYMBOLS = (
    ("openblas_set_num_threads", "openblas_get_num_threads"),
    ("scipy_openblas_set_num_threads", "scipy_openblas_get_num_threads"),
    ("scipy_openblas_set_num_threads64_", "scipy_openblas_get_num_threads64_"),
    ("openblas_set_num_threads64_", "openblas_get_num_threads64_"),
)


def _openblas_controls() -> list:
    """``(set, get)`` thread functions of every OpenBLAS loaded in this process (Linux)."""
    if not sys.platform.startswith("linux") or os.environ.get("VECTORADJUST_BLAS_THREADS"):
        return []
    try:
        with open("/proc/self/maps", encoding="utf-8") as fh:
            paths = sorted({ln.split()[-1] for ln in fh if "openblas" in ln.lower()
                            and ln.split()[-1].startswith("/")})
    except OSError:
        return []
    controls = []
    for path in paths:
        try:
            lib = ctypes.CDLL(path)
        except OSError:
            continue
        for set_name, get_name in _BLAS_THREAD_SYMBOLS:
            if hasattr(lib, set_name) and hasattr(lib, get_name):
                controls.append((getattr(lib, set_name), getattr(lib, get_name)))
                break
    return controls


@contextmanager
def _single_blas_thread():
    """Run the adjustment with one OpenBLAS thread, then restore the previous setting.

    Its matrix products are small (a block's images) or many; a threaded BLAS splits
    them across cores that other work (or other processes on a shared machine) holds,
    and waits: on a loaded 2-core machine that made a 1200 x 1200 Cholesky take seconds.
    Set the environment variable ``VECTORADJUST_BLAS_THREADS`` (any value) to leave the
    BLAS threads alone. Without OpenBLAS (or off Linux) this does nothing.
    """
    controls = _openblas_controls()
    old = []
    try:
        for set_fn, get_fn in controls:
            old.append((set_fn, int(get_fn())))
            set_fn(1)
        yield
    finally:
        for set_fn, n in old:
            set_fn(n)


@dataclass
class BundleProblem:
    """Arrays that define one adjustment.

    Attributes
    ----------
    focal_length : float
        mm.
    principal_point : numpy.ndarray, shape (2,)
        mm.
    eo0 : numpy.ndarray, shape (n, 6)
        Approximate exterior orientation (m, rad); also the prior mean where priors exist.
    eo_sigma : numpy.ndarray, shape (n, 6)
        Prior sigmas (m, rad); ``inf`` (or NaN) for a free parameter.
    xyz0 : numpy.ndarray, shape (m, 3)
        Approximate point coordinates (start of the iteration).
    prior_xyz : numpy.ndarray, shape (m, 3)
        Prior point coordinates (ignored where ``prior_weight`` is zero).
    prior_weight : numpy.ndarray, shape (m, 3, 3)
        Weight matrix (inverse covariance) of the prior; zero for tie points.
    obs_point, obs_image : numpy.ndarray of int, shape (k,)
        Point and image index of each image observation.
    obs_xy : numpy.ndarray, shape (k, 2)
        Observed photo coordinates (mm).
    obs_sigma : numpy.ndarray, shape (k, 2)
        Their standard deviations (mm).
    """

    focal_length: float
    principal_point: np.ndarray
    eo0: np.ndarray
    eo_sigma: np.ndarray
    xyz0: np.ndarray
    prior_xyz: np.ndarray
    prior_weight: np.ndarray
    obs_point: np.ndarray
    obs_image: np.ndarray
    obs_xy: np.ndarray
    obs_sigma: np.ndarray
    #: where the iteration starts for the exterior orientation (default ``eo0``, which
    #: is also the prior mean); a warm start for repeated adjustments
    eo_start: Optional[np.ndarray] = None
    #: the sensor model of each image (:class:`vectoradjust.sensor.models.SensorSet`); None:
    #: every image is a frame camera. For an RPC image the six parameters are its
    #: image-space bias (px) and its observations are pixels (column, row)
    sensors: Optional[SensorSet] = None
    #: a free network: no prior fixes the datum, the reduced system is solved with inner
    #: constraints over the cameras (:mod:`vectoradjust.adjust.datum`; frame cameras and
    #: no priors only)
    free_datum: bool = False

    def __post_init__(self) -> None:
        self.principal_point = np.asarray(self.principal_point, float).reshape(2)
        self.eo0 = np.asarray(self.eo0, float).reshape(-1, 6)
        self.eo_sigma = np.asarray(self.eo_sigma, float).reshape(-1, 6)
        self.xyz0 = np.asarray(self.xyz0, float).reshape(-1, 3)
        self.prior_xyz = np.asarray(self.prior_xyz, float).reshape(-1, 3)
        self.prior_weight = np.asarray(self.prior_weight, float).reshape(-1, 3, 3)
        self.obs_point = np.asarray(self.obs_point, np.int64)
        self.obs_image = np.asarray(self.obs_image, np.int64)
        self.obs_xy = np.asarray(self.obs_xy, float).reshape(-1, 2)
        self.obs_sigma = np.asarray(self.obs_sigma, float).reshape(-1, 2)

    @property
    def n_images(self) -> int:
        """Number of images."""
        return self.eo0.shape[0]

    @property
    def n_points(self) -> int:
        """Number of object points."""
        return self.xyz0.shape[0]

    @property
    def eo_weight(self) -> np.ndarray:
        """Diagonal prior weights of the exterior orientation (0 for free parameters)."""
        s = self.eo_sigma
        with np.errstate(divide="ignore"):
            w = np.where(np.isfinite(s) & (s > 0), 1.0 / np.where(s > 0, s, 1.0) ** 2, 0.0)
        return w

    @property
    def eo_fixed(self) -> np.ndarray:
        """``(n, 6)`` bool: parameters held at ``eo0`` (not unknowns): the bias parameters
        an RPC image's bias model does not estimate."""
        if self.sensors is None:
            return np.zeros(self.eo0.shape, bool)
        return self.sensors.fixed()

    @property
    def is_rpc(self) -> np.ndarray:
        """``(n,)`` bool: the image has an RPC model."""
        if self.sensors is None:
            return np.zeros(self.n_images, bool)
        return self.sensors.is_rpc

    @property
    def has_prior(self) -> np.ndarray:
        """Points with a coordinate prior (control and shape points)."""
        return np.abs(self.prior_weight).reshape(-1, 9).sum(axis=1) > 0

    def counts(self) -> tuple[int, int]:
        """Number of observations ``n`` and of unknowns ``u`` (DESIGN section 3)."""
        n = 2 * len(self.obs_point) + 3 * int(self.has_prior.sum())
        fixed = self.eo_fixed
        n += int(((self.eo_weight > 0) & ~fixed).sum())
        u = 6 * self.n_images - int(fixed.sum()) + 3 * self.n_points
        if self.free_datum:  # the seven datum parameters are not estimable
            u -= 7
        return n, u


@dataclass
class _Groups:
    """Observations arranged by points that share the same set of images."""

    images: list  # per group: (c,) image indices
    points: list  # per group: (g,) point indices
    obs: list  # per group: (g, c) observation indices


def _observation_order(obs_point: np.ndarray, obs_image: np.ndarray) -> np.ndarray:
    """Observations sorted by point, then image (no sort when they already are)."""
    n_img = int(obs_image.max(initial=-1)) + 1
    key = obs_point * max(n_img, 1) + obs_image
    if len(key) < 2 or bool(np.all(key[1:] >= key[:-1])):
        return np.arange(len(key))
    return np.argsort(key, kind="stable")


def _image_set_keys(img_mat: np.ndarray):
    """Distinct rows of ``img_mat (g, c)`` (sorted) and each row's position among them."""
    g, c = img_mat.shape
    base = int(img_mat.max(initial=0)) + 1
    if c * np.log2(max(base, 2)) < 62:  # one int64 key per row, in lexicographic order
        key = np.zeros(g, np.int64)
        for j in range(c):
            key = key * base + img_mat[:, j]
        uniq, first, inverse = np.unique(key, return_index=True, return_inverse=True)
        return img_mat[first], np.asarray(inverse).reshape(-1)
    keys, inverse = np.unique(img_mat, axis=0, return_inverse=True)
    return keys, np.asarray(inverse).reshape(-1)


def _group_observations(obs_point: np.ndarray, obs_image: np.ndarray, n_points: int) -> _Groups:
    order = _observation_order(obs_point, obs_image)
    counts = np.bincount(obs_point, minlength=n_points)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    groups = _Groups([], [], [])
    for c in np.unique(counts[counts > 0]):
        pts = np.flatnonzero(counts == c)
        obs_mat = order[starts[pts][:, None] + np.arange(c)[None, :]]
        img_mat = obs_image[obs_mat]
        keys, inverse = _image_set_keys(img_mat)
        sort = np.argsort(inverse, kind="stable")
        bounds = np.searchsorted(inverse[sort], np.arange(len(keys) + 1))
        for g in range(len(keys)):
            sel = sort[bounds[g] : bounds[g + 1]]
            groups.images.append(keys[g])
            groups.points.append(pts[sel])
            groups.obs.append(obs_mat[sel])
    return groups


@dataclass
class BundleResult:
    """Result of :func:`adjust`.

    Attributes
    ----------
    eo : numpy.ndarray, shape (n, 6)
        Adjusted exterior orientation (m, rad).
    xyz : numpy.ndarray, shape (m, 3)
        Adjusted object points.
    eo_cov : numpy.ndarray, shape (n, 6, 6)
        A-posteriori covariance of each image's EO (``sigma0^2 S^-1`` blocks).
    point_cov : numpy.ndarray, shape (m, 3, 3)
        A-posteriori covariance of each object point (cameras' uncertainty included).
    v_image : numpy.ndarray, shape (k, 2)
        Image residuals, adjusted minus observed (mm).
    v_point : numpy.ndarray, shape (m, 3)
        Point prior residuals, adjusted minus prior (m); NaN for points without prior.
    v_eo : numpy.ndarray, shape (n, 6)
        EO prior residuals; NaN for free parameters.
    vtpv : float
    n_obs, n_unknowns, dof : int
    sigma0_squared : float
        ``v'Pv / dof`` (NaN when dof = 0).
    iterations : int
    converged : bool
    history : list of dict
        Per iteration: vtpv before the step and the largest corrections.
    """

    eo: np.ndarray
    xyz: np.ndarray
    eo_cov: np.ndarray
    point_cov: np.ndarray
    v_image: np.ndarray
    v_point: np.ndarray
    v_eo: np.ndarray
    vtpv: float
    n_obs: int
    n_unknowns: int
    dof: int
    sigma0_squared: float
    iterations: int
    converged: bool
    history: list = field(default_factory=list)
    # factorisation kept for reliability and joint covariances (cofactors, no sigma0^2)
    s_inv: Optional[np.ndarray] = None
    npp_inv: Optional[np.ndarray] = None
    nep_obs: Optional[np.ndarray] = None
    a_eo: Optional[np.ndarray] = None
    a_pt: Optional[np.ndarray] = None
    problem: Optional[BundleProblem] = None

    #: "a-posteriori" (cofactors times sigma0^2), "a-priori" (times 1) or "groups" (times
    #: ``group_factor``: the variance factor of the groups whose sigma is known or estimated)
    covariance_scale: str = "a-posteriori"
    group_factor: float = 1.0
    # database offsets estimated with the adjustment (adjust/offsets.py), None without:
    # their cofactor Q_TT (q, q), Q_xx B per point (m, 3, q), S^-1 Z' B (6n, q) and the
    # offsets' design matrix G per point (m, 3, q)
    offset_cofactor: Optional[np.ndarray] = None
    offset_qb: Optional[np.ndarray] = None
    offset_u: Optional[np.ndarray] = None
    offset_g: Optional[np.ndarray] = None
    # with self-calibration: the image rows' partials by the nuisance parameters (k, 2, q)
    # (zero for the offsets' columns)
    offset_a: Optional[np.ndarray] = None

    #: the kept blocks that :meth:`release_factorisation` lets go
    RELEASABLE = ("npp_inv", "nep_obs", "a_eo", "a_pt", "offset_qb", "offset_g", "offset_a")

    def release_factorisation(self) -> None:
        """Let go of the per-point and per-observation blocks kept for covariances.

        ``npp_inv``, ``nep_obs``, ``a_eo``, ``a_pt``, ``offset_qb``, ``offset_g`` and the
        cached cofactors (about 1 GB at a million shape points). What was computed from
        them stays: ``point_cov``, ``eo_cov``, the reliability of the run, and the small
        ``s_inv``. Covariances between points
        (:func:`vectoradjust.accuracy.derived.cross_covariance`,
        :meth:`joint_covariance`) and reliability can no longer be computed from this
        result; they raise :class:`vectoradjust.errors.ProjectError`. The command line
        calls it when nothing it still has to write needs them.
        """
        for name in self.RELEASABLE:
            setattr(self, name, None)
        self.__dict__.pop("_cofactor_cache", None)

    def eo_cofactor(self) -> np.ndarray:
        """Cofactor matrix (6n, 6n) of the exterior orientation, offsets included."""
        if self.offset_cofactor is None:
            return self.s_inv
        u = self.offset_u
        q = self.s_inv + u @ self.offset_cofactor @ u.T
        return 0.5 * (q + q.T)

    def offset_cross(self, pa, pb) -> np.ndarray:
        """The offsets' share ``(Q B)_a Q_TT (Q B)_b'`` of point cofactors, (p, 3, 3)."""
        pa = np.asarray(pa, np.int64).reshape(-1)
        pb = np.asarray(pb, np.int64).reshape(-1)
        if self.offset_cofactor is None:
            return np.zeros((len(pa), 3, 3))
        qb = self.offset_qb
        return np.einsum("piq,qr,pjr->pij", qb[pa], self.offset_cofactor, qb[pb])

    @property
    def variance_factor(self) -> float:
        """The factor applied to cofactors: sigma0^2 (1 when dof = 0, or a-priori)."""
        if self.covariance_scale == "a-priori":
            return 1.0
        if self.covariance_scale == "groups":
            return float(self.group_factor)
        s = self.sigma0_squared
        return float(s) if np.isfinite(s) else 1.0

    def set_covariance_scale(self, scale: str, factor: float = 1.0) -> None:
        """Scale the covariances a posteriori (by sigma0^2), a priori (by 1) or by the
        groups' variance factor ``factor`` (``scale = "groups"``), in place."""
        if scale not in ("a-posteriori", "a-priori", "groups"):
            raise ValueError(f"covariance scale {scale!r}: use 'a-posteriori' or 'a-priori'")
        old = self.variance_factor
        self.covariance_scale = scale
        self.group_factor = float(factor)
        ratio = self.variance_factor / old
        self.eo_cov = self.eo_cov * ratio
        if self.point_cov is not None:
            self.point_cov = self.point_cov * ratio

    def joint_covariance(self, points) -> np.ndarray:
        """Full a-posteriori covariance of a set of object points.

        Parameters
        ----------
        points : array_like of int
            Point indices (length ``p``).

        Returns
        -------
        numpy.ndarray, shape (3p, 3p)
            ``sigma0^2 [D + Z S^-1 Z']`` with ``D`` block-diagonal ``N_pp^-1`` and
            ``Z = N_pp^-1 N_pe``; no full inverse of ``N`` is formed.
        """
        pts_in = np.asarray(points, np.int64).reshape(-1)
        pts, inverse = np.unique(pts_in, return_inverse=True)
        if len(pts) != len(pts_in):  # repeated points: compute once, then expand
            full = self.joint_covariance(pts)
            idx = (3 * np.asarray(inverse).reshape(-1)[:, None] + np.arange(3)).ravel()
            return full[np.ix_(idx, idx)]
        pts = pts_in
        prob = self.problem
        n = prob.n_images
        p = len(pts)
        # Z_j = Npp_inv_j sum_k (Nep_k)^T placed at the image of k  -> (p, 3, 6n)
        pos = np.full(prob.n_points, -1, np.int64)
        pos[pts] = np.arange(p)
        sel = np.flatnonzero(pos[prob.obs_point] >= 0)
        contrib = np.einsum("kab,kbc->kac", self.npp_inv[prob.obs_point[sel]],
                            np.transpose(self.nep_obs[sel], (0, 2, 1)))  # (s, 3, 6)
        z = np.zeros((p, 3, n, 6))
        np.add.at(z, (pos[prob.obs_point[sel]], slice(None), prob.obs_image[sel]),
                  contrib)
        z = z.reshape(3 * p, 6 * n)
        cov = z @ self.s_inv @ z.T
        d = np.zeros((3 * p, 3 * p))
        for a in range(3):
            for b in range(3):
                d[a::3, b::3] += np.diag(self.npp_inv[pts, a, b])
        if self.offset_cofactor is not None:  # the database offsets' share
            qb = self.offset_qb[pts].reshape(3 * p, -1)
            cov = cov + qb @ self.offset_cofactor @ qb.T
        return self.variance_factor * (d + cov)


# --------------------------------------------------------------------------- the kernel
#: observations per block: few numpy calls per point, temporaries of a few MB (the calls'
#: overhead costs more than the cache misses: the 10^6 pair took 5.5-5.8 s with 2048,
#: 3.8-4.6 s with 16384)
_CHUNK_OBS = 16384


@dataclass
class _Block:
    """``g`` points seen by the same ``c`` images, observations laid out by image.

    Every array is ``(c, ..., g)``: the camera values of a column are scalars that
    broadcast over the points, sums over a point's images are sums over axis 0, sums
    over an image's points are matrix products.
    """

    images: np.ndarray  # (c,)
    idx6: np.ndarray  # (6c,) rows of these images' EO in the reduced system
    points: np.ndarray  # (g,)
    obs: np.ndarray  # (c, g) observation indices
    xy: np.ndarray  # (c, 2, g) observed photo coordinates
    sw: np.ndarray  # (c, 2, g) square roots of the weights
    repeated: bool  # an image occurs twice in the set (a point measured twice on it)
    pw: np.ndarray  # (3, 3, g) prior weights of the points
    prior: np.ndarray  # (3, g) prior coordinates (0 where there is no prior)
    has: np.ndarray  # (g,) whether the point has a prior
    rpc_cols: Optional[np.ndarray] = None  # positions of the RPC images among ``images``


@dataclass
class _Layout:
    """The observations in blocks, and the points without image observations."""

    blocks: list
    lonely: np.ndarray
    has_prior: np.ndarray


def _layout(prob: BundleProblem, groups: _Groups) -> _Layout:
    """Cut the image-set groups into cache-sized blocks (done once per adjustment)."""
    blocks = []
    six = np.arange(6)
    sw_all = 1.0 / prob.obs_sigma
    has = prob.has_prior
    is_rpc = prob.is_rpc
    for imgs, pts, obs in zip(groups.images, groups.points, groups.obs):
        c = len(imgs)
        step = max(1, _CHUNK_OBS // c)
        idx6 = (6 * np.asarray(imgs, np.int64)[:, None] + six).ravel()
        repeated = len(np.unique(imgs)) < c
        for lo in range(0, len(pts), step):
            o = np.ascontiguousarray(obs[lo:lo + step].T)  # (c, g)
            p = pts[lo:lo + step]
            blocks.append(_Block(
                images=np.asarray(imgs, np.int64), idx6=idx6, points=p, obs=o,
                xy=np.ascontiguousarray(prob.obs_xy[o].transpose(0, 2, 1)),
                sw=np.ascontiguousarray(sw_all[o].transpose(0, 2, 1)), repeated=repeated,
                pw=np.ascontiguousarray(prob.prior_weight[p].transpose(1, 2, 0)),
                prior=np.where(has[p], prob.prior_xyz[p].T, 0.0), has=has[p],
                rpc_cols=np.flatnonzero(is_rpc[imgs]) if is_rpc[imgs].any() else None))
    counts = np.bincount(prob.obs_point, minlength=prob.n_points)
    return _Layout(blocks, np.flatnonzero(counts == 0), has)


def _cameras(eo: np.ndarray):
    """Per image (once, not per observation): projection centre ``(n, 3)`` and
    ``[M; dM/domega; dM/dphi]`` stacked ``(n, 9, 3)``."""
    m = rotation_matrix(eo[:, 3], eo[:, 4], eo[:, 5])
    d = rotation_derivatives(eo[:, 3], eo[:, 4], eo[:, 5])
    return np.ascontiguousarray(eo[:, :3]), np.concatenate([m, d[:, 0], d[:, 1]], axis=1)


def _rays(blk: _Block, cams, xyz: np.ndarray, rows: int = 9) -> np.ndarray:
    """``r, s, q`` (and their omega, phi derivatives with ``rows = 9``), ``(c, rows, g)``,
    and the block's points ``(3, g)``."""
    centre, mats = cams
    xg = xyz[blk.points].T
    d = xg[None, :, :] - centre[blk.images][:, :, None]  # (c, 3, g)
    return mats[blk.images, :rows] @ d, xg


def _linearise(blk: _Block, cams, xyz: np.ndarray, f: float, pp: np.ndarray):
    """Misclosures ``(c, 2, g)`` (observed minus computed), the design rows, the points.

    The rows ``(c, 2, 9, g)`` are the partials of ``x, y`` with respect to
    ``XL, YL, ZL, omega, phi, kappa, XA, YA, ZA`` (DESIGN section 2; with
    ``a = f/q``: ``dx/dtheta = a (r/q dq/dtheta - dr/dtheta)``, ``dx/dXA = a (r/q m3 - m1)``).
    """
    rr, xg = _rays(blk, cams, xyz)
    r, s, q = rr[:, 0], rr[:, 1], rr[:, 2]
    a = f / q
    xr = r / q
    ys = s / q
    m = cams[1][blk.images]  # (c, 9, 3): rows m1, m2, m3 first
    c, g = r.shape
    b = np.empty((c, 2, 9, g))
    b[:, 0, 6:] = a[:, None] * (xr[:, None] * m[:, 2, :, None] - m[:, 0, :, None])
    b[:, 1, 6:] = a[:, None] * (ys[:, None] * m[:, 2, :, None] - m[:, 1, :, None])
    np.negative(b[:, :, 6:], out=b[:, :, :3])
    b[:, 0, 3] = a * (xr * rr[:, 5] - rr[:, 3])
    b[:, 0, 4] = a * (xr * rr[:, 8] - rr[:, 6])
    b[:, 0, 5] = -a * s
    b[:, 1, 3] = a * (ys * rr[:, 5] - rr[:, 4])
    b[:, 1, 4] = a * (ys * rr[:, 8] - rr[:, 7])
    b[:, 1, 5] = a * r
    ell = np.empty((c, 2, g))
    ell[:, 0] = blk.xy[:, 0] - (pp[0] - f * xr)
    ell[:, 1] = blk.xy[:, 1] - (pp[1] - f * ys)
    return ell, b, xg


def _linearise_block(blk: _Block, cams, xyz: np.ndarray, prob: BundleProblem, eo: np.ndarray):
    """:func:`_linearise` through each image's sensor model: the frame images of the block
    by the collinearity equations, its RPC images (``blk.rpc_cols``) by
    :func:`vectoradjust.sensor.models.observe_rpc` (pixels, bias parameters)."""
    f, pp = float(prob.focal_length), prob.principal_point
    if blk.rpc_cols is None:
        return _linearise(blk, cams, xyz, f, pp)
    c, g = len(blk.images), len(blk.points)
    xg = xyz[blk.points].T
    ell, b = np.empty((c, 2, g)), np.empty((c, 2, 9, g))
    frame_cols = np.setdiff1d(np.arange(c), blk.rpc_cols)
    if frame_cols.size:
        sub = replace(blk, images=blk.images[frame_cols], xy=blk.xy[frame_cols])
        ell[frame_cols], b[frame_cols], _ = _linearise(sub, cams, xyz, f, pp)
    llh, jac = prob.sensors.frame.to_geodetic(xg.T)
    for j in blk.rpc_cols.tolist():
        i = int(blk.images[j])
        colrow, d_par, d_xyz = observe_rpc(prob.sensors.rpc[i], eo[i], llh, jac)
        ell[j] = blk.xy[j] - colrow.T
        b[j, :, :6] = d_par.transpose(1, 2, 0)
        b[j, :, 6:] = d_xyz.transpose(1, 2, 0)
    return ell, b, xg


def _block_normals(blk: _Block, ell: np.ndarray, b: np.ndarray, nep: np.ndarray):
    """Normal-equation pieces of a block from its weighted design rows.

    Returns ``nee (c, 6, 6)``, ``te (c, 6)`` per image, ``npp (3, 3, g)``, ``tp (3, g)``
    per point (image observations only) and the block's ``v'Pv``; fills ``nep
    (c, 6, 3, g)`` per observation.
    """
    b *= blk.sw[:, :, None, :]
    ell *= blk.sw
    c, _, _, g = b.shape
    e = b[:, :, :6].transpose(0, 2, 1, 3).reshape(c, 6, 2 * g)
    lw = ell.reshape(c, 2 * g)
    nee = e @ e.transpose(0, 2, 1)
    te = (e @ lw[:, :, None])[:, :, 0]
    tp = (b[:, :, 6:] * ell[:, :, None, :]).sum(axis=(0, 1))
    np.multiply(b[:, 0, :6, None, :], b[:, 0, None, 6:, :], out=nep)
    nep += b[:, 1, :6, None, :] * b[:, 1, None, 6:, :]
    if blk.rpc_cols is None:
        npp = -nep[:, :3].sum(axis=0)  # the position rows are minus the point rows
    else:  # an RPC image's parameters are no position: the point rows' own products
        npp = np.einsum("caig,cajg->ijg", b[:, :, 6:], b[:, :, 6:])
    return nee, te, npp, tp, float((lw * lw).sum())


def _add_point_priors(blk: _Block, xg: np.ndarray, npp: np.ndarray, tp: np.ndarray) -> None:
    """Add the coordinate priors of the block's points to ``npp (3, 3, g)``, ``tp (3, g)``."""
    npp += blk.pw
    d = np.where(blk.has, blk.prior - xg, 0.0)
    tp += (blk.pw * d[None, :, :]).sum(axis=1)


def _inv_sym3(a: np.ndarray):
    """Inverse and determinant of symmetric 3x3 blocks laid out ``(3, 3, g)``."""
    a00, a01, a02, a11, a12, a22 = a[0, 0], a[0, 1], a[0, 2], a[1, 1], a[1, 2], a[2, 2]
    c00 = a11 * a22 - a12 * a12
    c01 = a02 * a12 - a01 * a22
    c02 = a01 * a12 - a02 * a11
    c11 = a00 * a22 - a02 * a02
    c12 = a02 * a01 - a00 * a12
    c22 = a00 * a11 - a01 * a01
    det = a00 * c00 + a01 * c01 + a02 * c02
    with np.errstate(divide="ignore", invalid="ignore"):
        r = 1.0 / det
    inv = np.empty_like(a)
    inv[0, 0] = c00 * r
    inv[1, 1] = c11 * r
    inv[2, 2] = c22 * r
    inv[0, 1] = inv[1, 0] = c01 * r
    inv[0, 2] = inv[2, 0] = c02 * r
    inv[1, 2] = inv[2, 1] = c12 * r
    return inv, det


def _undetermined(det: np.ndarray, trace: np.ndarray) -> np.ndarray:
    """Positions of numerically singular point blocks (same test as the dense check)."""
    scale = trace**3
    return np.flatnonzero(~(np.abs(det) > 1e-12 * np.maximum(scale, 1e-300)))


def _times_cholesky(nep: np.ndarray, inv: np.ndarray) -> np.ndarray:
    """``U = N_ep L`` per observation with ``N_pp^-1 = L L'`` (closed form), so that
    ``N_ep N_pp^-1 N_pe = U U'`` (one symmetric product per block)."""
    l00 = np.sqrt(inv[0, 0])
    l10 = inv[1, 0] / l00
    l20 = inv[2, 0] / l00
    l11 = np.sqrt(inv[1, 1] - l10 * l10)
    l21 = (inv[2, 1] - l20 * l10) / l11
    l22 = np.sqrt(inv[2, 2] - l20 * l20 - l21 * l21)
    n0, n1, n2 = nep[:, :, 0], nep[:, :, 1], nep[:, :, 2]
    u = np.empty_like(nep)
    u[:, :, 0] = n0 * l00 + n1 * l10 + n2 * l20
    u[:, :, 1] = n1 * l11 + n2 * l21
    u[:, :, 2] = n2 * l22
    return u


def _times_inverse(nep: np.ndarray, inv: np.ndarray) -> np.ndarray:
    """``Y = N_ep N_pp^-1`` per observation, ``(c, 6, 3, g)``, explicit products."""
    y = nep[:, :, 0:1] * inv[0]
    y += nep[:, :, 1:2] * inv[1]
    y += nep[:, :, 2:3] * inv[2]
    return y


def _add_block(s: np.ndarray, rhs: np.ndarray, blk: _Block, loc: np.ndarray,
               r6: np.ndarray) -> None:
    """Scatter a block's ``(6c, 6c)`` reduced-system share and right-hand side."""
    if blk.repeated:
        np.add.at(s, np.ix_(blk.idx6, blk.idx6), loc)
        np.add.at(rhs, blk.idx6, r6)
    else:
        s[np.ix_(blk.idx6, blk.idx6)] += loc
        rhs[blk.idx6] += r6


@dataclass
class _Step:
    """One Gauss-Newton step: the corrections and the normal-equation pieces it used."""

    dx_e: np.ndarray
    dx_p: np.ndarray
    vtpv_image: float
    parts: list  # per block: (nep (c, 6, 3, g), npp^-1 (3, 3, g))
    lonely_inv: np.ndarray  # npp^-1 of the points without image observations
    factor: tuple
    eo: np.ndarray  # the linearisation point
    xyz: np.ndarray
    #: free network: what to subtract from the inverse of the regularised system
    free_corr: Optional[np.ndarray] = None


def _eliminate_points(prob: BundleProblem, lay: _Layout, eo: np.ndarray, xyz: np.ndarray,
                      check_points: bool):
    """Reduced camera system ``S dx_e = rhs`` with the points eliminated, block by block."""
    n = prob.n_images
    cams = _cameras(eo)
    s = np.zeros((6 * n, 6 * n))
    rhs = np.zeros(6 * n)
    parts, tps, bad = [], [], []
    vtpv = 0.0
    # every block's N_ep in one buffer: freed in one piece (memory back to the system)
    buf = np.empty(18 * len(prob.obs_point))
    at = 0
    for blk in lay.blocks:
        ell, b, xg = _linearise_block(blk, cams, xyz, prob, eo)
        c, g = len(blk.images), len(blk.points)
        nep = buf[at:at + 18 * c * g].reshape(c, 6, 3, g)
        at += 18 * c * g
        nee, te, npp, tp, vv = _block_normals(blk, ell, b, nep)
        vtpv += vv
        _add_point_priors(blk, xg, npp, tp)
        inv, det = _inv_sym3(npp)
        if check_points:
            bad.append(blk.points[_undetermined(det, npp[0, 0] + npp[1, 1] + npp[2, 2])])
        with np.errstate(invalid="ignore"):  # undetermined points: raised below
            ur = _times_cholesky(nep, inv).reshape(6 * c, 3 * g)
            loc = -(ur @ ur.T)
        diag = loc.reshape(c, 6, c, 6)
        diag[np.arange(c), :, np.arange(c), :] += nee
        itp = (inv * tp[None]).sum(axis=1)  # N_pp^-1 t_p
        _add_block(s, rhs, blk, loc, te.ravel() - nep.reshape(6 * c, 3 * g) @ itp.ravel())
        parts.append((nep, inv))
        tps.append(tp)
    lonely_npp = prob.prior_weight[lay.lonely]
    if check_points:
        det = np.linalg.det(lonely_npp) if len(lay.lonely) else np.zeros(0)
        bad.append(lay.lonely[_undetermined(det, np.einsum("mii->m", lonely_npp))])
        _raise_undetermined(np.concatenate(bad))
    # EO priors
    we = prob.eo_weight
    s[np.arange(6 * n), np.arange(6 * n)] += we.ravel()
    rhs += (we * np.where(we > 0, prob.eo0 - eo, 0.0)).ravel()
    _hold_fixed(s, rhs, prob.eo_fixed.ravel())
    return s, rhs, parts, tps, inv3x3(lonely_npp), vtpv


def _hold_fixed(s: np.ndarray, rhs: np.ndarray, fixed: np.ndarray) -> None:
    """Take fixed parameters out of the reduced system (unit diagonal, no coupling, zero
    right-hand side), so that their corrections are zero."""
    if fixed.any():
        s[fixed, :] = 0.0
        s[:, fixed] = 0.0
        s[fixed, fixed] = 1.0
        rhs[fixed] = 0.0


def _raise_undetermined(bad: np.ndarray) -> None:
    """Raise :class:`SingularityError` naming the points that cannot be determined."""
    if bad.size:
        bad = np.sort(bad)
        raise SingularityError(
            f"{bad.size} object point(s) cannot be determined (e.g. point index {bad[0]}): "
            "a point without a coordinate prior must be measured on at least two images",
            "Measure tie points on two or more images, or remove them from the measurements",
            details={"points": bad.tolist()},
        )


def _solve_reduced(s: np.ndarray, rhs: np.ndarray):
    """Cholesky factor of the reduced camera system and its solution ``(n, 6)``."""
    try:
        factor = scipy.linalg.cho_factor(s, lower=False, check_finite=True)
        dx_e = scipy.linalg.cho_solve(factor, rhs).reshape(-1, 6)
    except (np.linalg.LinAlgError, ValueError) as exc:
        raise SingularityError(
            "The reduced normal equations are singular: the exterior orientation is not "
            "determined (datum defect)",
            "Give at least 3 well-spread, non-collinear control points measured on the "
            "images, or priors on the exterior orientation",
        ) from exc
    return factor, dx_e


def _gauss_newton_step(prob: BundleProblem, lay: _Layout, eo: np.ndarray, xyz: np.ndarray,
                       check_points: bool) -> _Step:
    """Corrections of one iteration: reduced camera system, then point back-substitution."""
    s, rhs, parts, tps, lonely_inv, vtpv = _eliminate_points(prob, lay, eo, xyz, check_points)
    free_corr = None
    if prob.free_datum:  # inner constraints over the cameras (the minimum-norm step)
        g2, a, free_corr = free_network_correction(eo, s)
        s += a * (g2 @ g2.T)
    factor, dx_e = _solve_reduced(s, rhs)
    dx_p = np.zeros((prob.n_points, 3))
    flat = dx_e.ravel()
    for blk, (nep, inv), tp in zip(lay.blocks, parts, tps):
        c, g = len(blk.images), len(blk.points)
        v = tp - (flat[blk.idx6] @ nep.reshape(6 * c, 3 * g)).reshape(3, g)
        dx_p[blk.points] = (inv * v[None]).sum(axis=1).T
    if len(lay.lonely):
        lo = lay.lonely
        d = np.where(lay.has_prior[lo, None], prob.prior_xyz[lo] - xyz[lo], 0.0)
        tp = np.einsum("mij,mj->mi", prob.prior_weight[lo], d)
        dx_p[lo] = np.einsum("mij,mj->mi", lonely_inv, tp)
    return _Step(dx_e=dx_e, dx_p=dx_p, vtpv_image=vtpv, parts=parts, lonely_inv=lonely_inv,
                 factor=factor, eo=eo.copy(), xyz=xyz.copy(), free_corr=free_corr)


def _check_diverged(it: int, max_pos: float, max_ang: float, history: list) -> None:
    """Raise :class:`NonConvergenceError` on non-finite or too large corrections."""
    if not (np.isfinite(max_pos) and np.isfinite(max_ang)) or max_ang > 1.0:
        raise NonConvergenceError(
            f"The adjustment diverged at iteration {it} (corrections of "
            f"{max_pos:.3g} m and {max_ang:.3g} rad)",
            "Check the approximate exterior orientation in [[images]] (position within "
            "a fraction of the flying height, attitude in degrees) and the image measurement "
            "units (mm)",
            details={"iteration": it, "history": history},
        )


def _raise_not_converged(max_iterations: int, history: list) -> None:
    """Raise :class:`NonConvergenceError` for an iteration that ran out of steps."""
    raise NonConvergenceError(
        f"The adjustment did not converge in {max_iterations} iterations (last corrections "
        f"{history[-1]['max_position_correction']:.3g} m, "
        f"{history[-1]['max_angle_correction']:.3g} rad)",
        "Raise [adjustment] max_iterations, improve the approximate exterior orientation, "
        "or look for blunders in the measurements",
        details={"history": history},
    )


def _final_residuals(prob: BundleProblem, lay: _Layout, eo: np.ndarray,
                     xyz: np.ndarray) -> np.ndarray:
    """Image residuals (adjusted minus observed, ``(k, 2)``) at the estimate; raises if a
    point ends up behind a camera."""
    cams = _cameras(eo)
    f, pp = float(prob.focal_length), prob.principal_point
    v = np.empty((len(prob.obs_point), 2))
    behind = len(prob.obs_point)
    for blk in lay.blocks:
        if blk.rpc_cols is not None:  # pixels of the RPC images; the frame images below
            ell, _, _ = _linearise_block(blk, cams, xyz, prob, eo)
            v[blk.obs] = -ell.transpose(0, 2, 1)
            fc = np.setdiff1d(np.arange(len(blk.images)), blk.rpc_cols)
            if not fc.size:
                continue
            blk = replace(blk, images=blk.images[fc], xy=blk.xy[fc], obs=blk.obs[fc])
        rr, _ = _rays(blk, cams, xyz, rows=3)
        q = rr[:, 2]
        if np.any(q >= 0):
            behind = min(behind, int(blk.obs[q >= 0].min()))
        v[blk.obs, 0] = (pp[0] - f * (rr[:, 0] / q)) - blk.xy[:, 0]
        v[blk.obs, 1] = (pp[1] - f * (rr[:, 1] / q)) - blk.xy[:, 1]
    if behind < len(prob.obs_point):
        raise NonConvergenceError(
            f"The adjustment converged to a solution with object points behind the camera "
            f"(observation {behind})",
            "Check the approximate exterior orientation and the sign of the photo coordinates "
            "(x right, y up, mm)",
        )
    return v


def _kept_arrays(prob: BundleProblem, lay: _Layout, step: _Step, s_inv: np.ndarray,
                 compute_covariance: bool):
    """The last step's factorisation in observation order, and the point cofactors.

    Returns ``a_eo (k, 2, 6)``, ``a_pt (k, 2, 3)``, ``nep (k, 6, 3)``, ``npp_inv (m, 3, 3)``
    and ``N_pp^-1 + N_pp^-1 N_pe S^-1 N_ep N_pp^-1`` per point (None without covariances):
    the exact 3x3 blocks of ``N^-1``, from ``S^-1`` restricted to each block's images.
    The step's blocks are released before the partials are recomputed (peak memory).
    """
    k, m = len(prob.obs_point), prob.n_points
    nep_obs, npp_inv = np.empty((k, 6, 3)), np.empty((m, 3, 3))
    q = np.empty((m, 3, 3)) if compute_covariance else None
    nep2, npp_inv2 = nep_obs.reshape(k, 18), npp_inv.reshape(m, 9)
    for i, blk in enumerate(lay.blocks):
        nep, inv = step.parts[i]
        c, g = len(blk.images), len(blk.points)
        nep2[blk.obs.ravel()] = nep.reshape(c, 18, g).transpose(0, 2, 1).reshape(c * g, 18)
        npp_inv2[blk.points] = inv.reshape(9, g).T
        if compute_covariance:
            y = _times_inverse(nep, inv).reshape(6 * c, 3, g)
            # einsum, not BLAS: a wide product that a threaded BLAS splits badly on a busy machine
            t = np.einsum("ab,bmg->amg", s_inv[np.ix_(blk.idx6, blk.idx6)], y)
            qb = inv + (y[:, :, None, :] * t[:, None, :, :]).sum(axis=0)
            q[blk.points] = (0.5 * (qb + qb.transpose(1, 0, 2))).transpose(2, 0, 1)
    step.parts = []  # the one N_ep buffer goes back to the system here ...
    nep = inv = y = t = None  # ... once no view of it is left
    npp_inv[lay.lonely] = step.lonely_inv
    if compute_covariance:
        q[lay.lonely] = 0.5 * (step.lonely_inv + step.lonely_inv.transpose(0, 2, 1))
    a_eo, a_pt = _kept_partials(prob, lay, step)
    return a_eo, a_pt, nep_obs, npp_inv, q


def _kept_partials(prob: BundleProblem, lay: _Layout, step: _Step):
    """Unweighted partials ``a_eo (k, 2, 6)``, ``a_pt (k, 2, 3)`` at the last step's point."""
    k = len(prob.obs_point)
    a_eo, a_pt = np.empty((k, 2, 6)), np.empty((k, 2, 3))
    a_eo2, a_pt2 = a_eo.reshape(k, 12), a_pt.reshape(k, 6)
    cams = _cameras(step.eo)
    for blk in lay.blocks:
        _, b, _ = _linearise_block(blk, cams, step.xyz, prob, step.eo)
        c, g = len(blk.images), len(blk.points)
        rows = blk.obs.ravel()
        bt = b.reshape(c, 18, g).transpose(0, 2, 1).reshape(c * g, 2, 9)
        a_eo2[rows] = bt[:, :, :6].reshape(c * g, 12)
        a_pt2[rows] = bt[:, :, 6:].reshape(c * g, 6)
    return a_eo, a_pt


def _converged_result(prob: BundleProblem, lay: _Layout, eo: np.ndarray, xyz: np.ndarray,
                      step: _Step, it: int, history: list,
                      compute_covariance: bool) -> BundleResult:
    """Residuals, sigma0 and covariances at the converged estimate, as a BundleResult."""
    v_image = _final_residuals(prob, lay, eo, xyz)
    vtpv = _vtpv(prob, v_image, xyz, eo)
    n_obs, n_unk = prob.counts()
    dof = n_obs - n_unk
    s0sq = vtpv / dof if dof > 0 else float("nan")
    n = prob.n_images
    s_inv = scipy.linalg.cho_solve(step.factor, np.eye(6 * n))
    if step.free_corr is not None:  # the pseudo-inverse: inner constraints over the cameras
        s_inv = s_inv - step.free_corr
    s_inv = 0.5 * (s_inv + s_inv.T)
    fixed = prob.eo_fixed
    if fixed.any():  # held parameters have no variance
        s_inv[fixed.ravel(), :] = 0.0
        s_inv[:, fixed.ravel()] = 0.0
    vf = s0sq if np.isfinite(s0sq) else 1.0
    eo_cov = vf * s_inv.reshape(n, 6, n, 6)[np.arange(n), :, np.arange(n), :]
    a_eo, a_pt, nep, npp_inv, q = _kept_arrays(prob, lay, step, s_inv, compute_covariance)
    point_cov = None if q is None else vf * q
    has_prior = lay.has_prior
    v_point = np.where(has_prior[:, None], xyz - prob.prior_xyz, np.nan)
    we = prob.eo_weight
    v_eo = np.where((we > 0) & ~fixed, eo - prob.eo0, np.nan)
    return BundleResult(
        eo=eo, xyz=xyz, eo_cov=eo_cov, point_cov=point_cov, v_image=v_image,
        v_point=v_point, v_eo=v_eo, vtpv=float(vtpv), n_obs=n_obs, n_unknowns=n_unk, dof=dof,
        sigma0_squared=float(s0sq), iterations=it, converged=True, history=history,
        s_inv=s_inv, npp_inv=npp_inv, nep_obs=nep, a_eo=a_eo, a_pt=a_pt, problem=prob,
    )


def adjust(
    prob: BundleProblem,
    *,
    max_iterations: int = 20,
    tolerance_position: float = 1e-4,
    tolerance_angle: float = 1e-8,
    progress: Optional[ProgressCallback] = None,
    is_cancelled: Optional[Callable[[], bool]] = None,
    compute_covariance: bool = True,
) -> BundleResult:
    """Run the Gauss-Newton bundle adjustment.

    Parameters
    ----------
    prob : BundleProblem
    max_iterations : int
    tolerance_position : float
        Converged when every position correction (m) is below this ...
    tolerance_angle : float
        ... and every angle correction (rad) below this.
    progress : callable, optional
        ``progress(fraction, message)``.
    is_cancelled : callable, optional
        Polled once per iteration; a true value raises :class:`CancelledError`.
    compute_covariance : bool
        Whether to compute the a-posteriori covariances of the points.

    Returns
    -------
    BundleResult

    Raises
    ------
    NonConvergenceError
        If the iteration diverges or does not converge within ``max_iterations``.
    SingularityError
        If the normal equations are singular (datum defect, undetermined points).
    """
    with _single_blas_thread():
        return _iterate(prob, max_iterations, tolerance_position, tolerance_angle, progress,
                        is_cancelled, compute_covariance)


def _iterate(prob: BundleProblem, max_iterations: int, tolerance_position: float,
             tolerance_angle: float, progress: Optional[ProgressCallback],
             is_cancelled: Optional[Callable[[], bool]],
             compute_covariance: bool) -> BundleResult:
    """The Gauss-Newton iteration of :func:`adjust` and its converged result."""
    eo = (prob.eo0 if prob.eo_start is None else np.asarray(prob.eo_start, float)).copy()
    xyz = prob.xyz0.copy()
    lay = _layout(prob, _group_observations(prob.obs_point, prob.obs_image, prob.n_points))
    history: list = []
    converged = False
    best = np.inf
    it = 0
    for it in range(1, max_iterations + 1):
        if is_cancelled is not None and is_cancelled():
            raise CancelledError("The adjustment was cancelled", "Run it again when ready")
        step = None  # free the previous step's blocks before building the next
        step = _gauss_newton_step(prob, lay, eo, xyz, check_points=it == 1)
        vtpv_now = step.vtpv_image + _prior_vtpv(prob, lay.has_prior, xyz, eo)
        max_pos, max_ang, max_bias = _largest_corrections(prob, step)
        history.append({"iteration": it, "vtpv": vtpv_now, "max_position_correction": max_pos,
                        "max_angle_correction": max_ang})
        if prob.sensors is not None and prob.is_rpc.any():
            history[-1]["max_bias_correction"] = max_bias
        _check_diverged(it, max_pos, max_ang + max_bias / 1e4, history)
        best = min(best, vtpv_now)
        eo += step.dx_e
        xyz += step.dx_p
        if progress is not None:
            progress(min(0.9, it / max_iterations), f"iteration {it}: v'Pv = {vtpv_now:.6g}")
        if max_pos < tolerance_position and max_ang < tolerance_angle and max_bias < TOLERANCE_BIAS:
            converged = True
            break
    if not converged:
        _raise_not_converged(max_iterations, history)
    result = _converged_result(prob, lay, eo, xyz, step, it, history, compute_covariance)
    if progress is not None:
        progress(1.0, f"converged after {it} iterations")
    return result


#: an RPC image's bias parameters are converged when every correction is below this (px)
TOLERANCE_BIAS = 1e-5


def _largest_corrections(prob: BundleProblem, step: _Step) -> tuple[float, float, float]:
    """Largest position (m: frame cameras and points), angle (rad: frame cameras) and
    bias (px: RPC images) correction of a step."""
    rpc = prob.is_rpc
    frame = step.dx_e[~rpc]
    max_pos = max(np.abs(frame[:, :3]).max(initial=0.0), np.abs(step.dx_p).max(initial=0.0))
    max_ang = float(np.abs(frame[:, 3:]).max(initial=0.0))
    max_bias = float(np.abs(step.dx_e[rpc]).max(initial=0.0))
    return float(max_pos), max_ang, max_bias


def _prior_vtpv(prob: BundleProblem, has: np.ndarray, xyz: np.ndarray, eo: np.ndarray) -> float:
    """``v'Pv`` of the point and EO priors."""
    d = np.where(has[:, None], xyz - prob.prior_xyz, 0.0)
    total = float(np.einsum("mi,mij,mj->", d, prob.prior_weight, d))
    we = prob.eo_weight
    de = np.where(we > 0, eo - prob.eo0, 0.0)
    return total + float(np.sum(we * de * de))


def _vtpv(prob: BundleProblem, ell: np.ndarray, xyz: np.ndarray, eo: np.ndarray) -> float:
    w = 1.0 / prob.obs_sigma**2
    total = float(np.sum(ell * ell * w))
    d = np.where(prob.has_prior[:, None], xyz - prob.prior_xyz, 0.0)
    total += float(np.einsum("mi,mij,mj->", d, prob.prior_weight, d))
    we = prob.eo_weight
    de = np.where(we > 0, eo - prob.eo0, 0.0)
    total += float(np.sum(we * de * de))
    return total


def intersect(
    eo: np.ndarray,
    obs_point: np.ndarray,
    obs_image: np.ndarray,
    obs_xy: np.ndarray,
    obs_sigma: np.ndarray,
    n_points: int,
    focal_length: float,
    principal_point=(0.0, 0.0),
    *,
    eo_cov_full: Optional[np.ndarray] = None,
    variance_factor: float = 1.0,
    max_iterations: int = 20,
    tolerance: float = 1e-6,
    sensors: Optional[SensorSet] = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Forward intersection of points from fixed (adjusted) exterior orientation.

    Used for check points, which stay out of the adjustment. The covariance includes
    the exterior orientation's uncertainty:
    ``C = s0^2 Npp^-1 + Npp^-1 N_pe C_ee N_ep Npp^-1``.

    Parameters
    ----------
    eo : numpy.ndarray, shape (n, 6)
    obs_point, obs_image : numpy.ndarray of int, shape (k,)
    obs_xy, obs_sigma : numpy.ndarray, shape (k, 2)
    n_points : int
    focal_length : float
    principal_point : (float, float)
    eo_cov_full : numpy.ndarray, shape (6n, 6n), optional
        Full a-posteriori covariance of all exterior orientations.
    variance_factor : float
        sigma0^2 applied to the image weights' cofactors.
    max_iterations : int
    tolerance : float
        Largest coordinate correction (m) at convergence.
    sensors : SensorSet, optional
        The images' sensor models (RPC images: ``eo`` rows are their bias parameters and
        ``obs_xy`` pixels); None: frame cameras.

    Returns
    -------
    xyz : numpy.ndarray, shape (n_points, 3)
        NaN for points with fewer than two rays.
    cov : numpy.ndarray, shape (n_points, 3, 3)
    """
    pp = np.asarray(principal_point, float)
    if sensors is None or not sensors.is_rpc.any():
        xyz = ray_intersection(eo, obs_point, obs_image, obs_xy, n_points, focal_length, pp)
    else:
        xyz = approximate_points(sensors, eo, obs_point, obs_image, obs_xy, n_points,
                                 focal_length, pp)
    ok = np.isfinite(xyz).all(axis=1)
    use = ok[obs_point]
    op, oi, oxy, osg = obs_point[use], obs_image[use], obs_xy[use], obs_sigma[use]
    x = np.where(ok[:, None], xyz, 0.0)
    w = 1.0 / osg**2
    for _ in range(max_iterations):
        pred, a_eo, a_pt = _observe(eo, oi, x[op], focal_length, pp, sensors)
        ell = oxy - pred
        wap = a_pt * w[:, :, None]
        npp = _block_sum(op, np.einsum("kri,krj->kij", a_pt, wap), n_points)
        npp[~ok] = np.eye(3)
        tp = _block_sum(op, np.einsum("kri,kr->ki", wap, ell), n_points)
        dx = np.einsum("mij,mj->mi", inv3x3(npp), tp)
        x += dx
        if np.abs(dx).max(initial=0.0) < tolerance:
            break
    _, a_eo, a_pt = _observe(eo, oi, x[op], focal_length, pp, sensors)
    wap = a_pt * w[:, :, None]
    npp = _block_sum(op, np.einsum("kri,krj->kij", a_pt, wap), n_points)
    npp[~ok] = np.eye(3)
    npp_inv = inv3x3(npp)
    cov = variance_factor * npp_inv
    if eo_cov_full is not None:
        n = eo.shape[0]
        nep = np.einsum("kri,krj->kij", a_eo * w[:, :, None], a_pt)  # (k, 6, 3)
        z = np.zeros((n_points, 3, n, 6))
        np.add.at(z, (op, slice(None), oi), np.transpose(nep, (0, 2, 1)))
        z = np.einsum("mab,mbc->mac", npp_inv, z.reshape(n_points, 3, 6 * n))
        cov = cov + np.einsum("mai,ij,mbj->mab", z, eo_cov_full, z)
    x[~ok] = np.nan
    cov[~ok] = np.nan
    return x, cov


def _observe(eo: np.ndarray, oi: np.ndarray, x: np.ndarray, focal_length: float,
             pp: np.ndarray, sensors: Optional[SensorSet]):
    """Computed image coordinates ``(k, 2)`` of points ``x (k, 3)`` on images ``oi`` and
    the partials ``a_eo (k, 2, 6)``, ``a_pt (k, 2, 3)``, each image through its model."""
    if sensors is None or not sensors.is_rpc[oi].any():
        pred = project(eo[oi], x, focal_length, pp)
        a_eo, a_pt = partials(eo[oi], x, focal_length)
        return pred, a_eo, a_pt
    k = len(oi)
    pred, a_eo, a_pt = np.empty((k, 2)), np.empty((k, 2, 6)), np.empty((k, 2, 3))
    rpc = sensors.is_rpc[oi]
    if (~rpc).any():
        pred[~rpc] = project(eo[oi[~rpc]], x[~rpc], focal_length, pp)
        a_eo[~rpc], a_pt[~rpc] = partials(eo[oi[~rpc]], x[~rpc], focal_length)
    llh, jac = sensors.frame.to_geodetic(x[rpc])
    sel = np.flatnonzero(rpc)
    for i in np.unique(oi[sel]).tolist():
        on = oi[sel] == i
        pred[sel[on]], a_eo[sel[on]], a_pt[sel[on]] = observe_rpc(
            sensors.rpc[i], eo[i], llh[on], jac[on])
    return pred, a_eo, a_pt
