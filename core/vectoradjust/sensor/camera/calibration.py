"""The camera calibration: :class:`CameraCalibration` (focal length, principal point,
fiducials, lens distortion, pixel size).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from vectoradjust.errors import CameraError
from vectoradjust.sensor.camera.camera_file import _distortion_table, _merge, load_camera_file
from vectoradjust.sensor.camera.validators import (
    _BROWN_KEYS,
    _CAMERA_KEYS,
    _POLY_KEYS,
    _SMAC_KEYS,
    DISTORTION_CONVENTIONS,
    DISTORTION_MODELS,
    PIXEL_ORIGINS,
    PathLike,
    _coefficients,
    _fiducials,
    _image_size,
    _pair,
    _pixel_size,
    _positive,
    _show,
)

__all__ = ["CameraCalibration"]


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

