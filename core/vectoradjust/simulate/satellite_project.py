"""A simulated satellite block as an in-memory project, and its coverage against the truth.

:func:`scenario_project_data` turns a
:class:`~vectoradjust.simulate.satellite.SatelliteScenario` (a pushbroom pair or triplet
with RPCs fitted "as the vendor delivered them" and a known image-space bias) into the
:class:`~vectoradjust.model.ProjectData` that :func:`vectoradjust.pipeline.run` adjusts:

- ground frame: an exact :class:`~vectoradjust.sensor.ground.EnuFrame` at the scene
  centre (height 0 m, so ``Z`` is close to the ellipsoidal height); every coordinate of
  the project and of the truth is in it (m);
- images: ``model = "rpc"``, one :class:`~vectoradjust.sensor.models.RpcImage` per image
  with the scenario's bias model (ids ``forward``, ``nadir``, ``backward``);
- measurements: the scenario's pixel observations (GDAL corner convention) with their
  sigma;
- control: the control and check points, surveyed with ``control_sigma`` (their
  coordinates are the truth plus that noise);
- tie points: the scenario's tie points (measured, in no table);
- a road database (:class:`~vectoradjust.model.LineLayer` ``ROADS``): the scenario's road
  points grouped into features by the part of their id before the last ``_`` (``RD1``,
  ``RD2``, ``RD3`` for a generated scene), measured as ``<feature>_<vertex>``.

The road points of the scenario are the points the analyst measured on the images. The
real road vertex lies an identification error ``e_id ~ N(0, identification_sigma^2)``
(horizontal) away from it, and the database vertex is the real vertex plus a systematic
``database_shift`` plus ``e_db ~ N(0, database_sigma^2)`` per axis - so the prior the
adjustment uses, ``X_db = X_measured + shift + e_db - e_id``, has exactly the error model
it is told (:class:`~vectoradjust.model.VectorSpec` ``sigma`` and
``identification_sigma``; ``stated_*`` arguments misstate it on purpose). Drawing
``e_id`` after imaging instead of before changes no distribution: it is independent of
everything else. (The product adds ``identification_sigma^2`` to the measured point's
covariance for the real vertex; since the prior holds ``-e_id`` too, that is
conservative by ``2 w identification_sigma^2``, ``w`` the prior's share of the adjusted
point: ~0.5 % of the identification variance here, where the images dominate.)

:func:`redraw` gives the scenario of another ``seed`` on the same geometry (the RPC fits
are the slow part of :func:`~vectoradjust.simulate.satellite.satellite_scenario`, and
``geometry_seed`` alone does not avoid them); :func:`bias_errors` and
:func:`vertex_errors` read a run's standardised errors, from which
:func:`coverage` counts the share inside the stated 90 % intervals.

Every random component draws from its own stream ``default_rng([seed, crc32(tag)])``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Optional, Union

import numpy as np

from vectoradjust.accuracy.tables import LE90_FACTOR
from vectoradjust.model import (
    AdjustmentSettings,
    Camera,
    ControlPoints,
    ImageSpec,
    LineLayer,
    Measurements,
    ProjectData,
    VectorSpec,
)
from vectoradjust.sensor.ground import EnuFrame
from vectoradjust.sensor.models import RpcImage, bias_free_mask
from vectoradjust.simulate.satellite import (  # the simulator's own draws, for redraw()
    SatelliteScenario,
    _draw_bias,
    _observe,
    _rng,
)

__all__ = [
    "DATABASE",
    "SatelliteTruth",
    "scenario_project_data",
    "redraw",
    "bias_errors",
    "vertex_errors",
    "coverage",
]

#: name of the road database of the project
DATABASE = "ROADS"


@dataclass
class SatelliteTruth:
    """The truth of a project made by :func:`scenario_project_data` (ENU metres).

    Attributes
    ----------
    frame : EnuFrame
        The project's ground frame.
    image_ids : list of str
    bias : numpy.ndarray, shape (n_images, 6)
        True ``a0, a1, a2, b0, b1, b2`` (px).
    free : numpy.ndarray of bool, shape (n_images, 6)
        The parameters the bias model estimates.
    road_ids : numpy.ndarray of str, shape (nv,)
        Vertex ids ``<feature>_<vertex>`` in the layer's order.
    road_xyz : numpy.ndarray, shape (nv, 3)
        The real road vertices.
    measured_xyz : numpy.ndarray, shape (nv, 3)
        The points measured on the images (real vertex plus identification error).
    database_xyz : numpy.ndarray, shape (nv, 3)
        The database's vertices (the layer's coordinates).
    control_ids : numpy.ndarray of str
        Control and check points.
    control_xyz : numpy.ndarray, shape (nc, 3)
        Their true coordinates (the project has them with survey noise).
    """

    frame: EnuFrame
    image_ids: list
    bias: np.ndarray
    free: np.ndarray
    road_ids: np.ndarray
    road_xyz: np.ndarray
    measured_xyz: np.ndarray
    database_xyz: np.ndarray
    control_ids: np.ndarray
    control_xyz: np.ndarray


def _road_layout(ids: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Feature ids, each point's feature index and vertex index (order of the points)."""
    feature = np.array([i.rsplit("_", 1)[0] if "_" in i else "road" for i in ids], dtype=str)
    names, first, vf = np.unique(feature, return_index=True, return_inverse=True)
    order = np.argsort(first, kind="stable")  # features in the order they first appear
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    vf = rank[np.asarray(vf).reshape(-1)]
    vi = np.zeros(len(ids), np.int64)
    for f in range(len(names)):
        at = np.flatnonzero(vf == f)
        vi[at] = np.arange(len(at))
    return names[order], vf, vi


def _road_layer(sc: SatelliteScenario, xyz: np.ndarray, road: np.ndarray, seed: int,
                database_sigma, database_shift, identification_sigma: float):
    """The road layer, the measured ids of the road points and their truth."""
    feature_ids, vf, vi = _road_layout(sc.point_ids[road])
    measured = xyz[road]
    e_id = np.zeros_like(measured)
    e_id[:, :2] = _rng(seed, "identification").normal(0.0, identification_sigma,
                                                      (len(measured), 2))
    true = measured - e_id
    e_db = _rng(seed, "database").normal(0.0, 1.0, true.shape) * np.asarray(database_sigma)
    db = true + np.asarray(database_shift, float) + e_db
    layer = LineLayer(DATABASE, feature_ids, {"name": [f"road {f}" for f in feature_ids]}, db,
                      vf, vi, np.zeros(len(vf), np.int64), crs="local ENU",
                      source="<simulated road database>")
    ids = np.char.add(np.char.add(feature_ids[vf], "_"), vi.astype(str))
    return layer, ids, true, measured


def _control(sc: SatelliteScenario, xyz: np.ndarray, seed: int, control_sigma):
    """Control and check points with survey noise; their truth."""
    sel = np.flatnonzero(np.isin(sc.kind, ("control", "check")))
    sigma = np.broadcast_to(np.asarray(control_sigma, float), (3,))
    noisy = xyz[sel] + _rng(seed, "control").normal(0.0, 1.0, (len(sel), 3)) * sigma
    ctrl = ControlPoints(sc.point_ids[sel], noisy, sigma, sc.kind[sel],
                         source="<simulated control>")
    return ctrl, sc.point_ids[sel], xyz[sel]


def scenario_project_data(
    sc: SatelliteScenario,
    *,
    database_sigma: Sequence[float] = (2.0, 2.0, 1.0),
    database_shift: Sequence[float] = (1.5, -1.0, 0.0),
    identification_sigma: float = 0.15,
    control_sigma: Union[float, Sequence[float]] = 0.05,
    offset: str = "shift",
    reweight: str = "none",
    bias_sigma: Optional[Sequence[float]] = None,
    seed: Optional[int] = None,
    stated_database_sigma: Optional[Sequence[float]] = None,
    stated_identification_sigma: Optional[float] = None,
) -> tuple[ProjectData, SatelliteTruth]:
    """The project of a simulated satellite block (module docstring) and its truth.

    Parameters
    ----------
    sc : SatelliteScenario
    database_sigma : (float, float, float)
        Standard deviation of the database's random error per axis (m), stated as the
        database's ``sigma``.
    database_shift : (float, float, float)
        Systematic offset of the whole database (m).
    identification_sigma : float
        Horizontal identification error (m), stated as ``identification_sigma``.
    control_sigma : float or (float, float, float)
        Survey error of the control and check points (m), stated as their sigma.
    offset : str
        The database's offset model (``VectorSpec.offset``; the product's default is
        ``"shift"``).
    reweight : str
        ``[adjustment] reweight`` (``"none"``, ``"two-pass"``, ``"vce"``).
    bias_sigma : sequence of float, optional
        A-priori sigmas of the bias parameters (px); free (no prior) by default.
    seed : int, optional
        Seed of the database, identification and survey errors (``sc.seed`` by default).
    stated_database_sigma, stated_identification_sigma : optional
        What the project states, when it is not the simulated sigma (a misstated error
        model, to see a coverage fail); the simulated one by default.

    Returns
    -------
    data : ProjectData
    truth : SatelliteTruth
    """
    seed = sc.seed if seed is None else int(seed)
    frame = EnuFrame(sc.area.lon, sc.area.lat, 0.0)
    xyz = frame.from_geodetic(np.column_stack([sc.lon, sc.lat, sc.h]))
    road = sc.kind == "road"
    layer, road_ids, true, measured = _road_layer(
        sc, xyz, road, seed, database_sigma, database_shift, identification_sigma)
    names = [s.name for s in sc.sensors]
    prior = np.full(6, np.inf) if bias_sigma is None else bias_sigma
    images = [ImageSpec(n, np.zeros(3), np.zeros(3), model="rpc",
                        rpc=RpcImage(rpc, sc.bias_model, prior, path=f"<simulated {n}>"))
              for n, rpc in zip(names, sc.rpcs)]
    meas_id = sc.point_ids.astype(object).copy()
    meas_id[np.flatnonzero(road)] = road_ids
    meas = Measurements(meas_id[sc.obs_point], np.array(names)[sc.obs_image],
                        np.column_stack([sc.obs_col, sc.obs_row]), sc.obs_sigma[:, None],
                        source="<simulated pixels>")
    ctrl, ctrl_ids, ctrl_true = _control(sc, xyz, seed, control_sigma)
    stated = database_sigma if stated_database_sigma is None else stated_database_sigma
    stated_id = (identification_sigma if stated_identification_sigma is None
                 else stated_identification_sigma)
    spec = VectorSpec(DATABASE, sigma=tuple(float(s) for s in stated),
                      identification_sigma=(float(stated_id), 0.0), offset=offset)
    data = ProjectData(crs="local ENU", camera=Camera(float("nan")), images=images,
                       measurements=meas, control=ctrl, vectors=[(spec, layer)],
                       settings=AdjustmentSettings(reweight=reweight),
                       truth={DATABASE: (road_ids, true)}, ground_frame=frame,
                       source=f"<satellite scenario seed {sc.seed}>")
    free = np.array([bias_free_mask(sc.bias_model)] * sc.n_images)
    truth = SatelliteTruth(frame, names, sc.true_bias.copy(), free, road_ids, true, measured,
                           layer.coords.copy(), ctrl_ids, ctrl_true)
    return data, truth


def redraw(sc: SatelliteScenario, seed: int, bias: Optional[str] = None,
           bias_size_px: float = 8.0, linear_size_px: Optional[float] = None,
           ) -> SatelliteScenario:
    """The scenario of another ``seed`` on the same scene, images and RPCs.

    Draws the true bias and the pixel noise as
    :func:`~vectoradjust.simulate.satellite.satellite_scenario` does, without fitting the
    RPCs again: for ``sc = satellite_scenario(n, b, size, g, ...)`` (default ground),
    ``redraw(sc, s, bias, size)`` equals ``satellite_scenario(n, bias, size, s, ...,
    geometry_seed=g)`` (the geometry depends on the geometry seed only, not on the bias
    model).

    Parameters
    ----------
    sc : SatelliteScenario
    seed : int
        Seed of the bias and the noise.
    bias : str, optional
        Bias model (``sc.bias_model`` by default).
    bias_size_px, linear_size_px : float
        As :func:`~vectoradjust.simulate.satellite.satellite_scenario`'s (not kept in
        the scenario, so given again).

    Returns
    -------
    SatelliteScenario
    """
    model = sc.bias_model if bias is None else bias
    linear = bias_size_px / 5.0 if linear_size_px is None else linear_size_px
    true_bias = _draw_bias(model, bias_size_px, linear, sc.n_images, _rng(seed, "bias"))
    obs = _observe(sc.rpcs, sc.sensors, true_bias, sc.lon, sc.lat, sc.h, sc.sigma_px,
                   _rng(seed, "noise"))
    return replace(sc, seed=int(seed), bias_model=model, true_bias=true_bias,
                   obs_point=obs[0], obs_image=obs[1], obs_col=obs[2], obs_row=obs[3],
                   obs_sigma=np.full(len(obs[0]), float(sc.sigma_px)))


def bias_errors(run, truth: SatelliteTruth) -> np.ndarray:
    """Standardised errors ``(estimate - true) / sigma`` of the estimated bias parameters.

    Parameters
    ----------
    run : vectoradjust.results.AdjustmentRun
        ``run.result.eo`` and ``eo_cov`` rows are the RPC images' bias (px).
    truth : SatelliteTruth

    Returns
    -------
    numpy.ndarray, shape (n_images, n_free)
        Per image, the free parameters in ``a0 .. b2`` order.
    """
    rows = [truth.image_ids.index(i) for i in run.image_ids]
    eo = np.asarray(run.result.eo, float)
    sd = np.sqrt(np.diagonal(np.asarray(run.result.eo_cov, float), axis1=1, axis2=2))
    free = truth.free[rows]
    z = (eo - truth.bias[rows]) / np.where(free, sd, np.nan)
    return z[free].reshape(len(rows), -1)


def vertex_errors(run, truth: SatelliteTruth) -> tuple[np.ndarray, np.ndarray]:
    """Errors of the adjusted road vertices over their CE90 and LE90.

    Parameters
    ----------
    run : vectoradjust.results.AdjustmentRun
    truth : SatelliteTruth

    Returns
    -------
    ce_ratio, le_ratio : numpy.ndarray, shape (n_adjusted,)
        ``|e_xy| / CE90`` and ``|e_z| / LE90`` of the adjusted vertices (<= 1: covered),
        against the real vertices.
    """
    v = next(d.vertices for d in run.databases if d.name == DATABASE)
    pos = {p: k for k, p in enumerate(truth.road_ids)}
    idx = np.array([pos[str(p)] for p in v["point_id"]], np.int64)
    adj = np.asarray(v["Adjusted"]) == 1
    e = np.column_stack([v["AdjX"], v["AdjY"], v["AdjZ"]])[adj] - truth.road_xyz[idx[adj]]
    ce = np.hypot(e[:, 0], e[:, 1]) / np.asarray(v["CE90"], float)[adj]
    le = np.abs(e[:, 2]) / np.asarray(v["LE90"], float)[adj]
    return ce, le


def coverage(errors: np.ndarray, kind: str, scale: float = 1.0) -> float:
    """Share of errors inside their 90 % interval, the interval scaled by ``scale``.

    Parameters
    ----------
    errors : array_like
        ``kind = "z"``: standardised errors (inside: ``|z| <= 1.645 scale``);
        ``kind = "ratio"``: errors over their CE90/LE90 (inside: ``<= scale``).
    kind : {"z", "ratio"}
    scale : float
        ``0.8``: the coverage the intervals would have with every sigma 20 % smaller.

    Returns
    -------
    float
    """
    a = np.abs(np.asarray(errors, float)).ravel()
    if kind == "z":
        return float(np.mean(a <= LE90_FACTOR * scale))
    if kind == "ratio":
        return float(np.mean(a <= scale))
    raise ValueError(f"kind must be 'z' or 'ratio', not {kind!r}")
