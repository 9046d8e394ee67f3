"""Measurement on the images: prediction, area-based matching, road-aware measurement.

Layer 2 of the package (numpy and scipy only; it uses the sensor model of layer 1):

* :mod:`~vectoradjust.measure.geometry` - object point -> pixel through the collinearity
  equations and the camera model, pixel -> ground (ray and DEM), the image-space
  covariance of a prediction and its search window;
* :mod:`~vectoradjust.measure.matching` - normalised cross-correlation (FFT, batched)
  and least-squares matching (affine geometry, linear radiometry; Gruen 1985) with
  their quality measures and failure flags;
* :mod:`~vectoradjust.measure.roads` - the centreline crossing of two road arms near a
  predicted junction or corner (profile analysis across the database direction);
* :mod:`~vectoradjust.measure.transfer` - transfer of points between images (prediction,
  NCC search, LSM refinement, flags);
* :mod:`~vectoradjust.measure.ties` - automatic tie points between frame images.

Reading image windows and writing chips and CSV files is :mod:`vectoradjust.files.images`.
"""
