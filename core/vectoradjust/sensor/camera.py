"""Camera calibration: focal length, principal point, fiducials, lens distortion, pixels.

A :class:`CameraCalibration` holds what a calibration report gives for one camera and
what image coordinate refinement (:mod:`vectoradjust.sensor.refine`) needs. It is built from
the project's ``[camera]`` table (a plain dict as read from TOML) by
:meth:`CameraCalibration.from_dict`, or from a separate camera TOML file by
:meth:`CameraCalibration.from_file`, so that one calibration report serves many
projects. The contract's two keys ``focal_length`` and ``principal_point`` alone are
still a complete camera (no fiducials, no distortion).

Camera table / file (all lengths in millimetres)::

    name = "Wild RC10 15/4 UAG"      # optional, for reports
    focal_length = 152.4              # calibrated focal length (mm), required
    principal_point = [0.003, -0.001] # x0, y0 (mm) in the fiducial frame; default [0, 0]
    pixel_size = 0.012                # mm (12 um); or [sx, sy]; optional
    image_size = [19200, 19200]       # columns, rows; optional
    pixel_origin = "center"           # center | corner (see refine.pixel_to_photo)

    [fiducials]                       # calibrated fiducial coordinates (mm)
    1 = [-106.004, -106.002]
    2 = [106.001, 105.998]
    3 = [-105.997, 106.003]
    4 = [106.002, -105.999]

    [distortion]
    model = "smac"                    # none | smac | polynomial | brown
    convention = "correction"         # correction | distortion (see below)
    center = [0.003, -0.001]          # optional point of symmetry (mm); default principal point
    K0 = -0.2165e-3                   # smac: K0..K4, P1..P4 (missing ones are 0)
    K1 = 0.4230e-7
    P1 = -0.1483e-6

In the project file, ``[camera]`` may instead say ``path = "rc10.toml"`` (relative
to the project file); the file is loaded and any key given inline next to ``path``
overrides the file's value (sub-tables ``fiducials`` and ``distortion`` are merged
key by key).

Distortion models (``xb = x - xc``, ``yb = y - yc`` with ``(xc, yc)`` the centre of
symmetry, ``r^2 = xb^2 + yb^2``):

``smac`` (USGS Simultaneous Multiframe Analytical Calibration)
    radial ``dxr = xb (K0 + K1 r^2 + K2 r^4 + K3 r^6 + K4 r^8)`` (same for y);
    decentering ``dxd = (1 + P3 r^2 + P4 r^4) [P1 (r^2 + 2 xb^2) + 2 P2 xb yb]``,
    ``dyd = (1 + P3 r^2 + P4 r^4) [2 P1 xb yb + P2 (r^2 + 2 yb^2)]``.
``polynomial``
    radial only in odd powers of ``r``: ``dr = k1 r^3 + k2 r^5 + k3 r^7 + k4 r^9``,
    ``dxr = xb dr / r``; the decentering terms ``P1..P4`` above may be added.
``brown`` (OpenCV / OpenSfM / OpenDroneMap Brown-Conrady)
    coefficients ``k1 k2 k3`` (radial) and ``p1 p2`` (tangential), unitless, of the
    *normalised* coordinates ``x_n = x / f``, ``y_n = y / f`` about the principal point
    (or ``center``). Unlike the two models above the formula maps the **ideal**
    position to the **distorted** (recorded) one, in OpenCV's axes (``y`` down, as
    pixel rows):
    ``x_d = x_n (1 + k1 r^2 + k2 r^4 + k3 r^6) + 2 p1 x_n y_n + p2 (r^2 + 2 x_n^2)``,
    ``y_d = y_n (1 + ...) + p1 (r^2 + 2 y_n^2) + 2 p2 x_n y_n``. The coefficients are
    written as OpenCV and OpenSfM give them; photo coordinates have ``y`` up, so with
    ``y = -y_n f`` the same formula in photo axes has ``p1`` with the opposite sign
    (:func:`brown_distort` does that). A measurement is corrected by inverting the
    formula exactly (:func:`brown_undistort`, Newton's method); ``convention`` does not
    apply (it may only be ``"distortion"``).
``none``
    no lens distortion correction.

Sign convention (``convention``): the formula above, evaluated at the *measured*
coordinate, gives ``F``.

* ``"correction"`` (default; the USGS calibration report and Wolf & Dewitt convention):
  ``F`` is the correction to add: ``corrected = measured + F``.
* ``"distortion"``: ``F`` is the distortion present in the measurement:
  ``corrected = measured - F``.

Either way ``corrected = measured - distortion``; the two differ only in the sign of
every coefficient. A coefficient set from a report that tabulates "distortion" (image
displaced outward is positive) needs ``convention = "distortion"``.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Union

import numpy as np

from vectoradjust.errors import CameraError

__all__ = [
    "CameraCalibration",
    "DISTORTION_MODELS",
    "DISTORTION_CONVENTIONS",
    "load_camera_file",
    "read_toml_text",
    "decode_text",
    "toml_error_hint",
    "brown_distort",
    "brown_undistort",
]

#: Accepted distortion model names.
DISTORTION_MODELS = ("none", "smac", "polynomial", "brown")
#: Accepted sign conventions of the distortion coefficients.
DISTORTION_CONVENTIONS = ("correction", "distortion")
#: Accepted pixel origin conventions.
PIXEL_ORIGINS = ("center", "corner")

_SMAC_KEYS = ("K0", "K1", "K2", "K3", "K4", "P1", "P2", "P3", "P4")
_POLY_KEYS = ("k1", "k2", "k3", "k4", "P1", "P2", "P3", "P4")
_BROWN_KEYS = ("k1", "k2", "k3", "p1", "p2")
_CAMERA_KEYS = (
    "path",
    "name",
    "focal_length",
    "principal_point",
    "fiducials",
    "distortion",
    "pixel_size",
    "image_size",
    "pixel_origin",
)
_DISTORTION_META = ("model", "convention", "center")

PathLike = Union[str, Path]


def _coefficient_keys(model: str) -> tuple[str, ...]:
    if model == "smac":
        return _SMAC_KEYS
    if model == "polynomial":
        return _POLY_KEYS
    if model == "brown":
        return _BROWN_KEYS
    return ()


@dataclass
class CameraCalibration:
    """A camera calibration (all lengths in millimetres).

    Attributes
    ----------
    focal_length : float
        Calibrated focal length (mm), > 0.
    principal_point : tuple of float
        ``x0, y0`` (mm) in the fiducial (photo) frame.
    fiducials : dict or None
        Calibrated fiducial coordinates, ``{id: (x, y)}`` in mm (ids are strings);
        at least 3 when given.
    distortion_model : str
        ``"none"``, ``"smac"``, ``"polynomial"`` or ``"brown"`` (see the module docstring).
    distortion_coefficients : dict
        ``smac``: ``K0..K4``, ``P1..P4``; ``polynomial``: ``k1..k4``, ``P1..P4``;
        ``brown``: ``k1 k2 k3 p1 p2`` (normalised, OpenCV). Missing coefficients are zero.
    distortion_convention : str
        ``"correction"`` (default, USGS: ``corrected = measured + F``) or
        ``"distortion"`` (``corrected = measured - F``).
    distortion_center : tuple of float or None
        Centre of symmetry of the distortion (mm, fiducial frame); ``None`` = the
        principal point.
    pixel_size : tuple of float or None
        ``(sx, sy)`` in mm (column and row spacing).
    image_size : tuple of int or None
        ``(columns, rows)``.
    pixel_origin : str
        ``"center"``: integer pixel coordinates are pixel centres (pixel (0, 0) is the
        centre of the top-left pixel); ``"corner"``: (0, 0) is the top-left corner of
        the top-left pixel (GDAL style).
    name : str or None
        A label for reports.
    source : str or None
        The camera file it came from, if any.
    """

    focal_length: float
    principal_point: tuple[float, float] = (0.0, 0.0)
    fiducials: dict[str, tuple[float, float]] | None = None
    distortion_model: str = "none"
    distortion_coefficients: dict[str, float] = field(default_factory=dict)
    distortion_convention: str = "correction"
    distortion_center: tuple[float, float] | None = None
    pixel_size: tuple[float, float] | None = None
    image_size: tuple[int, int] | None = None
    pixel_origin: str = "center"
    name: str | None = None
    source: str | None = None

    def __post_init__(self) -> None:
        if self.name is not None and not isinstance(self.name, str):
            raise CameraError(f"[camera]: name must be a text, not {_show(self.name)}",
                              'Write name = "RC30 s/n 5042", or leave it out',
                              path=self.source, details={"key": "name"})
        where = self._where()
        self.focal_length = _positive(self.focal_length, "focal_length", where)
        self.principal_point = _pair(self.principal_point, "principal_point", where)
        if self.fiducials is not None:
            self.fiducials = _fiducials(self.fiducials, where)
        model = str(self.distortion_model).strip().lower()
        if model not in DISTORTION_MODELS:
            raise CameraError(
                f"{where}: unknown distortion model {self.distortion_model!r}",
                f"Use one of {', '.join(repr(m) for m in DISTORTION_MODELS)}",
                path=self.source,
                details={"key": "distortion.model", "value": self.distortion_model},
            )
        self.distortion_model = model
        conv = str(self.distortion_convention).strip().lower()
        if conv not in DISTORTION_CONVENTIONS:
            raise CameraError(
                f"{where}: unknown distortion convention {self.distortion_convention!r}",
                "Use 'correction' (corrected = measured + formula, USGS reports) or "
                "'distortion' (corrected = measured - formula)",
                path=self.source,
                details={"key": "distortion.convention", "value": self.distortion_convention},
            )
        if model == "brown":  # the formula is the distortion (ideal -> recorded)
            conv = "distortion"
        self.distortion_convention = conv
        self.distortion_coefficients = _coefficients(
            self.distortion_coefficients, model, where, self.source
        )
        if self.distortion_center is not None:
            self.distortion_center = _pair(self.distortion_center, "distortion.center", where)
        if self.pixel_size is not None:
            self.pixel_size = _pixel_size(self.pixel_size, where)
        if self.image_size is not None:
            self.image_size = _image_size(self.image_size, where)
        origin = str(self.pixel_origin).strip().lower()
        if origin not in PIXEL_ORIGINS:
            raise CameraError(
                f"{where}: unknown pixel_origin {self.pixel_origin!r}",
                "Use 'center' (integer coordinates are pixel centres) or 'corner'",
                path=self.source,
            )
        self.pixel_origin = origin

    # ------------------------------------------------------------------ helpers
    def _where(self) -> str:
        if self.source:
            return f"camera file {self.source}"
        if self.name:
            return f"camera {self.name!r}"
        return "[camera]"

    @property
    def radial_coefficients(self) -> np.ndarray:
        """Radial coefficients in SMAC form ``[K0, K1, K2, K3, K4]``.

        For the ``polynomial`` model ``K0 = 0`` and ``K1..K4 = k1..k4``; for ``none``
        and ``brown`` (normalised coordinates, see :attr:`brown_coefficients`) all zero.
        """
        c = self.distortion_coefficients
        if self.distortion_model == "smac":
            return np.array([c.get(k, 0.0) for k in _SMAC_KEYS[:5]], float)
        if self.distortion_model == "polynomial":
            return np.array([0.0] + [c.get(k, 0.0) for k in _POLY_KEYS[:4]], float)
        return np.zeros(5)

    @property
    def decentering_coefficients(self) -> np.ndarray:
        """Decentering coefficients ``[P1, P2, P3, P4]`` (zero for ``none`` and ``brown``)."""
        c = self.distortion_coefficients
        if self.distortion_model in ("none", "brown"):
            return np.zeros(4)
        return np.array([c.get(k, 0.0) for k in ("P1", "P2", "P3", "P4")], float)

    @property
    def brown_coefficients(self) -> np.ndarray:
        """``[k1, k2, k3, p1, p2]`` of the ``brown`` model (zero for the others)."""
        if self.distortion_model != "brown":
            return np.zeros(5)
        c = self.distortion_coefficients
        return np.array([c.get(k, 0.0) for k in _BROWN_KEYS], float)

    @property
    def distortion_sign(self) -> float:
        """``+1`` when the formula is the correction to add, ``-1`` when it is the distortion."""
        return 1.0 if self.distortion_convention == "correction" else -1.0

    @property
    def has_distortion(self) -> bool:
        """True when the model is not ``none`` and some coefficient is non-zero."""
        if self.distortion_model == "brown":
            return bool(np.any(self.brown_coefficients))
        return self.distortion_model != "none" and (
            bool(np.any(self.radial_coefficients)) or bool(np.any(self.decentering_coefficients))
        )

    @property
    def symmetry_center(self) -> tuple[float, float]:
        """The distortion's centre of symmetry (mm, fiducial frame)."""
        if self.distortion_center is None:
            return self.principal_point
        return self.distortion_center

    # ------------------------------------------------------------------ readers
    @classmethod
    def from_dict(
        cls,
        d: Mapping[str, Any],
        base_dir: PathLike | None = None,
        *,
        where: str = "[camera]",
    ) -> CameraCalibration:
        """Build a calibration from the project's ``[camera]`` table.

        Parameters
        ----------
        d : mapping
            The table as read from TOML. With ``path = "file.toml"`` the camera file
            is loaded (relative to ``base_dir``) and the other inline keys override it.
        base_dir : str or Path, optional
            Directory that relative ``path`` values are resolved against (the project
            file's directory); default the current directory.
        where : str
            How to name the table in messages.

        Returns
        -------
        CameraCalibration

        Raises
        ------
        CameraError
            Missing ``focal_length``, unknown keys or distortion model, malformed
            values, an unreadable camera file.
        """
        if not isinstance(d, Mapping):
            raise CameraError(
                f"{where} must be a table, not {type(d).__name__}",
                "Write [camera] with focal_length = ... and principal_point = [x0, y0]",
            )
        d = dict(d)
        source = None
        if "path" in d:
            p = d.pop("path")
            if not isinstance(p, (str, Path)):
                raise CameraError(
                    f"{where}: path must be a file name, not {p!r}",
                    'Write path = "camera.toml" (relative to the project file)',
                )
            fpath = Path(p)
            if not fpath.is_absolute() and base_dir is not None:
                fpath = Path(base_dir) / fpath
            file_table = load_camera_file(fpath)
            source = str(fpath)
            where = f"camera file {fpath}" + (" with the inline keys of " + where if d else "")
            d = _merge(file_table, d)
        return cls._from_plain(d, where, source)

    @classmethod
    def from_file(cls, path: PathLike) -> CameraCalibration:
        """Load a camera TOML file (keys at top level or inside a ``[camera]`` table).

        Raises
        ------
        CameraError
            When the file is missing, not valid TOML or its content is wrong.
        """
        table = load_camera_file(path)
        return cls._from_plain(table, f"camera file {path}", str(path))

    @classmethod
    def _from_plain(
        cls, d: Mapping[str, Any], where: str, source: str | None
    ) -> CameraCalibration:
        unknown = sorted(str(k) for k in set(d) - set(_CAMERA_KEYS))
        if unknown:
            raise CameraError(
                f"{where}: unknown key(s) {', '.join(repr(k) for k in unknown)}",
                f"Accepted keys: {', '.join(_CAMERA_KEYS)}",
                path=source,
                details={"keys": unknown},
            )
        if "focal_length" not in d:
            raise CameraError(
                f"{where}: focal_length is missing",
                "Give the calibrated focal length in millimetres, e.g. focal_length = 152.4",
                path=source,
                details={"key": "focal_length"},
            )
        model, conv, center, coeffs = _distortion_table(d.get("distortion"), where, source)
        if not isinstance(model, str):
            raise CameraError(
                f"{where}: distortion model must be a name, not {model!r}",
                f"Use one of {', '.join(repr(m) for m in DISTORTION_MODELS)}",
                path=source,
            )
        if d.get("name") is not None and not isinstance(d["name"], str):
            raise CameraError(f"{where}: name must be a text, not {_show(d['name'])}",
                              'Write name = "RC30 s/n 5042", or leave it out', path=source,
                              details={"key": "name"})
        try:
            return cls._checked(d, model, conv, center, coeffs, source)
        except CameraError as exc:  # __post_init__ names the camera; say where it is written
            label = f"camera file {source}" if source else (
                f"camera {d['name']!r}" if d.get("name") else "[camera]")
            if where == label or not exc.what.startswith(label):
                raise
            raise CameraError(where + exc.what[len(label):], exc.mend, path=exc.path or source,
                              details=exc.details) from None

    @classmethod
    def _checked(cls, d: Mapping[str, Any], model: str, conv: Any, center: Any,
                 coeffs: Any, source: str | None) -> CameraCalibration:
        """The calibration of a plain table whose keys were checked (its values are
        checked by ``__post_init__``)."""
        return cls(
            focal_length=d["focal_length"],
            principal_point=d.get("principal_point", (0.0, 0.0)),
            fiducials=d.get("fiducials"),
            distortion_model=model,
            distortion_coefficients=coeffs,
            distortion_convention=conv,
            distortion_center=center,
            pixel_size=d.get("pixel_size"),
            image_size=d.get("image_size"),
            pixel_origin=d.get("pixel_origin", "center"),
            name=d.get("name"),
            source=source,
        )

    def to_dict(self) -> dict[str, Any]:
        """The calibration as a plain dict in the camera-file layout (TOML/JSON-ready)."""
        out: dict[str, Any] = {}
        if self.name:
            out["name"] = self.name
        out["focal_length"] = self.focal_length
        out["principal_point"] = list(self.principal_point)
        if self.pixel_size is not None:
            out["pixel_size"] = list(self.pixel_size)
        if self.image_size is not None:
            out["image_size"] = list(self.image_size)
        out["pixel_origin"] = self.pixel_origin
        if self.fiducials is not None:
            out["fiducials"] = {k: list(v) for k, v in self.fiducials.items()}
        dist: dict[str, Any] = {
            "model": self.distortion_model,
            "convention": self.distortion_convention,
        }
        if self.distortion_center is not None:
            dist["center"] = list(self.distortion_center)
        dist.update(self.distortion_coefficients)
        out["distortion"] = dist
        return out


# ---------------------------------------------------------------------- Brown lens
def _brown_parts(xy: Any, focal_length: float, coefficients: Any,
                 center: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Photo coordinates as normalised OpenCV coordinates (``y`` down) and the checked
    coefficients ``[k1, k2, k3, p1, p2]`` and centre."""
    xy = np.asarray(xy, dtype=float)
    if xy.ndim == 0 or xy.shape[-1] != 2:
        raise CameraError(f"photo coordinates must have two columns (x, y), got shape "
                          f"{xy.shape}", "Pass an (n, 2) array")
    c = np.zeros(5)
    given = np.asarray(coefficients, dtype=float).ravel()
    if given.size > 5:
        raise CameraError(f"the brown model has 5 coefficients (k1 k2 k3 p1 p2), not "
                          f"{given.size}", "Give k1, k2, k3, p1, p2")
    c[:given.size] = given
    f = _positive(focal_length, "focal_length", "brown distortion")
    centre = np.asarray(center, dtype=float).reshape(2)
    u = (xy - centre) / f
    u[..., 1] = -u[..., 1]  # photo y up -> OpenCV y down
    return u, c, centre, np.asarray(f)


def _brown_formula(u: np.ndarray, c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """OpenCV's formula ``d(u)`` at normalised ``u`` (``y`` down) and its Jacobian."""
    k1, k2, k3, p1, p2 = c
    x, y = u[..., 0], u[..., 1]
    s = x * x + y * y
    radial = 1.0 + s * (k1 + s * (k2 + s * k3))
    dradial = k1 + s * (2.0 * k2 + 3.0 * k3 * s)  # d radial / d s
    d = np.stack([x * radial + 2.0 * p1 * x * y + p2 * (s + 2.0 * x * x),
                  y * radial + p1 * (s + 2.0 * y * y) + 2.0 * p2 * x * y], axis=-1)
    jac = np.empty(u.shape[:-1] + (2, 2))
    cross = 2.0 * x * y * dradial + 2.0 * p1 * x + 2.0 * p2 * y
    jac[..., 0, 0] = radial + 2.0 * x * x * dradial + 2.0 * p1 * y + 6.0 * p2 * x
    jac[..., 0, 1] = cross
    jac[..., 1, 0] = cross
    jac[..., 1, 1] = radial + 2.0 * y * y * dradial + 6.0 * p1 * y + 2.0 * p2 * x
    return d, jac


def brown_distort(xy: Any, focal_length: float, coefficients: Any,
                  center: Any = (0.0, 0.0)) -> np.ndarray:
    """Where the lens records an ideal position: the Brown (OpenCV) model, forward.

    Parameters
    ----------
    xy : array_like, shape (..., 2)
        Ideal photo coordinates (mm, ``x`` right, ``y`` up).
    focal_length : float
        ``f`` (mm): the coordinates are normalised as ``x / f``.
    coefficients : sequence of up to 5 floats
        ``k1, k2, k3, p1, p2`` as OpenCV and OpenSfM give them (``y`` down); missing
        trailing ones are zero.
    center : (float, float)
        The principal point (mm) in the frame of ``xy``.

    Returns
    -------
    numpy.ndarray, shape (..., 2)
        Distorted photo coordinates (mm, same frame).
    """
    u, c, centre, f = _brown_parts(xy, focal_length, coefficients, center)
    d, _ = _brown_formula(u, c)
    d[..., 1] = -d[..., 1]
    return d * f + centre


def brown_undistort(xy: Any, focal_length: float, coefficients: Any,
                    center: Any = (0.0, 0.0), *, tol: float = 1e-12,
                    max_iter: int = 50) -> np.ndarray:
    """The ideal position of recorded photo coordinates: :func:`brown_distort` inverted.

    Newton's method in the plane, vectorised over the points, started at the recorded
    position, until every point's residual ``|distort(ideal) - recorded|`` is below
    ``tol`` (mm).

    Parameters
    ----------
    xy : array_like, shape (..., 2)
        Recorded (distorted) photo coordinates (mm, ``y`` up).
    focal_length, coefficients, center
        As for :func:`brown_distort`.
    tol : float
        Convergence tolerance (mm).
    max_iter : int
        Iteration limit.

    Returns
    -------
    numpy.ndarray, shape (..., 2)
        Ideal photo coordinates (mm).

    Raises
    ------
    CameraError
        When some point does not converge (beyond the radius where the model folds
        back: coefficients of another convention or unit).
    """
    target, c, centre, f = _brown_parts(xy, focal_length, coefficients, center)
    m = target.copy()
    res = np.zeros_like(m)
    with np.errstate(all="ignore"):
        for _ in range(max_iter):
            d, jac = _brown_formula(m, c)
            res = target - d
            if m.size == 0 or float(np.max(np.abs(res))) * f <= tol:
                break
            det = jac[..., 0, 0] * jac[..., 1, 1] - jac[..., 0, 1] * jac[..., 1, 0]
            m = m + np.stack([jac[..., 1, 1] * res[..., 0] - jac[..., 0, 1] * res[..., 1],
                              jac[..., 0, 0] * res[..., 1] - jac[..., 1, 0] * res[..., 0]],
                             axis=-1) / det[..., None]
    bad = ~(np.abs(res).max(axis=-1) * f <= tol) if m.size else np.zeros(0, bool)
    if np.any(bad):
        r = np.hypot(target[..., 0], target[..., 1])[bad] * f
        raise CameraError(
            f"the brown lens distortion could not be inverted to {tol:g} mm at "
            f"{int(np.sum(bad))} point(s), up to {float(np.max(r)):.4g} mm from the "
            "principal point (the model folds back there)",
            "Check k1 k2 k3 p1 p2: they are unitless, of coordinates normalised by the "
            "focal length (OpenCV/OpenSfM), and the points lie inside the frame",
            details={"points": int(np.sum(bad))})
    m[..., 1] = -m[..., 1]
    return m * f + centre


# ---------------------------------------------------------------------- file I/O
def load_camera_file(path: PathLike) -> dict[str, Any]:
    """Read a camera TOML file into a plain dict.

    The keys may be at the top level or inside a single ``[camera]`` table. A camera
    file may not itself refer to another file (``path``).

    Raises
    ------
    CameraError
        When the file is missing, unreadable or not valid TOML.
    """
    path = Path(path)
    text = read_toml_text(
        path, f"Camera file {path}", CameraError,
        missing="Check the path (relative paths are relative to the project file)",
    )
    try:
        table = _tomllib().loads(text)
    except ValueError as exc:  # tomllib.TOMLDecodeError derives from ValueError
        raise CameraError(
            f"Camera file {path} is not valid TOML: {exc}{toml_error_hint(exc, text)}",
            "Fix the syntax at the line named",
            path=str(path),
        ) from exc
    except RecursionError:
        raise CameraError(
            f"Camera file {path} is not valid TOML: its arrays or tables are nested too deeply",
            "Check the brackets", path=str(path),
        ) from None
    if set(table) == {"camera"} and isinstance(table["camera"], Mapping):
        table = dict(table["camera"])
    if "path" in table:
        raise CameraError(
            f"Camera file {path} refers to another file (path = {table['path']!r})",
            "Put the calibration itself in the camera file; only [camera] in the project "
            "file may use path",
            path=str(path),
        )
    return table


#: larger than any project or camera file: a bigger file was given by mistake (an image)
_MAX_TOML_BYTES = 32 * 1024 * 1024
#: byte order marks other than UTF-8's, longest first
_BOMS = ((b"\xff\xfe\x00\x00", "UTF-32 (little-endian)", "UTF-32"),
         (b"\x00\x00\xfe\xff", "UTF-32 (big-endian)", "UTF-32"),
         (b"\xff\xfe", "UTF-16 (little-endian)", "UTF-16"),
         (b"\xfe\xff", "UTF-16 (big-endian)", "UTF-16"))
#: the first bytes of files that are given as a project or camera file by mistake
_MAGIC = ((b"II*\x00", "a TIFF image (GeoTIFF?)"), (b"MM\x00*", "a TIFF image (GeoTIFF?)"),
          (b"SQLite format 3\x00", "an SQLite database (a GeoPackage?)"),
          (b"PK\x03\x04", "a ZIP archive (a .zip, .kmz, .xlsx or .docx?)"),
          (b"%PDF", "a PDF document"), (b"\x89PNG", "a PNG image"),
          (b"\xff\xd8\xff", "a JPEG image"), (b"\x00\x00\x27\x0a", "a shapefile (.shp)"),
          (b"\x1f\x8b", "a gzip archive"), (b"\xd0\xcf\x11\xe0", "an old Office document"))


def read_toml_text(path: PathLike, name: str, error: type, *,
                   missing: Union[str, Callable[[], str]]) -> str:
    """The text of a TOML file (the project or a camera file), or a clear error.

    A UTF-8 byte order mark (as Windows Notepad writes it) is dropped. Anything that
    stops the file from being read is said as what it is: a missing file, a folder (with
    the ``.toml`` files in it), a permission, another encoding (named, with the line and
    the byte), a binary file (an image, a GeoPackage ...).

    Parameters
    ----------
    path : str or Path
    name : str
        How messages name the file (``"Project file 'p.toml'"``).
    error : type
        The :class:`vectoradjust.errors.VectorAdjustError` subclass to raise.
    missing : str or callable
        The mend of the message for a missing file (or a function that makes it, called
        only then).

    Returns
    -------
    str
        The text, without a byte order mark.

    Raises
    ------
    VectorAdjustError
        ``error``, naming the file and what to do.
    """
    path = Path(path)
    return decode_text(_read_bytes(path, name, error, missing), path, name, error)


def decode_text(data: bytes, path: PathLike, name: str, error: type, *,
                kind: str = "TOML files", example: str = "the TOML file (text)") -> str:
    """``data`` (a text file's bytes) as UTF-8 text, or an error naming the encoding found.

    A UTF-8 byte order mark is dropped. Another encoding (UTF-16 or UTF-32 with or
    without a byte order mark, Windows-1252, Latin-1) is an ``error`` that names it, the
    line and the byte, and how to save the file as UTF-8; NUL bytes that are no UTF-16
    make it a binary file.

    Parameters
    ----------
    data : bytes
    path : str or Path
        The file, for messages.
    name : str
        How messages name the file.
    error : type
        The :class:`vectoradjust.errors.VectorAdjustError` subclass to raise.
    kind : str
        What must be UTF-8 (``"TOML files"``, ``"CSV tables"``), for messages.
    example : str
        What to give instead of a binary file, for messages.

    Returns
    -------
    str
    """
    path = Path(path)
    if data.startswith(b"\xef\xbb\xbf"):
        data = data[3:]
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        nul = data.find(b"\x00", 0, exc.start)  # the first byte that is no text
        span = (nul, nul + 1) if nul >= 0 else (exc.start, exc.end)
        raise _encoding_error(data, span, path, name, error, (kind, example)) from None
    if "\x00" in text:  # UTF-16 without a byte order mark, or a binary file
        at = data.index(b"\x00")
        raise _encoding_error(data, (at, at + 1), path, name, error, (kind, example))
    return text


def _read_bytes(path: Path, name: str, error: type, missing: Any) -> bytes:
    """The bytes of ``path`` (at most :data:`_MAX_TOML_BYTES`), or ``error``."""
    p = str(path)
    try:
        with open(path, "rb") as fh:
            data = fh.read(_MAX_TOML_BYTES + 1)
    except (FileNotFoundError, NotADirectoryError):
        raise error(f"{name} does not exist", missing if isinstance(missing, str) else missing(),
                    path=p) from None
    except IsADirectoryError:
        raise error(f"{name} is a folder, not a file", _folder_mend(path), path=p) from None
    except PermissionError:
        raise error(f"{name} cannot be read: permission denied",
                    "Give yourself read permission on the file and on the folders above it "
                    f"(chmod u+r {p!r}), or copy the project to a folder of your own",
                    path=p) from None
    except OSError as exc:
        raise error(f"{name} cannot be read ({exc.strerror or exc})", "Check the path and the "
                    "disk, or copy the file to a local folder", path=p) from None
    except ValueError:  # a NUL character in the path
        raise error(f"{name} is not a valid path (it holds a NUL character)",
                    "Give the path of the file as text", path=p.replace("\x00", "")) from None
    if len(data) > _MAX_TOML_BYTES:
        raise error(f"{name} is larger than {_MAX_TOML_BYTES // 2**20} MB: not a TOML file",
                    "Give the TOML file itself (a few kB of text), not a data file", path=p)
    for magic, what in _MAGIC:
        if data.startswith(magic):
            raise error(f"{name} is not a text file: it looks like {what}",
                        "Give the TOML file (text), not a data file", path=p)
    return data


def _folder_mend(path: Path) -> str:
    """What to give instead of the folder ``path``: the ``.toml`` files found in it."""
    try:
        found = sorted((q.name for q in path.iterdir() if q.suffix.lower() == ".toml"),
                       key=lambda n: (n.lower() != "project.toml", n))
    except OSError:
        found = []
    if len(found) == 1:
        return f"Give the .toml file inside it: {path / found[0]}"
    if found:
        shown = ", ".join(found[:10]) + (f" and {len(found) - 10} more" if len(found) > 10
                                         else "")
        return f"Give one of the .toml files inside it ({shown}), e.g. {path / found[0]}"
    return "Give the path of the .toml file itself; this folder holds no .toml file"


def _encoding_error(data: bytes, span: tuple, path: Path, name: str, error: type,
                    said: tuple = ("TOML files", "the TOML file (text)")) -> Exception:
    """The error for a file that is not UTF-8 (``data[span[0]:span[1]]`` is the first
    byte that is not), naming the encoding the file seems to be in; ``said``: what must
    be UTF-8, and what to give instead of a binary file (see :func:`decode_text`)."""
    (start, end), (kind, example) = span, said
    convert = "Save it as UTF-8 (in the editor: Save As, encoding UTF-8)"

    def iconv(codec: str) -> str:
        out = path.with_name(f"{path.stem}-utf8{path.suffix}")
        return (f"{convert}, or convert it: iconv -f {codec} -t UTF-8 {str(path)!r} > "
                f"{str(out)!r} and give that file")

    for bom, label, codec in _BOMS:
        if data.startswith(bom):
            return error(f"{name} is encoded as {label}, with a byte order mark; {kind} "
                         "must be UTF-8", iconv(codec), path=str(path),
                         details={"encoding": codec})
    line = data.count(b"\n", 0, start) + 1
    # in characters: the bytes before the first bad one are UTF-8
    column = len(data[data.rfind(b"\n", 0, start) + 1:start].decode("utf-8", "replace")) + 1
    head = data[:4096]
    if b"\x00" in head:
        even, odd = head[0::2].count(0), head[1::2].count(0)
        if max(even, odd) > 0.3 * len(head) / 2 and min(even, odd) <= 0.02 * len(head):
            codec = "UTF-16BE" if even > odd else "UTF-16LE"
            return error(f"{name} seems encoded as {codec} (UTF-16 without a byte order mark); "
                         f"{kind} must be UTF-8", iconv(codec), path=str(path),
                         details={"encoding": codec})
        return error(f"{name} is not a text file (line {line}, column {column} holds the "
                     f"byte 0x{data[start]:02X})", f"Give {example}, not a data file",
                     path=str(path))
    codec, label, short, iconv_name = (
        ("cp1252", "Windows-1252 (ANSI)", "Windows-1252", "WINDOWS-1252")
        if any(0x80 <= b <= 0x9F for b in data)
        else ("latin-1", "Latin-1 (ISO-8859-1)", "Latin-1", "LATIN1"))
    try:
        shown = f", {data[start:end].decode(codec)!r} in {short}"
    except UnicodeDecodeError:
        shown = ""
    lines = data.decode(codec, errors="replace").splitlines()
    words = lines[line - 1].strip()[:80] if line <= len(lines) else ""
    return error(f"{name} is not UTF-8 but seems encoded as {label}: line {line}, column "
                 f"{column} holds the byte 0x{data[start]:02X}{shown} (line {line}: {words!r})",
                 iconv(iconv_name), path=str(path),
                 details={"encoding": codec, "line": line, "column": column})


#: hints for TOML syntax errors users make (the error text, then what to say)
_TOML_HINTS = (
    ("escape", "a Windows path in double quotes: write it in single quotes "
               "('C:\\data\\roads.shp') or with forward slashes"),
    ("overwrite", "a key or table is written twice"),
    ("invalid value", "a text needs quotes (crs = \"EPSG:32616\"), a list brackets"),
)


def toml_error_hint(exc: Exception, text: str) -> str:
    """`` (line N: '...'; <likely cause>)`` for a TOML syntax error, or ``""``.

    Parameters
    ----------
    exc : Exception
        The :class:`tomllib.TOMLDecodeError` (its text holds ``(at line N, column M)``).
    text : str
        The file's text.
    """
    m = re.search(r"line (\d+)", str(exc))
    lines = text.splitlines()
    parts = []
    if m and 1 <= int(m.group(1)) <= len(lines):
        parts.append(f"line {m.group(1)}: {lines[int(m.group(1)) - 1].strip()[:80]!r}")
    said = str(exc).lower()
    parts += [f"perhaps {hint}" for key, hint in _TOML_HINTS if key in said]
    return f" ({'; '.join(parts)})" if parts else ""


def _tomllib():
    try:
        import tomllib  # Python >= 3.11
    except ModuleNotFoundError:  # pragma: no cover - Python < 3.11
        import tomli as tomllib
    return tomllib


def _distortion_table(
    dist: Any, where: str, source: str | None
) -> tuple[Any, Any, Any, dict[str, Any]]:
    """``distortion`` (a model name or a table) as model, convention, center, coefficients."""
    model, conv, center, coeffs = "none", "correction", None, {}
    if dist is not None:
        if isinstance(dist, str):
            model = dist
        elif isinstance(dist, Mapping):
            model = dist.get("model", "none")
            conv = dist.get("convention", "correction")
            if str(model).strip().lower() == "brown" and "convention" in dist and str(
                    conv).strip().lower() != "distortion":
                raise CameraError(
                    f"{where}: the brown model maps ideal to distorted coordinates; "
                    f"convention = {conv!r} does not apply to it",
                    "Remove convention (or write convention = \"distortion\"); give k1 k2 k3 "
                    "p1 p2 as OpenCV/OpenSfM write them",
                    path=source, details={"key": "distortion.convention"})
            center = dist.get("center")
            coeffs = {k: v for k, v in dist.items() if k not in _DISTORTION_META}
            if "model" not in dist and coeffs:
                raise CameraError(
                    f"{where}: [distortion] has coefficients but no model",
                    f"Add model = one of {', '.join(repr(m) for m in DISTORTION_MODELS)}",
                    path=source,
                    details={"key": "distortion.model"},
                )
        else:
            raise CameraError(
                f"{where}: distortion must be a table or a model name, not {dist!r}",
                'Write [camera.distortion] with model = "smac" and the coefficients',
                path=source,
            )
    return model, conv, center, coeffs


def _merge(base: Mapping[str, Any], override: Mapping[str, Any]) -> dict[str, Any]:
    out = dict(base)
    for k, v in override.items():
        if isinstance(v, Mapping) and isinstance(out.get(k), Mapping):
            merged = dict(out[k])
            merged.update(v)
            out[k] = merged
        else:
            out[k] = v
    return out


# ---------------------------------------------------------------------- validators
def _number(value: Any, key: str, where: str) -> float:
    if isinstance(value, bool):
        raise CameraError(
            f"{where}: {key} must be a number, not {value!r}", "Write a plain number"
        )
    try:
        x = float(value)
    except (TypeError, ValueError, OverflowError):
        raise CameraError(
            f"{where}: {key} must be a number, not {_show(value)}",
            "Write a plain number (millimetres unless stated otherwise)",
            details={"key": key},
        ) from None
    if not math.isfinite(x):
        raise CameraError(f"{where}: {key} is not finite ({_show(value)})",
                          "Give a finite number", details={"key": key})
    return x


def _positive(value: Any, key: str, where: str) -> float:
    x = _number(value, key, where)
    if x <= 0:
        raise CameraError(
            f"{where}: {key} must be positive, not {value!r}",
            "Give the value in millimetres",
            details={"key": key},
        )
    return x


def _show(value: Any, limit: int = 60) -> str:
    """``repr(value)`` cut to ``limit`` characters, for messages."""
    try:
        text = repr(value)
    except RecursionError:  # pragma: no cover - a structure nested beyond repr's reach
        text = f"<{type(value).__name__}>"
    return text if len(text) <= limit else text[:limit - 5] + " ...]"


def _is_list(value: Any) -> bool:
    """A TOML array (a list or tuple; a numpy array from Python callers)."""
    return isinstance(value, (list, tuple)) or (isinstance(value, np.ndarray)
                                                and value.ndim == 1)


def _pair(value: Any, key: str, where: str) -> tuple[float, float]:
    if not _is_list(value) or len(value) != 2:
        raise CameraError(
            f"{where}: {key} must be two numbers [x, y], not {_show(value)}",
            f"Write {key} = [x, y] in millimetres",
            details={"key": key},
        )
    return (_number(value[0], key, where), _number(value[1], key, where))


def _fiducials(value: Any, where: str) -> dict[str, tuple[float, float]]:
    if not isinstance(value, Mapping):
        raise CameraError(
            f"{where}: fiducials must be a table of id = [x, y], not {type(value).__name__}",
            'Write [camera.fiducials] with one line per fiducial, e.g. 1 = [-106.0, -106.0]',
            details={"key": "fiducials"},
        )
    out = {}
    for fid, xy in value.items():
        if isinstance(xy, Mapping):  # [fiducials.1] x = ..., or a table one level too deep
            raise CameraError(
                f"{where}: fiducial {fid!s} must be [x, y] (mm), not a table {_show(xy)}",
                "Write one line per fiducial under [camera.fiducials], e.g. "
                "1 = [-106.0, -106.0]", details={"key": f"fiducials.{fid!s}"})
        out[str(fid)] = _pair(xy, f"fiducial {fid!s}", where)
    if len(out) < 3:
        raise CameraError(
            f"{where}: only {len(out)} calibrated fiducial(s) given",
            "The fiducial affine needs at least 3 (4 or 8 give a check); add them from the "
            "calibration report",
            details={"key": "fiducials", "count": len(out)},
        )
    xy = np.array(list(out.values()))
    if _collinear(xy):
        raise CameraError(
            f"{where}: the calibrated fiducials {', '.join(out)} lie on one line",
            "Check the fiducial coordinates against the calibration report",
            details={"key": "fiducials"},
        )
    return out


def _collinear(xy: np.ndarray) -> bool:
    xy = xy / max(float(np.abs(xy).max()), 1e-300)  # no overflow for any finite input
    d = xy - xy.mean(axis=0)
    s = np.linalg.svd(d, compute_uv=False)
    return bool(s[-1] <= 1e-9 * max(s[0], 1e-300))


def _coefficients(
    value: Any, model: str, where: str, source: str | None
) -> dict[str, float]:
    if not isinstance(value, Mapping):
        raise CameraError(
            f"{where}: distortion coefficients must be a table, not {value!r}", "", path=source
        )
    accepted = _coefficient_keys(model)
    lookup = {k.lower(): k for k in accepted}
    out: dict[str, float] = {}
    for key, v in value.items():
        canon = lookup.get(str(key).lower())
        if canon is None:
            if model == "none":
                mend = "Remove the coefficients or set model = 'smac', 'polynomial' or 'brown'"
            else:
                mend = f"The {model} model accepts {', '.join(accepted)}"
            raise CameraError(
                f"{where}: distortion coefficient {key!r} is not part of the "
                f"{model!r} model",
                mend,
                path=source,
                details={"key": f"distortion.{key}"},
            )
        out[canon] = _number(v, f"distortion.{key}", where)
    return out


def _pixel_size(value: Any, where: str) -> tuple[float, float]:
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        sx = sy = _positive(value, "pixel_size", where)
    else:
        sx, sy = _pair(value, "pixel_size", where)
        if sx <= 0 or sy <= 0:
            raise CameraError(
                f"{where}: pixel_size must be positive, not {value!r}",
                "Give the pixel spacing in millimetres",
            )
    if max(sx, sy) > 0.5:
        raise CameraError(
            f"{where}: pixel_size {value!r} mm is implausibly large",
            "pixel_size is in millimetres: 12 micrometres is 0.012",
            details={"key": "pixel_size"},
        )
    return (sx, sy)


def _image_size(value: Any, where: str) -> tuple[int, int]:
    if not _is_list(value) or len(value) != 2:
        raise CameraError(
            f"{where}: image_size must be [columns, rows], not {_show(value)}",
            "Write image_size = [columns, rows] in pixels",
        )
    out = []
    for v in value:
        if isinstance(v, (float, np.floating)) and math.isfinite(v) and float(v).is_integer():
            v = int(v)
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or not 1 <= v < 2**31:
            raise CameraError(
                f"{where}: image_size must be two positive whole numbers, not {_show(value)}",
                "Write image_size = [columns, rows] in pixels",
            )
        out.append(int(v))
    return (out[0], out[1])
