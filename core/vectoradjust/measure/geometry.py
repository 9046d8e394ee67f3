"""Image geometry for measurement: prediction of pixel positions and their uncertainty.

An :class:`ImageGeometry` is one image's exterior orientation with the camera and the
``[corrections]`` switches: :meth:`ImageGeometry.to_pixel` maps object points to the
pixel (column, row) where the camera records them (collinearity equations, then the
inverse of the image coordinate refinement: lens distortion, refraction, earth
curvature, principal point, pixel size or fiducial affine - :func:`sensor.refine.distort`),
:meth:`ImageGeometry.to_ground` maps pixels back to the ground (refinement, ray,
intersection with a height function such as a DEM).

The uncertainty of a prediction is propagated to the image by the partials of the
collinearity equations (``DESIGN.md`` section 2) and the local Jacobian of the
mm -> pixel mapping: ``C_px = J (A_pt C_xyz A_pt' + A_eo C_eo A_eo') J'``. A search window
is the ellipse ``d' C_px^-1 d <= k^2``; ``k = 3.717`` holds a 2-D normal error with
probability 0.999.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Callable, Optional

import numpy as np

from vectoradjust.errors import CameraError
from vectoradjust.sensor.camera import CameraCalibration
from vectoradjust.sensor.collinearity import partials, project, rotation_matrix
from vectoradjust.sensor.refine import AffineFit, distort, refine

__all__ = [
    "ImageGeometry",
    "WINDOW_K",
    "pixel_covariance",
    "window_axes",
    "inside_window",
    "local_affine",
    "inv2",
]

#: Scale of the search ellipse: P(chi2 with 2 dof <= k^2) = 0.999.
WINDOW_K = 3.7169


@dataclass
class ImageGeometry:
    """Exterior orientation, camera and refinement of one image.

    Attributes
    ----------
    image_id : str
    eo : numpy.ndarray, shape (6,)
        ``XL, YL, ZL`` (m), ``omega, phi, kappa`` (radians).
    camera : CameraCalibration
        Needs ``pixel_size`` and ``image_size`` (digital frame) unless ``affine`` is given.
    corrections : dict
        ``[corrections]`` switches as :func:`sensor.refine.refine` takes them.
    terrain_height : float or None
        Mean terrain height (m), needed by refraction and earth curvature.
    affine : AffineFit or None
        Fiducial affine pixel -> mm of a scanned photograph.
    sigma_eo : numpy.ndarray, shape (6,)
        Standard deviations of the exterior orientation (m, radians); 0 = known.
    """

    image_id: str
    eo: np.ndarray
    camera: CameraCalibration
    corrections: Mapping[str, bool] = field(default_factory=dict)
    terrain_height: Optional[float] = None
    affine: Optional[AffineFit] = None
    sigma_eo: np.ndarray = field(default_factory=lambda: np.zeros(6))

    def __post_init__(self) -> None:
        self.eo = np.asarray(self.eo, float).reshape(6)
        self.sigma_eo = np.asarray(self.sigma_eo, float).reshape(6)
        if self.affine is None and (self.camera.pixel_size is None
                                    or self.camera.image_size is None):
            raise CameraError(
                f"image {self.image_id!r}: pixel positions need the camera's pixel_size and "
                "image_size (a digital frame) or the image's fiducial affine",
                "Add pixel_size (mm) and image_size = [columns, rows] to [camera], or give "
                "measured fiducials of the image",
                details={"image_id": self.image_id})

    # ------------------------------------------------------------------ mapping
    def _kw(self, n_shape) -> dict[str, Any]:
        sw = dict(self.corrections)
        need_h = sw.get("refraction") or sw.get("earth_curvature")
        return {
            "camera": self.camera, "affine": self.affine, "unit": "pixel",
            "flying_height": self.eo[2] if need_h else None,
            "terrain_height": self.terrain_height if need_h else None,
            "corrections": sw, "image_id": self.image_id,
        }

    @property
    def _pp(self) -> tuple[float, float]:
        """Principal point the collinearity equations use with refined coordinates."""
        if dict(self.corrections).get("principal_point", True):
            return (0.0, 0.0)
        return tuple(self.camera.principal_point)

    def photo_to_pixel(self, xy: np.ndarray) -> np.ndarray:
        """Refined photo coordinates (mm) -> pixel (column, row) as the camera records them."""
        xy = np.asarray(xy, float)
        if xy.size == 0:
            return xy.reshape(xy.shape[:-1] + (2,))
        return distort(xy, **self._kw(xy.shape[:-1]))

    def pixel_to_photo(self, px: np.ndarray) -> np.ndarray:
        """Pixel (column, row) -> refined photo coordinates (mm) (:func:`refine`)."""
        px = np.asarray(px, float)
        if px.size == 0:
            return px.reshape(px.shape[:-1] + (2,))
        return refine(px, **self._kw(px.shape[:-1])).xy

    def pixel_to_measured_mm(self, px: np.ndarray) -> np.ndarray:
        """Pixel -> photo mm as measured (fiducial affine or pixel size only, unrefined).

        These are the ``x, y`` of ``image_points.csv`` (``[measurements] unit = "mm"``):
        ``vectoradjust adjust`` applies the principal point, lens distortion, refraction
        and earth curvature to them as ``[corrections]`` says.
        """
        sw = {k: False for k in ("principal_point", "distortion", "refraction",
                                 "earth_curvature")}
        sw["affine"] = True
        px = np.asarray(px, float)
        if px.size == 0:
            return px.reshape(px.shape[:-1] + (2,))
        return refine(px, camera=self.camera, affine=self.affine, unit="pixel",
                      corrections=sw, image_id=self.image_id).xy

    def to_pixel(self, xyz: np.ndarray) -> np.ndarray:
        """Object points ``(n, 3)`` -> pixel (column, row) ``(n, 2)``."""
        xyz = np.asarray(xyz, float).reshape(-1, 3)
        xy = project(self.eo, xyz, self.camera.focal_length, self._pp)
        return self.photo_to_pixel(xy)

    def pixel_jacobian(self, xy: np.ndarray, h: float = 1e-3) -> np.ndarray:
        """``d(column, row) / d(x, y)`` at refined photo coordinates, ``(n, 2, 2)``."""
        xy = np.asarray(xy, float).reshape(-1, 2)
        jac = np.empty((len(xy), 2, 2))
        for j in range(2):
            e = np.zeros(2)
            e[j] = h
            jac[:, :, j] = (self.photo_to_pixel(xy + e) - self.photo_to_pixel(xy - e)) / (2 * h)
        return jac

    def ray(self, px: np.ndarray) -> np.ndarray:
        """Unit direction (object frame) of the ray through each pixel, ``(n, 3)``."""
        xy = self.pixel_to_photo(np.asarray(px, float).reshape(-1, 2))
        x0, y0 = self._pp
        v = np.stack([xy[:, 0] - x0, xy[:, 1] - y0,
                      np.full(len(xy), -self.camera.focal_length)], axis=1)
        m = rotation_matrix(*self.eo[3:])
        # M' v (image -> object frame), written out: a (n, 3) @ (3, 3) product through
        # BLAS is slow on a busy machine
        d = v[:, 0, None] * m[0] + v[:, 1, None] * m[1] + v[:, 2, None] * m[2]
        return d / np.sqrt(np.sum(d * d, axis=1))[:, None]

    def to_ground(self, px: np.ndarray, height: Callable[[np.ndarray], np.ndarray] | float,
                  z0: Optional[float] = None, iterations: int = 30,
                  tol: float = 1e-4) -> np.ndarray:
        """Intersect the rays of pixels with the terrain, ``(n, 3)``.

        Parameters
        ----------
        px : array_like, shape (n, 2)
        height : callable or float
            ``height(xy (n, 2)) -> z (n,)`` (e.g. a DEM) or a constant height.
        z0 : float, optional
            Starting height (default: the height below the exposure station).
        iterations, tol : int, float
            Fixed-point iteration ``Z <- height(XY(Z))`` until it moves less than ``tol`` m.

        Returns
        -------
        numpy.ndarray, shape (n, 3)
            NaN where the iteration leaves the height function's domain.
        """
        d = self.ray(px)
        hfun = height if callable(height) else (lambda xy: np.full(len(xy), float(height)))
        c = self.eo[:3]
        z = np.full(len(d), hfun(c[None, :2])[0] if z0 is None else z0, float)
        for _ in range(iterations):
            t = (z - c[2]) / d[:, 2]
            xy = c[:2] + t[:, None] * d[:, :2]
            z_new = hfun(xy)
            moved = np.abs(z_new - z)
            z = z_new
            if not np.any(moved > tol):
                break
        t = (z - c[2]) / d[:, 2]
        return np.column_stack([c[:2] + t[:, None] * d[:, :2], z])


def pixel_covariance(geom: ImageGeometry, xyz: np.ndarray, cov_xyz: np.ndarray) -> np.ndarray:
    """Covariance ``(n, 2, 2)`` (pixels^2) of the predicted pixel positions of ``xyz``.

    Parameters
    ----------
    geom : ImageGeometry
        Its ``sigma_eo`` is the orientation's uncertainty (independent parameters).
    xyz : array_like, shape (n, 3)
    cov_xyz : array_like, shape (n, 3, 3) or (n, 3)
        Covariance of each object point (or its standard deviations per axis).

    Returns
    -------
    numpy.ndarray, shape (n, 2, 2)
        ``J (A_pt C_xyz A_pt' + A_eo C_eo A_eo') J'``.
    """
    xyz = np.asarray(xyz, float).reshape(-1, 3)
    c = np.asarray(cov_xyz, float)
    if c.ndim == 2:
        c = np.einsum("ni,ij->nij", c**2, np.eye(3))
    a_eo, a_pt = partials(np.broadcast_to(geom.eo, (len(xyz), 6)), xyz,
                          geom.camera.focal_length)
    c_mm = a_pt @ c @ np.swapaxes(a_pt, 1, 2)
    c_mm += (a_eo * geom.sigma_eo**2) @ np.swapaxes(a_eo, 1, 2)
    xy = project(geom.eo, xyz, geom.camera.focal_length, geom._pp)
    jac = geom.pixel_jacobian(xy)
    return jac @ c_mm @ np.swapaxes(jac, 1, 2)


def inv2(c: np.ndarray) -> np.ndarray:
    """Inverses of ``(..., 2, 2)`` matrices in closed form (NaN where singular)."""
    c = np.asarray(c, float)
    det = c[..., 0, 0] * c[..., 1, 1] - c[..., 0, 1] * c[..., 1, 0]
    out = np.empty_like(c)
    out[..., 0, 0] = c[..., 1, 1]
    out[..., 1, 1] = c[..., 0, 0]
    out[..., 0, 1] = -c[..., 0, 1]
    out[..., 1, 0] = -c[..., 1, 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        return out / np.where(det != 0, det, np.nan)[..., None, None]


def window_axes(cov: np.ndarray, k: float = WINDOW_K) -> np.ndarray:
    """Search ellipse of each covariance: ``(n, 3)`` semi-major, semi-minor (px), angle.

    The angle (degrees) is that of the major axis from the column axis towards the row
    axis.
    """
    cov = np.asarray(cov, float).reshape(-1, 2, 2)
    a, b, d = cov[:, 0, 0], cov[:, 0, 1], cov[:, 1, 1]
    root = np.sqrt(0.25 * (a - d) ** 2 + b * b)
    big = np.clip(0.5 * (a + d) + root, 0.0, None)
    small = np.clip(0.5 * (a + d) - root, 0.0, None)
    ang = np.degrees(0.5 * np.arctan2(2.0 * b, a - d))
    return np.column_stack([k * np.sqrt(big), k * np.sqrt(small), ang])


def inside_window(cov: np.ndarray, d: np.ndarray, k: float = WINDOW_K,
                  floor_px: float = 0.5) -> np.ndarray:
    """Whether offsets ``d (n, 2)`` lie in the ellipses ``d' C^-1 d <= k^2``.

    ``floor_px`` (pixels) is added in quadrature to both axes so that a nearly exact
    prediction still has a window of a fraction of a pixel.
    """
    cov = np.asarray(cov, float).reshape(-1, 2, 2) + floor_px**2 / k**2 * np.eye(2)
    d = np.asarray(d, float).reshape(-1, 2)
    m = np.einsum("ni,nij,nj->n", d, inv2(cov), d)
    return m <= k * k


def local_affine(src: ImageGeometry, dst: ImageGeometry, px_src: np.ndarray,
                 height: Callable[[np.ndarray], np.ndarray] | float,
                 step: float = 2.0) -> tuple[np.ndarray, np.ndarray]:
    """Transfer pixels from one image to another over the terrain, with the local affine.

    Parameters
    ----------
    src, dst : ImageGeometry
    px_src : array_like, shape (n, 2)
        Pixels of ``src``.
    height : callable or float
        Terrain height function (as :meth:`ImageGeometry.to_ground`).
    step : float
        Pixel step of the central differences.

    Returns
    -------
    px_dst : numpy.ndarray, shape (n, 2)
        The same ground points in ``dst``.
    a : numpy.ndarray, shape (n, 2, 2)
        ``d px_dst / d px_src`` over the local terrain (``px_dst ~ px_dst0 + a dp``).
    """
    p = np.asarray(px_src, float).reshape(-1, 2)
    n = len(p)
    offs = np.array([[0, 0], [step, 0], [-step, 0], [0, step], [0, -step]], float)
    allp = (p[None, :, :] + offs[:, None, :]).reshape(-1, 2)
    g = src.to_ground(allp, height)
    q = dst.to_pixel(g).reshape(5, n, 2)
    a = np.empty((n, 2, 2))
    a[:, :, 0] = (q[1] - q[2]) / (2 * step)
    a[:, :, 1] = (q[3] - q[4]) / (2 * step)
    return q[0], a
