"""The adjustment: shape points, the bundle adjustment and what is estimated with it.

- :mod:`~vectoradjust.adjust.shapepoints` - road vertices as object points (ids, merging).
- :mod:`~vectoradjust.adjust.dem` - bilinear DEM heights.
- :mod:`~vectoradjust.adjust.bundle` - Gauss-Newton over the reduced camera system,
  covariances, intersection (docs/method.md section 3).
- :mod:`~vectoradjust.adjust.classify` - measured ids to control, check, shape and tie
  points, and the bundle problem built from them.
- :mod:`~vectoradjust.adjust.passes` - the adjustment passes: two-pass reweighting,
  variance components, data snooping.
- :mod:`~vectoradjust.adjust.reliability` - redundancy numbers, w-test, data snooping.
- :mod:`~vectoradjust.adjust.vce` - variance component estimation.
- :mod:`~vectoradjust.adjust.orientation` - relative/absolute orientation, 3D conformal,
  two-step (docs/method.md section 6).
- :mod:`~vectoradjust.adjust.intersection` - forward intersection of the rays of a point.
- :mod:`~vectoradjust.adjust.datum` - what fixes the block in space; the free network.
- :mod:`~vectoradjust.adjust.offsets` - systematic database offsets as nuisance
  parameters.
- :mod:`~vectoradjust.adjust.selfcal` - self-calibration of the camera with the bundle.
- :mod:`~vectoradjust.adjust.plausibility` - plausibility checks before the adjustment.
- :mod:`~vectoradjust.adjust.junctions` - vertices of left-out roads that are junctions
  with the roads of a run.

Imports numpy and scipy only.
"""
