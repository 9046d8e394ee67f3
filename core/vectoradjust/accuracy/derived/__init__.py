"""Derived quantities of an adjustment run with their sigmas (``docs/method.md`` section 6).

Everything computed from adjusted points - the length of a road, the distance between
two points, a height profile, the G-band of a road segment, the equal-error map of a
stereo pair - gets its standard deviation from the FULL a-posteriori covariance of the
points involved, and beside it the value "without covariances" (each point's own 3x3
block only), to show what the covariances between points change.

The covariances come from the reduced camera system of the bundle adjustment
(:class:`~vectoradjust.adjust.bundle.BundleResult`), never from a full inverse. With
``D_j = N_pp,j^-1`` (the point's own cofactor block), ``Z_j = N_pp,j^-1 N_pe,j``
(3 x 6n, nonzero only at the images that see point ``j``) and ``S^-1`` the inverse of
the reduced camera system, the cross covariance of two points is

    C_jl = s0^2 [delta_jl D_j + Z_j S^-1 Z_l']

and the variance of a linear function ``L = sum_j J_j x_j`` (1 x 3 gradients ``J_j``)

    sigma_L^2 = s0^2 [sum_j J_j D_j J_j' + b S^-1 b'],   b = sum_j J_j Z_j.

Both are evaluated for many points or functions at once (:func:`cross_covariance`,
:func:`feature_length_sigma`): the ``b`` rows are accumulated over the observations of
the points with ``bincount``, so the cost grows with the number of observations, not
with the number of images squared per point.

What the bands, lengths, distances and profiles state is the real road, as the
vertices' CE90/LE90 do: the adjustment's covariance (the database offsets' share
included) plus the identification error of each shape point (``identification_sigma``,
independent from object point to object point), and for the vertices the conflation
predicted their covariance from it (:func:`vertex_covariance`). ``LengthSD`` is the
root mean square error of a length, its expected lengthening included
(:func:`segment_lengthening`); the G-band's ellipses are drawn at the one-dimensional
scale of the error across the line (:func:`band_scale`), at a line's free ends at
:func:`end_scale` (the band holds the end vertex itself).

Heart module: numpy and scipy only (and other vectoradjust heart modules).

Modules (by topic)
------------------
- :mod:`~vectoradjust.accuracy.derived.covariance` - cross covariances, shared helpers.
- :mod:`~vectoradjust.accuracy.derived.length` - length of features and feature accuracy.
- :mod:`~vectoradjust.accuracy.derived.band_geometry` - the G-band polygons (numpy).
- :mod:`~vectoradjust.accuracy.derived.band_kernels` - G-bands in bulk, the compiled kernels.
- :mod:`~vectoradjust.accuracy.derived.bands` - segment covariances and uncertainty bands.
- :mod:`~vectoradjust.accuracy.derived.between` - distance, length, height between ids; profiles.
- :mod:`~vectoradjust.accuracy.derived.equal_error` - the equal-error map of a stereo pair.
- :mod:`~vectoradjust.accuracy.derived.compare` - two-step orientation versus the bundle.
"""

from __future__ import annotations

# the public API (``__all__``) and, as ``name as name``, the other names that modules
# and tests use from here (patch a name in the module that looks it up, not here)
from vectoradjust.accuracy.derived.band_geometry import (
    _band_chain as _band_chain,
)
from vectoradjust.accuracy.derived.band_geometry import (
    _drop_collinear as _drop_collinear,
)
from vectoradjust.accuracy.derived.band_geometry import (
    _g_band_flat as _g_band_flat,
)
from vectoradjust.accuracy.derived.band_geometry import (
    _tangent_normals as _tangent_normals,
)
from vectoradjust.accuracy.derived.band_geometry import (
    _upper_envelope as _upper_envelope,
)
from vectoradjust.accuracy.derived.band_kernels import (
    _BAND_BUDGET as _BAND_BUDGET,
)
from vectoradjust.accuracy.derived.band_kernels import (
    _KERNEL as _KERNEL,
)
from vectoradjust.accuracy.derived.band_kernels import (
    _KERNEL_CHUNK as _KERNEL_CHUNK,
)
from vectoradjust.accuracy.derived.band_kernels import (
    _KERNEL_MIN as _KERNEL_MIN,
)
from vectoradjust.accuracy.derived.band_kernels import (
    _UNION as _UNION,
)
from vectoradjust.accuracy.derived.band_kernels import (
    _compiled_rings as _compiled_rings,
)
from vectoradjust.accuracy.derived.band_kernels import (
    _numba_off as _numba_off,
)
from vectoradjust.accuracy.derived.band_kernels import (
    _ring_kernel as _ring_kernel,
)
from vectoradjust.accuracy.derived.band_kernels import (
    _Rings as _Rings,
)
from vectoradjust.accuracy.derived.band_kernels import (
    _splice as _splice,
)
from vectoradjust.accuracy.derived.band_kernels import (
    _union_kernel as _union_kernel,
)
from vectoradjust.accuracy.derived.band_kernels import (
    g_band_batch,
    g_band_rings,
)
from vectoradjust.accuracy.derived.band_kernels import (
    warm_ring_kernel as warm_ring_kernel,
)
from vectoradjust.accuracy.derived.bands import (
    SegmentBands,
    SegmentCovariances,
    band_scale,
    band_segment_counts,
    end_scale,
    segment_bands,
    segment_covariances,
    uncertainty_bands,
    vertex_covariance,
)
from vectoradjust.accuracy.derived.between import (
    DerivedValue,
    FeatureProfile,
    distance_between,
    length_between,
    mean_height_between,
    profile,
    resolve_points,
)
from vectoradjust.accuracy.derived.compare import (
    compare_two_step,
)
from vectoradjust.accuracy.derived.covariance import (
    DEFAULT_FRAME_MM as DEFAULT_FRAME_MM,
)
from vectoradjust.accuracy.derived.covariance import (
    _block_sum as _block_sum,
)
from vectoradjust.accuracy.derived.covariance import (
    cross_covariance,
)
from vectoradjust.accuracy.derived.equal_error import (
    EqualErrorGrid,
    equal_error_grid,
    equal_error_range,
    image_footprint,
)
from vectoradjust.accuracy.derived.length import (
    conflated_length_sigma,
    conflated_length_variance,
    feature_accuracy,
    feature_length_sigma,
    feature_vertex_accuracy,
    segment_lengthening,
)

__all__ = [
    "cross_covariance",
    "segment_covariances",
    "SegmentCovariances",
    "feature_length_sigma",
    "segment_lengthening",
    "conflated_length_variance",
    "conflated_length_sigma",
    "feature_vertex_accuracy",
    "feature_accuracy",
    "g_band_batch",
    "g_band_rings",
    "SegmentBands",
    "segment_bands",
    "band_segment_counts",
    "band_scale",
    "end_scale",
    "vertex_covariance",
    "uncertainty_bands",
    "DerivedValue",
    "resolve_points",
    "distance_between",
    "length_between",
    "mean_height_between",
    "FeatureProfile",
    "profile",
    "EqualErrorGrid",
    "equal_error_grid",
    "equal_error_range",
    "image_footprint",
    "compare_two_step",
]
