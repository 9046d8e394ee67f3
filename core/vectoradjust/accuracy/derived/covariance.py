"""Cross covariances of adjusted points from the reduced camera system, and the helpers the
other modules of :mod:`vectoradjust.accuracy.derived` share (observation index, segments).

Heart module: numpy and scipy only.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from vectoradjust.adjust.intersection import _block_sum  # the one definition
from vectoradjust.errors import ProjectError

if TYPE_CHECKING:  # pragma: no cover
    from vectoradjust.adjust.bundle import BundleResult
    from vectoradjust.results import AdjustmentRun, DatabaseResult

__all__ = ["cross_covariance"]


DEFAULT_FRAME_MM = 230.0  # 23 x 23 cm aerial film (docs/method.md section 1)
_CHUNK = 200_000  # rows of temporary (rows, 3, 3)-sized arrays per chunk


# ---------------------------------------------------------------------------- helpers


@dataclass
class _ObsIndex:
    """Observations of the bundle grouped by point (CSR layout)."""

    order: np.ndarray  # observation indices sorted by point
    starts: np.ndarray  # first position in ``order`` of each point
    counts: np.ndarray  # observations per point

    @classmethod
    def of(cls, result: BundleResult) -> _ObsIndex:
        prob = result.problem
        order = np.argsort(prob.obs_point, kind="stable")
        counts = np.bincount(prob.obs_point, minlength=prob.n_points)
        starts = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)
        return cls(order, starts, counts)

    def expand(self, points: np.ndarray):
        """Every observation of every entry of ``points``: ``(entry, observation)``."""
        c = self.counts[points]
        entry = np.repeat(np.arange(len(points)), c)
        offs = np.arange(int(c.sum())) - np.repeat(np.cumsum(c) - c, c)
        return entry, self.order[np.repeat(self.starts[points], c) + offs]


def _check_result(result: BundleResult) -> None:
    if result.s_inv is None or result.npp_inv is None or result.nep_obs is None \
            or result.problem is None:
        raise ProjectError(
            "The adjustment result holds no factorisation (s_inv, npp_inv, nep_obs), so "
            "covariances between points cannot be computed",
            "Use a BundleResult from vectoradjust.adjust.bundle.adjust (pipeline.run keeps them; "
            "BundleResult.release_factorisation lets them go)",
        )


def cross_covariance(result: BundleResult, pa, pb) -> np.ndarray:
    """A-posteriori cross covariances ``C_jl`` of many pairs of bundle points at once.

    ``C_jl = s0^2 [delta_jl N_pp,j^-1 + Z_j S^-1 Z_l']`` with ``Z_j = N_pp,j^-1 N_pe,j``
    (module docstring); ``pa[i] == pb[i]`` gives the point's own covariance block.
    The work is one small product per pair of observations of the two points.

    Parameters
    ----------
    result : BundleResult
    pa, pb : array_like of int, shape (m,)
        Bundle point indices.

    Returns
    -------
    numpy.ndarray, shape (m, 3, 3)
        ``Cov(x_pa[i], x_pb[i])``.
    """
    _check_result(result)
    pa = np.asarray(pa, np.int64).reshape(-1)
    pb = np.asarray(pb, np.int64).reshape(-1)
    if pa.shape != pb.shape:
        raise ValueError("cross_covariance: pa and pb must have the same length")
    prob = result.problem
    n = prob.n_images
    m = len(pa)
    sinv = result.s_inv.reshape(n, 6, n, 6)
    idx = _ObsIndex.of(result)
    ca, cb = idx.counts[pa], idx.counts[pb]
    nt = ca * cb
    acc = np.zeros((m, 3, 3))
    if m == 0:
        return acc
    # chunks of pairs so that the per-observation-pair temporaries stay small
    ends = np.cumsum(nt)
    cuts = np.searchsorted(ends, np.arange(_CHUNK, int(ends[-1]), _CHUNK), side="left") + 1
    cuts = np.unique(np.concatenate([[0], np.clip(cuts, 1, m), [m]]))
    for lo, hi in zip(cuts[:-1], cuts[1:]):
        ntc = nt[lo:hi]
        entry = np.repeat(np.arange(lo, hi), ntc)
        local = np.arange(int(ntc.sum())) - np.repeat(np.cumsum(ntc) - ntc, ntc)
        ia = local // cb[entry]
        ib = local % cb[entry]
        ka = idx.order[idx.starts[pa[entry]] + ia]
        kb = idx.order[idx.starts[pb[entry]] + ib]
        blk = sinv[prob.obs_image[ka], :, prob.obs_image[kb], :]  # (T, 6, 6)
        t = np.matmul(np.swapaxes(result.nep_obs[ka], 1, 2), blk) @ result.nep_obs[kb]
        acc[lo:hi] = _block_sum(entry - lo, t, hi - lo)
    cov = result.npp_inv[pa] @ acc @ result.npp_inv[pb]
    same = pa == pb
    cov[same] += result.npp_inv[pa[same]]
    cov += result.offset_cross(pa, pb)  # database offsets (zero without)
    return result.variance_factor * cov


def _adjusted_coords(run: AdjustmentRun, db: DatabaseResult) -> np.ndarray:
    if db.adjusted_coords is not None:
        return np.asarray(db.adjusted_coords, float)
    adj = np.array(db.shape.layer.coords, float)
    m = db.vertex_point >= 0
    adj[m] = run.result.xyz[db.vertex_point[m]]
    return adj


def _segments(db: DatabaseResult):
    """Start vertex of every segment within a part of a feature (``a`` -> ``a + 1``)."""
    layer = db.shape.layer
    fi, part = layer.vertex_feature, layer.vertex_part
    if len(fi) < 2:
        return np.zeros(0, np.int64)
    same = (fi[1:] == fi[:-1]) & (part[1:] == part[:-1])
    return np.flatnonzero(same)


def _identification_variance(db) -> np.ndarray:
    """Per-axis variance (3,) of the database's identification error (zeros when none is
    stated, or for a stand-in without a ``spec``)."""
    spec = getattr(db, "spec", None)
    return np.zeros(3) if spec is None else np.asarray(spec.identification_variance, float)
