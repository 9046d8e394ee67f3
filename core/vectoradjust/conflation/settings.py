"""Conflation settings: the ``[conflation]`` table of a project and the constants
(sources, CE90/LE90 factors, the sill prior's degrees of freedom).

Heart module: numpy and scipy only.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np

from vectoradjust.errors import ProjectError

__all__ = ["SOURCES", "CONFLATION_KEYS", "CE90_CIRCULAR", "LE90", "SILL_PRIOR_DOF",
           "ConflationSettings", "settings_from_table"]


#: the ``Source`` values of a vertex
SOURCES = ("measured", "interpolated", "extrapolated", "unchanged")
#: keys of the project's ``[conflation]`` table
CONFLATION_KEYS = ("enabled", "k", "max_distance", "model", "min_points")
#: CE90 / sigma of a circular normal error, sqrt(-2 ln 0.1)
CE90_CIRCULAR = float(np.sqrt(-2.0 * np.log(0.1)))
#: LE90 / sigma of a normal error, Phi^-1(0.95)
LE90 = 1.6448536269514722
_MODELS = ("auto", "exponential", "gaussian")
#: degrees of freedom of the database's stated variance as the sill's prior
#: (:func:`_sill_prior`): known to about +-50 % (``sqrt(2 / 8)``)
SILL_PRIOR_DOF = 8.0


@dataclass
class ConflationSettings:
    """The project's ``[conflation]`` table.

    Attributes
    ----------
    enabled : bool
        Correct the unmeasured vertices (default true).
    k : int
        Measured points per prediction (nearest neighbours).
    max_distance : float
        A vertex farther than this (m) from every measured point, or outside their
        convex hull, is ``extrapolated``, else ``interpolated``; 0 (default): the fitted
        covariance's practical range.
    model : str
        ``"exponential"`` (``C0 exp(-r/L)``), ``"gaussian"`` (``C0 exp(-(r/L)^2)``) or
        ``"auto"`` (default: both fitted, the better leave-one-out score kept).
    min_points : int
        Fewest measured points a database needs for its field (fewer: ``unchanged``).
    """

    enabled: bool = True
    k: int = 12
    max_distance: float = 0.0
    model: str = "auto"
    min_points: int = 5


def settings_from_table(table: Optional[dict], source: str = "<project>") -> ConflationSettings:
    """Validate a ``[conflation]`` table (None: the defaults).

    Raises
    ------
    ProjectError
        Naming the key and the allowed values.
    """
    s = ConflationSettings()
    if not table:
        return s
    unknown = [k for k in table if k not in CONFLATION_KEYS]
    if unknown:
        raise ProjectError(f"{source}: [conflation] has no key {unknown[0]!r}",
                           f"Use only: {', '.join(CONFLATION_KEYS)}", path=source)

    def bad(key, what):
        return ProjectError(f"{source}: [conflation] {key} = {table[key]!r} is not {what}",
                            f"Write {key} as {what} (README: [conflation])", path=source)

    if "enabled" in table:
        if not isinstance(table["enabled"], bool):
            raise bad("enabled", "true or false")
        s.enabled = table["enabled"]
    for key, low in (("k", 1), ("min_points", 2)):
        if key in table:
            v = table[key]
            if isinstance(v, bool) or not isinstance(v, int) or v < low:
                raise bad(key, f"an integer >= {low}")
            setattr(s, key, int(v))
    if "max_distance" in table:
        v = table["max_distance"]
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not v >= 0:
            raise bad("max_distance", "a distance >= 0 in metres")
        s.max_distance = float(v)
    if "model" in table:
        if table["model"] not in _MODELS:
            raise bad("model", " or ".join(repr(m) for m in _MODELS))
        s.model = table["model"]
    return s
