"""The QA specification of a run: the ``[qa]`` table read into a
:class:`~vectoradjust.qa.tolerances.QASpec`, the pixel size (also from the interior
orientation fits) and the working-area radius.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any, Optional

import numpy as np

from vectoradjust.errors import ProjectError
from vectoradjust.formatting import float_or_none as _num
from vectoradjust.qa.tolerances import (
    PRODUCTS,
    QASpec,
    StageResult,
)

__all__ = ["spec_from_table", "resolve_pixel_size", "working_radius_mm"]


PAIR_MODES = ("consecutive", "all")



def _na_stage(name: str, values=None, ids: Optional[Sequence] = None, statistic: str = "mean",
              unit: str = "", tolerance: float = float("nan")) -> StageResult:
    """A stage that is reported but not evaluated (tolerance unknown or nothing to judge)."""
    v = np.abs(np.asarray([] if values is None else values, float).ravel())
    ids = list(range(v.size)) if ids is None else list(ids)
    fin = v[np.isfinite(v)]
    if fin.size == 0:
        measured = float("nan")
    elif statistic == "mean":
        measured = float(fin.mean())
    elif statistic == "rms":
        measured = float(np.sqrt(np.mean(fin**2)))
    else:
        measured = float(fin.max())
    rows = [{"id": i, "value": float(x), "tolerance": float("nan"), "passed": None}
            for i, x in zip(ids, v.tolist())]
    return StageResult(name=name, tolerance=float(tolerance), measured=measured,
                       statistic=statistic, point_tolerance=float("nan"), passed=None,
                       unit=unit, rows=rows)


def _stats_um(py_mm: np.ndarray, pixel: Optional[float]) -> dict:
    """Mean |py|, RMS, max in micrometres and (when the pixel is known) pixels."""
    a = np.abs(np.asarray(py_mm, float))
    a = a[np.isfinite(a)]
    if a.size == 0:
        vals = (float("nan"),) * 3
    else:
        vals = (float(a.mean()), float(np.sqrt(np.mean(a * a))), float(a.max()))
    out = {"n": int(a.size)}
    for key, v in zip(("mean", "rms", "max"), vals):
        out[f"{key}_um"] = _num(v * 1e3)
    for key, v in zip(("mean", "rms", "max"), vals):
        out[f"{key}_px"] = _num(v / pixel) if pixel else None
    return out


# --------------------------------------------------------------------- the spec
def spec_from_table(table: Optional[dict], *, product: Optional[str] = None,
                    scale=None, contour_interval: Optional[float] = None,
                    terrain: Optional[str] = None, pixel_size: Optional[float] = None,
                    source: str = "<project>") -> QASpec:
    """The product specification from the ``[qa]`` table and overrides (command line).

    Parameters
    ----------
    table : dict or None
        The project's raw ``[qa]`` table (``ProjectData.qa``).
    product, terrain : str, optional
        Override ``product`` / ``terrain``.
    scale : float or str, optional
        Scale denominator of the product (``2000`` or ``"1:2000"``): sets ``map_scale``
        for a topographic map, ``orthophoto_scale`` for an orthophoto / orthomosaic.
    contour_interval : float, optional
        Override (metres).
    pixel_size : float, optional
        Override (mm).
    source : str
        Project file, for messages.

    Returns
    -------
    QASpec

    Raises
    ------
    ProjectError
        Neither a ``[qa]`` table nor a product given, or an invalid value.
    """
    if table is not None and not isinstance(table, dict):
        raise ProjectError(f"{source}: [qa] is not a table",
                           'Write [qa] with product = "topographic map", map_scale = 2000, '
                           "contour_interval = 1.0")
    d = dict(table or {})
    if not d and product is None:
        raise ProjectError(
            f"{source}: there is no product specification for the accuracy control (no [qa] "
            "table and no --product)",
            'Add to the project [qa] product = "topographic map", map_scale = 2000, '
            "contour_interval = 1.0 (or product = \"orthophoto\", orthophoto_scale = 10000), or "
            "give --product and --scale (and --contour-interval for a map)",
            path=source, details={"key": "qa"},
        )
    if product is not None:
        d["product"] = product
    if terrain is not None:
        d["terrain"] = terrain
    if contour_interval is not None:
        d["contour_interval"] = contour_interval
    if pixel_size is not None:
        d["pixel_size"] = pixel_size
    if scale is not None:
        prod = d.get("product")
        canon = " ".join(str(prod).strip().lower().replace("_", " ").replace("-", " ").split())
        if canon == "topographic map":
            d["map_scale"] = scale
        elif canon in PRODUCTS:
            d["orthophoto_scale"] = scale
        else:
            d["map_scale"] = scale  # QASpec names the bad product
    try:
        return QASpec.from_dict(d)
    except ProjectError as exc:
        raise ProjectError(f"{source}: {exc.what}",
                           f"{exc.mend} (or give it on the command line: --product, --scale, "
                           "--contour-interval, --terrain, --pixel-size)",
                           path=source, details=exc.details) from None


def _pixel_from_value(value) -> Optional[float]:
    if value is None:
        return None
    a = np.asarray(value, float).ravel()
    if a.size == 1:
        p = float(a[0])
    elif a.size == 2:
        p = float(np.sqrt(a[0] * a[1]))
    else:
        return None
    return p if math.isfinite(p) and p > 0 else None


def resolve_pixel_size(camera: Any, spec: Optional[QASpec] = None,
                       pixel_size: Optional[float] = None, interior: Any = None) -> tuple:
    """The pixel size (mm) for the pixel-based stages, and where it came from.

    Parameters
    ----------
    camera : vectoradjust.model.Camera or None
        Its ``calibration`` may be a ``CameraCalibration`` (``.pixel_size``), the raw
        ``[camera]`` table (``"pixel_size"`` key) or None.
    spec : QASpec, optional
        ``[qa] pixel_size``.
    pixel_size : float, optional
        Explicit value (wins).
    interior : dict, optional
        ``ProjectData.interior``: last resort, the pixel size of the fiducial fits
        (for scanned film measured in pixels, the scale of the fiducial affine).

    Returns
    -------
    (float or None, str)
        ``sqrt(sx sy)`` for a rectangular pixel; ``(None, "unknown")`` when nothing
        gives one.
    """
    if pixel_size is not None:
        p = _pixel_from_value(pixel_size)
        if p is None:
            raise ValueError(f"pixel size must be a positive number of mm, got {pixel_size!r}")
        return p, "--pixel-size / argument"
    if spec is not None and spec.pixel_size is not None:
        return float(spec.pixel_size), "[qa] pixel_size"
    cal = getattr(camera, "calibration", None)
    if cal is not None:
        value = cal.get("pixel_size") if isinstance(cal, dict) else getattr(cal, "pixel_size",
                                                                             None)
        p = _pixel_from_value(value)
        if p is not None:
            return p, "camera calibration"
    p = _interior_pixel(interior)
    if p is not None:
        return p, "fiducial affine"
    return None, "unknown"


def working_radius_mm(run) -> float:
    """Largest radial distance (mm) of a measured photo point from the principal point.

    The radius ``r`` of the working area in ``dh_DTM = 0.3 mm f M / r``.
    """
    prob = run.result.problem if run.result.problem is not None else run.problem
    d = prob.obs_xy - prob.principal_point[None, :]
    return float(np.hypot(d[:, 0], d[:, 1]).max(initial=0.0))



def _interior_entries(interior: Any) -> list:
    """``(image_id, entry dict)`` from ``data.interior`` (a list or a mapping by id)."""
    if not isinstance(interior, dict):
        return []
    images = interior.get("images", {})
    if isinstance(images, dict):
        return [(str(k), v) for k, v in images.items() if isinstance(v, dict)]
    if isinstance(images, list):
        return [(str(v.get("id", v.get("image_id", j))), v) for j, v in enumerate(images)
                if isinstance(v, dict)]
    return []


def _fit_report(entry: dict) -> Optional[dict]:
    """The fiducial affine report of one image entry, or None when no fit was made.

    Accepts the layout of :func:`vectoradjust.sensor.interior.refine_measurements` (the
    report under ``entry["fiducials"]``, itself with per-fiducial ``"fiducials"``) and a
    flat ``AffineFit.to_dict()``.
    """
    fit = entry.get("fiducials")
    if isinstance(fit, dict) and isinstance(fit.get("fiducials"), dict):
        return fit
    if isinstance(fit, dict) and fit and all(isinstance(v, dict) for v in fit.values()):
        return entry
    if entry.get("max_um") is not None or entry.get("max_residual_um") is not None:
        return entry
    return None


def _first(entry: dict, *keys):
    for k in keys:
        if entry.get(k) is not None:
            return entry[k]
    return None


def _fit_pixel(fit: dict) -> Optional[float]:
    """Pixel size (mm) a fiducial report was judged with, if it says."""
    p = _pixel_from_value(fit.get("pixel_size_mm"))
    if p is None:
        mx_um = _first(fit, "max_um", "max_residual_um")
        mx_px = _first(fit, "max_px", "max_residual_px")
        if mx_um and mx_px:
            p = float(mx_um) / 1e3 / float(mx_px)
    return p


def _interior_pixel(interior: Any) -> Optional[float]:
    """Mean pixel size of the fiducial fits (e.g. the affine scale of scanned film)."""
    ps = [p for p in (_fit_pixel(f) for f in (_fit_report(e) for _, e in
                                               _interior_entries(interior)) if f is not None)
          if p is not None]
    return float(np.mean(ps)) if ps else None
