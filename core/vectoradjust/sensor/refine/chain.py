"""The refinement chain: :class:`RefineResult`, :func:`refine` (pixels to refined photo
coordinates, step by step) and :func:`distort` (its inverse).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, Callable, NamedTuple

import numpy as np

from vectoradjust.errors import CameraError
from vectoradjust.sensor.camera import brown_distort, brown_undistort
from vectoradjust.sensor.refine.coerce import (
    STEPS,
    _as_calibration,
    _as_xy,
    _check_unit,
    _image_label,
    _switches,
)
from vectoradjust.sensor.refine.corrections import (
    ardc_k,
    earth_curvature_correction,
    refraction_correction,
    smac_correction,
)
from vectoradjust.sensor.refine.fiducials import AffineFit
from vectoradjust.sensor.refine.pixels import photo_to_pixel, pixel_to_photo

__all__ = ["RefineResult", "refine", "distort"]


# ============================================================================ the chain
class RefineResult(NamedTuple):
    """Refined coordinates and what was done to them.

    Attributes
    ----------
    xy : numpy.ndarray, shape (..., 2)
        Refined photo coordinates (mm).
    summary : dict
        ``image_id``, ``input_unit``, ``corrections`` (per step: ``applied``,
        ``max_um`` = largest size of that step's change in micrometres, ``None`` for
        unit conversions), ``applied`` (step names in order) and ``principal_point``
        (the ``(x0, y0)`` the collinearity equations must use with ``xy``: ``(0, 0)``
        when the principal point was reduced here).
    """

    xy: np.ndarray
    summary: dict


class _Chain:
    """The resolved refinement chain of one image (shared by refine and distort)."""

    def __init__(
        self,
        camera: Any,
        affine: AffineFit | None,
        unit: str,
        flying_height: Any,
        terrain_height: Any,
        corrections: Mapping[str, bool] | None,
        image_id: str | None,
        shape: tuple[int, ...],
    ) -> None:
        self.img = _image_label(image_id)
        self.image_id = image_id
        self.cam = _as_calibration(camera)
        self.unit = _check_unit(unit, self.img)
        sw = _switches(corrections, self.img)
        self.affine = affine if (affine is not None and sw["affine"]) else None
        if self.affine is not None and self.affine.unit != self.unit:
            raise CameraError(
                f"{self.img}: the fiducial affine was fitted to {self.affine.unit} "
                f"measurements but the image coordinates are in {self.unit}",
                "Measure fiducials and points in the same unit",
                details={"image_id": image_id},
            )
        self.digital = self.affine is None and self.unit == "pixel"
        if self.digital:
            missing = [
                k for k in ("pixel_size", "image_size") if getattr(self.cam, k) is None
            ]
            if missing:
                raise CameraError(
                    f"{self.img}: image coordinates are in pixels but there are no fiducial "
                    f"measurements for it and the camera has no {' and no '.join(missing)}",
                    f"Measure at least 3 fiducials of {self.img} (4 or more for a check), or "
                    "for a digital frame give pixel_size (mm) and image_size [columns, rows] "
                    "in [camera]",
                    details={"image_id": image_id, "keys": missing},
                )
        self.pp_applied = sw["principal_point"]
        pp = np.array(self.cam.principal_point, float)
        self.pp = pp if self.pp_applied else np.zeros(2)
        self.dist_applied = sw["distortion"] and self.cam.has_distortion
        self.center = np.array(self.cam.symmetry_center, float) - self.pp
        self.refr_applied = sw["refraction"]
        self.curv_applied = sw["earth_curvature"]
        self.H = self.h = None
        if self.refr_applied or self.curv_applied:
            need = [
                name
                for name, val in (
                    ("refraction", sw["refraction"]),
                    ("earth curvature", sw["earth_curvature"]),
                )
                if val
            ]
            if flying_height is None or terrain_height is None:
                raise CameraError(
                    f"{self.img}: the {' and '.join(need)} correction needs the flying height "
                    "and the terrain height",
                    "Give the image's approximate position (ZL, m above sea level) and the "
                    "mean terrain height, or switch the correction off in [corrections]",
                    details={"image_id": image_id},
                )
            try:
                self.H = np.broadcast_to(np.asarray(flying_height, float), shape)
                self.h = np.broadcast_to(np.asarray(terrain_height, float), shape)
            except ValueError:
                raise CameraError(
                    f"{self.img}: flying_height/terrain_height do not match the {shape} points",
                    "Give one value per image or one per point",
                ) from None
        self.f = self.cam.focal_length

    # -- forward steps (measured -> refined) --------------------------------------
    def to_photo(self, xy: np.ndarray) -> np.ndarray:
        if self.affine is not None:
            return self.affine.transform(xy)
        if self.digital:
            return pixel_to_photo(
                xy, self.cam.pixel_size, self.cam.image_size, origin=self.cam.pixel_origin
            )
        return xy

    def lens(self, xy: np.ndarray) -> np.ndarray:
        if self.cam.distortion_model == "brown":  # its formula is the distortion: inverted
            try:
                return brown_undistort(xy, self.f, self.cam.brown_coefficients, self.center)
            except CameraError as exc:
                raise CameraError(f"{self.img}: {exc.what}", exc.mend,
                                  details={**(exc.details or {}), "image_id": self.image_id}
                                  ) from None
        dx, dy = smac_correction(
            xy,
            self.center[0],
            self.center[1],
            self.cam.radial_coefficients,
            self.cam.decentering_coefficients,
        )
        return xy + self.cam.distortion_sign * np.stack([dx, dy], axis=-1)

    def refraction(self, xy: np.ndarray) -> np.ndarray:
        return refraction_correction(xy, self.f, self.H, self.h)

    def curvature(self, xy: np.ndarray) -> np.ndarray:
        return earth_curvature_correction(xy, self.f, self.H - self.h)

    # -- inverse steps ---------------------------------------------------------------
    def from_photo(self, xy: np.ndarray) -> np.ndarray:
        if self.affine is not None:
            return self.affine.inverse_transform(xy)
        if self.digital:
            return photo_to_pixel(
                xy, self.cam.pixel_size, self.cam.image_size, origin=self.cam.pixel_origin
            )
        return xy


def refine(
    xy: Any,
    camera: Any,
    *,
    affine: AffineFit | None = None,
    unit: str = "mm",
    flying_height: Any = None,
    terrain_height: Any = None,
    corrections: Mapping[str, bool] | None = None,
    image_id: str | None = None,
) -> RefineResult:
    """Refine the measured image coordinates of one image.

    Order: affine (or pixel_to_photo) -> principal point -> lens distortion ->
    atmospheric refraction -> earth curvature.

    Parameters
    ----------
    xy : array_like, shape (..., 2)
        Measured coordinates: pixels (column, row) with ``unit="pixel"``, or mm.
    camera : CameraCalibration or object with ``focal_length``/``principal_point``
        A :class:`vectoradjust.model.Camera` is accepted too; its ``calibration``
        (a CameraCalibration or the raw ``[camera]`` table) is used when present.
    affine : AffineFit, optional
        The image's fiducial affine (:func:`fit_fiducial_affine`).
    unit : {"mm", "pixel"}
        Unit of ``xy``. Pixels need either ``affine`` or the camera's ``pixel_size``
        and ``image_size`` (digital frame).
    flying_height : float or array_like, shape (...)
        Flying height above sea level (m): the image's ZL, or one per point.
        Needed by refraction and earth curvature.
    terrain_height : float or array_like
        Mean terrain height above sea level (m).
    corrections : mapping, optional
        Switches overriding :data:`DEFAULT_CORRECTIONS` (keys ``affine``,
        ``principal_point``, ``distortion``, ``refraction``, ``earth_curvature``). The
        caller switches earth curvature on only for a map-projection ground frame.
    image_id : str, optional
        Names the image in messages and in the summary.

    Returns
    -------
    RefineResult
        ``(xy, summary)``; see :class:`RefineResult`.

    Raises
    ------
    CameraError
        Pixel measurements without an affine or a pixel size, unknown switches,
        a correction that lacks its heights, an affine fitted in another unit.
    """
    xy = _as_xy(xy, f"{_image_label(image_id)}: image coordinates")
    ch = _Chain(
        camera, affine, unit, flying_height, terrain_height, corrections, image_id, xy.shape[:-1]
    )
    out, steps = _run_steps(ch, xy)
    summary = {
        "image_id": image_id,
        "input_unit": ch.unit,
        "corrections": steps,
        "applied": [s for s in STEPS if steps[s]["applied"]],
        "principal_point": (0.0, 0.0) if ch.pp_applied else tuple(ch.cam.principal_point),
    }
    return RefineResult(out, summary)


def _step_size(a: np.ndarray, b: np.ndarray) -> float:
    """Largest shift (um) between the coordinates ``a`` and ``b`` (mm); 0 for none."""
    if a.size == 0:
        return 0.0
    d = a - b
    return float(np.max(np.hypot(d[..., 0], d[..., 1]))) * 1000.0


def _run_steps(ch: _Chain, xy: np.ndarray) -> tuple[np.ndarray, dict[str, dict[str, Any]]]:
    """Apply the chain's steps in order; the refined coordinates and each step's record
    (``applied``, ``max_um`` and, for some, ``model`` or ``K_urad``)."""
    steps: dict[str, dict[str, Any]] = {s: {"applied": False, "max_um": None} for s in STEPS}
    out = ch.to_photo(xy)
    if ch.affine is not None:
        steps["affine"] = {
            "applied": True,
            "max_um": None if ch.unit == "pixel" else _step_size(out, xy),
        }
    elif ch.digital:
        steps["pixel_to_photo"] = {"applied": True, "max_um": None}
    if ch.pp_applied:
        new = out - ch.pp
        steps["principal_point"] = {"applied": True, "max_um": _step_size(new, out)}
        out = new
    if ch.dist_applied:
        new = ch.lens(out)
        steps["distortion"] = {
            "applied": True,
            "max_um": _step_size(new, out),
            "model": ch.cam.distortion_model,
        }
        out = new
    if ch.refr_applied:
        new = ch.refraction(out)
        k = np.asarray(ardc_k(ch.H / 1000.0, ch.h / 1000.0))
        steps["refraction"] = {
            "applied": True,
            "max_um": _step_size(new, out),
            "K_urad": float(np.max(k)) * 1e6 if k.size else None,
        }
        out = new
    if ch.curv_applied:
        new = ch.curvature(out)
        steps["earth_curvature"] = {"applied": True, "max_um": _step_size(new, out)}
        out = new
    return out, steps


def distort(
    xy_true: Any,
    camera: Any,
    *,
    affine: AffineFit | None = None,
    unit: str = "mm",
    flying_height: Any = None,
    terrain_height: Any = None,
    corrections: Mapping[str, bool] | None = None,
    image_id: str | None = None,
    tol: float = 1e-11,
    max_iter: int = 100,
) -> np.ndarray:
    """Inverse of :func:`refine`: ideal photo coordinates -> what would be measured.

    For simulation: ideal coordinates (as :func:`refine` returns them, i.e. relative
    to the principal point when it is reduced) are given earth curvature, refraction
    and lens distortion, shifted by the principal point and mapped through the
    inverse affine (or to pixels), so that ``refine(distort(x)) == x``. The
    non-linear steps are inverted by fixed-point iteration to ``tol`` (mm).

    Parameters
    ----------
    xy_true : array_like, shape (..., 2)
        Ideal photo coordinates (mm).
    camera, affine, unit, flying_height, terrain_height, corrections, image_id
        As for :func:`refine` (``unit`` is the unit of the returned measurements).
    tol : float
        Convergence tolerance of each inversion (mm).
    max_iter : int
        Iteration limit of each inversion.

    Returns
    -------
    numpy.ndarray, shape (..., 2)
        Measured coordinates (pixels or mm).

    Raises
    ------
    CameraError
        As :func:`refine`, or when a correction is too strong to be inverted.
    """
    xy = _as_xy(xy_true, f"{_image_label(image_id)}: photo coordinates")
    ch = _Chain(
        camera, affine, unit, flying_height, terrain_height, corrections, image_id, xy.shape[:-1]
    )
    out = xy
    if ch.curv_applied:
        out = _invert(ch.curvature, out, tol, max_iter, "earth curvature", ch.img)
    if ch.refr_applied:
        out = _invert(ch.refraction, out, tol, max_iter, "refraction", ch.img)
    if ch.dist_applied and ch.cam.distortion_model == "brown":  # the forward model itself
        out = brown_distort(out, ch.f, ch.cam.brown_coefficients, ch.center)
    elif ch.dist_applied:
        out = _invert(ch.lens, out, tol, max_iter, "lens distortion", ch.img)
    if ch.pp_applied:
        out = out + ch.pp
    return ch.from_photo(out)


def _invert(
    forward: Callable[[np.ndarray], np.ndarray],
    target: np.ndarray,
    tol: float,
    max_iter: int,
    what: str,
    img: str,
) -> np.ndarray:
    """Solve ``forward(m) = target`` for ``m`` by ``m <- m + (target - forward(m))``.

    Converges when the Jacobian of ``forward`` is close to the identity, as it is for
    every correction here (they change coordinates by parts per thousand at most).
    """
    m = target.copy()
    for _ in range(max_iter):
        res = target - forward(m)
        if res.size == 0 or float(np.max(np.abs(res))) <= tol:
            return m
        m = m + res
    raise CameraError(
        f"{img}: the {what} correction could not be inverted to {tol:g} mm in "
        f"{max_iter} iterations",
        "Check the camera's distortion coefficients and their convention",
    )

