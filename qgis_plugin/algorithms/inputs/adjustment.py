"""One adjustment from the dialog's parameters: :func:`run_adjustment`.

The road layer (if any) and the project read, the error model chosen in the dialog
(:func:`road_error_model`) applied, and the core's pipeline run with progress and
cancel.
"""

from dataclasses import dataclass
from typing import Optional

from .parameters import (
    DEM,
    ID_FIELD,
    IDENT_XY,
    IDENT_Z,
    INPUT,
    NAME,
    OFFSET,
    OFFSET_CHOICES,
    SIGMA_XY,
    SIGMA_Z,
)
from .project_file import ProjectInputs, _is_set, _number, project_inputs
from .road_layers import RoadDatabase, project_data_with, read_road_layer

__all__ = [
    "road_error_model",
    "Adjusted",
    "run_adjustment",
]


def road_error_model(alg, parameters, context) -> dict:
    """Identification sigma and offset chosen in the dialog (None: the project's)."""
    h = _number(alg, parameters, IDENT_XY, context)
    v = _number(alg, parameters, IDENT_Z, context)
    choice = alg.parameterAsEnum(parameters, OFFSET, context) if OFFSET in parameters else 0
    return {"identification": None if h is None and v is None else (h or 0.0, v or 0.0),
            "offset": None if choice == 0 else OFFSET_CHOICES[choice]}


@dataclass
class Adjusted:
    """One adjustment run by :func:`run_adjustment`."""

    run: object  # vectoradjust.pipeline.AdjustmentRun
    prj: ProjectInputs
    road: Optional[RoadDatabase]


def run_adjustment(alg, parameters, context, feedback, *, road_optional=False, start=10.0,
                   span=75.0, conflation: Optional[bool] = None,
                   datum: Optional[str] = None):
    """Read the road layer (if any) and the project, and run the adjustment.

    With a road layer, that database is adjusted (``pipeline.run(data,
    vectors=[name])``) with every other ``[[vectors]]`` entry of the project read
    too; without one (``road_optional``), every ``[[vectors]]`` entry is adjusted
    together (as ``vectoradjust qa PROJECT`` / ``equal-error`` do). ``conflation``
    (not None) replaces the project's ``[conflation] enabled``, ``datum`` (not None)
    its ``[adjustment] datum`` (``"free"``: a free network).

    Returns
    -------
    Adjusted
    """
    from qgis.core import QgsProcessingException

    from vectoradjust.pipeline import run as run_pipeline

    from ..base import cancel_callback, check_cancelled, progress_callback

    source = None
    if _is_set(parameters, INPUT) or not road_optional:
        source = alg.parameterAsSource(parameters, INPUT, context)
        if source is None:
            raise QgsProcessingException(alg.invalidSourceError(parameters, INPUT))
    feedback.setProgressText("reading the inputs")
    prj = project_inputs(alg, parameters, context, feedback,
                         source.sourceCrs() if source is not None else None)
    road = None
    given = []
    if source is not None:
        vlayer = alg.parameterAsVectorLayer(parameters, INPUT, context)
        road = read_road_layer(
            prj, source, vlayer, context, feedback,
            name=alg.parameterAsString(parameters, NAME, context),
            id_field=alg.parameterAsString(parameters, ID_FIELD, context),
            sigma_xy=_number(alg, parameters, SIGMA_XY, context),
            sigma_z=_number(alg, parameters, SIGMA_Z, context),
            dem=alg.parameterAsRasterLayer(parameters, DEM, context),
            error_model=road_error_model(alg, parameters, context))
        given.append(road)
    check_cancelled(feedback)
    data = project_data_with(prj, given, context, feedback)
    if conflation is not None:
        from dataclasses import replace

        data = replace(data, conflation={**(data.conflation or {}), "enabled": bool(conflation)})
    if datum is not None:
        from dataclasses import replace

        data = replace(data, settings=replace(data.settings, datum=datum))
        feedback.pushInfo(f"datum: {datum} (instead of the project's)")
    feedback.setProgress(start)
    out = run_pipeline(data, vectors=[road.spec.name] if road is not None else None,
                       progress=progress_callback(feedback, start, span),
                       is_cancelled=cancel_callback(feedback))
    check_cancelled(feedback)
    for w in out.warnings:
        feedback.pushWarning(w)
    return Adjusted(out, prj, road)
