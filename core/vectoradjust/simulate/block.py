"""A simulated photogrammetric block with known truth, as a bundle problem.

:func:`make_block` lays out ``n_strips`` east-west strips of ``images_per_strip``
vertical photographs of the dissertation's camera (Wild RC10, ``f = 152.4 mm``, 23 x 23
cm, 1:4000) with a given forward and side overlap (60 % / 30 % by default), scatters
control, tie and road shape points over the area seen on at least two images, and
returns the :class:`~vectoradjust.adjust.bundle.BundleProblem` of their image
measurements together with the true exterior orientation and the true points. A stereo
pair is ``make_block(n_strips=1, images_per_strip=2)``.

It is built for speed tests (``benchmarks/``) and for tests of the solver against its
truth: everything is vectorised over points (a few seconds for a million points), and
every random component draws from its own stream (:func:`vectoradjust.simulate.geometry._rng`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vectoradjust.adjust.bundle import BundleProblem
from vectoradjust.simulate.geometry import (
    CENTER,
    CONTROL_SIGMA,
    FLYING_HEIGHT,
    FOCAL_LENGTH,
    FORMAT_HALF,
    GROUND_HALF,
    TERRAIN_LEVEL,
    _rng,
    terrain_height,
)
from vectoradjust.simulate.physics import image_of

__all__ = ["SimulatedBlock", "make_block"]

_CHUNK = 131_072  # points projected at a time (memory of the candidate test)


@dataclass
class SimulatedBlock:
    """A simulated block: the bundle problem and the truth it was drawn from.

    Attributes
    ----------
    problem : BundleProblem
        Image measurements (noisy), priors and approximate values.
    true_eo : numpy.ndarray, shape (n, 6)
        True exterior orientation (m, rad).
    true_xyz : numpy.ndarray, shape (m, 3)
        True object points.
    point_kind : numpy.ndarray of str, shape (m,)
        ``"control"``, ``"tie"`` or ``"shape"``.
    strip, column : numpy.ndarray of int, shape (n,)
        Strip and position in the strip of every image.
    """

    problem: BundleProblem
    true_eo: np.ndarray
    true_xyz: np.ndarray
    point_kind: np.ndarray
    strip: np.ndarray
    column: np.ndarray


def _layout(n_strips: int, per_strip: int, forward: float, side: float, center, seed: int,
            position_noise: float, attitude_noise: float):
    """Flight plan and true EO: strips along X, stacked along Y, alternating direction."""
    base = (1.0 - forward) * 2.0 * GROUND_HALF
    spacing = (1.0 - side) * 2.0 * GROUND_HALF
    strip = np.repeat(np.arange(n_strips), per_strip)
    column = np.tile(np.arange(per_strip), n_strips)
    plan = np.column_stack([
        center[0] + (column - (per_strip - 1) / 2.0) * base,
        center[1] + (strip - (n_strips - 1) / 2.0) * spacing,
    ])
    n = len(strip)
    rng = _rng(seed, "block-eo")
    eo = np.zeros((n, 6))
    eo[:, :2] = plan + rng.normal(0.0, position_noise, (n, 2))
    eo[:, 2] = TERRAIN_LEVEL + FLYING_HEIGHT + rng.normal(0.0, position_noise / 2.0, n)
    eo[:, 3:] = np.radians(rng.normal(0.0, attitude_noise, (n, 3)))
    eo[strip % 2 == 1, 5] += np.pi  # every other strip flown west
    return eo, plan, base, spacing, strip, column


def _seen(xyz: np.ndarray, eo: np.ndarray, plan: np.ndarray, base: float, spacing: float,
          per_strip: int, n_strips: int):
    """Images (inside the format) of each point: candidate neighbours, then the test.

    Returns point index, image index and ideal photo coordinates of every sighting.
    """
    x0, y0 = plan[0]
    col = np.floor((xyz[:, 0] - x0) / base).astype(np.int64)
    row = np.floor((xyz[:, 1] - y0) / spacing).astype(np.int64)
    dc = np.arange(-2, 4)
    dr = np.arange(-1, 3)
    cc = (col[:, None, None] + dc[None, None, :]).repeat(len(dr), 1)
    rr = (row[:, None, None] + dr[None, :, None]).repeat(len(dc), 2)
    cc, rr = cc.reshape(len(xyz), -1), rr.reshape(len(xyz), -1)
    valid = (cc >= 0) & (cc < per_strip) & (rr >= 0) & (rr < n_strips)
    pi, slot = np.nonzero(valid)
    ii = rr[pi, slot] * per_strip + cc[pi, slot]
    xy = image_of(eo[ii], xyz[pi], FOCAL_LENGTH)  # the independent projection (physics.py)
    inside = np.all(np.abs(xy) < FORMAT_HALF - 1.0, axis=1)
    return pi[inside], ii[inside], xy[inside]


def _scatter_points(n: int, eo, plan, base, spacing, per_strip, n_strips, rng, center):
    """``n`` points uniform over the area seen on >= 2 images, with their sightings."""
    lo = plan.min(axis=0) - GROUND_HALF
    hi = plan.max(axis=0) + GROUND_HALF
    xyz_parts, pi_parts, ii_parts, xy_parts = [], [], [], []
    have = 0
    while have < n:
        want = min(_CHUNK, max(2 * (n - have), 64))
        xy = rng.uniform(lo, hi, (want, 2))
        xyz = np.column_stack([xy, terrain_height(xy[:, 0], xy[:, 1], center)])
        pi, ii, pxy = _seen(xyz, eo, plan, base, spacing, per_strip, n_strips)
        count = np.bincount(pi, minlength=want)
        keep = np.flatnonzero(count >= 2)[: n - have]
        new = np.full(want, -1, np.int64)
        new[keep] = have + np.arange(len(keep))
        sel = new[pi] >= 0
        xyz_parts.append(xyz[keep])
        pi_parts.append(new[pi[sel]])
        ii_parts.append(ii[sel])
        xy_parts.append(pxy[sel])
        have += len(keep)
    return (np.concatenate(xyz_parts), np.concatenate(pi_parts), np.concatenate(ii_parts),
            np.concatenate(xy_parts))


def make_block(
    n_strips: int = 10,
    images_per_strip: int = 20,
    *,
    n_shape_points: int = 100_000,
    n_control: int | None = None,
    n_tie: int | None = None,
    forward_overlap: float = 0.6,
    side_overlap: float = 0.3,
    sigma_image: float = 0.015,
    shape_sigma: tuple[float, float, float] = (3.0, 3.0, 1.0),
    control_sigma: tuple[float, float, float] = CONTROL_SIGMA,
    position_noise: float = 3.0,
    attitude_noise: float = 0.3,
    sigma_position: float = 100.0,
    sigma_attitude: float = 5.0,
    seed: int = 0,
    center: tuple[float, float] = CENTER,
) -> SimulatedBlock:
    """Simulate a block of vertical photographs with control, tie and shape points.

    Parameters
    ----------
    n_strips, images_per_strip : int
        Block layout (``1, 2``: a stereo pair).
    n_shape_points : int
        Road shape points (light coordinate prior, the database error drawn from
        ``shape_sigma``).
    n_control : int, optional
        Control points (heavy prior ``control_sigma``); default ``max(6, n_images)``.
    n_tie : int, optional
        Tie points (no prior); default ``10 * n_images``.
    forward_overlap, side_overlap : float
        Overlap of neighbouring images along a strip and of neighbouring strips.
    sigma_image : float
        Image coordinate noise (mm).
    shape_sigma, control_sigma : (float, float, float)
        Prior sigmas (m) of shape and control points, also the sigma of their errors.
    position_noise, attitude_noise : float
        True EO about the flight plan: sigma (m; half in Z) and sigma (degrees).
    sigma_position, sigma_attitude : float
        Prior sigmas of the approximate EO (m, degrees); the approximate EO is the true
        one plus ``position_noise`` / ``attitude_noise`` errors.
    seed : int
    center : (float, float)
        Block centre (m).

    Returns
    -------
    SimulatedBlock
    """
    if n_strips < 1 or images_per_strip < 1 or n_strips * images_per_strip < 2:
        raise ValueError("a block needs at least two images")
    eo, plan, base, spacing, strip, column = _layout(
        n_strips, images_per_strip, forward_overlap, side_overlap, center, seed,
        position_noise, attitude_noise)
    n_img = len(eo)
    n_control = max(6, n_img) if n_control is None else int(n_control)
    n_tie = 10 * n_img if n_tie is None else int(n_tie)
    rng = _rng(seed, "block-points")
    xyz, pi, ii, xy = _scatter_points(n_control + n_tie + n_shape_points, eo, plan, base,
                                      spacing, images_per_strip, n_strips, rng, center)
    kind = np.array(["control"] * n_control + ["tie"] * n_tie + ["shape"] * n_shape_points)
    return _assemble_problem(eo, xyz, kind, pi, ii, xy, seed, sigma_image, shape_sigma,
                             control_sigma, position_noise, attitude_noise, sigma_position,
                             sigma_attitude, strip, column)


def _assemble_problem(eo, xyz, kind, pi, ii, xy, seed, sigma_image, shape_sigma,
                      control_sigma, position_noise, attitude_noise, sigma_position,
                      sigma_attitude, strip, column) -> SimulatedBlock:
    """Noisy measurements, priors and approximations of a simulated block."""
    rng = _rng(seed, "block-noise")
    order = np.lexsort((ii, pi))
    pi, ii, xy = pi[order], ii[order], xy[order]
    obs_xy = xy + rng.normal(0.0, sigma_image, xy.shape)
    m = len(xyz)
    sig = np.zeros((m, 3))
    sig[kind == "control"] = control_sigma
    sig[kind == "shape"] = shape_sigma
    has = kind != "tie"
    prior = np.where(has[:, None], xyz + rng.normal(0.0, 1.0, (m, 3)) * sig, 0.0)
    weight = np.zeros((m, 3, 3))
    idx = np.arange(3)
    weight[np.flatnonzero(has)[:, None], idx, idx] = 1.0 / sig[has] ** 2
    eo0 = eo.copy()
    n = len(eo)
    eo0[:, :3] += rng.normal(0.0, 1.0, (n, 3)) * np.array([1.0, 1.0, 0.5]) * position_noise
    eo0[:, 3:] += np.radians(rng.normal(0.0, attitude_noise, (n, 3)))
    eo_sigma = np.tile([sigma_position] * 3 + [np.radians(sigma_attitude)] * 3, (n, 1))
    xyz0 = np.where(has[:, None], prior, xyz + rng.normal(0.0, 1.0, (m, 3)))
    prob = BundleProblem(
        focal_length=FOCAL_LENGTH, principal_point=(0.0, 0.0), eo0=eo0, eo_sigma=eo_sigma,
        xyz0=xyz0, prior_xyz=prior, prior_weight=weight, obs_point=pi, obs_image=ii,
        obs_xy=obs_xy, obs_sigma=np.full(obs_xy.shape, float(sigma_image)))
    return SimulatedBlock(problem=prob, true_eo=eo, true_xyz=xyz, point_kind=kind,
                          strip=strip, column=column)
