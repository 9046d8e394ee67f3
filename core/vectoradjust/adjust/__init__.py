"""The adjustment: shape points, the bundle adjustment and what is estimated with it.

- :mod:`~vectoradjust.adjust.shapepoints` - road vertices as object points (ids, merging).
- :mod:`~vectoradjust.adjust.dem` - bilinear DEM heights.
- :mod:`~vectoradjust.adjust.bundle` - Gauss-Newton over the reduced camera system,
  covariances, intersection (DESIGN section 3).
- :mod:`~vectoradjust.adjust.classify` - measured ids to control, check, shape and tie
  points, and the bundle problem built from them.
- :mod:`~vectoradjust.adjust.passes` - the adjustment passes: two-pass reweighting,
  variance components, data snooping.
- :mod:`~vectoradjust.adjust.reliability` - redundancy numbers, w-test, data snooping.
- :mod:`~vectoradjust.adjust.vce` - variance component estimation.
- :mod:`~vectoradjust.adjust.orientation` - relative/absolute orientation, 3D conformal,
  two-step (DESIGN section 6).

Imports numpy and scipy only.
"""
