"""Approximate object points (the start of the bundle adjustment and of check points).

The frame cameras' rays are intersected in closed form (:func:`ray_intersection`); an RPC
image has no ray, so its points are found by Gauss-Newton on their pixel observations
(:func:`rpc_intersection`), all points at once; :func:`approximate_points` does both for a
block that mixes the two. :func:`check_bias_determined` refuses an RPC bias model that
the block cannot determine.
"""

from __future__ import annotations

import numpy as np

from vectoradjust.errors import ProjectError
from vectoradjust.sensor.collinearity import rotation_matrix
from vectoradjust.sensor.models import SensorSet, observe_rpc

__all__ = [
    "inv3x3",
    "ray_intersection",
    "rpc_intersection",
    "approximate_points",
    "check_bias_determined",
    "pts_have_prior",
]


def inv3x3(a: np.ndarray) -> np.ndarray:
    """Closed-form inverse of a stack of 3x3 matrices ``(..., 3, 3)``.

    Singular blocks give ``inf``/``nan`` entries; callers check the determinant.
    """
    a = np.asarray(a, float)
    c00 = a[..., 1, 1] * a[..., 2, 2] - a[..., 1, 2] * a[..., 2, 1]
    c01 = a[..., 0, 2] * a[..., 2, 1] - a[..., 0, 1] * a[..., 2, 2]
    c02 = a[..., 0, 1] * a[..., 1, 2] - a[..., 0, 2] * a[..., 1, 1]
    c10 = a[..., 1, 2] * a[..., 2, 0] - a[..., 1, 0] * a[..., 2, 2]
    c11 = a[..., 0, 0] * a[..., 2, 2] - a[..., 0, 2] * a[..., 2, 0]
    c12 = a[..., 0, 2] * a[..., 1, 0] - a[..., 0, 0] * a[..., 1, 2]
    c20 = a[..., 1, 0] * a[..., 2, 1] - a[..., 1, 1] * a[..., 2, 0]
    c21 = a[..., 0, 1] * a[..., 2, 0] - a[..., 0, 0] * a[..., 2, 1]
    c22 = a[..., 0, 0] * a[..., 1, 1] - a[..., 0, 1] * a[..., 1, 0]
    det = a[..., 0, 0] * c00 + a[..., 0, 1] * c10 + a[..., 0, 2] * c20
    out = np.stack(
        [np.stack([c00, c01, c02], -1), np.stack([c10, c11, c12], -1),
         np.stack([c20, c21, c22], -1)],
        -2,
    )
    with np.errstate(divide="ignore", invalid="ignore"):
        return out / det[..., None, None]


def _block_sum(index: np.ndarray, values: np.ndarray, n: int) -> np.ndarray:
    """Sum ``values`` (k, ...) into ``n`` bins by ``index`` (k,), vectorised.

    The one definition (``adjust.bundle``, ``adjust.offsets`` and ``adjust.selfcal``
    import it from here); zeros for no values.
    """
    k = values.shape[0]
    inner = values.shape[1:]
    size = int(np.prod(inner)) if inner else 1
    if k == 0:
        return np.zeros((n,) + inner)
    flat = values.reshape(k, size)
    idx = (index[:, None] * size + np.arange(size)[None, :]).ravel()
    out = np.bincount(idx, weights=flat.ravel(), minlength=n * size)
    return out.reshape((n,) + inner)


def ray_intersection(
    eo: np.ndarray,
    obs_point: np.ndarray,
    obs_image: np.ndarray,
    obs_xy: np.ndarray,
    n_points: int,
    focal_length: float,
    principal_point=(0.0, 0.0),
) -> np.ndarray:
    """Linear least-squares intersection of image rays (approximations for points).

    Returns the point closest to all of its rays, ``(n_points, 3)``; points with fewer
    than two rays get NaN.
    """
    eo = np.asarray(eo, float)
    m_img = rotation_matrix(eo[:, 3], eo[:, 4], eo[:, 5]).reshape(-1, 3, 3)  # per image
    v = np.column_stack([
        obs_xy[:, 0] - principal_point[0],
        obs_xy[:, 1] - principal_point[1],
        np.full(len(obs_xy), -float(focal_length)),
    ])
    d = np.empty_like(v)  # M^T v (= v' M): direction in the ground frame, image by image
    order = np.argsort(obs_image, kind="stable")
    imgs, starts = np.unique(obs_image[order], return_index=True)
    for i, lo, hi in zip(imgs.tolist(), starts.tolist(), [*starts[1:].tolist(), len(order)]):
        sel = order[lo:hi]
        d[sel] = v[sel] @ m_img[i]
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    proj = np.eye(3)[None] - d[:, :, None] * d[:, None, :]
    c = eo[obs_image, :3]
    a = _block_sum(obs_point, proj, n_points)
    b = _block_sum(obs_point, c - d * np.sum(d * c, axis=1, keepdims=True), n_points)
    counts = np.bincount(obs_point, minlength=n_points)
    x = np.matmul(inv3x3(a), b[:, :, None])[:, :, 0]
    x[counts < 2] = np.nan
    return x


def rpc_intersection(sensors: SensorSet, params: np.ndarray, obs_point: np.ndarray,
                     obs_image: np.ndarray, obs_colrow: np.ndarray, n_points: int,
                     iterations: int = 10) -> np.ndarray:
    """Approximate object points from their observations on RPC images.

    Starts every point at the inverse RPC of its first observation at the RPC's height
    offset, then runs Gauss-Newton on the three coordinates of each point (unit
    weights), all points at once.

    Parameters
    ----------
    sensors : SensorSet
    params : numpy.ndarray, shape (n_images, 6)
        Bias parameters (the approximate values).
    obs_point, obs_image : numpy.ndarray of int, shape (k,)
        Observations on RPC images only.
    obs_colrow : numpy.ndarray, shape (k, 2)
    n_points : int
    iterations : int

    Returns
    -------
    numpy.ndarray, shape (n_points, 3)
        Object coordinates; NaN for points with fewer than two observations or whose
        iteration did not settle.
    """
    counts = np.bincount(obs_point, minlength=n_points)
    xyz = np.full((n_points, 3), np.nan)
    first = np.full(n_points, -1, np.int64)
    first[obs_point[::-1]] = np.arange(len(obs_point))[::-1]
    for i in np.unique(obs_image[first[first >= 0]]):
        sel = first[(first >= 0)]
        sel = sel[obs_image[sel] == i]
        rpc = sensors.rpc[i].rpc
        h = np.full(len(sel), float(rpc.height_off))
        ll = rpc.localize(obs_colrow[sel, 0], obs_colrow[sel, 1], h)
        xyz[obs_point[sel]] = sensors.frame.from_geodetic(np.column_stack([ll, h]))
    ok = counts >= 2
    for _ in range(iterations):
        x = np.where(ok[:, None] & np.isfinite(xyz), xyz, 0.0)
        llh, jac = sensors.frame.to_geodetic(x[obs_point])
        a = np.empty((len(obs_point), 2, 3))
        ell = np.empty((len(obs_point), 2))
        for i in np.unique(obs_image):
            sel = obs_image == i
            cr, _, a[sel] = observe_rpc(sensors.rpc[i], params[i], llh[sel], jac[sel])
            ell[sel] = obs_colrow[sel] - cr
        npp = _block_sum(obs_point, np.einsum("kri,krj->kij", a, a), n_points)
        npp[~ok] = np.eye(3)
        tp = _block_sum(obs_point, np.einsum("kri,kr->ki", a, ell), n_points)
        dx = np.einsum("mij,mj->mi", inv3x3(npp), tp)
        xyz = xyz + dx
        if np.nanmax(np.abs(dx[ok]), initial=0.0) < 1e-4:
            break
    xyz[~ok | ~np.isfinite(xyz).all(axis=1)] = np.nan
    return xyz


def approximate_points(sensors: SensorSet, eo: np.ndarray, obs_point: np.ndarray,
                       obs_image: np.ndarray, obs_xy: np.ndarray, n_points: int,
                       focal_length: float, principal_point) -> np.ndarray:
    """Approximate object points of a block that may mix frame and RPC images: the frame
    cameras' rays intersected, then the points they leave open from their RPC
    observations (:func:`rpc_intersection`). ``(n_points, 3)``, NaN where neither works."""
    rpc = sensors.is_rpc[obs_image]
    approx = np.full((n_points, 3), np.nan)
    if (~rpc).any():
        approx = ray_intersection(eo, obs_point[~rpc], obs_image[~rpc], obs_xy[~rpc], n_points,
                                  focal_length, principal_point)
    if rpc.any():
        fill = ~np.isfinite(approx).all(axis=1)
        from_rpc = rpc_intersection(sensors, eo, obs_point[rpc], obs_image[rpc], obs_xy[rpc],
                                    n_points)
        approx[fill] = from_rpc[fill]
    return approx


#: known points (with a coordinate prior) an RPC image needs for each bias model when its
#: free bias parameters have no prior
_NEEDED = {"none": 0, "shift": 1, "shift+drift": 2, "affine": 3}


def pts_have_prior(weight: np.ndarray) -> np.ndarray:
    """``(m,)`` bool: the point has a coordinate prior (control or road vertex)."""
    return np.abs(weight).reshape(len(weight), -1).sum(axis=1) > 0


def check_bias_determined(sensors: SensorSet, eo_sigma: np.ndarray, obs_point: np.ndarray,
                          obs_image: np.ndarray, obs_xy: np.ndarray, has_prior: np.ndarray,
                          image_ids: list) -> None:
    """Refuse an RPC image whose bias model the block cannot determine.

    An image whose estimated bias parameters all have a prior is always determined. Else
    it needs points with known coordinates (control points or road vertices) measured on
    it: one for ``shift``, two for ``shift+drift``, three not on one line for ``affine``.

    Raises
    ------
    ProjectError
        Naming the image, its bias model, what it has and what would determine it.
    """
    for i in sensors.rpc_images.tolist():
        img = sensors.rpc[i]
        free = img.free
        if not free.any() or np.isfinite(eo_sigma[i][free]).all():
            continue
        on = (obs_image == i) & has_prior[obs_point]
        pts, first = np.unique(obs_point[on], return_index=True)
        need = _NEEDED[img.bias]
        xy = obs_xy[np.flatnonzero(on)[first]]
        rank = np.linalg.matrix_rank(np.column_stack([np.ones(len(xy)), xy - xy.mean(0)]),
                                     tol=1.0) if len(xy) else 0
        if len(pts) >= need and (img.bias != "affine" or rank >= 3):
            continue
        smaller = [m for m, k in _NEEDED.items() if 0 < k <= len(pts) and k < need]
        raise ProjectError(
            f"RPC image {image_ids[i]!r}: bias = {img.bias!r} cannot be determined: it needs "
            f"{need} point(s) with known coordinates measured on the image"
            + (" that are not on one line" if img.bias == "affine" else "")
            + f", and the image has {len(pts)}",
            "Measure more control points (or road vertices) on it, give the bias parameters "
            "a-priori sigmas (bias_sigma = [shift px, drift px]), or use a smaller bias model"
            + (f" (bias = {smaller[-1]!r})" if smaller else ""),
            details={"image": image_ids[i], "bias": img.bias, "known_points": int(len(pts))})


#: normalised RPC coordinates beyond which a point is refused (the RPC's polynomials are
#: meaningless that far out: wrong CRS, zone, heights or image)
FAR_OUTSIDE = 3.0


def check_rpc_domain(sensors: SensorSet, xyz: np.ndarray, obs_point: np.ndarray,
                     obs_image: np.ndarray, image_ids: list, point_ids, warnings: list) -> None:
    """Warn about measured points outside an RPC's validity domain; refuse far outside.

    A point whose normalised longitude, latitude or height (``RpcModel.normalized``)
    exceeds 1.1 in magnitude is outside the domain the vendor fitted the RPCs on: a
    warning. Beyond :data:`FAR_OUTSIDE` the point cannot be on the image at all.

    Raises
    ------
    ProjectError
        A point far outside, naming the image, the point, its height and the domain.
    """
    for i in sensors.rpc_images.tolist():
        rpc = sensors.rpc[i].rpc
        pts = np.unique(obs_point[obs_image == i])
        pts = pts[np.isfinite(xyz[pts]).all(axis=1)]
        if not len(pts):
            continue
        llh, _ = sensors.frame.to_geodetic(xyz[pts])
        norm = np.abs(rpc.normalized(llh[:, 0], llh[:, 1], llh[:, 2]))
        worst = norm.max(axis=1)
        k = int(np.argmax(worst))
        where = (f"e.g. point {str(point_ids[pts[k]])!r} at longitude {llh[k, 0]:.5f}, "
                 f"latitude {llh[k, 1]:.5f}, height {llh[k, 2]:.1f} m; the RPC covers "
                 f"longitude {rpc.long_off:.5f} +- {abs(rpc.long_scale):.5f}, latitude "
                 f"{rpc.lat_off:.5f} +- {abs(rpc.lat_scale):.5f}, height {rpc.height_off:.0f} "
                 f"+- {abs(rpc.height_scale):.0f} m (ellipsoidal)")
        if worst[k] > FAR_OUTSIDE:
            raise ProjectError(
                f"RPC image {image_ids[i]!r}: {int((worst > FAR_OUTSIDE).sum())} measured "
                f"point(s) lie far outside the RPC's validity domain ({where})",
                "Check the project crs (zone), the point coordinates (X and Y swapped, "
                "degrees), the heights (ellipsoidal for RPCs: heights = \"orthometric\" with "
                "vertical_crs converts them) and that the measurements belong to this image")
        if worst[k] > 1.1:
            warnings.append(
                f"RPC image {image_ids[i]!r}: {int((worst > 1.1).sum())} of {len(pts)} measured "
                f"point(s) lie outside the RPC's validity domain ({where}); the RPC "
                "extrapolates there")
