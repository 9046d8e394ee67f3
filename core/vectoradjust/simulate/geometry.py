"""The simulated set-up: flight geometry, terrain, DEM and the random streams.

The dissertation's stereo set-up (``docs/method.md`` sections 1, 9): vertical aerial
photographs of a Wild RC10 (``f = 152.4 mm``, 23 x 23 cm, 1:4000, 609.6 m above a
terrain at about 188 m, 80 % forward overlap, east-west flight line, EPSG:32616 around
the Purdue campus), a smooth true terrain (:func:`terrain_height`) and a DEM sampled
from it.

Every random component draws from its own stream ``default_rng([seed, crc32(tag)])``
(:func:`_rng`), so that changing, say, the number of tie points leaves the road
databases unchanged.
"""

from __future__ import annotations

import math
import zlib
from collections.abc import Sequence

import numpy as np

# --- the dissertation's set-up -------------------------------------------------------
CRS = "EPSG:32616"
CENTER = (506400.0, 4475000.0)  # model centre (UTM 16N), Purdue campus area
FOCAL_LENGTH = 152.4  # mm, Wild RC10
FORMAT_HALF = 115.0  # mm: 23 x 23 cm format
PHOTO_SCALE = 4000.0
TERRAIN_LEVEL = 188.0  # m MSL, mean terrain height of the model
FLYING_HEIGHT = FOCAL_LENGTH / 1000.0 * PHOTO_SCALE  # 609.6 m above terrain
FORWARD_OVERLAP = 0.8
GROUND_HALF = FORMAT_HALF / 1000.0 * PHOTO_SCALE  # 460 m
BASE = (1.0 - FORWARD_OVERLAP) * 2.0 * GROUND_HALF  # 184 m
DEM_CELL = 5.0
DEM_NODATA = -9999.0
CONTROL_SIGMA = (0.05, 0.05, 0.08)  # m, surveyed GCPs
DEFAULT_DATE = "1999-10-05"  # acquisition date written for provenance (simulated)
_INSET = 30.0  # m kept free inside the stereo overlap for control, ties and dense roads


def terrain_height(x, y, center: Sequence[float] = CENTER) -> np.ndarray:
    """True terrain height (m MSL) of the simulated area.

    A gentle plane (4 m/km rising east, 3 m/km falling north), a 6 m hill 120 m east
    and 80 m north of the centre and a 2.5 m hollow to the south-west:
    ``z = 186 + 0.004 dx - 0.003 dy + 6 exp(-((dx-120)^2 + (dy-80)^2) / (2 180^2))
    - 2.5 exp(-((dx+250)^2 + (dy+200)^2) / (2 120^2))``, ``dx, dy`` from ``center``.

    Parameters
    ----------
    x, y : array_like
        Ground coordinates (m), broadcastable.
    center : (float, float)
        Model centre.

    Returns
    -------
    numpy.ndarray
    """
    dx = np.asarray(x, float) - center[0]
    dy = np.asarray(y, float) - center[1]
    hill = 6.0 * np.exp(-((dx - 120.0) ** 2 + (dy - 80.0) ** 2) / (2.0 * 180.0**2))
    hollow = 2.5 * np.exp(-((dx + 250.0) ** 2 + (dy + 200.0) ** 2) / (2.0 * 120.0**2))
    return TERRAIN_LEVEL - 2.0 + 0.004 * dx - 0.003 * dy + hill - hollow


def _rng(seed: int, tag: str) -> np.random.Generator:
    return np.random.default_rng([int(seed), zlib.crc32(tag.encode("utf-8"))])


def _terrain_xyz(xy: np.ndarray, center) -> np.ndarray:
    """``(n, 2)`` ground XY with the true terrain height as Z, rounded to 0.1 mm."""
    return np.round(np.column_stack([xy, terrain_height(xy[:, 0], xy[:, 1], center)]), 4)


def _stereo_overlap(plan_x: np.ndarray, cy: float):
    """The stereo overlap (seen on >= 2 images) of the flight plan, and an inset.

    Returns ``(overlap_x, inset_x, inset_y)``, each a ``(low, high)`` pair (m).
    """
    ov_x = (plan_x[0] + BASE - GROUND_HALF, plan_x[-1] - BASE + GROUND_HALF)
    ov_y = (cy - GROUND_HALF, cy + GROUND_HALF)
    in_x = (ov_x[0] + _INSET, ov_x[1] - _INSET)
    in_y = (ov_y[0] + _INSET, ov_y[1] - _INSET)
    return ov_x, in_x, in_y


def _make_dem(true_eo, center, seed, dem_noise):
    margin = 60.0
    x_lo = math.floor((true_eo[:, 0].min() - GROUND_HALF - margin) / DEM_CELL) * DEM_CELL
    x_hi = math.ceil((true_eo[:, 0].max() + GROUND_HALF + margin) / DEM_CELL) * DEM_CELL
    y_lo = math.floor((true_eo[:, 1].min() - GROUND_HALF - margin) / DEM_CELL) * DEM_CELL
    y_hi = math.ceil((true_eo[:, 1].max() + GROUND_HALF + margin) / DEM_CELL) * DEM_CELL
    cols = int(round((x_hi - x_lo) / DEM_CELL))
    rows = int(round((y_hi - y_lo) / DEM_CELL))
    transform = (float(x_lo), DEM_CELL, 0.0, float(y_hi), 0.0, -DEM_CELL)
    xc = x_lo + (np.arange(cols) + 0.5) * DEM_CELL
    yc = y_hi - (np.arange(rows) + 0.5) * DEM_CELL
    z = terrain_height(xc[None, :], yc[:, None], center)
    z = z + _rng(seed, "dem").normal(0.0, dem_noise, z.shape)
    grid = z.astype(np.float32)
    grid[:4, :4] = DEM_NODATA  # a nodata patch in the north-west margin, outside every image
    return grid, transform
