"""Rational polynomial coefficients fitted to a sensor (terrain-independent, ridge-
regularised linear least squares), the image domain and projection with a bias.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Callable, Union

import numpy as np
from scipy import linalg

from vectoradjust.sensor.rpc import RpcModel
from vectoradjust.simulate.satellite.geodesy import _shift
from vectoradjust.simulate.satellite.pushbroom import PushbroomSensor, pushbroom_localize

__all__ = ["rpc_terms", "RIDGES", "fit_rpc", "image_domain", "biased_project"]


#: ridge (Tikhonov) candidates of :func:`fit_rpc`
RIDGES = (0.0, 1e-12, 1e-10, 1e-8, 1e-6, 1e-4)



def rpc_terms(lon_n, lat_n, h_n) -> np.ndarray:
    """The 20 cubic terms of an RPC00B polynomial in normalised L (lon), P (lat), H.

    Parameters
    ----------
    lon_n, lat_n, h_n : array_like
        Normalised coordinates.

    Returns
    -------
    numpy.ndarray, shape (n, 20)
        ``1 L P H LP LH PH L^2 P^2 H^2 PLH L^3 LP^2 LH^2 L^2P P^3 PH^2 L^2H P^2H H^3``.
    """
    lo, la, hh = (np.asarray(a, dtype=float).ravel() for a in (lon_n, lat_n, h_n))
    one = np.ones_like(lo)
    return np.stack([
        one, lo, la, hh, lo * la, lo * hh, la * hh, lo**2, la**2, hh**2,
        la * lo * hh, lo**3, lo * la**2, lo * hh**2, lo**2 * la, la**3, la * hh**2,
        lo**2 * hh, la**2 * hh, hh**3], axis=-1)


def _fit_ratio(terms: np.ndarray, y: np.ndarray, ridge: float, iterations: int):
    """Numerator and denominator (constant 1) of ``y = num.T / den.T`` (Tao & Hu 2001).

    Linearised ``num.T - y (den.T - 1) = y``, each row weighted by ``1 / den.T`` of the
    previous solution, with ``ridge`` times the identity added to the normal matrix;
    stops when the weights change by less than 1e-6.
    """
    n_terms = terms.shape[1]
    a = np.hstack([terms, -y[:, None] * terms[:, 1:]])
    reg = math.sqrt(ridge) * np.eye(a.shape[1])
    den = np.ones(len(y))
    for _ in range(max(int(iterations), 1)):
        w = 1.0 / den
        x = linalg.lstsq(np.vstack([a * w[:, None], reg]),
                         np.concatenate([y * w, np.zeros(a.shape[1])]))[0]
        den_new = terms @ np.concatenate([[1.0], x[n_terms:]])
        converged = np.max(np.abs(den_new - den)) < 1e-6  # weights settled
        den = den_new
        if converged:
            break
    return x[:n_terms], np.concatenate([[1.0], x[n_terms:]])


def _fit_coordinate(terms, y, check_terms, check_y, ridges, iterations):
    """The fit of :func:`_fit_ratio` with the best of the ``ridges``.

    Best: the smallest largest misfit on the check points among the fits whose
    denominator stays above 0.5 on the nodes and the check points (if none does, the
    smallest misfit).
    """
    best = None
    for ridge in ridges:
        num, den = _fit_ratio(terms, y, float(ridge), iterations)
        den_min = min(np.min(terms @ den), np.min(check_terms @ den))
        misfit = np.max(np.abs((check_terms @ num) / (check_terms @ den) - check_y))
        key = (bool(den_min < 0.5), float(misfit))
        if best is None or key < best[0]:
            best = (key, num, den)
    return best[1], best[2]


def _grid(ranges, counts, cell_centres: bool) -> tuple[np.ndarray, ...]:
    axes = []
    for (lo, hi), n in zip(ranges, counts):
        nodes = np.linspace(lo, hi, int(n))
        axes.append(0.5 * (nodes[1:] + nodes[:-1]) if cell_centres else nodes)
    return tuple(g.ravel() for g in np.meshgrid(*axes, indexing="ij"))


def _as_col_row(result) -> tuple[np.ndarray, np.ndarray]:
    if isinstance(result, np.ndarray) and result.ndim == 2 and result.shape[1] == 2:
        return result[:, 0], result[:, 1]
    col, row = result
    return np.asarray(col, dtype=float).ravel(), np.asarray(row, dtype=float).ravel()


def _normalised(pts, off, scale) -> list:
    """Ground coordinates ``(lon, lat, h)`` normalised by the RPC offsets and scales."""
    return [(p - o) / sc for p, o, sc in zip(pts, off, scale)]


def _fit_pixel_coordinate(terms, v, check_terms, v_check, v_off: float, v_scale: float,
                          s: float, ridges, iterations: int):
    """Fit one image coordinate (line or sample) as a ratio of the ``terms``.

    ``v`` and ``v_check`` are the coordinate (``origin`` convention, shift ``s``) at the
    nodes and the check points, ``v_off, v_scale`` its RPC offset and scale. Returns
    the numerator, the denominator and the misfit at the check points (px).
    """
    num, den = _fit_coordinate(terms, (v - s - v_off) / v_scale, check_terms,
                               (v_check - s - v_off) / v_scale, ridges, iterations)
    misfit = (check_terms @ num) / (check_terms @ den) * v_scale + v_off - (v_check - s)
    return num, den, misfit


def fit_rpc(
    project_fn: Callable,
    lon_range: Sequence[float], lat_range: Sequence[float], h_range: Sequence[float],
    size: tuple[int, int],
    *,
    grid: tuple[int, int, int] = (20, 20, 7),
    origin: str = "corner",
    ridge: Union[float, Sequence[float]] = RIDGES,
    iterations: int = 10,
    source: str = "<simulated>",
) -> tuple[RpcModel, float, float]:
    """Terrain-independent RPC fit of a rigorous sensor model.

    The ground domain ``lon_range x lat_range x h_range`` (which sets the RPC offsets
    and scales) is sampled on a ``grid`` of nodes; line and sample are fitted
    separately as cubic rationals (RPC00B), by linear least squares of the linearised
    equations reweighted by the denominator (Tao & Hu 2001), with a ridge term
    ``ridge * I`` on the normal equations that keeps the denominators near 1. The fit is
    checked on the grid's cell centres (points between the nodes); with several
    ``ridge`` values, each coordinate takes the one with the smallest largest misfit
    there among the fits whose denominator stays above 0.5 (so for a smooth sensor the
    smallest ridge, for one that no cubic rational describes a stronger one that keeps
    the denominator from a pole).

    Parameters
    ----------
    project_fn : callable
        ``project_fn(lon, lat, h) -> (col, row)`` (or an ``(n, 2)`` array) for 1-D
        arrays, in the ``origin`` convention, e.g.
        ``lambda lo, la, h: pushbroom_project(sensor, lo, la, h)``.
    lon_range, lat_range, h_range : (float, float)
        The domain (degrees, degrees, ellipsoidal m).
    size : (int, int)
        ``(n_cols, n_rows)`` of the image; SAMP/LINE offsets and scales are its middle
        and half size.
    grid : (int, int, int)
        Nodes in lon, lat, h (at least 4 each for the cubic terms).
    origin : {"corner", "center"}
        Pixel convention of ``project_fn``.
    ridge : float or sequence of float
        Tikhonov parameter(s) (normalised coordinates); default :data:`RIDGES`.
    iterations : int
        Reweighting iterations at most.
    source : str
        ``RpcModel.source``.

    Returns
    -------
    rpc : RpcModel
    fit_rms_px : float
        RMS of the radial misfit ``hypot(dcol, drow)`` on the check points (px).
    fit_max_px : float
        Largest radial misfit on the check points (px).
    """
    s = _shift(origin)
    n_cols, n_rows = int(size[0]), int(size[1])
    ranges = [tuple(map(float, r)) for r in (lon_range, lat_range, h_range)]
    off = [0.5 * (lo + hi) for lo, hi in ranges]
    scale = [0.5 * (hi - lo) for lo, hi in ranges]
    samp_off, samp_scale = 0.5 * n_cols, 0.5 * n_cols
    line_off, line_scale = 0.5 * n_rows, 0.5 * n_rows
    ridges = np.atleast_1d(np.asarray(ridge, dtype=float))
    nodes, check = _grid(ranges, grid, False), _grid(ranges, grid, True)
    terms = rpc_terms(*_normalised(nodes, off, scale))
    t = rpc_terms(*_normalised(check, off, scale))
    col, row = _as_col_row(project_fn(*nodes))
    col_k, row_k = _as_col_row(project_fn(*check))
    line_num, line_den, d_row = _fit_pixel_coordinate(terms, row, t, row_k, line_off,
                                                      line_scale, s, ridges, iterations)
    samp_num, samp_den, d_col = _fit_pixel_coordinate(terms, col, t, col_k, samp_off,
                                                      samp_scale, s, ridges, iterations)
    radial = np.hypot(d_col, d_row)
    rpc = RpcModel(
        line_off=line_off, samp_off=samp_off, lat_off=off[1], long_off=off[0],
        height_off=off[2], line_scale=line_scale, samp_scale=samp_scale,
        lat_scale=scale[1], long_scale=scale[0], height_scale=scale[2],
        line_num=line_num, line_den=line_den, samp_num=samp_num, samp_den=samp_den,
        source=source)
    return rpc, float(np.sqrt(np.mean(radial**2))), float(np.max(radial))


def image_domain(
    sensor: PushbroomSensor, h_range: Sequence[float], margin: float = 0.02
) -> tuple[tuple[float, float], tuple[float, float]]:
    """The lon/lat bounding box of an image's footprint over a height range.

    Parameters
    ----------
    sensor : PushbroomSensor
    h_range : (float, float)
        Lowest and highest ellipsoidal height (m).
    margin : float
        Fraction of the box's width added on every side.

    Returns
    -------
    lon_range, lat_range : (float, float)
    """
    n_cols, n_rows = sensor.size
    edge = np.linspace(0.0, 1.0, 9)
    col = np.concatenate([edge * n_cols, np.full(9, n_cols), edge * n_cols, np.zeros(9)])
    row = np.concatenate([np.zeros(9), edge * n_rows, np.full(9, n_rows), edge * n_rows])
    lons, lats = [], []
    for h in h_range:
        lo, la = pushbroom_localize(sensor, col, row, h)
        lons.append(lo)
        lats.append(la)
    lons, lats = np.concatenate(lons), np.concatenate(lats)
    d_lon, d_lat = margin * np.ptp(lons), margin * np.ptp(lats)
    return ((float(lons.min() - d_lon), float(lons.max() + d_lon)),
            (float(lats.min() - d_lat), float(lats.max() + d_lat)))


def biased_project(rpc: RpcModel, params, lon, lat, h, origin: str = "corner") -> np.ndarray:
    """The RPC projection plus the image-space bias (Grodecki & Dial 2003).

    ``col' = col + a0 + a1 u + a2 v``, ``row' = row + b0 + b1 u + b2 v`` with
    ``u = (col_c - SAMP_OFF) / SAMP_SCALE``, ``v = (row_c - LINE_OFF) / LINE_SCALE`` of the
    raw (centre-convention) RPC values (the definition of
    :func:`vectoradjust.sensor.rpc.biased_partials`, computed here independently).

    Parameters
    ----------
    rpc : RpcModel
    params : array_like, shape (6,)
        ``a0, a1, a2, b0, b1, b2`` (px).
    lon, lat, h : array_like
    origin : {"corner", "center"}

    Returns
    -------
    numpy.ndarray, shape (n, 2)
        ``col', row'``.
    """
    p = np.asarray(params, dtype=float)
    raw = np.asarray(rpc.project(lon, lat, h, origin="center"), dtype=float)
    out = np.array(rpc.project(lon, lat, h, origin=origin), dtype=float)
    u = (raw[:, 0] - rpc.samp_off) / rpc.samp_scale
    v = (raw[:, 1] - rpc.line_off) / rpc.line_scale
    out[:, 0] += p[0] + p[1] * u + p[2] * v
    out[:, 1] += p[3] + p[4] * u + p[5] * v
    return out

