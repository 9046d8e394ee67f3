"""The equal-error map of a stereo pair: the sigma of a forward-intersected ground point
on a grid over the pair's overlap (:func:`equal_error_grid`, :func:`equal_error_range`).

Heart module: numpy and scipy only.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Callable, NamedTuple, Optional, Union

import numpy as np

from vectoradjust.accuracy import propagate as prop
from vectoradjust.accuracy.derived.covariance import DEFAULT_FRAME_MM, _check_result
from vectoradjust.errors import ProjectError
from vectoradjust.sensor.collinearity import rotation_matrix

if TYPE_CHECKING:  # pragma: no cover
    from vectoradjust.results import AdjustmentRun

__all__ = ["EqualErrorGrid", "image_footprint", "equal_error_grid", "equal_error_range"]


# ----------------------------------------------------------------------- equal error map
class EqualErrorGrid(NamedTuple):
    """Equal-error map of a stereo pair (:func:`equal_error_grid`).

    ``X, Y`` are the grid nodes (pixel centres; row 0 is the northernmost), the sigmas
    (m) are NaN outside the stereo overlap, ``transform`` is the affine geotransform of
    the pixel grid in ``Affine(a, b, c, d, e, f)`` order:
    ``x = a col + b row + c``, ``y = d col + e row + f`` (pixel corners).
    """

    X: np.ndarray
    Y: np.ndarray
    sigma_x: np.ndarray
    sigma_y: np.ndarray
    sigma_z: np.ndarray
    transform: tuple


def _frame_mm(run: AdjustmentRun, frame_mm) -> np.ndarray:
    if frame_mm is not None:
        return np.broadcast_to(np.asarray(frame_mm, float), (2,)).copy()
    cal = getattr(run.data.camera, "calibration", None)
    px = getattr(cal, "pixel_size", None) if not isinstance(cal, dict) else cal.get("pixel_size")
    sz = getattr(cal, "image_size", None) if not isinstance(cal, dict) else cal.get("image_size")
    if px is not None and sz is not None:
        return np.broadcast_to(np.asarray(px, float), (2,)) * np.asarray(sz, float)
    return np.array([DEFAULT_FRAME_MM, DEFAULT_FRAME_MM])


def image_footprint(eo, focal_length: float, frame_mm, z: float,
                    principal_point=(0.0, 0.0)) -> np.ndarray:
    """Ground footprint of a frame image on the plane ``Z = z``.

    Parameters
    ----------
    eo : array_like, shape (6,)
        ``XL, YL, ZL, omega, phi, kappa`` (m, rad).
    focal_length : float
        mm.
    frame_mm : float or (float, float)
        Width and height of the image format (mm), centred on the principal point.
    z : float
        Terrain height of the plane.
    principal_point : (float, float)

    Returns
    -------
    numpy.ndarray, shape (4, 2)
        Corners X, Y (counter-clockwise when the image is not mirrored).
    """
    e = np.asarray(eo, float)
    w, h = np.broadcast_to(np.asarray(frame_mm, float), (2,)) / 2.0
    corners = np.array([[-w, -h], [w, -h], [w, h], [-w, h]])
    v = np.column_stack([corners, np.full(4, -float(focal_length))])
    m = rotation_matrix(e[3], e[4], e[5])
    d = v @ m  # M' v for each corner (ground direction)
    with np.errstate(divide="ignore", invalid="ignore"):
        s = (z - e[2]) / d[:, 2]
    if not np.all(np.isfinite(s) & (s > 0)):
        raise ProjectError(
            "An image corner's ray does not reach the terrain (the image looks above the "
            "horizon or the terrain is above the camera)",
            "Check the exterior orientation and the terrain height of the equal-error map",
        )
    return e[None, :2] + s[:, None] * d[:, :2]


def _inside_convex(poly: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Points inside (or on) a convex polygon of either orientation."""
    p0 = poly
    p1 = np.roll(poly, -1, axis=0)
    cross = ((p1[:, 0] - p0[:, 0])[:, None] * (y.ravel()[None, :] - p0[:, 1][:, None])
             - (p1[:, 1] - p0[:, 1])[:, None] * (x.ravel()[None, :] - p0[:, 0][:, None]))
    inside = np.all(cross >= 0, axis=0) | np.all(cross <= 0, axis=0)
    return inside.reshape(x.shape)


def _pair_indices(run: AdjustmentRun, image_pair) -> tuple[int, int]:
    ids = list(run.image_ids)
    if image_pair is None:
        if len(ids) < 2:
            raise ProjectError("The adjustment has fewer than two images, so there is no "
                               "stereo pair", "Measure points on at least two images")
        ia, ib = 0, 1
    else:
        ia, ib = _named_pair(ids, image_pair)
    prob = run.result.problem
    if prob is not None and prob.is_rpc[[ia, ib]].any():
        raise ProjectError(
            f"Images {ids[ia]!r} and {ids[ib]!r}: the equal-error map and the two-step "
            "orientation are frame camera methods (a perspective centre, a rotation); an "
            "RPC image has neither",
            "Name two frame images with --images, or use adjust: its CE90/LE90 per vertex "
            "cover RPC images")
    return ia, ib


def _named_pair(ids: list, image_pair) -> tuple[int, int]:
    pair = [str(i) for i in image_pair]
    bad = [i for i in pair if i not in ids]
    if len(pair) != 2 or bad or pair[0] == pair[1]:
        raise ProjectError(
            f"Image pair {pair} is not two different images of this adjustment"
            + (f" (unknown: {', '.join(bad)})" if bad else ""),
            f"Name two of: {', '.join(ids)}",
        )
    return ids.index(pair[0]), ids.index(pair[1])


def equal_error_grid(
    run: AdjustmentRun,
    spacing: float = 10.0,
    image_pair: Optional[Sequence[str]] = None,
    z: Union[None, float, np.ndarray, Callable[[np.ndarray, np.ndarray], np.ndarray]] = None,
    *,
    frame_mm=None,
) -> EqualErrorGrid:
    """Equal-error map: sigma X, Y, Z of a new point intersected from a stereo pair.

    Over the stereo overlap of the pair (the two image footprints on the plane of the
    mean terrain height, intersected), every grid node is projected into both images and
    intersected back (:func:`vectoradjust.accuracy.propagate.point_sigma_grid`): the covariance
    ``s0^2 N_pp^-1 + N_pp^-1 N_pe C_ee N_ep N_pp^-1`` includes the adjusted exterior
    orientation's 12x12 joint covariance ``C_ee = s0^2 S^-1`` of the pair. The photo
    coordinate sigma is the median of the pair's measurement sigmas.

    Parameters
    ----------
    run : AdjustmentRun
    spacing : float
        Grid spacing (m); nodes at multiples of it.
    image_pair : (str, str), optional
        Image ids (default: the first two images of the adjustment).
    z : None, float, array or callable, optional
        Terrain height of the nodes: ``None`` = mean height of the adjusted points, a
        constant, an array of the grid's shape, or ``z(X, Y)`` (e.g. a DEM sampler;
        NaN heights fall back to the mean).
    frame_mm : float or (float, float), optional
        Image format (mm); default from the camera calibration (pixel size x image
        size), else 230 mm.

    Returns
    -------
    EqualErrorGrid
    """
    if not spacing > 0:
        raise ProjectError(f"Grid spacing {spacing!r} is not positive",
                           "Give a spacing in metres, e.g. --spacing 10")
    res = run.result
    _check_result(res)
    prob = res.problem
    ia, ib = _pair_indices(run, image_pair)
    eo = res.eo[[ia, ib]]
    sel = np.r_[6 * ia:6 * ia + 6, 6 * ib:6 * ib + 6]
    cee = res.variance_factor * res.eo_cofactor()[np.ix_(sel, sel)]
    on_pair = np.isin(prob.obs_image, [ia, ib])
    sig = float(np.median(prob.obs_sigma[on_pair])) if on_pair.any() else \
        float(np.median(prob.obs_sigma))
    sig *= np.sqrt(res.variance_factor)
    zmean = float(np.mean(res.xyz[:, 2]))
    frame = _frame_mm(run, frame_mm)
    f = prob.focal_length
    fa = image_footprint(eo[0], f, frame, zmean)
    fb = image_footprint(eo[1], f, frame, zmean)
    xs, ys = _overlap_nodes(run, (ia, ib), fa, fb, spacing)
    X, Y = np.meshgrid(xs, ys)
    inside = _inside_convex(fa, X, Y) & _inside_convex(fb, X, Y)
    Z = _node_heights(z, X, Y, zmean)
    sx = np.full(X.shape, np.nan)
    sy = np.full(X.shape, np.nan)
    sz = np.full(X.shape, np.nan)
    if inside.any():
        gs = prop.point_sigma_grid(eo, cee, f, sig, X[inside], Y[inside], Z[inside])
        sx[inside], sy[inside], sz[inside] = gs.sigma_x, gs.sigma_y, gs.sigma_z
    transform = (float(spacing), 0.0, float(xs[0] - spacing / 2), 0.0, -float(spacing),
                 float(ys[0] + spacing / 2))
    return EqualErrorGrid(X, Y, sx, sy, sz, transform)


def _overlap_nodes(run: AdjustmentRun, pair: tuple[int, int], fa: np.ndarray, fb: np.ndarray,
                   spacing: float) -> tuple[np.ndarray, np.ndarray]:
    """The node coordinates (multiples of ``spacing``) over the bounding box of the two
    footprints' overlap: ``xs`` west to east, ``ys`` north to south.

    Raises
    ------
    ProjectError
        If the footprints do not overlap by at least one node.
    """
    x0 = max(fa[:, 0].min(), fb[:, 0].min())
    x1 = min(fa[:, 0].max(), fb[:, 0].max())
    y0 = max(fa[:, 1].min(), fb[:, 1].min())
    y1 = min(fa[:, 1].max(), fb[:, 1].max())
    xs = np.arange(np.ceil(x0 / spacing), np.floor(x1 / spacing) + 1) * spacing
    ys = (np.arange(np.ceil(y0 / spacing), np.floor(y1 / spacing) + 1) * spacing)[::-1]
    if xs.size == 0 or ys.size == 0:
        ia, ib = pair
        raise ProjectError(
            f"Images {run.image_ids[ia]!r} and {run.image_ids[ib]!r} do not overlap (or the "
            f"overlap is smaller than the spacing {spacing} m)",
            "Choose a stereo pair with overlap (--images) or a smaller spacing",
        )
    return xs, ys


def _node_heights(z, X: np.ndarray, Y: np.ndarray, zmean: float) -> np.ndarray:
    """The terrain height of the nodes from the ``z`` of :func:`equal_error_grid` (NaN and
    None: ``zmean``)."""
    if z is None:
        Z = np.full(X.shape, zmean)
    elif callable(z):
        Z = np.asarray(z(X, Y), float).reshape(X.shape)
    else:
        Z = np.broadcast_to(np.asarray(z, float), X.shape).astype(float)
    return np.where(np.isfinite(Z), Z, zmean)


def equal_error_range(grid: EqualErrorGrid) -> dict:
    """Range of an equal-error grid inside the overlap.

    Returns
    -------
    dict
        ``nodes`` (inside the overlap), ``spacing`` and for ``sigma_x``, ``sigma_y``,
        ``sigma_z`` and ``sigma_h`` (``sqrt(sx^2 + sy^2)``) the ``min``, ``max``,
        ``mean`` and ``median`` (m).
    """
    sh = np.hypot(grid.sigma_x, grid.sigma_y)
    out: dict = {"nodes": int(np.isfinite(grid.sigma_z).sum()),
                 "spacing": float(grid.transform[0])}
    for name, a in (("sigma_x", grid.sigma_x), ("sigma_y", grid.sigma_y),
                    ("sigma_z", grid.sigma_z), ("sigma_h", sh)):
        st = _stats(a)
        out[name] = {k: st[k] for k in ("min", "max", "mean", "median")}
    return out


def _stats(a: np.ndarray) -> dict:
    a = np.asarray(a, float)
    a = a[np.isfinite(a)]
    if a.size == 0:
        return {"count": 0, "mean": None, "median": None, "min": None, "max": None}
    return {"count": int(a.size), "mean": float(a.mean()), "median": float(np.median(a)),
            "min": float(a.min()), "max": float(a.max())}
