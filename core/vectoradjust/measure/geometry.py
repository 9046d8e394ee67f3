"""Image geometry for measurement: prediction of pixel positions and their uncertainty.

An :class:`ImageGeometry` is one image's exterior orientation with the camera and the
``[corrections]`` switches: :meth:`ImageGeometry.to_pixel` maps object points to the
pixel (column, row) where the camera records them (collinearity equations, then the
inverse of the image coordinate refinement: lens distortion, refraction, earth
curvature, principal point, pixel size or fiducial affine - :func:`sensor.refine.distort`),
:meth:`ImageGeometry.to_ground` maps pixels back to the ground (refinement, ray,
intersection with a height function such as a DEM).

The uncertainty of a prediction is propagated to the image by the partials of the
collinearity equations (``docs/method.md`` section 2) and the local Jacobian of the
mm -> pixel mapping: ``C_px = J (A_pt C_xyz A_pt' + A_eo C_eo A_eo') J'``. A search window
is the ellipse ``d' C_px^-1 d <= k^2``; ``k = 3.717`` holds a 2-D normal error with
probability 0.999.

An :class:`RpcGeometry` is the same for a satellite image with RPCs
(:mod:`vectoradjust.sensor.rpc`): object point -> ground frame (longitude, latitude,
ellipsoidal height) -> RPC -> plus the image-space bias ``a0 .. b2`` (the bias an
adjustment estimated, else zero); its covariance is
``C_px = A_pt C_xyz A_pt' + A_b C_b A_b'`` with the RPC partials chained through the
ground frame's Jacobian (``A_pt``), the bias partials (``A_b``) and the bias covariance
``C_b`` (estimated, else the a-priori sigmas of :func:`rpc_bias_prior`). Its pixels are
GDAL's: ``(0, 0)`` is the upper-left *corner* of the first pixel, so the array element
``[r, c]`` of an image is centred on ``(c + 0.5, r + 0.5)`` (``index_offset = 0.5``; a
frame camera's pixel coordinates are array indices, ``index_offset = 0``).

:func:`transfer_covariance` is the covariance of a point carried from one image to
another over the terrain (the two images' orientation or bias, the pointing of the
reference measurement, and the terrain height's uncertainty along the reference image's
line of sight); it takes any pair of the two geometries.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Callable, ClassVar, Optional

import numpy as np

from vectoradjust.errors import CameraError
from vectoradjust.sensor.camera import CameraCalibration
from vectoradjust.sensor.collinearity import partials, project, rotation_matrix
from vectoradjust.sensor.models import bias_free_mask
from vectoradjust.sensor.refine import AffineFit, distort, refine
from vectoradjust.sensor.rpc import biased_partials

__all__ = [
    "ImageGeometry",
    "RpcGeometry",
    "WINDOW_K",
    "DEFAULT_BIAS_SIGMA",
    "pixel_covariance",
    "rpc_bias_prior",
    "point_at_height",
    "height_parallax",
    "transfer_covariance",
    "window_axes",
    "inside_window",
    "local_affine",
    "inv2",
]

#: Scale of the search ellipse: P(chi2 with 2 dof <= k^2) = 0.999.
WINDOW_K = 3.7169

#: A-priori sigmas (px) of the bias parameters of an RPC image that the bias model
#: estimates when neither the project (``bias_sigma``) nor an adjustment gives them: the
#: shift ``a0, b0`` (unless the RPC states its ``ERR_BIAS``, converted to pixels) and the
#: drift and affine terms ``a1, a2, b1, b2`` (px at the image edge). Vendor RPCs of
#: today's sub-metre satellites are located within a few metres, i.e. some pixels.
DEFAULT_BIAS_SIGMA = (10.0, 2.0)


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
    cov_eo : numpy.ndarray, shape (6, 6), optional
        Full covariance of the exterior orientation (m, radians), with the correlations
        between position and attitude (an adjustment's estimate); when given it
        replaces ``sigma_eo`` (which becomes the square root of its diagonal).
        Position and attitude errors that are strongly correlated largely cancel on
        the ground, so the search windows shrink.

    Notes
    -----
    ``index_offset`` is the pixel coordinate of the centre of the array element 0: 0
    for the default ``pixel_origin = "center"`` and 0.5 for a camera whose
    ``pixel_origin`` is ``"corner"`` (and for none with a fiducial affine: its pixels
    are the array indices the fiducials were measured in).
    """

    image_id: str
    eo: np.ndarray
    camera: CameraCalibration
    corrections: Mapping[str, bool] = field(default_factory=dict)
    terrain_height: Optional[float] = None
    affine: Optional[AffineFit] = None
    sigma_eo: np.ndarray = field(default_factory=lambda: np.zeros(6))
    cov_eo: Optional[np.ndarray] = None
    #: pixel coordinate of the centre of the image array's element 0 (pixel
    #: coordinates are array indices); an instance whose camera's ``pixel_origin`` is
    #: ``"corner"`` has 0.5
    index_offset: ClassVar[float] = 0.0

    def __post_init__(self) -> None:
        self.eo = np.asarray(self.eo, float).reshape(6)
        self.sigma_eo = np.asarray(self.sigma_eo, float).reshape(6)
        if self.cov_eo is not None:
            self.cov_eo = np.asarray(self.cov_eo, float).reshape(6, 6)
            self.sigma_eo = np.sqrt(np.clip(np.diag(self.cov_eo), 0.0, None))
        if self.affine is None and str(getattr(self.camera, "pixel_origin", "center")
                                       ).lower() == "corner":
            self.index_offset = 0.5  # type: ignore[misc]  # element [r, c] at c + 0.5
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

    def eo_covariance(self) -> np.ndarray:
        """Covariance ``(6, 6)`` of the exterior orientation (``cov_eo``, else the
        diagonal of ``sigma_eo``)."""
        if self.cov_eo is not None:
            return self.cov_eo
        return np.diag(self.sigma_eo**2)

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


def pixel_covariance(geom: ImageGeometry, xyz: np.ndarray, cov_xyz: np.ndarray,
                     cov_eo_xyz: Optional[np.ndarray] = None) -> np.ndarray:
    """Covariance ``(n, 2, 2)`` (pixels^2) of the predicted pixel positions of ``xyz``.

    The joint covariance of the image's orientation and the point, propagated to the
    image: ``J [A_eo A_pt] [[C_eo, C_eo,pt], [C_pt,eo, C_pt]] [A_eo A_pt]' J'``.

    Parameters
    ----------
    geom : ImageGeometry or RpcGeometry
        Its :meth:`ImageGeometry.eo_covariance` (``cov_eo`` with the correlations
        between position and attitude, else the independent ``sigma_eo``) is the
        orientation's uncertainty; an RPC image's ``bias_cov`` that of its bias
        (:meth:`RpcGeometry.pixel_covariance`).
    xyz : array_like, shape (n, 3)
    cov_xyz : array_like, shape (n, 3, 3) or (n, 3)
        Covariance of each object point (or its standard deviations per axis).
    cov_eo_xyz : array_like, shape (n, 6, 3), optional
        Cross-covariance of the orientation and each point (e.g. both from one
        adjustment); default none.

    Returns
    -------
    numpy.ndarray, shape (n, 2, 2)
        ``J (A_pt C_xyz A_pt' + A_eo C_eo A_eo' + A_eo C_eo,pt A_pt' + ...') J'``.
    """
    if isinstance(geom, RpcGeometry):
        return geom.pixel_covariance(xyz, cov_xyz)
    xyz = np.asarray(xyz, float).reshape(-1, 3)
    c = np.asarray(cov_xyz, float)
    if c.ndim == 2:
        c = np.einsum("ni,ij->nij", c**2, np.eye(3))
    a_eo, a_pt = partials(np.broadcast_to(geom.eo, (len(xyz), 6)), xyz,
                          geom.camera.focal_length)
    c_mm = a_pt @ c @ np.swapaxes(a_pt, 1, 2)
    c_mm += a_eo @ geom.eo_covariance() @ np.swapaxes(a_eo, 1, 2)
    if cov_eo_xyz is not None:
        cross = a_eo @ np.asarray(cov_eo_xyz, float) @ np.swapaxes(a_pt, 1, 2)
        c_mm += cross + np.swapaxes(cross, 1, 2)
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


def _cov3(cov_xyz: np.ndarray, n: int) -> np.ndarray:
    """Point covariances ``(n, 3, 3)`` from covariances or per-axis standard deviations."""
    c = np.asarray(cov_xyz, float)
    if c.ndim <= 2:
        c = np.broadcast_to(c, (n, 3))[:, :, None] ** 2 * np.eye(3)
    return np.broadcast_to(c, (n, 3, 3))


@dataclass
class RpcGeometry:
    """A satellite image with RPCs, its image-space bias and the ground frame.

    Attributes
    ----------
    image_id : str
    rpc : vectoradjust.sensor.rpc.RpcModel
        The vendor's RPCs (as delivered, without the bias).
    frame : vectoradjust.sensor.ground.GroundFrame
        Object coordinates ``X, Y, Z`` (m, project CRS and heights) to WGS84 longitude,
        latitude and ellipsoidal height, with the Jacobian.
    bias : numpy.ndarray, shape (6,)
        ``a0, a1, a2, b0, b1, b2`` (px) added to the RPC's pixels
        (:func:`vectoradjust.sensor.rpc.biased_partials`); zero when none is known.
    bias_cov : numpy.ndarray, shape (6, 6)
        Covariance of ``bias`` (px^2): an adjustment's estimate, or the a-priori sigmas
        (:func:`rpc_bias_prior`).
    image_size : (int, int) or None
        Columns, rows of the image file.
    terrain_height : float or None
        Mean terrain height (object ``Z``, m), the transfer's height without a DEM.
    bias_source : str
        Where ``bias`` and ``bias_cov`` came from (for messages).

    Notes
    -----
    Pixels are GDAL's corner convention (module docstring): ``index_offset = 0.5``.
    """

    image_id: str
    rpc: Any
    frame: Any
    bias: np.ndarray = field(default_factory=lambda: np.zeros(6))
    bias_cov: np.ndarray = field(default_factory=lambda: np.zeros((6, 6)))
    image_size: Optional[tuple] = None
    terrain_height: Optional[float] = None
    bias_source: str = ""
    #: pixel coordinate of the centre of the image array's element 0 (GDAL: a corner
    #: at 0, the first pixel's centre at 0.5)
    index_offset: ClassVar[float] = 0.5

    def __post_init__(self) -> None:
        self.bias = np.asarray(self.bias, float).reshape(6)
        self.bias_cov = np.asarray(self.bias_cov, float).reshape(6, 6)

    def observe(self, xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Pixels of object points and their partials.

        Parameters
        ----------
        xyz : array_like, shape (n, 3)
            Object coordinates.

        Returns
        -------
        px : numpy.ndarray, shape (n, 2)
            Column, row (corner convention) with the bias; NaN (and NaN partials) for
            points with a non-finite coordinate.
        d_xyz : numpy.ndarray, shape (n, 2, 3)
            ``d(column, row) / d(X, Y, Z)``.
        d_bias : numpy.ndarray, shape (n, 2, 6)
            ``d(column, row) / d(a0, a1, a2, b0, b1, b2)``.
        """
        xyz = np.asarray(xyz, float).reshape(-1, 3)
        n = len(xyz)
        px, d_xyz, d_bias = np.full((n, 2), np.nan), np.full((n, 2, 3), np.nan), \
            np.full((n, 2, 6), np.nan)
        ok = np.isfinite(xyz).all(axis=1)  # a failed intersection stays NaN
        if not ok.any():
            return px, d_xyz, d_bias
        llh, jac = self.frame.to_geodetic(xyz[ok])
        px[ok], d_ground, d_bias[ok] = biased_partials(self.rpc, llh[:, 0], llh[:, 1],
                                                       llh[:, 2], self.bias)
        d_xyz[ok] = np.einsum("nai,nij->naj", d_ground, jac)
        return px, d_xyz, d_bias

    def to_pixel(self, xyz: np.ndarray) -> np.ndarray:
        """Object points ``(n, 3)`` -> pixel (column, row) ``(n, 2)`` (with the bias)."""
        return self.observe(xyz)[0]

    def pixel_covariance(self, xyz: np.ndarray, cov_xyz: np.ndarray) -> np.ndarray:
        """Covariance ``(n, 2, 2)`` (px^2) of the predicted pixels of ``xyz``.

        Parameters
        ----------
        xyz : array_like, shape (n, 3)
        cov_xyz : array_like, shape (n, 3, 3) or (n, 3)
            Covariance of each object point (or its standard deviations per axis).

        Returns
        -------
        numpy.ndarray, shape (n, 2, 2)
            ``A_pt C_xyz A_pt' + A_b C_b A_b'``.
        """
        _, a_pt, a_b = self.observe(xyz)
        c = _cov3(cov_xyz, len(a_pt))
        return (a_pt @ c @ np.swapaxes(a_pt, 1, 2)
                + a_b @ self.bias_cov @ np.swapaxes(a_b, 1, 2))

    def pixel_to_measured_mm(self, px: np.ndarray) -> np.ndarray:
        """The measurement as ``image_points.csv`` holds it: an RPC image's rows are
        pixels (column, row), so the pixels themselves."""
        return np.array(px, float)

    def raw_pixel(self, px: np.ndarray) -> np.ndarray:
        """Observed pixels (corner convention, with the bias) -> the RPC's own pixels
        (centre convention, without the bias), ``(n, 2)``.

        The bias is affine in the RPC's centre-convention pixels, so it is removed
        exactly by a 2 x 2 solve.
        """
        r, p = self.rpc, self.bias
        pc = np.asarray(px, float).reshape(-1, 2) - 0.5
        m = np.eye(2) + np.array([[p[1] / r.samp_scale, p[2] / r.line_scale],
                                  [p[4] / r.samp_scale, p[5] / r.line_scale]])
        k = np.array([p[0] - p[1] * r.samp_off / r.samp_scale - p[2] * r.line_off / r.line_scale,
                      p[3] - p[4] * r.samp_off / r.samp_scale - p[5] * r.line_off / r.line_scale])
        return (pc - k) @ np.linalg.inv(m).T

    def _on_line(self, raw: np.ndarray, h: np.ndarray) -> np.ndarray:
        """Object points of raw pixels at ellipsoidal heights ``h`` (NaN where lost)."""
        ll = self.rpc.localize(raw[:, 0], raw[:, 1], h, origin="center")
        out = np.full((len(raw), 3), np.nan)
        ok = np.isfinite(ll).all(axis=1) & np.isfinite(h)
        if ok.any():
            out[ok] = self.frame.from_geodetic(np.column_stack([ll[ok], h[ok]]))
        out[~np.isfinite(out).all(axis=1)] = np.nan
        return out

    def at_height(self, px: np.ndarray, z: np.ndarray | float, iterations: int = 10,
                  tol: float = 1e-6) -> np.ndarray:
        """Points on the lines of sight of pixels at given object heights.

        Parameters
        ----------
        px : array_like, shape (n, 2)
        z : array_like, shape (n,) or float
            Object heights (m; the project's heights, ellipsoidal or orthometric).
        iterations, tol : int, float
            The ellipsoidal height is corrected by the object height's misfit until it
            moves less than ``tol`` m.

        Returns
        -------
        numpy.ndarray, shape (n, 3)
        """
        raw = self.raw_pixel(px)
        z = np.broadcast_to(np.asarray(z, float), (len(raw),)).copy()
        h = z.copy()
        p = self._on_line(raw, h)
        for _ in range(iterations):
            dz = z - p[:, 2]
            h = h + dz
            p = self._on_line(raw, h)
            if not np.any(np.abs(dz) > tol):
                break
        return p

    def to_ground(self, px: np.ndarray, height: Callable[[np.ndarray], np.ndarray] | float,
                  z0: Optional[float] = None, iterations: int = 30,
                  tol: float = 1e-4) -> np.ndarray:
        """Intersect the lines of sight of pixels with the terrain, ``(n, 3)``.

        Parameters
        ----------
        px : array_like, shape (n, 2)
            Pixels (corner convention, with the bias).
        height : callable or float
            ``height(xy (n, 2)) -> z (n,)`` (e.g. a DEM, object coordinates) or a
            constant height.
        z0 : float, optional
            Starting ellipsoidal height (default the RPC's ``HEIGHT_OFF``).
        iterations, tol : int, float
            Fixed-point iteration ``Z <- height(XY(Z))`` (as
            :meth:`ImageGeometry.to_ground`) until it moves less than ``tol`` m.

        Returns
        -------
        numpy.ndarray, shape (n, 3)
            Points on the lines of sight; NaN where the RPC cannot be inverted.
        """
        raw = self.raw_pixel(px)
        hfun = height if callable(height) else (lambda xy: np.full(len(xy), float(height)))
        h = np.full(len(raw), float(self.rpc.height_off) if z0 is None else float(z0))
        p = self._on_line(raw, h)
        for _ in range(iterations):
            ok = np.isfinite(p).all(axis=1)
            dz = np.full(len(p), np.nan)
            if ok.any():
                dz[ok] = np.asarray(hfun(p[ok, :2]), float).reshape(-1) - p[ok, 2]
            h = h + dz
            p = self._on_line(raw, h)
            if not np.any(np.abs(dz) > tol):
                break
        return p


def rpc_bias_prior(rpc, frame, bias_model: str, bias_sigma: Optional[np.ndarray] = None,
                   default: tuple[float, float] = DEFAULT_BIAS_SIGMA
                   ) -> tuple[np.ndarray, str]:
    """A-priori covariance of an RPC image's bias parameters for prediction windows.

    Parameters the bias model estimates take their ``bias_sigma``; where that is not
    finite (no prior), the shift takes the RPC's ``ERR_BIAS`` (the vendor's RMS bias,
    metres per horizontal axis) through the RPC's ground-to-pixel partials at the centre
    of its domain, ``C = ERR_BIAS^2 J J'``, or ``default[0]`` px when the RPC states none
    (GDAL writes -1 for unknown), and the drift and affine terms ``default[1]`` px.
    Parameters the model does not estimate are taken as zero (the bias model says they
    are negligible; ``bias = "none"`` takes the RPCs as exact, e.g. corrected RPCs).

    Parameters
    ----------
    rpc : RpcModel
    frame : GroundFrame
    bias_model : str
        ``none``, ``shift``, ``shift+drift`` or ``affine``.
    bias_sigma : array_like, shape (6,), optional
        The project's ``bias_sigma`` (px; ``inf`` = none).
    default : (float, float)
        Shift and drift sigmas (px) without a prior (:data:`DEFAULT_BIAS_SIGMA`).

    Returns
    -------
    cov : numpy.ndarray, shape (6, 6)
        px^2.
    source : str
        Where the sigmas came from, for messages.
    """
    free = bias_free_mask(bias_model)
    sig = np.full(6, np.inf) if bias_sigma is None else \
        np.broadcast_to(np.asarray(bias_sigma, float), (6,))
    cov = np.zeros((6, 6))
    given = np.flatnonzero(free & np.isfinite(sig))
    cov[given, given] = sig[given] ** 2
    said = [f"bias_sigma {sig[given].max():g} px"] if len(given) else []
    shift = [k for k in (0, 3) if free[k] and not np.isfinite(sig[k])]
    err = rpc.err_bias
    if shift and err is not None and err > 0:
        llh0 = np.array([[rpc.long_off, rpc.lat_off, rpc.height_off]])
        geom = RpcGeometry("", rpc, frame)
        j = geom.observe(frame.from_geodetic(llh0))[1][0, :, :2]
        c2 = err**2 * j @ j.T
        pos = {0: 0, 3: 1}
        for a in shift:
            for b in shift:
                cov[a, b] = c2[pos[a], pos[b]]
        said.append(f"ERR_BIAS {err:g} m = {np.sqrt(np.diag(c2)).max():.2g} px")
    elif shift:
        cov[shift, shift] = default[0] ** 2
        said.append(f"default shift {default[0]:g} px")
    drift = [k for k in (1, 2, 4, 5) if free[k] and not np.isfinite(sig[k])]
    if drift:
        cov[drift, drift] = default[1] ** 2
        said.append(f"default drift {default[1]:g} px")
    return cov, ", ".join(said) if said else "none (the RPCs taken as exact)"


def point_at_height(geom, px: np.ndarray, z: np.ndarray) -> np.ndarray:
    """Points ``(n, 3)`` on the rays (lines of sight) of pixels at object heights ``z``.

    Parameters
    ----------
    geom : ImageGeometry or RpcGeometry
    px : array_like, shape (n, 2)
    z : array_like, shape (n,)
    """
    if isinstance(geom, RpcGeometry):
        return geom.at_height(px, z)
    d = geom.ray(px)
    c = geom.eo[:3]
    t = (np.asarray(z, float) - c[2]) / d[:, 2]
    return c + t[:, None] * d


def height_parallax(src, dst, px_src: np.ndarray, ground: np.ndarray,
                    dz: float = 1.0) -> np.ndarray:
    """``d px_dst / d Z`` along the rays of ``src``'s pixels, ``(n, 2)`` px per metre.

    A terrain height error moves the transferred point along the reference image's
    line of sight, i.e. along the epipolar line in ``dst`` by this much per metre.

    Parameters
    ----------
    src, dst : ImageGeometry or RpcGeometry
    px_src : array_like, shape (n, 2)
    ground : array_like, shape (n, 3)
        The points on the rays (e.g. intersected with the terrain).
    dz : float
        Half the central-difference step (m).
    """
    z = np.asarray(ground, float)[:, 2]
    hi = dst.to_pixel(point_at_height(src, px_src, z + dz))
    lo = dst.to_pixel(point_at_height(src, px_src, z - dz))
    return (hi - lo) / (2.0 * dz)


def transfer_covariance(src, dst, px_src: np.ndarray, ground: np.ndarray,
                        affine: np.ndarray, sigma_height: float,
                        sigma_ref_px: float) -> np.ndarray:
    """Covariance ``(n, 2, 2)`` (px^2 of ``dst``) of points carried from ``src`` to ``dst``.

    ``A (C_src + s_ref^2 I) A' + C_dst + s_h^2 e e'``: the reference image's
    orientation or bias (``C_src``, mapped by the local affine ``A``) and pointing
    ``s_ref``, the target image's orientation or bias ``C_dst`` (both
    :func:`pixel_covariance` of the ground points), and the terrain height's
    uncertainty ``s_h`` along the epipolar direction ``e`` (:func:`height_parallax`).
    The two images' errors are taken as independent.

    Parameters
    ----------
    src, dst : ImageGeometry or RpcGeometry
    px_src : array_like, shape (n, 2)
        The reference pixels.
    ground : array_like, shape (n, 3)
        Their points on the terrain.
    affine : array_like, shape (n, 2, 2)
        ``d px_dst / d px_src`` (:func:`local_affine`).
    sigma_height : float
        Terrain height uncertainty (m).
    sigma_ref_px : float
        Pointing precision of the reference measurement (px).
    """
    ground = np.asarray(ground, float).reshape(-1, 3)
    a = np.asarray(affine, float)
    zero = np.zeros((len(ground), 3))
    c_src = pixel_covariance(src, ground, zero) + sigma_ref_px**2 * np.eye(2)
    cov = a @ c_src @ np.swapaxes(a, 1, 2) + pixel_covariance(dst, ground, zero)
    e = height_parallax(src, dst, px_src, ground)
    return cov + sigma_height**2 * e[:, :, None] * e[:, None, :]
