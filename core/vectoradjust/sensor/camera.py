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
    model = "smac"                    # none | smac | polynomial
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
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Union

import numpy as np

from vectoradjust.errors import CameraError

__all__ = [
    "CameraCalibration",
    "DISTORTION_MODELS",
    "DISTORTION_CONVENTIONS",
    "load_camera_file",
]

#: Accepted distortion model names.
DISTORTION_MODELS = ("none", "smac", "polynomial")
#: Accepted sign conventions of the distortion coefficients.
DISTORTION_CONVENTIONS = ("correction", "distortion")
#: Accepted pixel origin conventions.
PIXEL_ORIGINS = ("center", "corner")

_SMAC_KEYS = ("K0", "K1", "K2", "K3", "K4", "P1", "P2", "P3", "P4")
_POLY_KEYS = ("k1", "k2", "k3", "k4", "P1", "P2", "P3", "P4")
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
        ``"none"``, ``"smac"`` or ``"polynomial"`` (see the module docstring).
    distortion_coefficients : dict
        ``smac``: ``K0..K4``, ``P1..P4``; ``polynomial``: ``k1..k4``, ``P1..P4``.
        Missing coefficients are zero.
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
        all zero.
        """
        c = self.distortion_coefficients
        if self.distortion_model == "smac":
            return np.array([c.get(k, 0.0) for k in _SMAC_KEYS[:5]], float)
        if self.distortion_model == "polynomial":
            return np.array([0.0] + [c.get(k, 0.0) for k in _POLY_KEYS[:4]], float)
        return np.zeros(5)

    @property
    def decentering_coefficients(self) -> np.ndarray:
        """Decentering coefficients ``[P1, P2, P3, P4]`` (zero for ``none``)."""
        c = self.distortion_coefficients
        if self.distortion_model == "none":
            return np.zeros(4)
        return np.array([c.get(k, 0.0) for k in ("P1", "P2", "P3", "P4")], float)

    @property
    def distortion_sign(self) -> float:
        """``+1`` when the formula is the correction to add, ``-1`` when it is the distortion."""
        return 1.0 if self.distortion_convention == "correction" else -1.0

    @property
    def has_distortion(self) -> bool:
        """True when the model is not ``none`` and some coefficient is non-zero."""
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
        unknown = sorted(set(d) - set(_CAMERA_KEYS))
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
    if not path.is_file():
        raise CameraError(
            f"Camera file {path} does not exist",
            "Check the path (relative paths are relative to the project file)",
            path=str(path),
        )
    try:
        tomllib = _tomllib()
        with open(path, "rb") as fh:
            table = tomllib.load(fh)
    except OSError as exc:
        raise CameraError(
            f"Camera file {path} cannot be read ({exc})", "Check its permissions", path=str(path)
        ) from exc
    except ValueError as exc:  # tomllib.TOMLDecodeError derives from ValueError
        raise CameraError(
            f"Camera file {path} is not valid TOML: {exc}",
            "Fix the syntax at the line named",
            path=str(path),
        ) from exc
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
    except (TypeError, ValueError):
        raise CameraError(
            f"{where}: {key} must be a number, not {value!r}",
            "Write a plain number (millimetres unless stated otherwise)",
            details={"key": key},
        ) from None
    if not math.isfinite(x):
        raise CameraError(f"{where}: {key} is not finite ({value!r})", "Give a finite number")
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


def _pair(value: Any, key: str, where: str) -> tuple[float, float]:
    if isinstance(value, (str, bytes)) or not hasattr(value, "__len__") or len(value) != 2:
        raise CameraError(
            f"{where}: {key} must be two numbers [x, y], not {value!r}",
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
                mend = "Remove the coefficients or set model = 'smac' or 'polynomial'"
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
    if isinstance(value, (str, bytes)) or not hasattr(value, "__len__") or len(value) != 2:
        raise CameraError(
            f"{where}: image_size must be [columns, rows], not {value!r}",
            "Write image_size = [columns, rows] in pixels",
        )
    out = []
    for v in value:
        ok = isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool)
        if not ok or not float(v).is_integer() or int(v) < 1:
            raise CameraError(
                f"{where}: image_size must be two positive whole numbers, not {value!r}",
                "Write image_size = [columns, rows] in pixels",
            )
        out.append(int(v))
    return (out[0], out[1])
