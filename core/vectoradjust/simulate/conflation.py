"""Scenarios for the conflation (correcting every vertex): a database whose error is a
constant shift plus a smooth spatial field plus white noise, of which only a subset of
vertices is measured on the images.

The database of :func:`make_scenario` is rebuilt from the truth: ``X_db = X_true + bias +
s(X_true) + e``, with ``s`` a sum of random plane waves (a stationary field with a
Gaussian-like covariance of correlation length ``length``) and ``e`` white noise drawn
once per object point, so that vertices at the same place (intersections, closed
rings) stay at the same place. The images measure the true points, so the measurements
of the scenario stay valid; those of the vertices not in the measured subset are
dropped.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from vectoradjust.adjust.shapepoints import extract_shape_points, lookup
from vectoradjust.model import Measurements, ProjectData
from vectoradjust.simulate.roads import DatabaseModel
from vectoradjust.simulate.scenario import make_scenario

__all__ = ["smooth_field", "wave_field", "measured_subset", "conflation_scenario"]

#: the error fields of :func:`conflation_scenario`
FIELDS = ("gaussian", "waves")
#: how the measured object points are chosen
LAYOUTS = ("random", "clusters")


def smooth_field(xy: np.ndarray, amplitude: float, length: float, seed: int,
                 n_waves: int = 64) -> np.ndarray:
    """A smooth random 2D displacement field at ``xy`` (n, 2).

    ``sum_j a_j cos(w_j . x + phi_j)`` per component with wave vectors ``w ~ N(0, 1/L^2)``:
    a stationary field of standard deviation ``amplitude`` per component and covariance
    ``amplitude^2 exp(-r^2 / (2 L^2))`` (in the limit of many waves).
    """
    rng = np.random.default_rng(seed)
    out = np.zeros((len(xy), 2))
    for c in range(2):
        w = rng.normal(0.0, 1.0 / length, (n_waves, 2))
        phi = rng.uniform(0.0, 2 * np.pi, n_waves)
        out[:, c] = amplitude * np.sqrt(2.0 / n_waves) * np.cos(xy @ w.T + phi).sum(axis=1)
    return out


def wave_field(xy: np.ndarray, amplitude: float, wavelengths=(300.0, 1500.0), seed: int = 0,
               n_waves: int = 3) -> np.ndarray:
    """A long-wavelength 2D displacement field at ``xy`` (n, 2): a few plane waves.

    Per component ``sum_j a sqrt(2 / n) cos(2 pi u_j . x / lambda_j + phi_j)`` with
    ``n_waves`` waves, wavelengths ``lambda_j`` uniform in ``wavelengths`` (m), random
    directions ``u_j`` and phases: a field of standard deviation ``amplitude`` per
    component (over the phases) whose few long waves a Gaussian covariance of one
    length does not describe (on an extent shorter than a wavelength a wave looks like
    a trend).
    """
    rng = np.random.default_rng(seed)
    lo, hi = (float(w) for w in wavelengths)
    out = np.zeros((len(xy), 2))
    for c in range(2):
        lam = rng.uniform(lo, hi, n_waves)
        ang = rng.uniform(0.0, 2 * np.pi, n_waves)
        w = (2 * np.pi / lam)[:, None] * np.column_stack([np.cos(ang), np.sin(ang)])
        phi = rng.uniform(0.0, 2 * np.pi, n_waves)
        out[:, c] = amplitude * np.sqrt(2.0 / n_waves) * np.cos(xy @ w.T + phi).sum(axis=1)
    return out


def measured_subset(xy: np.ndarray, fraction: float, rng: np.random.Generator,
                    layout: str = "random", clusters: int = 3,
                    radius: float = 120.0) -> np.ndarray:
    """Which object points (n,) the images measure.

    ``"random"``: each with probability ``fraction``; ``"clusters"``: only those within
    ``radius`` (m) of one of ``clusters`` centres (random object points), each of them
    with probability ``fraction``, so that the predicted vertices lie from 0 to several
    hundred metres from the nearest measured one (as where an operator measured a few
    image patches).
    """
    draw = rng.random(len(xy)) < fraction
    if layout == "random":
        return draw
    if layout != "clusters":
        raise ValueError(f"layout {layout!r} is not one of {LAYOUTS}")
    centres = xy[rng.choice(len(xy), clusters, replace=False)]
    near = np.min(np.hypot(*(xy[:, None, :] - centres[None, :, :]).transpose(2, 0, 1)),
                  axis=1) <= radius
    return draw & near


def _without_points(meas: Measurements, drop: np.ndarray) -> Measurements:
    """The measurements less those of the points ``drop``."""
    keep = ~np.isin(meas.point_id, drop)
    return replace(meas, point_id=meas.point_id[keep], image_id=meas.image_id[keep],
                   xy=meas.xy[keep], sigma=meas.sigma[keep],
                   rows=None if meas.rows is None else meas.rows[keep])


def conflation_scenario(seed: int = 1, *, bias=(3.0, -2.0), amplitude: float = 2.0,
                        length: float = 150.0, noise: float = 0.3,
                        measured_fraction: float = 0.3, true_roads=None,
                        spacing: float = 20.0, identification_sigma=(0.3, 0.1),
                        stated_sigma: float | None = None,
                        conflation: dict | None = None, field: str = "gaussian",
                        wavelengths=(300.0, 1500.0), layout: str = "random",
                        clusters: int = 3, cluster_radius: float = 120.0) -> ProjectData:
    """Project data of one database ``OSM`` with a smooth error field, partly measured.

    Parameters
    ----------
    seed : int
    bias : (float, float)
        Constant shift of the database (m).
    amplitude, length : float
        Standard deviation per component (m) and correlation length (m) of the smooth
        field; ``amplitude = 0``: a constant shift only.
    noise : float
        White noise per component and object point (m).
    measured_fraction : float
        Share of the object points measured on the images (random, from ``seed``).
    true_roads : optional
        Real road geometry (``make_scenario(true_roads=...)``).
    spacing : float
        Vertex spacing of the database (m).
    identification_sigma : (float, float)
        The analyst's pointing error (horizontal, used as the scenario's
        ``pointing_sigma``) and the stated identification sigma.
    stated_sigma : float, optional
        The database's stated horizontal sigma (its prior in the adjustment). Default:
        its real error once the shift is removed, ``hypot(amplitude, noise)``. Stating
        only the white ``noise`` while a 2 m field is present strains the adjustment
        (sigma0^2 of 7-12 on Helsinki): the database's priors bend the orientation, the
        images' positions then err by more than their covariance says, and smoothly, so
        that no cross-validation can see it.
    conflation : dict, optional
        The ``[conflation]`` table.
    field : str
        ``"gaussian"``: :func:`smooth_field` of correlation length ``length``;
        ``"waves"``: :func:`wave_field`, three plane waves per component of
        ``wavelengths`` (m).
    wavelengths : (float, float)
        Range of the waves' wavelengths (``field = "waves"``).
    layout, clusters, cluster_radius :
        Which object points are measured (:func:`measured_subset`).

    Returns
    -------
    ProjectData
        With ``truth`` of every vertex; ``offset = "shift"``.
    """
    model = DatabaseModel("OSM", "osm_id", "osm", spacing, 0.5, (0.0, 0.0), 0.0, 0.0, 0.0)
    sc = make_scenario(seed, databases=(model,), pointing_sigma=identification_sigma[0],
                       shape_sigma=(3.0, 3.0, 3.0), true_roads=true_roads)
    data = sc.to_project_data()
    spec, layer = data.vectors[0]
    tid, txyz = data.truth["OSM"]
    sp = extract_shape_points(layer)
    ti = lookup(tid, sp.vertex_ids)
    true_obj = np.asarray(txyz, float)[ti[sp.object_vertex], :2]
    rng = np.random.default_rng(seed + 1000)
    if field not in FIELDS:
        raise ValueError(f"field {field!r} is not one of {FIELDS}")
    sig = (smooth_field(true_obj, amplitude, length, seed + 2000) if field == "gaussian"
           else wave_field(true_obj, amplitude, wavelengths, seed + 2000))
    err = np.asarray(bias, float) + sig + rng.normal(0.0, noise, (len(true_obj), 2))
    coords = layer.coords.copy()
    coords[:, :2] = true_obj[sp.vertex_object] + err[sp.vertex_object]
    measured_obj = measured_subset(true_obj, measured_fraction, rng, layout, clusters,
                                   cluster_radius)
    meas = _without_points(data.measurements, sp.vertex_ids[~measured_obj[sp.vertex_object]])
    st = float(np.hypot(amplitude, max(noise, 0.1)) if stated_sigma is None else stated_sigma)
    spec = replace(spec, sigma=(st, st, 3.0), offset="shift",
                   identification_sigma=tuple(identification_sigma))
    return replace(data, vectors=[(spec, replace(layer, coords=coords))], measurements=meas,
                   conflation=conflation)
