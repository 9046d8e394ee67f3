"""What one adjustment produces: :class:`AdjustmentRun` and one :class:`DatabaseResult`
per road database.

The stages of :func:`vectoradjust.pipeline.run` fill them in turn (classify, adjust,
tabulate, derived quantities, summary); the outputs, the report, the accuracy control and
the QGIS plugin read them. Plain data: numpy only.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Optional

import numpy as np

if TYPE_CHECKING:  # annotations only
    from vectoradjust.adjust.bundle import BundleProblem, BundleResult
    from vectoradjust.adjust.shapepoints import ShapePoints
    from vectoradjust.model import ProjectData, VectorSpec

__all__ = ["AdjustmentRun", "DatabaseResult"]


@dataclass
class DatabaseResult:
    """Results for one road database (one ``[[vectors]]`` entry).

    Attributes
    ----------
    spec : VectorSpec
    shape : ShapePoints
    vertex_point : numpy.ndarray of int, shape (nv,)
        Bundle point index of each vertex, -1 where not measured.
    vertices : dict of str to numpy.ndarray
        The ``shape_points`` columns of this database, one row per vertex.
    features : dict of str to numpy.ndarray
        The computed ``features`` columns (one row per input feature).
    adjusted_coords : numpy.ndarray, shape (nv, 3)
        Vertex coordinates of the adjusted geometry.
    sigma_used : tuple of float
        Prior sigma of the shape points in the final pass.
    truth : dict or None
        Truth comparison (simulations).
    conflation : FieldModel or None
        The fitted displacement field (:mod:`vectoradjust.conflation`), None
        when the database was not conflated.
    """

    spec: VectorSpec
    shape: ShapePoints
    vertex_point: np.ndarray
    vertices: dict = field(default_factory=dict)
    features: dict = field(default_factory=dict)
    adjusted_coords: Optional[np.ndarray] = None
    sigma_used: tuple = (10.0, 10.0, 10.0)
    truth: Optional[dict] = None
    conflation: Optional[object] = None

    @property
    def name(self) -> str:
        """Database name."""
        return self.spec.name


@dataclass
class AdjustmentRun:
    """Everything one adjustment produced.

    Attributes
    ----------
    data : ProjectData
    problem : BundleProblem
    result : BundleResult
    point_ids : numpy.ndarray of str
        Id of every bundle point (control id, canonical shape point id, tie id).
    point_kind : numpy.ndarray of str
        ``"control"``, ``"shape"`` or ``"tie"`` per bundle point.
    point_database : numpy.ndarray of str
        Database name for shape points, ``""`` otherwise.
    image_ids : list of str
        Images in the adjustment (those with measurements).
    obs_rows : numpy.ndarray of int
        Row of ``data.measurements`` for each bundle observation.
    databases : list of DatabaseResult
    control_points : dict of str to numpy.ndarray
        The ``control_points`` columns.
    summary : dict
        JSON-ready run summary (contract fields and more).
    warnings : list of str
    passes : list of dict
        One entry per adjustment pass (two-pass reweighting).
    """

    data: ProjectData
    problem: BundleProblem
    result: BundleResult
    point_ids: np.ndarray
    point_kind: np.ndarray
    point_database: np.ndarray
    image_ids: list
    obs_rows: np.ndarray
    databases: list
    control_points: dict
    summary: dict
    warnings: list = field(default_factory=list)
    passes: list = field(default_factory=list)
    reliability: object = None
    flagged: list = field(default_factory=list)
