"""What ``vectoradjust measure`` and the QGIS "Measure on the images" algorithm both show.

The rows of the measurement layer (predicted, manual, transferred and automatic
positions on every image, :func:`measurement_rows`), the terrain height a transfer
assumes where nothing better is known (:func:`height_from_samples`,
:func:`control_height`) and an RPC image's bias line (:func:`rpc_bias_line`): computed
here once, so that the command line and the plugin (which only converts and calls,
docs/architecture.md) say the same. Numpy only.
"""

from __future__ import annotations

from typing import Callable, Optional

import numpy as np

__all__ = ["measurement_rows", "height_from_samples", "control_height", "rpc_bias_line"]


def _sigma_px(tab: dict, i: int) -> float:
    """Precision of a match in pixels: the larger of its column and row sigmas (LSM), or
    the fit's RMS of a road junction."""
    if "sigma_col" in tab:
        return float(np.fmax(tab["sigma_col"][i], tab["sigma_row"][i]))
    return float(tab["rms"][i])


def measurement_rows(geoms: dict, pred: dict, measured: Optional[dict] = None,
                     transferred: Optional[dict] = None,
                     automatic: Optional[dict] = None) -> list[dict]:
    """One row per position on an image: predictions, manual, transferred, automatic.

    Parameters
    ----------
    geoms : dict of str to ImageGeometry or RpcGeometry
        The images' geometries (:func:`vectoradjust.files.measuring.image_geometries`);
        a row without ``x_mm`` gets it from its pixel position.
    pred : dict
        :func:`vectoradjust.files.measuring.predict`'s table (``source`` "predicted",
        with the search window ``win_major``, ``win_minor``, ``win_angle``).
    measured : dict, optional
        The manual measurements (``point_id``, ``image_id``, ``col``, ``row``; accepted).
    transferred, automatic : dict, optional
        :func:`vectoradjust.files.measuring.transfer`'s and
        :func:`~vectoradjust.files.measuring.measure_roads`' tables (``sigma_px`` the
        larger LSM sigma, or the junction fit's RMS; ``flags`` their flag text).

    Returns
    -------
    list of dict
        Keys ``image_id, point_id, source, col, row, x_mm, y_mm, flags, accepted`` and,
        where they apply, ``kind, win_major, win_minor, win_angle, ncc, rho, sigma_px``.

    Examples
    --------
    >>> rows = measurement_rows({}, {"point_id": [], "image_id": []},
    ...                         {"point_id": ["p"], "image_id": ["L"], "col": [float("nan")],
    ...                          "row": [float("nan")]})
    >>> rows[0]["source"], rows[0]["accepted"]
    ('manual', 1)
    """
    rows = [dict(image_id=pred["image_id"][i], point_id=pred["point_id"][i],
                 kind=pred["kind"][i], source="predicted", col=pred["col"][i],
                 row=pred["row"][i], x_mm=pred["x"][i], y_mm=pred["y"][i],
                 win_major=pred["win_major"][i], win_minor=pred["win_minor"][i],
                 win_angle=pred["win_angle"][i], flags="", accepted=0)
            for i in range(len(pred["point_id"]))]
    if measured is not None:
        rows += [dict(image_id=measured["image_id"][i], point_id=measured["point_id"][i],
                      source="manual", col=measured["col"][i], row=measured["row"][i],
                      flags="", accepted=1) for i in range(len(measured["point_id"]))]
    for tab, src in ((transferred, "transferred"), (automatic, "automatic")):
        if tab is None:
            continue
        rows += [dict(image_id=tab["image_id"][i], point_id=tab["point_id"][i], source=src,
                      col=tab["col"][i], row=tab["row"][i],
                      ncc=tab["ncc"][i] if "ncc" in tab else np.nan,
                      rho=tab["rho"][i] if "rho" in tab else np.nan, sigma_px=_sigma_px(tab, i),
                      flags=tab["flag_text"][i], accepted=int(tab["accepted"][i]))
                 for i in range(len(tab["point_id"]))]
    for r in rows:
        if "x_mm" not in r and np.isfinite(r["col"]):
            mm = geoms[str(r["image_id"])].pixel_to_measured_mm(
                np.array([[r["col"], r["row"]]], float))
            r["x_mm"], r["y_mm"] = mm[0]
    return rows


def height_from_samples(sample: Callable[[np.ndarray], np.ndarray],
                        fallback: Optional[float] = None) -> Callable[[np.ndarray], np.ndarray]:
    """A terrain height function from a DEM sampler that may return NaN (outside the DEM,
    nodata): NaN heights become ``fallback``, or the mean of the heights found in the
    same call (0 when none is found).

    Parameters
    ----------
    sample : callable
        ``sample(xy) -> z`` for ground coordinates ``xy`` (n, 2).
    fallback : float, optional
        The height where the DEM has none (e.g. the DEM's mean height).

    Returns
    -------
    callable
        ``height(xy) -> z`` (n,), finite everywhere.

    Examples
    --------
    >>> h = height_from_samples(lambda xy: np.array([10.0, np.nan, 14.0]))
    >>> h(np.zeros((3, 2))).tolist()
    [10.0, 12.0, 14.0]
    """
    def height(xy):
        z = np.asarray(sample(np.asarray(xy, float).reshape(-1, 2)), float)
        ok = np.isfinite(z)
        fill = fallback if fallback is not None else (float(z[ok].mean()) if ok.any() else 0.0)
        return np.where(ok, z, fill)
    return height


def control_height(control) -> Optional[float]:
    """The mean height of the control points (a transfer's terrain height without a DEM),
    or None without control.

    Examples
    --------
    >>> from types import SimpleNamespace
    >>> control_height(SimpleNamespace(xyz=np.array([[0, 0, 10.0], [1, 1, 20.0]])))
    15.0
    """
    if control is None or not len(control.xyz):
        return None
    return float(np.mean(np.asarray(control.xyz, float)[:, 2]))


def rpc_bias_line(image_id: str, g, digits: str = ".2f") -> str:
    """One line on an RPC image's bias: the column and row shift, their sigmas and where
    they came from (``g``: :class:`vectoradjust.measure.geometry.RpcGeometry`).

    Examples
    --------
    >>> from types import SimpleNamespace
    >>> g = SimpleNamespace(bias=np.array([1.5, 0, 0, -2.25, 0, 0]),
    ...                     bias_cov=np.diag([0.04, 0, 0, 0.09, 0, 0]), bias_source="summary")
    >>> rpc_bias_line("S1", g)
    'RPC image S1: bias 1.50, -2.25 px (column, row shift), sigma 0.20, 0.30 px from summary'
    """
    sd = np.sqrt(np.clip(np.diag(np.asarray(g.bias_cov, float))[[0, 3]], 0.0, None))
    return (f"RPC image {image_id}: bias {g.bias[0]:.2f}, {g.bias[3]:.2f} px (column, row "
            f"shift), sigma {sd[0]:{digits}}, {sd[1]:{digits}} px from {g.bias_source}")
