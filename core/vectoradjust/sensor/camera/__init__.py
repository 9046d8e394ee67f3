"""Camera calibration: focal length, principal point, fiducials, lens distortion, pixels.

A :class:`CameraCalibration` holds what a calibration report gives for one camera and
what image coordinate refinement (:mod:`vectoradjust.sensor.refine`) needs. It is built from
the project's ``[camera]`` table (a plain dict as read from TOML) by
:meth:`CameraCalibration.from_dict`, or from a separate camera TOML file by
:meth:`CameraCalibration.from_file`, so that one calibration report serves many
projects. The contract's two keys ``focal_length`` and ``principal_point`` alone are
still a complete camera (no fiducials, no distortion).

Camera table / file (all lengths in millimetres)::

    name = "Wild RC10 15/4 UAG"      # optional, for reports
    focal_length = 152.4              # calibrated focal length (mm), required
    principal_point = [0.003, -0.001] # x0, y0 (mm) in the fiducial frame; default [0, 0]
    pixel_size = 0.012                # mm (12 um); or [sx, sy]; optional
    image_size = [19200, 19200]       # columns, rows; optional
    pixel_origin = "center"           # center | corner (see refine.pixel_to_photo)

    [fiducials]                       # calibrated fiducial coordinates (mm)
    1 = [-106.004, -106.002]
    2 = [106.001, 105.998]
    3 = [-105.997, 106.003]
    4 = [106.002, -105.999]

    [distortion]
    model = "smac"                    # none | smac | polynomial | brown
    convention = "correction"         # correction | distortion (see below)
    center = [0.003, -0.001]          # optional point of symmetry (mm); default principal point
    K0 = -0.2165e-3                   # smac: K0..K4, P1..P4 (missing ones are 0)
    K1 = 0.4230e-7
    P1 = -0.1483e-6

In the project file, ``[camera]`` may instead say ``path = "rc10.toml"`` (relative
to the project file); the file is loaded and any key given inline next to ``path``
overrides the file's value (sub-tables ``fiducials`` and ``distortion`` are merged
key by key).

Distortion models (``xb = x - xc``, ``yb = y - yc`` with ``(xc, yc)`` the centre of
symmetry, ``r^2 = xb^2 + yb^2``):

``smac`` (USGS Simultaneous Multiframe Analytical Calibration)
    radial ``dxr = xb (K0 + K1 r^2 + K2 r^4 + K3 r^6 + K4 r^8)`` (same for y);
    decentering ``dxd = (1 + P3 r^2 + P4 r^4) [P1 (r^2 + 2 xb^2) + 2 P2 xb yb]``,
    ``dyd = (1 + P3 r^2 + P4 r^4) [2 P1 xb yb + P2 (r^2 + 2 yb^2)]``.
``polynomial``
    radial only in odd powers of ``r``: ``dr = k1 r^3 + k2 r^5 + k3 r^7 + k4 r^9``,
    ``dxr = xb dr / r``; the decentering terms ``P1..P4`` above may be added.
``brown`` (OpenCV / OpenSfM / OpenDroneMap Brown-Conrady)
    coefficients ``k1 k2 k3`` (radial) and ``p1 p2`` (tangential), unitless, of the
    *normalised* coordinates ``x_n = x / f``, ``y_n = y / f`` about the principal point
    (or ``center``). Unlike the two models above the formula maps the **ideal**
    position to the **distorted** (recorded) one, in OpenCV's axes (``y`` down, as
    pixel rows):
    ``x_d = x_n (1 + k1 r^2 + k2 r^4 + k3 r^6) + 2 p1 x_n y_n + p2 (r^2 + 2 x_n^2)``,
    ``y_d = y_n (1 + ...) + p1 (r^2 + 2 y_n^2) + 2 p2 x_n y_n``. The coefficients are
    written as OpenCV and OpenSfM give them; photo coordinates have ``y`` up, so with
    ``y = -y_n f`` the same formula in photo axes has ``p1`` with the opposite sign
    (:func:`brown_distort` does that). A measurement is corrected by inverting the
    formula exactly (:func:`brown_undistort`, Newton's method); ``convention`` does not
    apply (it may only be ``"distortion"``).
``none``
    no lens distortion correction.

Sign convention (``convention``): the formula above, evaluated at the *measured*
coordinate, gives ``F``.

* ``"correction"`` (default; the USGS calibration report and Wolf & Dewitt convention):
  ``F`` is the correction to add: ``corrected = measured + F``.
* ``"distortion"``: ``F`` is the distortion present in the measurement:
  ``corrected = measured - F``.

Either way ``corrected = measured - distortion``; the two differ only in the sign of
every coefficient. A coefficient set from a report that tabulates "distortion" (image
displaced outward is positive) needs ``convention = "distortion"``.

Modules (by topic)
------------------
- :mod:`~vectoradjust.sensor.camera.brown` - the Brown (OpenCV/OpenSfM) lens model.
- :mod:`~vectoradjust.sensor.camera.camera_file` - camera files, TOML text and its errors.
- :mod:`~vectoradjust.sensor.camera.validators` - names of a camera file, validators of values.
- :mod:`~vectoradjust.sensor.camera.calibration` - :class:`CameraCalibration`.
"""

from __future__ import annotations

from vectoradjust.sensor.camera.brown import (
    brown_distort,
    brown_undistort,
)
from vectoradjust.sensor.camera.calibration import (
    CameraCalibration,
)
from vectoradjust.sensor.camera.camera_file import (
    decode_text,
    load_camera_file,
    read_toml_text,
    toml_error_hint,
)
from vectoradjust.sensor.camera.validators import (
    _CAMERA_KEYS as _CAMERA_KEYS,
)
from vectoradjust.sensor.camera.validators import (
    _DISTORTION_META as _DISTORTION_META,
)
from vectoradjust.sensor.camera.validators import (
    _POLY_KEYS as _POLY_KEYS,
)
from vectoradjust.sensor.camera.validators import (
    _SMAC_KEYS as _SMAC_KEYS,
)
from vectoradjust.sensor.camera.validators import (
    DISTORTION_CONVENTIONS,
    DISTORTION_MODELS,
)
from vectoradjust.sensor.camera.validators import (
    PIXEL_ORIGINS as PIXEL_ORIGINS,
)
from vectoradjust.sensor.camera.validators import (
    PathLike as PathLike,
)
from vectoradjust.sensor.camera.validators import (
    _show as _show,
)

__all__ = [
    "CameraCalibration",
    "DISTORTION_MODELS",
    "DISTORTION_CONVENTIONS",
    "load_camera_file",
    "read_toml_text",
    "decode_text",
    "toml_error_hint",
    "brown_distort",
    "brown_undistort",
]
