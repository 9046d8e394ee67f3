"""The exceptions vectoradjust raises for the user's mistakes.

Every error a user can cause derives from :class:`VectorAdjustError`. Each carries
``what`` (what was wrong, naming the file, row or feature) and ``mend`` (how to fix
it), and its ``str()`` reads as one message: ``"<what>. <mend>"``. Programming errors
(bugs) are ordinary Python exceptions and are never wrapped.
"""

from __future__ import annotations

from typing import Any, Optional

__all__ = [
    "VectorAdjustError",
    "ProjectError",
    "InputFileError",
    "CSVError",
    "LayerError",
    "CRSError",
    "DEMError",
    "ControlError",
    "DatumError",
    "MeasurementError",
    "NothingAdjustedError",
    "CameraError",
    "AdjustmentError",
    "NonConvergenceError",
    "SingularityError",
    "CancelledError",
]


class VectorAdjustError(Exception):
    """Base class of all errors caused by the user's input.

    Parameters
    ----------
    what : str
        What was wrong; names the file, row, feature or point.
    mend : str, optional
        What the user can do about it.
    path : str, optional
        The file concerned, when there is one.
    details : dict, optional
        Machine-readable context (row number, point id, ...).
    """

    def __init__(
        self,
        what: str,
        mend: str = "",
        *,
        path: Optional[str] = None,
        details: Optional[dict[str, Any]] = None,
    ) -> None:
        self.what = what
        self.mend = mend
        self.path = None if path is None else str(path)
        self.details = dict(details or {})
        super().__init__(self.message)

    @property
    def message(self) -> str:
        """The whole message: what was wrong, then how to mend it."""
        what = self.what.rstrip(".")
        if self.mend:
            return f"{what}. {self.mend.rstrip('.')}."
        return f"{what}."

    def __str__(self) -> str:  # pragma: no cover - trivial
        return self.message


class ProjectError(VectorAdjustError):
    """The project file is missing, unreadable or inconsistent."""


class InputFileError(VectorAdjustError):
    """An input file is missing or cannot be read."""


class CSVError(InputFileError):
    """A CSV table has wrong columns or bad values (the row is named)."""


class LayerError(InputFileError):
    """A vector layer is unusable (geometry type, fields, empty geometries)."""


class CRSError(VectorAdjustError):
    """A coordinate reference system is missing, geographic or not transformable."""


class DEMError(InputFileError):
    """The DEM is unreadable or does not cover a vertex."""


class ControlError(VectorAdjustError):
    """Ground control is insufficient (too few points, collinear)."""


class DatumError(ControlError):
    """Nothing, or not enough, fixes the block in space (a datum defect): names what can
    move freely and what would fix it."""


class MeasurementError(VectorAdjustError):
    """Image measurements are inconsistent (unknown image, duplicate, single ray)."""


class NothingAdjustedError(MeasurementError):
    """A road database selected for the run has no measured shape point (ids do not match)."""


class CameraError(VectorAdjustError):
    """Camera calibration or interior orientation input is wrong."""


class AdjustmentError(VectorAdjustError):
    """The least-squares adjustment cannot be carried out."""


class NonConvergenceError(AdjustmentError):
    """Gauss-Newton did not converge (diverged or ran out of iterations)."""


class SingularityError(AdjustmentError):
    """The normal equations are singular (datum defect or unconnected points)."""


class CancelledError(VectorAdjustError):
    """The user cancelled the run (from the CLI or QGIS)."""
