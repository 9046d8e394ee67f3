"""Simulated satellite pushbroom images with RPCs and known truth.

A physical line scanner on WGS84 (ECEF mathematics throughout, no map projection):

- :class:`CircularOrbit` - a circular orbit (Earth-fixed, Earth rotation ignored) at
  ``radius`` from the Earth's centre, through ``p0`` at ``t = 0`` moving along ``v0``;
  :meth:`~CircularOrbit.frame` is the orbital frame (x along track, z to the geocentre,
  y = z x x, to starboard).
- :class:`PushbroomSensor` - one image: a linear CCD of ``n_cols`` pixels across track
  with an angular pixel size ``ifov`` (GSD / altitude), ``n_rows`` lines of
  ``line_time`` seconds centred on ``t_center``, pointed by ``roll``, ``pitch`` and
  ``yaw`` (body to orbital frame ``R_y(pitch) R_x(roll) R_z(yaw)``; pitch > 0 looks
  forward) that drift smoothly, ``angle(t) = angle + drift[:, 0] tau + drift[:, 1] tau**2``
  with ``tau = t - t_center``. Pixel ``c`` of line ``r`` (centre convention, see below)
  looks along ``(0, (c - (n_cols - 1) / 2) ifov, 1)`` in the body frame at time
  ``t_center + (r - (n_rows - 1) / 2) line_time``.
- :func:`pushbroom_project` (ground to image; the line time is found by vectorised Newton
  iterations over all points at once), :func:`pushbroom_ray` and
  :func:`pushbroom_localize` (image to ground at a given height).
- :func:`stereo_sensors` - an along-track pair (forward, backward) or triplet (forward,
  nadir, backward) that all look at one ground point with a given base-to-height ratio.
- :func:`fit_rpc` - the terrain-independent RPC fit (Tao & Hu 2001): linear least
  squares of the rational functions on a 3-D grid of the ground domain, iteratively
  reweighted by the denominator with a small Tikhonov (ridge) term (the best of
  :data:`RIDGES` per coordinate), checked on the grid's cell centres. For the default
  scenario the fit is ~1e-8 px, for a 10 x 10 km image (20000 x 20000 px) with a
  strong attitude drift ~1e-4 px (``tests/test_satellite_sim.py`` prints the numbers).
- :func:`satellite_scenario` - a small scene (default near lon -87.0, lat 40.4, 3 x 3 km,
  smooth terrain 150-250 m ellipsoidal), its images with fitted RPCs as the vendor
  delivers them, a TRUE image-space bias per image (``BIAS_MODELS`` of
  :mod:`vectoradjust.sensor.rpc`, Grodecki & Dial 2003), control, check, tie and
  road-vertex points and their observations: the truth projected through the RPC plus
  the true bias (:func:`biased_project`) plus Gaussian noise.

Pixel convention as in :mod:`vectoradjust.sensor.rpc`: ``origin="center"`` puts the
centre of the first pixel at ``(0, 0)`` (the raw RPC formula: :func:`fit_rpc` fits the
RPC to these values), ``origin="corner"`` (GDAL's) puts the first pixel's upper-left
corner at ``(0, 0)``, i.e. ``corner = center + 0.5``. Columns run across track (RPC
"sample"), rows along track (RPC "line"). Heights are ellipsoidal (WGS84), lon/lat in
degrees.

Every random component draws from its own stream ``default_rng([seed, crc32(tag)])``,
so the scenario is deterministic per seed. Imports numpy and scipy only.

Modules (by topic)
------------------
- :mod:`~vectoradjust.simulate.satellite.geodesy` - WGS84, ECEF, ENU frames.
- :mod:`~vectoradjust.simulate.satellite.pushbroom` - the pushbroom sensor and its orbit.
- :mod:`~vectoradjust.simulate.satellite.rpc_fit` - RPCs fitted to the sensor.
- :mod:`~vectoradjust.simulate.satellite.scene` - the scene and :func:`satellite_scenario`.
"""

from __future__ import annotations

from vectoradjust.simulate.satellite.geodesy import (
    GM_EARTH,
    WGS84_A,
    WGS84_E2,
    ecef_to_geodetic,
    geodetic_to_ecef,
)
from vectoradjust.simulate.satellite.geodesy import (
    WGS84_F as WGS84_F,
)
from vectoradjust.simulate.satellite.geodesy import (
    _rng as _rng,
)
from vectoradjust.simulate.satellite.pushbroom import (
    CircularOrbit,
    PushbroomSensor,
    pushbroom_localize,
    pushbroom_project,
    pushbroom_ray,
    stereo_base_to_height,
    stereo_sensors,
)
from vectoradjust.simulate.satellite.rpc_fit import (
    RIDGES,
    biased_project,
    fit_rpc,
    image_domain,
    rpc_terms,
)
from vectoradjust.simulate.satellite.scene import (
    GroundPoints,
    SatelliteScenario,
    SceneArea,
    satellite_scenario,
)
from vectoradjust.simulate.satellite.scene import (
    _draw_bias as _draw_bias,
)
from vectoradjust.simulate.satellite.scene import (
    _observe as _observe,
)

__all__ = [
    "WGS84_A",
    "WGS84_E2",
    "GM_EARTH",
    "geodetic_to_ecef",
    "ecef_to_geodetic",
    "CircularOrbit",
    "PushbroomSensor",
    "pushbroom_project",
    "pushbroom_ray",
    "pushbroom_localize",
    "stereo_sensors",
    "stereo_base_to_height",
    "rpc_terms",
    "RIDGES",
    "fit_rpc",
    "image_domain",
    "biased_project",
    "SceneArea",
    "GroundPoints",
    "SatelliteScenario",
    "satellite_scenario",
]
