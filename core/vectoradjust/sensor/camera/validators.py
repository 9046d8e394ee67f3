"""The names of a camera file (distortion models and conventions, pixel origins,
coefficient and table keys) and the validators of its values: numbers, pairs, fiducials,
coefficients, pixel and image sizes.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any, Union

import numpy as np

from vectoradjust.errors import CameraError

__all__ = ["DISTORTION_MODELS", "DISTORTION_CONVENTIONS"]


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
