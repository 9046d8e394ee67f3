"""Reading and validating the project file (TOML, ``docs/method.md`` section 9).

This module parses the file into plain settings (:class:`ProjectSpec`); it reads no
data files. :func:`vectoradjust.files.readers.load_project_data` then reads the tables, layers
and DEMs the spec points to.
"""

from __future__ import annotations

import datetime
import difflib
import sys
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Optional

import numpy as np

from vectoradjust.conflation import CONFLATION_KEYS, settings_from_table
from vectoradjust.errors import ProjectError
from vectoradjust.model import AdjustmentSettings, Camera, ImageSpec, VectorSpec
from vectoradjust.qa.tolerances import _SPEC_KEYS as _QA_KEYS
from vectoradjust.sensor.camera import (
    _CAMERA_KEYS,
    _DISTORTION_META,
    _POLY_KEYS,
    _SMAC_KEYS,
    CameraCalibration,
    _show,
    read_toml_text,
    toml_error_hint,
)
from vectoradjust.sensor.interior import CORRECTION_KEYS, normalize_unit, parse_corrections

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python < 3.11
    import tomli as tomllib

__all__ = ["PROJECT_SCHEMA", "ProjectSpec", "load_project", "parse_project", "check_keys"]

#: The keys each table of the project file may hold (README: "The project file"). The
#: camera's keys are the camera file's (:mod:`vectoradjust.sensor.camera`) plus ``path``;
#: ``[corrections]`` those of :func:`vectoradjust.sensor.interior.parse_corrections`;
#: ``[qa]`` those of :class:`vectoradjust.qa.tolerances.QASpec`.
PROJECT_SCHEMA: dict = {
    "top level": ("name", "description", "crs", "vertical_crs", "heights", "camera",
                  "corrections", "images",
                  "measurements", "control", "vectors", "adjustment", "truth", "qa",
                  "conflation", "trajectory"),
    "[camera]": tuple(_CAMERA_KEYS),
    "[corrections]": tuple(CORRECTION_KEYS),
    "[[images]]": ("id", "position", "attitude", "sigma_position", "sigma_attitude", "date",
                   "path", "model", "rpc", "bias", "bias_sigma", "strip"),
    "[measurements]": ("path", "unit", "sigma", "fiducials"),
    "[control]": ("path", "crs", "vertical_crs"),
    "[trajectory]": ("path", "crs", "vertical_crs"),
    "[[vectors]]": ("name", "path", "layer", "where", "id_field", "sigma",
                    "identification_sigma", "offset", "dem", "truth", "role",
                    "systematic_sigma"),
    "[adjustment]": ("max_iterations", "reweight", "alpha", "snooping", "alpha0", "beta0",
                     "max_removals", "covariance_scale", "tolerance_position",
                     "tolerance_angle", "merge_tolerance", "reuse_tolerance",
                     "reuse_points", "datum", "self_calibration"),
    "[truth]": ("path", "widths"),
    "[qa]": tuple(_QA_KEYS),
    "[conflation]": CONFLATION_KEYS,
}
#: the optional tables that are single tables (``[name]``), not arrays (``[[name]]``)
_TABLES = ("camera", "corrections", "measurements", "control", "adjustment", "truth", "qa",
           "conflation", "trajectory")
_REWEIGHT = ("none", "two-pass", "vce")


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
        ``path`` (resolved) and further keys: ``crs`` and ``vertical_crs`` (stripped
        texts) when given.
    vectors : list of VectorSpec
        Paths resolved.
    settings : AdjustmentSettings
    raw : dict
        The whole parsed TOML.
    vertical_crs : str or None
        The top-level ``vertical_crs``: the vertical datum of the control heights (unless
        ``[control] vertical_crs``) and of the DEMs; None when not given.
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
    vertical_crs: Optional[str] = None
    #: the kind of the project's heights, ``"ellipsoidal"`` or ``"orthometric"`` (required
    #: with RPC images, whose heights are ellipsoidal); None when not given
    heights: Optional[str] = None
    #: ``[trajectory]``: GNSS/INS camera positions (and attitudes, sigmas) per image from a
    #: CSV (``path`` resolved, ``crs``, ``vertical_crs``); None when not given
    trajectory: Optional[dict] = None

    @property
    def has_rpc(self) -> bool:
        """Whether any image has an RPC model."""
        return any(im.model == "rpc" for im in self.images)

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
        If the file is missing, a folder, unreadable (permissions), not UTF-8 (the
        encoding found is named; a UTF-8 byte order mark is accepted), not valid TOML, or
        a key is missing or of the wrong type (the key and its table are named).
    """
    p = Path(path)
    text = read_toml_text(p, f"Project file {str(p)!r}", ProjectError,
                          missing=lambda: _missing_mend(p))
    try:
        raw = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        mend = ("Fix the syntax at the position given" if p.suffix.lower() == ".toml" else
                f"This is a {p.suffix or 'file without extension'}, not the project file: "
                "give the project's .toml file (README: 'The project file')")
        raise ProjectError(f"{p}: not valid TOML ({exc}){toml_error_hint(exc, text)}", mend,
                           path=str(p)) from exc
    except RecursionError:
        raise ProjectError(f"{p}: not valid TOML (arrays or tables nested too deeply)",
                           "Check the brackets", path=str(p)) from None
    return parse_project(raw, base_dir=p.parent.resolve(), path=p)


def _missing_mend(p: Path) -> str:
    """What to do about a project file that does not exist: the nearest ``.toml`` file
    of its folder, if there is one."""
    mend = "Give the path of a TOML project file (see README: 'The project file')"
    try:
        found = [q.name for q in p.parent.iterdir() if q.suffix.lower() == ".toml"]
    except (OSError, ValueError):
        return mend
    close = difflib.get_close_matches(p.name, found, n=1, cutoff=0.6)
    return f"{mend}; perhaps {p.parent / close[0]}" if close else mend


def _err(where: str, what: str, mend: str) -> ProjectError:
    return ProjectError(f"{where}: {what}", mend, path=where)


def _number(where: str, key: str, value: Any, *, positive: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise _err(where, f"{key} must be a number, not {_show(value)}",
                   f"Write {key} = <number>")
    try:
        v = float(value)
    except OverflowError:  # an integer beyond any float (not from TOML: int64 there)
        v = np.inf
    if not np.isfinite(v) or (positive and v <= 0):
        raise _err(where, f"{key} must be a finite{' positive' if positive else ''} number, "
                   f"not {_show(value)}", f"Correct {key}")
    return v


def _vector3(where: str, key: str, value: Any, *, positive: bool = False) -> np.ndarray:
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        value = [value] * 3
    if not isinstance(value, (list, tuple)) or len(value) != 3:
        raise _err(where, f"{key} must be a list of 3 numbers, not {_show(value)}",
                   f"Write {key} = [a, b, c]")
    return np.array([_number(where, key, v, positive=positive) for v in value])


def _resolve(base_dir: Path, value: Any, where: str, key: str) -> str:
    _path_text(where, key, value)
    q = Path(value)
    return str(q if q.is_absolute() else (base_dir / q))


def parse_project(raw: dict, base_dir, path=None) -> ProjectSpec:
    """Validate a parsed TOML mapping (see :func:`load_project`).

    Every table's keys are checked against :data:`PROJECT_SCHEMA`: an unknown key is an
    error naming the table (the ``[[vectors]]`` or ``[[images]]`` entry), the key and the
    nearest known key.
    """
    where = str(path) if path else "<project>"
    base_dir = Path(base_dir)
    if not isinstance(raw, Mapping):
        raise _err(where, f"the project must be a table of keys, not {_show(raw)}",
                   "See README: 'The project file'")
    check_keys(raw, PROJECT_SCHEMA["top level"], where, "")
    for name in _TABLES:
        if name in raw and not isinstance(raw[name], Mapping):
            raise _err(where, f"{name} must be a table ([{name}]), not {_show(raw[name])}",
                       f"Write [{name}] on a line of its own, followed by its keys")
    for name in ("name", "description"):
        if name in raw and not isinstance(raw[name], str):
            raise _err(where, f"{name} must be a text, not {_show(raw[name])}",
                       f'Write {name} = "..." (in quotes), or leave it out')
    crs = raw.get("crs")
    if crs is not None and not isinstance(crs, str):
        raise _err(where, f"crs must be a text, not {_show(crs)}",
                   'Write crs = "EPSG:32616" (in quotes; a projected CRS in metres)')
    if not isinstance(crs, str) or not crs.strip():
        raise _err(where, "crs is missing", 'Add crs = "EPSG:xxxxx" (a projected CRS in metres)')

    cam = raw.get("camera")
    camera = _parse_camera(cam, base_dir, where) if isinstance(cam, dict) else None
    images = _parse_images(raw.get("images"), where, base_dir)
    if camera is None:
        if cam is not None or not all(im.model == "rpc" for im in images):
            raise _err(where, "[camera] is missing", "Add [camera] with focal_length (mm)")
        cam = {}  # satellite images only: no frame camera

    corrections = _parse_corrections(raw.get("corrections", {}) or {}, where)
    heights = _parse_heights(raw, images, where)
    meas = _parse_measurements(raw.get("measurements"), base_dir, where)
    control = _parse_control(raw.get("control"), base_dir, where)
    trajectory = _parse_control(raw.get("trajectory"), base_dir, where, "trajectory",
                                "gnss_ins.csv")
    vectors = _parse_vectors(raw.get("vectors", []), base_dir, where)
    settings = _parse_adjustment(raw.get("adjustment", {}) or {}, where)
    for name in ("truth", "qa"):  # read where they are used (files.truth, qa.verdict)
        if name in raw:
            check_keys(raw[name], PROJECT_SCHEMA[f"[{name}]"], where, f"[{name}]")
    _check_truth(raw.get("truth"), where)
    if "conflation" in raw:  # used by pipeline.run (conflation/)
        check_keys(raw["conflation"], PROJECT_SCHEMA["[conflation]"], where, "[conflation]")
        settings_from_table(raw["conflation"], where)

    return ProjectSpec(
        path=Path(path) if path else None, base_dir=base_dir, crs=crs.strip(), camera=camera,
        camera_table=dict(cam), corrections=dict(corrections), images=images,
        measurements=meas, control=control, vectors=vectors, settings=settings, raw=raw,
        vertical_crs=_text(where, "vertical_crs", raw.get("vertical_crs"),
                           'vertical_crs = "EPSG:5703"'),
        heights=heights, trajectory=trajectory,
    )


def _parse_heights(raw: dict, images: list, where: str) -> Optional[str]:
    """The top-level ``heights``: required with RPC images (their heights are
    ellipsoidal; orthometric heights are converted with the ``vertical_crs``'s geoid)."""
    heights = raw.get("heights")
    if heights is None:
        if any(im.model == "rpc" for im in images):
            raise _err(where, "heights is missing: RPC images work in ellipsoidal heights, so "
                       "the project must say which kind its control, DEM and road heights are",
                       'Add heights = "ellipsoidal" (GNSS heights above the WGS84 ellipsoid) '
                       'or heights = "orthometric" with vertical_crs = "EPSG:5773" (EGM96), '
                       '"EPSG:3855" (EGM2008) or your datum\'s code')
        return None
    if not isinstance(heights, str) or heights not in ("ellipsoidal", "orthometric"):
        raise _err(where, f"heights = {_show(heights)} is unknown",
                   'Write heights = "ellipsoidal" or heights = "orthometric"')
    if heights == "orthometric" and not raw.get("vertical_crs"):
        raise _err(where, 'heights = "orthometric" needs the vertical datum to convert them '
                   "to the ellipsoidal heights of the RPCs",
                   'Add vertical_crs = "EPSG:5773" (EGM96 height), "EPSG:3855" (EGM2008) or '
                   "your datum's code")
    return heights


def _suggestion(key: str, allowed) -> Optional[str]:
    """The allowed key ``key`` is most likely a misspelling of, or None."""
    lower = {str(a).lower(): str(a) for a in allowed}
    k = str(key).lower()
    if k in lower:
        return lower[k]
    close = difflib.get_close_matches(k, list(lower), n=1, cutoff=0.6)
    return lower[close[0]] if close else None


def check_keys(table: Mapping, allowed, where: str, label: str,
               generic: Optional[str] = None) -> None:
    """Raise a :class:`ProjectError` for every key of ``table`` that is not ``allowed``.

    Parameters
    ----------
    table : mapping
        A table as read from TOML.
    allowed : sequence of str
        Its keys (:data:`PROJECT_SCHEMA`).
    where : str
        The project file, for the message.
    label : str
        The table as the message names it (``"[adjustment]"``, ``"[[vectors]] entry 2
        ('TNM')"``); ``""`` for the top level.
    generic : str, optional
        The table's kind for the list of keys (``"[[vectors]]"``); default ``label``.

    Raises
    ------
    ProjectError
        Naming the table, each unknown key and the nearest allowed one ("did you mean").
    """
    unknown = [str(k) for k in table if k not in allowed]
    if not unknown:
        return
    guesses = {k: _suggestion(k, allowed) for k in unknown}
    said = ", ".join(f"{k!r}" + (f" (did you mean {guesses[k]!r}?)" if guesses[k] else "")
                     for k in unknown)
    plural = "s" if len(unknown) > 1 else ""
    what = (f"{label}: unknown key{plural} {said}" if label else
            f"unknown top-level key{plural} {said}")
    kind = generic or label or "the top level"
    raise ProjectError(
        f"{where} {what}" if label else f"{where}: {what}",
        f"Check the spelling (README: 'The project file'); the keys of {kind} are "
        f"{', '.join(allowed)}",
        path=where,
        details={"table": kind, "keys": unknown, "suggestions": guesses,
                 "allowed": list(allowed)},
    )


def _check_truth(truth: Any, where: str) -> None:
    """``[truth]`` (optional) needs ``path``; ``widths`` (read by ``files.truth``) are
    numbers >= 0 (a list, or a text ``"1,2,5"``)."""
    if truth is None:
        return
    if "path" in truth and not isinstance(truth["path"], str):
        raise _err(f"{where} [truth]", f"path must be a file path string, not "
                   f"{_show(truth['path'])}", 'Write path = "truth_roads.shp"')
    if not truth.get("path"):
        raise _err(where, "[truth] has no path", 'Add [truth] path = "truth_roads.shp"')
    _path_text(f"{where} [truth]", "path", truth["path"])
    widths = truth.get("widths")
    if widths is None:
        return
    items = ([w for w in widths.replace(";", ",").split(",") if w.strip()]
             if isinstance(widths, str) else widths)
    ok = isinstance(items, list) and len(items) > 0
    for w in items if ok else ():
        if isinstance(w, str):
            try:
                w = float(w)
            except ValueError:
                w = None
        if isinstance(w, bool) or not isinstance(w, (int, float)) or not 0 <= w < np.inf:
            ok = False
    if not ok:
        raise _err(f"{where} [truth]", f"widths must be distances >= 0 in metres, not "
                   f"{_show(widths)}", "Write widths = [1.0, 2.0, 5.0]")


def _parse_corrections(corrections: Any, where: str) -> dict:
    """``[corrections]``: validated, returned as written."""
    if not isinstance(corrections, dict):
        raise _err(where, "[corrections] must be a table", "Write [corrections] refraction = true")
    check_keys(corrections, PROJECT_SCHEMA["[corrections]"], where, "[corrections]")
    parse_corrections(corrections, f"{where} [corrections]")  # validates keys and values
    return corrections


def _parse_images(images_raw: Any, where: str, base_dir: Path = Path(".")) -> list:
    """``[[images]]``: one :class:`ImageSpec` per entry, unique ids."""
    if isinstance(images_raw, Mapping):
        raise _err(where, "images is a single table", "Write [[images]] (an array of tables, "
                   "one per image) instead of [images]")
    if images_raw is not None and not isinstance(images_raw, list):
        raise _err(where, f"images = {_show(images_raw)} must be an array of tables",
                   "Write one [[images]] table per image, with id = ..., position = ...")
    if not images_raw:
        raise _err(where, "no [[images]] entries", "Add one [[images]] table per image")
    images = []
    seen: set = set()
    for i, im in enumerate(images_raw, start=1):
        w = f"{where} [[images]] entry {i}"
        if not isinstance(im, Mapping):
            raise _err(w, f"must be a table, not {_show(im)}",
                       'Write [[images]] on a line of its own, then id = "L", position = ...')
        if "id" not in im:
            raise _err(w, "has no id", 'Add id = "L"')
        iid = _name_of(w, "id", im["id"], 'id = "L"')
        check_keys(im, PROJECT_SCHEMA["[[images]]"], where, f"[[images]] entry {i} ({iid!r})",
                   "[[images]]")
        w = f"{where} [[images]] id {iid!r}"
        if iid in seen:
            raise _err(w, "is defined twice", "Give every image a unique id")
        seen.add(iid)
        model = im.get("model", "frame")
        if not isinstance(model, str) or model not in ("frame", "rpc"):
            raise _err(w, f"model = {_show(model)} is unknown",
                       'Write model = "frame" (a camera) or model = "rpc" (a satellite image '
                       "with rational polynomial coefficients)")
        if im.get("path") is not None:
            _path_text(w, "path", im["path"])
        if model == "rpc":
            images.append(_parse_rpc_image(im, iid, base_dir, w))
            continue
        for key in ("rpc", "bias", "bias_sigma"):
            if key in im:
                raise _err(w, f"{key} is given but the image is a frame camera",
                           f'Add model = "rpc" to the entry, or remove {key}')
        if "position" not in im:
            raise _err(w, "has no position", "Add position = [XL, YL, ZL] (approximate, m)")
        pos = _vector3(w, "position", im["position"])
        att = _vector3(w, "attitude", im.get("attitude", [0.0, 0.0, 0.0]))
        sp = im.get("sigma_position")
        sa = im.get("sigma_attitude")
        sp = _sigma_or_three(w, "sigma_position", sp)
        sa = _sigma_or_three(w, "sigma_attitude", sa)
        images.append(ImageSpec(iid, pos, att, sp, sa, _date(w, im.get("date"))))
    return images


def _sigma_or_three(where: str, key: str, value: Any):
    """A prior sigma: one number for all three axes, or ``[x, y, z]`` (e.g. GNSS: 3 m
    horizontal, 5 m vertical); None when not given."""
    if value is None:
        return None
    if isinstance(value, (list, tuple)):
        return tuple(float(v) for v in _vector3(where, key, value, positive=True))
    return _number(where, key, value, positive=True)


def _name_of(where: str, key: str, value: Any, example: str) -> str:
    """An id or name: a non-empty text (or a whole number, read as its digits)."""
    if isinstance(value, int) and not isinstance(value, bool):
        return str(value)
    if not isinstance(value, str) or not value.strip():
        raise _err(where, f"{key} must be a text (or a whole number), not {_show(value)}",
                   f"Write {example}")
    return value


def _date(where: str, value: Any) -> Optional[str]:
    """``date``: a TOML date (1999-10-05) or a text, as text; None when not given."""
    if value is None:
        return None
    if not isinstance(value, (str, datetime.date)):
        raise _err(where, f"date must be a date (1999-10-05) or a text, not {_show(value)}",
                   "Write date = 1999-10-05, or leave it out")
    return str(value)


def _path_text(where: str, key: str, value: Any) -> None:
    """A file path given in the project: a non-empty text without NUL characters."""
    if not isinstance(value, str) or not value.strip() or "\x00" in value:
        raise _err(where, f"{key} must be a file path string, not {_show(value)}",
                   f'Write {key} = "file.ext" (relative to the project file)')


def _parse_rpc_image(im: dict, iid: str, base_dir: Path, w: str) -> ImageSpec:
    """An ``[[images]]`` entry with ``model = "rpc"``: RPC file, bias model, bias priors."""
    from vectoradjust.sensor.models import RpcImage
    from vectoradjust.sensor.rpc import BIAS_MODELS

    for key in ("position", "attitude", "sigma_position", "sigma_attitude"):
        if key in im:
            raise _err(w, f"{key} is a frame camera's; an RPC image has no exterior "
                       "orientation", f'Remove {key}, or write model = "frame"')
    if "rpc" not in im:
        raise _err(w, "has no rpc file", 'Add rpc = "image.tif" (an image with RPC metadata, '
                   'or its _rpc.txt / .RPB file)')
    path = _resolve(base_dir, im["rpc"], w, "rpc")
    bias = im.get("bias", "shift")
    if not isinstance(bias, str) or bias not in BIAS_MODELS:
        raise _err(w, f"bias = {_show(bias)} is unknown",
                   "Write bias = " + ", ".join(f'"{m}"' for m in BIAS_MODELS))
    sig = im.get("bias_sigma")
    if sig is None:
        sigma = np.full(6, np.inf)
    else:
        vals = sig if isinstance(sig, (list, tuple)) else [sig]
        if len(vals) not in (1, 2, 6):
            raise _err(w, f"bias_sigma must be 1, 2 or 6 numbers (px), not {_show(sig)}",
                       "Write bias_sigma = 5.0 (every bias parameter), [shift, drift/affine] "
                       "or [a0, a1, a2, b0, b1, b2]")
        v = np.array([_number(w, "bias_sigma", x, positive=True) for x in vals])
        sigma = (np.full(6, v[0]) if len(v) == 1 else
                 np.array([v[0], v[1], v[1], v[0], v[1], v[1]]) if len(v) == 2 else v)
    return ImageSpec(iid, np.zeros(3), np.zeros(3), None, None,
                     _date(w, im.get("date")), model="rpc",
                     rpc=RpcImage(None, bias, sigma, path))


def _parse_control(control: Any, base_dir: Path, where: str, name: str = "control",
                   example_path: str = "gcps.csv") -> Optional[dict]:
    """``[control]`` or ``[trajectory]`` (optional): its path resolved, crs and
    vertical_crs stripped."""
    if control is not None:
        if not isinstance(control, Mapping) or "path" not in control:
            raise _err(where, f"[{name}] has no path", f'Add [{name}] path = "{example_path}"')
        check_keys(control, PROJECT_SCHEMA[f"[{name}]"], where, f"[{name}]")
        control = dict(control)
        control["path"] = _resolve(base_dir, control["path"], where, f"[{name}] path")
        for key, example in (("crs", 'crs = "EPSG:4326"'),
                             ("vertical_crs", 'vertical_crs = "EPSG:5703"')):
            if key in control:
                control[key] = _text(f"{where} [{name}]", key, control[key], example)
    return control


def _parse_vectors(vectors_raw: Any, base_dir: Path, where: str) -> list:
    """``[[vectors]]``: one :class:`VectorSpec` per entry, unique names, paths resolved."""
    if isinstance(vectors_raw, Mapping):
        raise _err(where, "vectors is a single table", "Write [[vectors]] (an array of tables, "
                   "one per road database) instead of [vectors]")
    if vectors_raw is None:
        vectors_raw = []
    if not isinstance(vectors_raw, list):
        raise _err(where, f"vectors = {_show(vectors_raw)} must be an array of tables",
                   "Write one [[vectors]] table per road database, with name = ... and "
                   "path = ... (README: 'The project file')")
    vectors = []
    names: set = set()
    for i, v in enumerate(vectors_raw, start=1):
        w = f"{where} [[vectors]] entry {i}"
        if not isinstance(v, Mapping):
            raise _err(w, f"must be a table, not {_show(v)}",
                       "Write [[vectors]] name = ... path = ...")
        name = _name_of(w, "name", v.get("name", f"vectors{i}"), 'name = "OSM"')
        check_keys(v, PROJECT_SCHEMA["[[vectors]]"], where, f"[[vectors]] entry {i} ({name!r})",
                   "[[vectors]]")
        w = f"{where} [[vectors]] entry {i} ({name!r})"
        if name in names:
            raise _err(w, f"name {name!r} is used twice", "Give every [[vectors]] a unique name")
        names.add(name)
        if "path" not in v:
            raise _err(w, "has no path", 'Add path = "roads.shp"')
        sigma = _vector3(w, "sigma", v.get("sigma", [10.0, 10.0, 10.0]), positive=True)
        vectors.append(VectorSpec(
            name=name,
            path=_resolve(base_dir, v["path"], w, "path"),
            id_field=_id_field(w, v.get("id_field")),
            sigma=tuple(float(s) for s in sigma),
            dem=None if v.get("dem") is None else _resolve(base_dir, v["dem"], w, "dem"),
            truth=None if v.get("truth") is None else _resolve(base_dir, v["truth"], w, "truth"),
            layer=_text(w, "layer", v.get("layer"), 'layer = "lines"'),
            identification_sigma=_identification(w, v.get("identification_sigma")),
            offset=_offset_kind(w, v.get("offset", "shift")),
            where=_text(w, "where", v.get("where"), "where = \"highway IS NOT NULL\""),
            **_control_role(w, v, sigma),
        ))
    return vectors


def _self_calibration(where: str, value: Any) -> tuple:
    """``[adjustment] self_calibration``: a list of f, x0, y0, k1, k2."""
    known = ("f", "x0", "y0", "k1", "k2")
    if isinstance(value, str):
        value = [value]
    if not isinstance(value, (list, tuple)) or not all(isinstance(v, str) for v in value) \
            or any(v not in known for v in value):
        raise _err(where, f"[adjustment] self_calibration must be a list of "
                   f"{', '.join(known)}, not {_show(value)}",
                   'Write self_calibration = ["f", "x0", "y0", "k1", "k2"] (or a subset)')
    return tuple(dict.fromkeys(value))


def _control_role(where: str, v: Mapping, sigma) -> dict:
    """``role`` (adjust | control) and ``systematic_sigma`` of a [[vectors]] entry."""
    role = v.get("role", "adjust")
    if role not in ("adjust", "control"):
        raise _err(where, f"role must be \"adjust\" or \"control\", not {_show(role)}",
                   'Write role = "control" for a database that fixes the datum (no GCPs), '
                   "or leave role out")
    sys_ = _identification(where, v.get("systematic_sigma"), "systematic_sigma")
    if sys_ is not None:
        h, z = sys_
        if h >= min(sigma[0], sigma[1]) or (z > 0 and z >= sigma[2]):
            raise _err(where, f"systematic_sigma {list(sys_)} must be smaller than sigma "
                       f"{[float(x) for x in sigma]} (it is the part of sigma common to all "
                       "vertices)", "State sigma as the whole error and systematic_sigma as "
                       "its systematic part, e.g. sigma = [1.5, 1.5, 3] with "
                       "systematic_sigma = [1.0, 2.0]")
    if sys_ is not None and role != "control" and v.get("offset", "shift") != "none":
        raise _err(where, "systematic_sigma is given but the database's offset is estimated "
                   "freely (offset = " + repr(v.get("offset", "shift")) + ")",
                   'Use role = "control" (the systematic part is then carried, not '
                   'estimated), or offset = "none", or leave systematic_sigma out')
    if role == "control" and v.get("offset", "shift") not in ("shift", "none"):
        raise _err(where, f"a control database cannot have offset = {v.get('offset')!r}: "
                   "a database cannot be offset against itself",
                   "Leave offset out (the systematic part comes from systematic_sigma)")
    return {"role": role, "systematic_sigma": sys_}


def _id_field(where: str, value: Any) -> Optional[str]:
    """``id_field``: a field name (text); None (or "") for the feature index."""
    if value is None or value == "":
        return None
    if not isinstance(value, str):
        raise _err(where, f"id_field must be the name of a field (a text), not {_show(value)}",
                   'Write id_field = "osm_id" (in quotes), or leave it out')
    return value


def _text(where: str, key: str, value: Any, example: str) -> Optional[str]:
    """An optional non-empty string (``layer``, ``where``); None when not given."""
    if value is None:
        return None
    if not isinstance(value, str) or not value.strip():
        raise _err(where, f"{key} must be a non-empty text, not {_show(value)}",
                   f"Write {example}, or leave {key} out")
    return value.strip()


def _identification(where: str, value: Any, key: str = "identification_sigma"):
    """``identification_sigma`` (or ``systematic_sigma``): a number (horizontal; vertical 0)
    or [horizontal, vertical]."""
    if value is None:
        return None
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        value = [value, 0.0]
    if not isinstance(value, (list, tuple)) or len(value) != 2:
        raise _err(where, f"{key} must be a number or [horizontal, vertical], "
                   f"not {value!r}", f"Write {key} = 0.5 or [0.5, 0.1] (metres)")
    h, v = (_number(where, key, x) for x in value)
    if h < 0 or v < 0:
        raise _err(where, f"{key} must not be negative, not {value!r}",
                   f"Write {key} = 0.5 or [0.5, 0.1] (metres)")
    return (h, v)


def _offset_kind(where: str, value: Any) -> str:
    """``offset``: none | shift | shift3d | similarity | affine."""
    from vectoradjust.adjust.offsets import OFFSET_KINDS

    if not isinstance(value, str) or value not in OFFSET_KINDS:
        raise _err(where, f"offset must be one of {', '.join(OFFSET_KINDS)}, not {_show(value)}",
                   'Write offset = "shift" to estimate a horizontal shift of the database')
    return str(value)


def _parse_adjustment(adj: Any, where: str) -> AdjustmentSettings:
    """``[adjustment]``: the settings that differ from :class:`AdjustmentSettings`."""
    check_keys(adj, PROJECT_SCHEMA["[adjustment]"], where, "[adjustment]")
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
        if cs not in ("auto", "a-posteriori", "a-priori"):
            raise _err(where, f"[adjustment] covariance_scale = {cs!r} is not known",
                       'Use "auto" (default), "a-posteriori" (times sigma0^2) or "a-priori"')
        settings.covariance_scale = cs
    if "self_calibration" in adj:
        settings.self_calibration = _self_calibration(where, adj["self_calibration"])
    if "datum" in adj:
        if adj["datum"] not in ("auto", "free"):
            raise _err(where, f"[adjustment] datum = {_show(adj['datum'])} is not known",
                       'Use "auto" (control, camera priors, control databases) or "free" '
                       "(a free network, relative precision only)")
        settings.datum = adj["datum"]
    if "reuse_points" in adj:
        if adj["reuse_points"] not in ("intersections", "all"):
            raise _err(where, f"[adjustment] reuse_points = {adj['reuse_points']!r} is not known",
                       'Use "intersections" (where features meet) or "all"')
        settings.reuse_points = adj["reuse_points"]
    for key in ("tolerance_position", "tolerance_angle", "merge_tolerance", "reuse_tolerance"):
        if key in adj:
            setattr(settings, key, _number(where, f"[adjustment] {key}", adj[key], positive=True))
    return settings


def _parse_measurements(meas: Any, base_dir: Path, where: str) -> dict:
    """``[measurements]``: path, sigma and unit of the image measurements, fiducials."""
    if not isinstance(meas, dict) or "path" not in meas:
        raise _err(where, "[measurements] path is missing",
                   'Add [measurements] path = "image_points.csv"')
    check_keys(meas, PROJECT_SCHEMA["[measurements]"], where, "[measurements]")
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
    ProjectError
        An unknown key in ``[camera]`` or ``[camera.distortion]``.
    CameraError
        Whatever :meth:`CameraCalibration.from_dict` finds wrong (missing
        ``focal_length``, unknown keys or distortion model, a missing camera file ...).
    """
    check_keys(cam, PROJECT_SCHEMA["[camera]"], where, "[camera]")
    dist = cam.get("distortion")
    if isinstance(dist, Mapping):  # its coefficients are checked against the model by the camera
        known = tuple(dict.fromkeys(_DISTORTION_META + _SMAC_KEYS + _POLY_KEYS))
        lower = {k.lower() for k in known}
        check_keys({k: 0 for k in dist if str(k).lower() not in lower}, known, where,
                   "[camera.distortion]")
    cal = CameraCalibration.from_dict(cam, base_dir, where=f"{where} [camera]")
    return Camera(focal_length=cal.focal_length, principal_point=tuple(cal.principal_point),
                  calibration=cal)
