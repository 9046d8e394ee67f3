"""The exceptions vectoradjust raises for the user's mistakes, and for a cancelled run.

Every error a user can cause derives from :class:`VectorAdjustError`. Each carries
``what`` (what was wrong, naming the file, row or feature) and ``mend`` (how to fix
it), and its ``str()`` reads as one message: ``"<what>. <mend>"``. Programming errors
(bugs) are ordinary Python exceptions and are never wrapped.

As rasterio's errors do, each class also derives from the built-in exception that fits
it, so that code which knows nothing of vectoradjust catches them as usual:

- :class:`OSError`: :class:`InputFileError` (a file missing, unreadable, unwritable or
  busy) and its subclasses;
- :class:`ValueError`: :class:`ProjectError`, :class:`CSVError`, :class:`LayerError`,
  :class:`CRSError`, :class:`ControlError`, :class:`MeasurementError`,
  :class:`CameraError` (a value or a combination of values is wrong; a bad CSV table or
  layer is both an :class:`OSError` and a :class:`ValueError`, as :mod:`io`'s
  ``UnsupportedOperation`` is);
- :class:`AdjustmentError` and its subclasses derive from :class:`RuntimeError`: no
  single value is wrong, the data as a whole cannot be adjusted.

:class:`CancelledError` is not a user's mistake and not a :class:`VectorAdjustError`:
``except VectorAdjustError`` does not catch a cancelled run (the command line exits
with status 130 and QGIS reports "Cancelled", ``cli/tools.py`` and
``qgis_plugin/algorithms/base.py``). It carries ``what`` and ``mend`` like the others
(both derive from :class:`MessageError`).
"""

from __future__ import annotations

from typing import Any, Optional

__all__ = [
    "MessageError",
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


class MessageError(Exception):
    """An exception whose message says what happened and what to do about it.

    The common base of :class:`VectorAdjustError` and :class:`CancelledError` (catch
    either, not this one).

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


class VectorAdjustError(MessageError):
    """Base class of all errors caused by the user's input (see the module for the
    built-in exception each subclass also derives from)."""


class ProjectError(VectorAdjustError, ValueError):
    """The project file is missing, unreadable or inconsistent."""


class InputFileError(VectorAdjustError, OSError):
    """An input file is missing or cannot be read."""


class CSVError(InputFileError, ValueError):
    """A CSV table has wrong columns or bad values (the row is named)."""


class LayerError(InputFileError, ValueError):
    """A vector layer is unusable (geometry type, fields, empty geometries)."""


class CRSError(VectorAdjustError, ValueError):
    """A coordinate reference system is missing, geographic or not transformable."""


class DEMError(InputFileError):
    """The DEM is unreadable or does not cover a vertex."""


class ControlError(VectorAdjustError, ValueError):
    """Ground control is insufficient (too few points, collinear)."""


class DatumError(ControlError):
    """Nothing, or not enough, fixes the block in space (a datum defect): names what can
    move freely and what would fix it."""


class MeasurementError(VectorAdjustError, ValueError):
    """Image measurements are inconsistent (unknown image, duplicate, single ray)."""


class NothingAdjustedError(MeasurementError):
    """A road database selected for the run has no measured shape point (ids do not match)."""


class CameraError(VectorAdjustError, ValueError):
    """Camera calibration or interior orientation input is wrong."""


class AdjustmentError(VectorAdjustError, RuntimeError):
    """The least-squares adjustment cannot be carried out."""


class NonConvergenceError(AdjustmentError):
    """Gauss-Newton did not converge (diverged or ran out of iterations)."""


class SingularityError(AdjustmentError):
    """The normal equations are singular (datum defect or unconnected points)."""


class CancelledError(MessageError):
    """The user cancelled the run (from the CLI or QGIS).

    Not a :class:`VectorAdjustError` (nothing was wrong with the input) and not one of
    the built-in exceptions: only ``except CancelledError`` (or ``except Exception``)
    catches it.
    """
