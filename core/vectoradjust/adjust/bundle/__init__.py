"""Weighted least-squares bundle adjustment over the reduced camera system.

Unknowns are the exterior orientation (6 per image) and the ground coordinates of
every object point (3 per point). Observations are image coordinates, optional priors
on object points (control points heavy, road shape points light, tie points none) and
optional priors on the exterior orientation. Gauss-Newton iterates on the normal
equations ``N dx = t`` with ``N = [[N_ee, N_ep], [N_pe, N_pp]]``; the point blocks are
eliminated (Schur complement) so that only the small reduced camera system
``S = N_ee - N_ep N_pp^-1 N_pe`` is solved (``docs/method.md`` section 3).

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

Modules (by topic)
------------------
- :mod:`~vectoradjust.adjust.bundle.blas` - one OpenBLAS thread while adjusting.
- :mod:`~vectoradjust.adjust.bundle.problem` - :class:`BundleProblem`, observation groups.
- :mod:`~vectoradjust.adjust.bundle.result` - :class:`BundleResult`.
- :mod:`~vectoradjust.adjust.bundle.normals` - blocks, linearisation, normal equations.
- :mod:`~vectoradjust.adjust.bundle.solve` - Schur complement, Gauss-Newton, :func:`adjust`.
- :mod:`~vectoradjust.adjust.bundle.forward` - forward intersection, :func:`intersect`.
"""

from __future__ import annotations

from vectoradjust.adjust.bundle.blas import (
    _openblas_controls as _openblas_controls,
)
from vectoradjust.adjust.bundle.blas import (
    _single_blas_thread as _single_blas_thread,
)
from vectoradjust.adjust.bundle.forward import (
    intersect,
)
from vectoradjust.adjust.bundle.normals import (
    _times_inverse as _times_inverse,
)
from vectoradjust.adjust.bundle.problem import (
    BundleProblem,
)
from vectoradjust.adjust.bundle.problem import (
    ProgressCallback as ProgressCallback,
)
from vectoradjust.adjust.bundle.problem import (
    _group_observations as _group_observations,
)
from vectoradjust.adjust.bundle.problem import (
    _image_set_keys as _image_set_keys,
)
from vectoradjust.adjust.bundle.result import (
    BundleResult,
)
from vectoradjust.adjust.bundle.solve import (
    TOLERANCE_BIAS as TOLERANCE_BIAS,
)
from vectoradjust.adjust.bundle.solve import (
    adjust,
)
from vectoradjust.adjust.intersection import _block_sum as _block_sum
from vectoradjust.adjust.intersection import inv3x3, ray_intersection

__all__ = [
    "BundleProblem",
    "BundleResult",
    "adjust",
    "intersect",
    "ray_intersection",
    "inv3x3",
]
