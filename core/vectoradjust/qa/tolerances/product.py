"""The product specification: :class:`QASpec` (the ``[qa]`` table) and the product, terrain
and scale names it accepts.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from vectoradjust.errors import ProjectError

__all__ = ["PRODUCTS", "TERRAINS", "QASpec"]


#: Allowed values of ``[qa] product``.
PRODUCTS = ("topographic map", "orthophoto", "orthomosaic")



#: Allowed values of ``[qa] terrain``.
TERRAINS = ("flat", "hilly", "mountainous")



#: Allowed statistics of a stage.
STATISTICS = ("mean", "rms", "max")



_SPEC_KEYS = ("product", "map_scale", "contour_interval", "terrain", "orthophoto_scale",
              "pixel_size", "working_radius")



def _canonical_product(value: Any) -> str:
    if not isinstance(value, str):
        raise ProjectError(
            f"[qa] product = {value!r} is not a text value",
            f"set product to one of: {', '.join(repr(p) for p in PRODUCTS)}",
            details={"key": "product", "allowed": list(PRODUCTS)},
        )
    canon = " ".join(value.strip().lower().replace("_", " ").replace("-", " ").split())
    if canon not in PRODUCTS:
        raise ProjectError(
            f"[qa] product = {value!r} is not allowed",
            f"set product to one of: {', '.join(repr(p) for p in PRODUCTS)}",
            details={"key": "product", "allowed": list(PRODUCTS)},
        )
    return canon


def _canonical_terrain(value: Any) -> str:
    canon = value.strip().lower() if isinstance(value, str) else value
    if canon not in TERRAINS:
        raise ProjectError(
            f"[qa] terrain = {value!r} is not allowed",
            f"set terrain to one of: {', '.join(repr(t) for t in TERRAINS)}",
            details={"key": "terrain", "allowed": list(TERRAINS)},
        )
    return canon


def _scale_denominator(key: str, value: Any) -> float | None:
    """``2000``, ``2000.0`` or ``"1:2000"`` -> 2000.0; ``None`` stays ``None``."""
    if value is None:
        return None
    mend = f"give {key} as the scale denominator, e.g. 2000 or \"1:2000\" for 1:2000"
    number: Any = value
    if isinstance(value, str):
        text = value.strip().replace(" ", "")
        if ":" in text:
            one, _, den = text.partition(":")
            if one != "1":
                raise ProjectError(f"[qa] {key} = {value!r} is not a map scale", mend,
                                   details={"key": key})
            text = den
        try:
            number = float(text)
        except ValueError:
            raise ProjectError(f"[qa] {key} = {value!r} is not a map scale", mend,
                               details={"key": key}) from None
    if isinstance(number, bool) or not isinstance(number, (int, float, np.integer, np.floating)):
        raise ProjectError(f"[qa] {key} = {value!r} is not a number", mend, details={"key": key})
    number = float(number)
    if not math.isfinite(number) or number <= 1.0:
        raise ProjectError(f"[qa] {key} = {value!r} is not a scale denominator (> 1)", mend,
                           details={"key": key})
    return number


def _positive(key: str, value: Any, unit: str) -> float | None:
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ProjectError(f"[qa] {key} = {value!r} is not a number",
                           f"give {key} in {unit}, a positive number", details={"key": key})
    number = float(value)
    if not math.isfinite(number) or number <= 0.0:
        raise ProjectError(f"[qa] {key} = {value!r} must be positive",
                           f"give {key} in {unit}, a positive number", details={"key": key})
    return number


@dataclass
class QASpec:
    """The product specification (``[qa]`` table of the project file).

    Parameters
    ----------
    product : str
        ``"topographic map"``, ``"orthophoto"`` or ``"orthomosaic"``.
    map_scale : float or None
        Scale denominator ``M`` of the map (2000 for 1:2000). Required for a
        topographic map; for an orthophoto/orthomosaic it is used when
        ``orthophoto_scale`` is not given.
    contour_interval : float or None
        Contour interval ``h`` in metres (required for a topographic map).
    terrain : str
        ``"flat"``, ``"hilly"`` or ``"mountainous"`` (orthomosaic tolerances).
    orthophoto_scale : float or None
        Scale denominator of the orthophoto / orthomosaic, if it differs from the map.
    pixel_size : float or None
        Scanning / sensor pixel size (mm) for the pixel-based stages, when the camera
        calibration does not give one (scanned film), e.g. 0.012 for 12 micrometres.
    working_radius : float or None
        Radius ``r`` of the working area on the image (mm) for the orthophoto height
        tolerance ``dh_DTM``; by default the caller derives it from the measurements.

    Raises
    ------
    ProjectError
        For an unknown product or terrain, a non-positive or missing number; the
        message names the ``[qa]`` key and the allowed values.
    """

    product: str
    map_scale: float | None = None
    contour_interval: float | None = None
    terrain: str = "flat"
    orthophoto_scale: float | None = None
    pixel_size: float | None = None
    working_radius: float | None = None

    def __post_init__(self) -> None:
        self.product = _canonical_product(self.product)
        self.terrain = _canonical_terrain(self.terrain)
        self.map_scale = _scale_denominator("map_scale", self.map_scale)
        self.orthophoto_scale = _scale_denominator("orthophoto_scale", self.orthophoto_scale)
        self.contour_interval = _positive("contour_interval", self.contour_interval, "metres")
        self.pixel_size = _positive("pixel_size", self.pixel_size, "millimetres (0.012 = 12 um)")
        if self.pixel_size is not None and self.pixel_size > 1.0:
            raise ProjectError(f"[qa] pixel_size = {self.pixel_size!r} mm is implausibly large",
                               "give pixel_size in millimetres: 12 micrometres is 0.012",
                               details={"key": "pixel_size"})
        self.working_radius = _positive("working_radius", self.working_radius, "millimetres")
        if self.product == "topographic map":
            for key in ("map_scale", "contour_interval"):
                if getattr(self, key) is None:
                    raise ProjectError(
                        f"[qa] {key} is missing (product = 'topographic map' needs it)",
                        "add map_scale (e.g. 2000 for 1:2000) and contour_interval "
                        "(metres) to [qa]",
                        details={"key": key},
                    )
        elif self.map_scale is None and self.orthophoto_scale is None:
            raise ProjectError(
                f"[qa] orthophoto_scale is missing (product = {self.product!r} needs a scale)",
                "add orthophoto_scale (or map_scale), e.g. 2000 for 1:2000, to [qa]",
                details={"key": "orthophoto_scale"},
            )

    @property
    def product_scale(self) -> float:
        """Scale denominator the product's tolerances refer to (orthophoto scale first)."""
        if self.product == "topographic map":
            return float(self.map_scale)  # type: ignore[arg-type]
        return float(self.orthophoto_scale if self.orthophoto_scale is not None
                     else self.map_scale)  # type: ignore[arg-type]

    @classmethod
    def from_dict(cls, d: dict) -> QASpec:
        """Build and validate a specification from the ``[qa]`` table.

        Parameters
        ----------
        d : dict
            Keys ``product`` (required), ``map_scale``, ``contour_interval``,
            ``terrain``, ``orthophoto_scale``, ``pixel_size`` (mm), ``working_radius``
            (mm).

        Returns
        -------
        QASpec

        Raises
        ------
        ProjectError
            Unknown key, missing product, or a value :class:`QASpec` rejects.
        """
        if not isinstance(d, dict):
            raise ProjectError("[qa] is not a table",
                               "write [qa] as a TOML table with product = ...")
        unknown = sorted(set(d) - set(_SPEC_KEYS))
        if unknown:
            raise ProjectError(
                f"[qa] has unknown key(s) {', '.join(repr(k) for k in unknown)}",
                f"use only {', '.join(_SPEC_KEYS)}",
                details={"keys": unknown, "allowed": list(_SPEC_KEYS)},
            )
        if "product" not in d:
            raise ProjectError(
                "[qa] product is missing",
                f"set product to one of: {', '.join(repr(p) for p in PRODUCTS)}",
                details={"key": "product", "allowed": list(PRODUCTS)},
            )
        return cls(
            product=d["product"],
            map_scale=d.get("map_scale"),
            contour_interval=d.get("contour_interval"),
            terrain=d.get("terrain", "flat"),
            orthophoto_scale=d.get("orthophoto_scale"),
            pixel_size=d.get("pixel_size"),
            working_radius=d.get("working_radius"),
        )

    def as_dict(self) -> dict:
        """JSON-serialisable copy of the specification."""
        return {
            "product": self.product,
            "map_scale": self.map_scale,
            "contour_interval": self.contour_interval,
            "terrain": self.terrain,
            "orthophoto_scale": self.orthophoto_scale,
            "pixel_size": self.pixel_size,
            "working_radius": self.working_radius,
        }

