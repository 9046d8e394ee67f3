"""Bias direction and statement, RMSE and the standards built on it: NSSDA and ASPRS 2023.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from vectoradjust.accuracy.stats.circular import _json, _out, circular_error

__all__ = ["rmse", "rmse_summary", "nssda", "asprs2023", "bias_direction", "bias_statement"]


_COMPASS = (
    "north",
    "north-east",
    "east",
    "south-east",
    "south",
    "south-west",
    "west",
    "north-west",
)


def bias_direction(mean_dx: float, mean_dy: float):
    """Length, azimuth and compass direction of a mean error vector.

    Parameters
    ----------
    mean_dx, mean_dy : float
        Mean error towards east (X) and north (Y).

    Returns
    -------
    magnitude : float
        ``hypot(mean_dx, mean_dy)``.
    azimuth : float
        Degrees clockwise from north in [0, 360); NaN when the magnitude is 0.
    direction : str
        8-point compass name ("north", "north-east", ..., "north-west"), each
        sector 45 degrees wide and centred on its direction; "none" for a zero
        vector, "" when an input is NaN.
    """
    dx, dy = float(mean_dx), float(mean_dy)
    if not (math.isfinite(dx) and math.isfinite(dy)):
        return math.nan, math.nan, ""
    mag = math.hypot(dx, dy)
    if mag == 0.0:
        return 0.0, math.nan, "none"
    az = math.degrees(math.atan2(dx, dy)) % 360.0
    return mag, az, _COMPASS[int(math.floor(az / 45.0 + 0.5)) % 8]


def bias_statement(mean_dx: float, mean_dy: float, units: str = "m", decimals: int = 1) -> str:
    """A sentence such as ``"14.0 m towards south-east"`` for a mean error vector.

    Parameters
    ----------
    mean_dx, mean_dy : float
        Mean error towards east and north.
    units : str, optional
    decimals : int, optional

    Returns
    -------
    str
        ``"<magnitude> <units> towards <direction>"``; ``"no bias"`` for a zero vector
        and ``"bias unknown"`` when an input is NaN.
    """
    mag, _, name = bias_direction(mean_dx, mean_dy)
    if name == "":
        return "bias unknown"
    if name == "none":
        return "no bias"
    return f"{mag:.{decimals}f} {units} towards {name}"


# ---------------------------------------------------------------------------
# RMSE and standards
# ---------------------------------------------------------------------------


def rmse(d, axis=0):
    """Root mean square of ``d`` along ``axis``, ignoring NaNs.

    Parameters
    ----------
    d : array_like
    axis : int or None, optional

    Returns
    -------
    float or numpy.ndarray
        ``sqrt(mean(d^2))`` over the finite values; NaN where there are none.
    """
    a = np.asarray(d, dtype=float)
    a = np.where(np.isfinite(a), a, np.nan)
    sq = a * a
    cnt = np.sum(~np.isnan(sq), axis=axis)
    tot = np.nansum(sq, axis=axis)
    with np.errstate(divide="ignore", invalid="ignore"):
        res = np.where(cnt > 0, np.sqrt(tot / np.maximum(cnt, 1)), np.nan)
    return _out(res)


def rmse_summary(dx, dy, dz=None) -> dict[str, Any]:
    """RMSE per axis and horizontal, the ``summary.json`` block of docs/method.md section 9.

    A row counts when every given component (dx, dy and, if given, dz) is finite;
    all RMSEs are taken over those rows, so that ``rmse_horizontal^2 =
    rmse_x^2 + rmse_y^2`` holds exactly.

    Parameters
    ----------
    dx, dy : array_like, shape (n,)
        Errors (or residuals) along X and Y.
    dz : array_like, shape (n,), optional

    Returns
    -------
    dict
        ``{count, rmse_x, rmse_y, rmse_z, rmse_horizontal}``; ``count`` is an int,
        the others plain floats, or None when ``count`` is 0 (``rmse_z`` is None
        too when ``dz`` is not given).
    """
    cols = [np.asarray(dx, dtype=float).ravel(), np.asarray(dy, dtype=float).ravel()]
    if dz is not None:
        cols.append(np.asarray(dz, dtype=float).ravel())
    n = {c.size for c in cols}
    if len(n) != 1:
        raise ValueError("dx, dy (and dz) must have the same length")
    a = np.column_stack(cols) if cols[0].size else np.zeros((0, len(cols)))
    good = np.all(np.isfinite(a), axis=1)
    a = a[good]
    count = int(a.shape[0])
    if count == 0:
        return {
            "count": 0,
            "rmse_x": None,
            "rmse_y": None,
            "rmse_z": None,
            "rmse_horizontal": None,
        }
    r = np.sqrt(np.mean(a * a, axis=0))
    return {
        "count": count,
        "rmse_x": float(r[0]),
        "rmse_y": float(r[1]),
        "rmse_z": float(r[2]) if dz is not None else None,
        "rmse_horizontal": float(math.hypot(r[0], r[1])),
    }


def nssda(
    rmse_x: float | None,
    rmse_y: float | None,
    rmse_z: float | None = None,
    *,
    units: str = "meters",
    decimals: int = 2,
) -> dict[str, Any]:
    """NSSDA accuracy at the 95 % confidence level (FGDC-STD-007.3-1998).

    Horizontal: ``1.7308 RMSE_r`` when ``RMSE_x = RMSE_y`` (to 1e-9 relative);
    ``2.4477 * 0.5 (RMSE_x + RMSE_y)`` when ``0.6 < RMSE_min/RMSE_max < 1``
    (Greenwalt and Schultz, as NSSDA prescribes); outside that range NSSDA gives no
    formula and the exact 95 % radius of ``N(0, diag(RMSE_x^2, RMSE_y^2))`` is used
    (``horizontal_method`` says which). The exact radius is always reported as
    ``horizontal_95_exact``. Vertical: ``1.9600 RMSE_z``.

    Parameters
    ----------
    rmse_x, rmse_y : float or None
    rmse_z : float, optional
    units : str, optional
        Unit name for the statements (default "meters").
    decimals : int, optional
        Decimals in the statements (default 2).

    Returns
    -------
    dict
        ``rmse_r, ratio, horizontal_95, horizontal_95_exact, horizontal_method,
        vertical_95, horizontal_statement, vertical_statement`` (None where not
        available), e.g. ``"Tested 4.35 (meters) horizontal accuracy at 95%
        confidence level"``.
    """
    rx, ry, rz = _json(rmse_x), _json(rmse_y), _json(rmse_z)
    out: dict[str, Any] = {
        "rmse_x": rx,
        "rmse_y": ry,
        "rmse_z": rz,
        "rmse_r": None,
        "ratio": None,
        "horizontal_95": None,
        "horizontal_95_exact": None,
        "horizontal_method": None,
        "vertical_95": None,
        "horizontal_statement": None,
        "vertical_statement": None,
    }
    if rx is not None and ry is not None:
        if rx < 0 or ry < 0:
            raise ValueError("RMSE values must be >= 0")
        rr, ratio, h95, exact, method = _nssda_horizontal(rx, ry)
        out.update(
            rmse_r=rr,
            ratio=ratio,
            horizontal_95=float(h95),
            horizontal_95_exact=float(exact),
            horizontal_method=method,
            horizontal_statement=(
                f"Tested {h95:.{decimals}f} ({units}) horizontal accuracy at 95% confidence level"
            ),
        )
    if rz is not None:
        if rz < 0:
            raise ValueError("RMSE values must be >= 0")
        v95 = 1.9600 * rz
        out.update(
            vertical_95=v95,
            vertical_statement=(
                f"Tested {v95:.{decimals}f} ({units}) vertical accuracy at 95% confidence level"
            ),
        )
    return out


def _nssda_horizontal(rx: float, ry: float) -> tuple[float, float, Any, Any, str]:
    """NSSDA's horizontal 95 % value (:func:`nssda`).

    Returns
    -------
    tuple
        ``(rmse_r, ratio, horizontal_95, horizontal_95_exact, horizontal_method)``.
    """
    rr = math.hypot(rx, ry)
    big, small = max(rx, ry), min(rx, ry)
    ratio = small / big if big > 0 else 1.0
    exact = circular_error(np.diag([rx * rx, ry * ry]), None, 0.95)
    if ratio >= 1.0 - 1e-9:
        h95, method = 1.7308 * rr, "1.7308 RMSE_r (RMSE_x = RMSE_y)"
    elif ratio > 0.6:
        h95, method = 2.4477 * 0.5 * (rx + ry), "2.4477 * 0.5 (RMSE_x + RMSE_y)"
    else:
        h95, method = exact, "exact 95% circle (RMSE_min/RMSE_max <= 0.6, no NSSDA formula)"
    return rr, ratio, h95, exact, method


def asprs2023(
    dx,
    dy,
    dz=None,
    *,
    survey_rmse_h: float | None = None,
    survey_rmse_v: float | None = None,
    units: str = "m",
    decimals: int = 3,
) -> dict[str, Any]:
    """Accuracy per the ASPRS Positional Accuracy Standards, Edition 2 (2023).

    ``RMSE_H = sqrt(RMSE_x^2 + RMSE_y^2)``, ``RMSE_V = RMSE_z``,
    ``RMSE_3D = sqrt(RMSE_H^2 + RMSE_V^2)``. Edition 2 no longer reports 95 %
    values, asks for at least 30 checkpoints and includes the checkpoints' own
    survey accuracy in the product accuracy; when ``survey_rmse_h`` /
    ``survey_rmse_v`` are given they are added in quadrature
    (``sqrt(RMSE_data^2 + RMSE_survey^2)``).

    The statement wording is our plain paraphrase of the standard's reporting
    clause (the official text was not available to check it against).

    Parameters
    ----------
    dx, dy : array_like, shape (n,)
        Checkpoint errors (data - checkpoint) along X and Y.
    dz : array_like, shape (n,), optional
    survey_rmse_h, survey_rmse_v : float, optional
        RMSE of the checkpoint survey itself.
    units : str, optional
    decimals : int, optional

    Returns
    -------
    dict
        ``count, rmse_x, rmse_y, rmse_h, rmse_v, rmse_3d, min_checkpoints_met,
        statement_h, statement_v, statement_3d`` (None where not available).
    """
    s = rmse_summary(dx, dy, dz)
    n = s["count"]
    rh = s["rmse_horizontal"]
    rv = s["rmse_z"]
    if rh is not None and survey_rmse_h is not None:
        rh = math.hypot(rh, float(survey_rmse_h))
    if rv is not None and survey_rmse_v is not None:
        rv = math.hypot(rv, float(survey_rmse_v))
    r3 = math.hypot(rh, rv) if (rh is not None and rv is not None) else None
    std = "ASPRS Positional Accuracy Standards for Digital Geospatial Data, Edition 2 (2023)"

    def sentence(kind: str, sym: str, val: float | None) -> str | None:
        if val is None:
            return None
        return (
            f"This data set was tested against {n} checkpoints following the {std}: "
            f"tested {kind} positional accuracy {sym} = {val:.{decimals}f} ({units})."
        )

    return {
        "count": n,
        "rmse_x": s["rmse_x"],
        "rmse_y": s["rmse_y"],
        "rmse_h": rh,
        "rmse_v": rv,
        "rmse_3d": r3,
        "min_checkpoints_met": n >= 30,
        "statement_h": sentence("horizontal", "RMSE_H", rh),
        "statement_v": sentence("vertical", "RMSE_V", rv),
        "statement_3d": sentence("three-dimensional", "RMSE_3D", r3),
    }

