"""The sensor: from pixels to refined photo coordinates and the collinearity model.

- :mod:`~vectoradjust.sensor.collinearity` - rotation matrix, projection, analytic partials
  (docs/method.md sections 2-3).
- :mod:`~vectoradjust.sensor.camera` - the camera calibration file (focal length,
  principal point, distortion, fiducials, pixels).
- :mod:`~vectoradjust.sensor.refine` - fiducial affine, lens distortion, refraction,
  earth curvature (docs/method.md section 5).
- :mod:`~vectoradjust.sensor.interior` - the interior-orientation step applied to a
  project's measurements.
- :mod:`~vectoradjust.sensor.rpc` - rational polynomial coefficients of satellite images
  (RPC00B), their image-space bias and the corrected RPC.
- :mod:`~vectoradjust.sensor.ground` - object coordinates to longitude, latitude and
  ellipsoidal height (the RPCs' ground), with the Jacobian.
- :mod:`~vectoradjust.sensor.models` - the seam: which model each image of an adjustment
  has.

Imports numpy and scipy only.
"""
