"""Reading and validating the project file (TOML, ``DESIGN.md`` section 9).

This module parses the file into plain settings (:class:`ProjectSpec`); it reads no
data files. :func:`vectoradjust.files.readers.load_project_data` then reads the tables, layers
and DEMs the spec points to.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Optional

import numpy as np

from vectoradjust.errors import ProjectError
from vectoradjust.model import AdjustmentSettings, Camera, ImageSpec, VectorSpec
from vectoradjust.sensor.camera import CameraCalibration
from vectoradjust.sensor.interior import normalize_unit, parse_corrections

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python < 3.11
    import tomli as tomllib

__all__ = ["ProjectSpec", "load_project", "parse_project"]

_TOP_KEYS = {
    "crs", "camera", "corrections", "images", "measurements", "control", "vectors",
    "adjustment", "qa", "truth", "name", "description", "report",
}
_REWEIGHT = ("none", "two-pass", "vce")
_MEASUREMENT_KEYS = ("path", "sigma", "unit", "fiducials")


@dataclass
class ProjectSpec:
    """A parsed project file.

    Attributes
    ----------
    path : pathlib.Path or None
        The project file.
    base_dir : pathlib.Path
        Directory that relative paths are resolved against.
    crs : str
    camera : Camera
        ``focal_length`` and ``principal_point`` of the calibration, which is in
        ``camera.calibration`` (a :class:`vectoradjust.sensor.camera.CameraCalibration`).
    camera_table : dict
        The raw ``[camera]`` table as written in the project file.
    corrections : dict
        The ``[corrections]`` table as written (validated).
    images : list of ImageSpec
    measurements : dict
        ``path`` (resolved), ``unit`` (``"mm"`` or ``"pixel"``), ``sigma`` (in that
        unit) when given, ``fiducials`` (resolved path) when given.
    control : dict or None
        ``path`` (resolved) and further keys.
    vectors : list of VectorSpec
        Paths resolved.
    settings : AdjustmentSettings
    raw : dict
        The whole parsed TOML.
    """

    path: Optional[Path]
    base_dir: Path
    crs: str
    camera: Camera
    camera_table: dict
    corrections: dict
    images: list
    measurements: dict
    control: Optional[dict]
    vectors: list
    settings: AdjustmentSettings
    raw: dict = field(default_factory=dict)

    def vector(self, name: str) -> VectorSpec:
        """The ``[[vectors]]`` entry called ``name``."""
        for v in self.vectors:
            if v.name == name:
                return v
        names = ", ".join(v.name for v in self.vectors) or "none"
        raise ProjectError(
            f"{self._where()}: no [[vectors]] entry is named {name!r}",
            f"Use one of: {names}",
            path=self._where(),
        )

    def _where(self) -> str:
        return str(self.path) if self.path else "<project>"


def load_project(path) -> ProjectSpec:
    """Read and validate a project file.

    Parameters
    ----------
    path : str or os.PathLike
        The TOML project file.

    Returns
    -------
    ProjectSpec

    Raises
    ------
    ProjectError
        If the file is missing, not valid TOML, or a key is missing or wrong.
    """
    p = Path(path)
    if not p.is_file():
        raise ProjectError(
            f"Project file {str(p)!r} does not exist",
            "Give the path of a TOML project file (see README: 'The project file')",
            path=str(p),
        )
    try:
        with open(p, "rb") as fh:
            raw = tomllib.load(fh)
    except tomllib.TOMLDecodeError as exc:
        raise ProjectError(
            f"{p}: not valid TOML ({exc})", "Fix the syntax at the position given", path=str(p)
        ) from exc
    return parse_project(raw, base_dir=p.parent.resolve(), path=p)


def _err(where: str, what: str, mend: str) -> ProjectError:
    return ProjectError(f"{where}: {what}", mend, path=where)


def _number(where: str, key: str, value: Any, *, positive: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise _err(where, f"{key} must be a number, not {value!r}", f"Write {key} = <number>")
    v = float(value)
    if not np.isfinite(v) or (positive and v <= 0):
        raise _err(where, f"{key} must be a finite{' positive' if positive else ''} number, "
                   f"not {value!r}", f"Correct {key}")
    return v


def _vector3(where: str, key: str, value: Any, *, positive: bool = False) -> np.ndarray:
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        value = [value] * 3
    if not isinstance(value, (list, tuple)) or len(value) != 3:
        raise _err(where, f"{key} must be a list of 3 numbers, not {value!r}",
                   f"Write {key} = [a, b, c]")
    return np.array([_number(where, key, v, positive=positive) for v in value])


def _resolve(base_dir: Path, value: Any, where: str, key: str) -> str:
    if not isinstance(value, str) or not value:
        raise _err(where, f"{key} must be a file path string, not {value!r}",
                   f'Write {key} = "file.ext" (relative to the project file)')
    q = Path(value)
    return str(q if q.is_absolute() else (base_dir / q))


def parse_project(raw: dict, base_dir, path=None) -> ProjectSpec:
    """Validate a parsed TOML mapping (see :func:`load_project`)."""
    where = str(path) if path else "<project>"
    base_dir = Path(base_dir)
    unknown = sorted(set(raw) - _TOP_KEYS)
    if unknown:
        raise _err(where, f"unknown top-level key(s) {', '.join(unknown)}",
                   f"Allowed keys are {', '.join(sorted(_TOP_KEYS))}; check the spelling")
    crs = raw.get("crs")
    if not isinstance(crs, str) or not crs.strip():
        raise _err(where, "crs is missing", 'Add crs = "EPSG:xxxxx" (a projected CRS in metres)')

    cam = raw.get("camera")
    if not isinstance(cam, dict):
        raise _err(where, "[camera] is missing", "Add [camera] with focal_length (mm)")
    camera = _parse_camera(cam, base_dir, where)

    corrections = _parse_corrections(raw.get("corrections", {}) or {}, where)
    images = _parse_images(raw.get("images"), where)
    meas = _parse_measurements(raw.get("measurements"), base_dir, where)
    control = _parse_control(raw.get("control"), base_dir, where)
    vectors = _parse_vectors(raw.get("vectors", []) or [], base_dir, where)
    settings = _parse_adjustment(raw.get("adjustment", {}) or {}, where)

    return ProjectSpec(
        path=Path(path) if path else None, base_dir=base_dir, crs=crs.strip(), camera=camera,
        camera_table=dict(cam), corrections=dict(corrections), images=images,
        measurements=meas, control=control, vectors=vectors, settings=settings, raw=raw,
    )


def _parse_corrections(corrections: Any, where: str) -> dict:
    """``[corrections]``: validated, returned as written."""
    if not isinstance(corrections, dict):
        raise _err(where, "[corrections] must be a table", "Write [corrections] refraction = true")
    parse_corrections(corrections, f"{where} [corrections]")  # validates keys and values
    return corrections


def _parse_images(images_raw: Any, where: str) -> list:
    """``[[images]]``: one :class:`ImageSpec` per entry, unique ids."""
    if not isinstance(images_raw, list) or not images_raw:
        raise _err(where, "no [[images]] entries", "Add one [[images]] table per image")
    images = []
    seen: set = set()
    for i, im in enumerate(images_raw, start=1):
        w = f"{where} [[images]] entry {i}"
        if not isinstance(im, dict) or "id" not in im:
            raise _err(w, "has no id", 'Add id = "L"')
        iid = str(im["id"])
        w = f"{where} [[images]] id {iid!r}"
        if iid in seen:
            raise _err(w, "is defined twice", "Give every image a unique id")
        seen.add(iid)
        if "position" not in im:
            raise _err(w, "has no position", "Add position = [XL, YL, ZL] (approximate, m)")
        pos = _vector3(w, "position", im["position"])
        att = _vector3(w, "attitude", im.get("attitude", [0.0, 0.0, 0.0]))
        sp = im.get("sigma_position")
        sa = im.get("sigma_attitude")
        sp = None if sp is None else _number(w, "sigma_position", sp, positive=True)
        sa = None if sa is None else _number(w, "sigma_attitude", sa, positive=True)
        date = im.get("date")
        images.append(ImageSpec(iid, pos, att, sp, sa, None if date is None else str(date)))
    return images


def _parse_control(control: Any, base_dir: Path, where: str) -> Optional[dict]:
    """``[control]`` (optional): its path resolved, further keys as written."""
    if control is not None:
        if not isinstance(control, dict) or "path" not in control:
            raise _err(where, "[control] has no path", 'Add [control] path = "gcps.csv"')
        control = dict(control)
        control["path"] = _resolve(base_dir, control["path"], where, "[control] path")
    return control


def _parse_vectors(vectors_raw: Any, base_dir: Path, where: str) -> list:
    """``[[vectors]]``: one :class:`VectorSpec` per entry, unique names, paths resolved."""
    vectors = []
    names: set = set()
    for i, v in enumerate(vectors_raw, start=1):
        w = f"{where} [[vectors]] entry {i}"
        if not isinstance(v, dict):
            raise _err(w, "must be a table", "Write [[vectors]] name = ... path = ...")
        name = str(v.get("name", f"vectors{i}"))
        if name in names:
            raise _err(w, f"name {name!r} is used twice", "Give every [[vectors]] a unique name")
        names.add(name)
        if "path" not in v:
            raise _err(w, "has no path", 'Add path = "roads.shp"')
        sigma = _vector3(w, "sigma", v.get("sigma", [10.0, 10.0, 10.0]), positive=True)
        vectors.append(VectorSpec(
            name=name,
            path=_resolve(base_dir, v["path"], w, "path"),
            id_field=None if v.get("id_field") in (None, "") else str(v["id_field"]),
            sigma=tuple(float(s) for s in sigma),
            dem=None if v.get("dem") is None else _resolve(base_dir, v["dem"], w, "dem"),
            truth=None if v.get("truth") is None else _resolve(base_dir, v["truth"], w, "truth"),
            layer=None if v.get("layer") is None else str(v["layer"]),
            identification_sigma=_identification(w, v.get("identification_sigma")),
            offset=_offset_kind(w, v.get("offset", "shift")),
        ))
    return vectors


def _identification(where: str, value: Any):
    """``identification_sigma``: a number (horizontal; vertical 0) or [horizontal, vertical]."""
    if value is None:
        return None
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        value = [value, 0.0]
    if not isinstance(value, (list, tuple)) or len(value) != 2:
        raise _err(where, f"identification_sigma must be a number or [horizontal, vertical], "
                   f"not {value!r}", "Write identification_sigma = 0.5 or [0.5, 0.1] (metres)")
    h, v = (_number(where, "identification_sigma", x) for x in value)
    if h < 0 or v < 0:
        raise _err(where, f"identification_sigma must not be negative, not {value!r}",
                   "Write identification_sigma = 0.5 or [0.5, 0.1] (metres)")
    return (h, v)


def _offset_kind(where: str, value: Any) -> str:
    """``offset``: none | shift | shift3d | similarity | affine."""
    from vectoradjust.adjust.offsets import OFFSET_KINDS

    if value not in OFFSET_KINDS:
        raise _err(where, f"offset must be one of {', '.join(OFFSET_KINDS)}, not {value!r}",
                   'Write offset = "shift" to estimate a horizontal shift of the database')
    return str(value)


def _parse_adjustment(adj: Any, where: str) -> AdjustmentSettings:
    """``[adjustment]``: the settings that differ from :class:`AdjustmentSettings`."""
    settings = AdjustmentSettings()
    if "max_iterations" in adj:
        mi = adj["max_iterations"]
        if isinstance(mi, bool) or not isinstance(mi, int) or mi < 1:
            raise _err(where, f"[adjustment] max_iterations must be a positive integer, not {mi!r}",
                       "Write max_iterations = 20")
        settings.max_iterations = mi
    if "reweight" in adj:
        rw = adj["reweight"]
        if rw not in _REWEIGHT:
            raise _err(where, f"[adjustment] reweight = {rw!r} is not known",
                       f"Use one of {', '.join(_REWEIGHT)}")
        settings.reweight = rw
    if "alpha" in adj:
        a = _number(where, "[adjustment] alpha", adj["alpha"], positive=True)
        if not a < 1:
            raise _err(where, f"[adjustment] alpha must be in (0, 1), not {a}",
                       "Write alpha = 0.05")
        settings.alpha = a
    if "snooping" in adj:
        if not isinstance(adj["snooping"], bool):
            raise _err(where, f"[adjustment] snooping must be true or false, not "
                       f"{adj['snooping']!r}", "Write snooping = true")
        settings.snooping = adj["snooping"]
    for key in ("alpha0", "beta0"):
        if key in adj:
            v = _number(where, f"[adjustment] {key}", adj[key], positive=True)
            if not v < 0.5:
                raise _err(where, f"[adjustment] {key} must be in (0, 0.5), not {v}",
                           f"Write {key} = {getattr(AdjustmentSettings, key)}")
            setattr(settings, key, v)
    if "max_removals" in adj:
        mr = adj["max_removals"]
        if isinstance(mr, bool) or not isinstance(mr, int) or mr < 0:
            raise _err(where, f"[adjustment] max_removals must be a whole number >= 0, not {mr!r}",
                       "Write max_removals = 10")
        settings.max_removals = mr
    if "covariance_scale" in adj:
        cs = adj["covariance_scale"]
        if cs not in ("a-posteriori", "a-priori"):
            raise _err(where, f"[adjustment] covariance_scale = {cs!r} is not known",
                       'Use "a-posteriori" (times sigma0^2) or "a-priori"')
        settings.covariance_scale = cs
    for key in ("tolerance_position", "tolerance_angle", "merge_tolerance"):
        if key in adj:
            setattr(settings, key, _number(where, f"[adjustment] {key}", adj[key], positive=True))
    return settings


def _parse_measurements(meas: Any, base_dir: Path, where: str) -> dict:
    """``[measurements]``: path, sigma and unit of the image measurements, fiducials."""
    if not isinstance(meas, dict) or "path" not in meas:
        raise _err(where, "[measurements] path is missing",
                   'Add [measurements] path = "image_points.csv"')
    unknown = sorted(set(meas) - set(_MEASUREMENT_KEYS))
    if unknown:
        raise _err(where, f"[measurements] has unknown key(s) {', '.join(unknown)}",
                   f"Accepted keys: {', '.join(_MEASUREMENT_KEYS)}")
    meas = dict(meas)
    meas["path"] = _resolve(base_dir, meas["path"], where, "[measurements] path")
    meas["unit"] = normalize_unit(meas.get("unit", "mm"), f"{where} [measurements]")
    if "sigma" in meas:
        meas["sigma"] = _number(where, f"[measurements] sigma ({meas['unit']})", meas["sigma"],
                                positive=True)
    if meas.get("fiducials") is not None:
        meas["fiducials"] = _resolve(base_dir, meas["fiducials"], where,
                                     "[measurements] fiducials")
    return meas


def _parse_camera(cam: dict, base_dir: Path, where: str) -> Camera:
    """``[camera]``, inline or ``path = "camera.toml"``, read by :class:`CameraCalibration`.

    Raises
    ------
    CameraError
        Whatever :meth:`CameraCalibration.from_dict` finds wrong (missing
        ``focal_length``, unknown keys or distortion model, a missing camera file ...).
    """
    cal = CameraCalibration.from_dict(cam, base_dir, where=f"{where} [camera]")
    return Camera(focal_length=cal.focal_length, principal_point=tuple(cal.principal_point),
                  calibration=cal)
