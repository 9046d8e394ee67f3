"""The bundle problem (:class:`BundleProblem`) and its observations grouped by points that
share the same set of images.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Optional

import numpy as np

from vectoradjust.adjust.intersection import (  # noqa: F401 (inv3x3, ray_intersection: API)
    _block_sum,
    approximate_points,
    inv3x3,
    ray_intersection,
)
from vectoradjust.sensor.models import SensorSet

__all__ = ["BundleProblem"]


ProgressCallback = Callable[[float, str], None]



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
        """Number of observations ``n`` and of unknowns ``u`` (docs/method.md section 3)."""
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

