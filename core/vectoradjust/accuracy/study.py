"""The numerical pieces of the dissertation's experiments (``vectoradjust study``).

- which ground control points a study keeps: well spread (:func:`spread_subset`), in one
  part of the block (:func:`directional_subset`, the "3-North" / "3-East" / "3-SW"
  configurations) or at random (:func:`random_subsets`);
- the spread of a quantity over repeated runs (:func:`spread_stats`);
- the per-point truth table: database and adjusted coordinates against the true ones,
  and whether the adjustment moved the point closer (:func:`truth_point_table`);
- the shift a shifted database's residuals recover (:func:`recovered_shift`).

Numpy only; the orchestration (runs of :func:`vectoradjust.pipeline.run` on modified
project data, tables, figures) is :mod:`vectoradjust.files.study`.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["DIRECTIONS", "spread_subset", "directional_subset", "random_subsets",
           "parse_configuration", "spread_stats", "truth_point_table", "moved_closer_share",
           "recovered_shift"]

#: unit vectors (east, north) of the named parts of a block; "Center" is handled apart
DIRECTIONS = {
    "North": (0.0, 1.0), "South": (0.0, -1.0), "East": (1.0, 0.0), "West": (-1.0, 0.0),
    "NE": (math.sqrt(0.5), math.sqrt(0.5)), "NW": (-math.sqrt(0.5), math.sqrt(0.5)),
    "SE": (math.sqrt(0.5), -math.sqrt(0.5)), "SW": (-math.sqrt(0.5), -math.sqrt(0.5)),
}
_ALIASES = {"n": "North", "north": "North", "s": "South", "south": "South", "e": "East",
            "east": "East", "w": "West", "west": "West", "ne": "NE", "nw": "NW", "se": "SE",
            "sw": "SW", "northeast": "NE", "northwest": "NW", "southeast": "SE",
            "southwest": "SW", "center": "Center", "centre": "Center", "c": "Center",
            "spread": "Spread"}


def spread_subset(xy: np.ndarray, k: int) -> np.ndarray:
    """Indices of ``k`` well-spread points (greedy farthest-point selection).

    The first point is the one farthest from the centroid; each next one is the point
    farthest from those already chosen, so the subset covers the extent of ``xy``.

    Parameters
    ----------
    xy : numpy.ndarray, shape (n, 2)
    k : int
        Number wanted (``min(k, n)`` are returned).

    Returns
    -------
    numpy.ndarray of int
        Indices into ``xy`` in the order chosen.
    """
    xy = np.asarray(xy, float).reshape(-1, 2)
    n = len(xy)
    k = int(min(max(k, 0), n))
    if k == 0:
        return np.zeros(0, np.int64)
    chosen = [int(np.argmax(np.hypot(*(xy - xy.mean(axis=0)).T)))]
    dmin = np.hypot(*(xy - xy[chosen[0]]).T)
    for _ in range(k - 1):
        nxt = int(np.argmax(dmin))
        chosen.append(nxt)
        dmin = np.minimum(dmin, np.hypot(*(xy - xy[nxt]).T))
    return np.asarray(chosen, np.int64)


def directional_subset(xy: np.ndarray, k: int, direction: str) -> np.ndarray:
    """Indices of ``k`` points in one part of the block ("3-North", "3-SW", ...).

    The candidates are the ``max(k, ceil(n / 3))`` points farthest along the direction
    (from the centroid; for ``"Center"`` the nearest to the centroid); of them the ``k``
    best spread (:func:`spread_subset`) are kept, so three northern points are not on
    one line when the northern third of the block allows it.

    Parameters
    ----------
    xy : numpy.ndarray, shape (n, 2)
    k : int
    direction : str
        A key of :data:`DIRECTIONS`, ``"Center"`` or ``"Spread"`` (all points are
        candidates).

    Returns
    -------
    numpy.ndarray of int
    """
    xy = np.asarray(xy, float).reshape(-1, 2)
    n = len(xy)
    rel = xy - xy.mean(axis=0)
    if direction == "Spread":
        return spread_subset(xy, k)
    if direction == "Center":
        score = -np.hypot(rel[:, 0], rel[:, 1])
    else:
        score = rel @ np.asarray(DIRECTIONS[direction])
    m = int(min(n, max(k, math.ceil(n / 3))))
    cand = np.argsort(-score, kind="stable")[:m]
    return cand[spread_subset(xy[cand], k)]


def random_subsets(n: int, k: int, repeats: int, seed: int = 0) -> list:
    """``repeats`` random subsets of ``k`` of ``n`` points (reproducible from ``seed``).

    Returns
    -------
    list of numpy.ndarray of int
        Sorted indices; subset ``r`` of size ``k`` depends only on ``(seed, k, r)``.
    """
    k = int(min(k, n))
    return [np.sort(np.random.default_rng([int(seed), k, r]).choice(n, k, replace=False))
            for r in range(int(repeats))]


def parse_configuration(name: str):
    """``"3-North"`` -> ``(3, "North")``; None when ``name`` is not of that form."""
    count, _, part = str(name).strip().partition("-")
    if not count.isdigit() or int(count) < 1:
        return None
    canon = _ALIASES.get(part.strip().lower().replace("-", "").replace(" ", ""))
    return (int(count), canon) if canon else None


def spread_stats(values) -> dict:
    """Mean, standard deviation (n - 1), minimum, maximum and count of the finite values."""
    a = np.asarray([np.nan if v is None else v for v in values], float)
    a = a[np.isfinite(a)]
    if not a.size:
        return {"count": 0, "mean": None, "sd": None, "min": None, "max": None}
    return {"count": int(a.size), "mean": float(a.mean()),
            "sd": float(a.std(ddof=1)) if a.size > 1 else 0.0,
            "min": float(a.min()), "max": float(a.max())}


def truth_point_table(database_xyz: np.ndarray, adjusted_xyz: np.ndarray,
                      truth_xyz: np.ndarray) -> dict:
    """Per point: database - truth and adjusted - truth, and whether it moved closer.

    Parameters
    ----------
    database_xyz, adjusted_xyz, truth_xyz : numpy.ndarray, shape (n, 3)

    Returns
    -------
    dict of str to numpy.ndarray
        ``dX_before, dY_before, dZ_before, D_before`` (horizontal distance),
        ``dX_after, dY_after, dZ_after, D_after`` and ``Closer`` (1 where the adjusted
        point is horizontally closer to the truth than the database point, else 0).
    """
    before = np.asarray(database_xyz, float) - np.asarray(truth_xyz, float)
    after = np.asarray(adjusted_xyz, float) - np.asarray(truth_xyz, float)
    d_before = np.hypot(before[:, 0], before[:, 1])
    d_after = np.hypot(after[:, 0], after[:, 1])
    return {"dX_before": before[:, 0], "dY_before": before[:, 1], "dZ_before": before[:, 2],
            "D_before": d_before, "dX_after": after[:, 0], "dY_after": after[:, 1],
            "dZ_after": after[:, 2], "D_after": d_after,
            "Closer": (d_after < d_before).astype(np.int64)}


def moved_closer_share(d_before: np.ndarray, d_after: np.ndarray):
    """Share (0-1) of the points whose distance to the truth shrank; None without points."""
    b = np.asarray(d_before, float)
    a = np.asarray(d_after, float)
    ok = np.isfinite(a) & np.isfinite(b)
    return float(np.mean(a[ok] < b[ok])) if ok.any() else None


def recovered_shift(v_unshifted: np.ndarray, v_shifted: np.ndarray) -> dict:
    """The shift that the residuals of a shifted database recover.

    With the database translated by ``t``, its residuals V = adjusted - database become
    ``V - t`` (the adjusted points come from the images), so ``mean(V_unshifted -
    V_shifted)`` estimates ``t``; its spread shows how much else changed.

    Parameters
    ----------
    v_unshifted, v_shifted : numpy.ndarray, shape (n, 3)
        Residuals of the same points in the two runs.

    Returns
    -------
    dict
        ``dx, dy, dz`` (means), ``sd_x, sd_y, sd_z`` and ``count``.
    """
    d = np.asarray(v_unshifted, float) - np.asarray(v_shifted, float)
    d = d[np.isfinite(d).all(axis=1)]
    if not len(d):
        return {"count": 0, "dx": None, "dy": None, "dz": None, "sd_x": None, "sd_y": None,
                "sd_z": None}
    mean = d.mean(axis=0)
    sd = d.std(axis=0, ddof=1) if len(d) > 1 else np.zeros(3)
    return {"count": int(len(d)), "dx": float(mean[0]), "dy": float(mean[1]),
            "dz": float(mean[2]), "sd_x": float(sd[0]), "sd_y": float(sd[1]),
            "sd_z": float(sd[2])}
