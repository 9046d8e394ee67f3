"""Common behaviour of the vectoradjust algorithms.

* user mistakes (:class:`vectoradjust.errors.VectorAdjustError`) become a
  ``QgsProcessingException`` with the core's message (what was wrong and how to mend
  it); a cancelled run ends with an exception that says so;
* the core's ``progress(fraction, message)`` and ``is_cancelled()`` callbacks are
  wired to ``QgsProcessingFeedback``;
* missing numpy/scipy give one clear message instead of a traceback.
"""

import os
import re

from qgis.core import QgsProcessingAlgorithm, QgsProcessingException
from qgis.PyQt.QtGui import QIcon

#: a parameter label up to its explanations: "Product (default: ...)" -> "Product"
_SHORT_LABEL = re.compile(r" \(|, e\.g\.| \[|:")

PLUGIN_DIR = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


class VectorAdjustAlgorithm(QgsProcessingAlgorithm):
    """Base class: subclasses define ``NAME``, ``DISPLAY``, ``HELP``, ``initAlgorithm``
    and ``run_algorithm(parameters, context, feedback)``."""

    NAME = ""
    DISPLAY = ""
    HELP = ""
    SHORT = ""

    def name(self):
        return self.NAME

    def displayName(self):
        return self.DISPLAY

    def group(self):
        return "Road vector adjustment"

    def groupId(self):
        return "roadvectors"

    def shortDescription(self):
        return self.SHORT

    def shortHelpString(self):
        # the Processing dialog turns newlines into <br>: give it flowing HTML
        return " ".join(self.HELP.split())

    def icon(self):
        return QIcon(os.path.join(PLUGIN_DIR, "icon.png"))

    def createInstance(self):
        return type(self)()

    #: command-line flags the core's messages name -> the parameter that does the same here
    CLI_FLAGS: dict = {}

    def dialog_message(self, text):
        """The core's message with the command-line flags of :attr:`CLI_FLAGS` replaced by
        the names of this algorithm's parameters (as the dialog shows them)."""
        def label(match):
            p = self.parameterDefinition(self.CLI_FLAGS.get(match.group(0), ""))
            if p is None:
                return match.group(0)
            return "'" + _SHORT_LABEL.split(p.description())[0].strip() + "'"

        if not any(flag in text for flag in self.CLI_FLAGS):
            return text
        text = text.replace("on the command line", "as parameters of this algorithm")
        return re.sub(r"--[a-z][a-z-]*", label, text)

    def checkParameterValues(self, parameters, context):  # noqa: N802 - the QGIS name
        """QGIS's check, which opens the input layers (GDAL's messages of that opening
        are kept for :meth:`processAlgorithm`'s log, folded with those of the run)."""
        from ..gdal_log import gdal_messages, keep_for

        with gdal_messages(None) as seen:
            result = super().checkParameterValues(parameters, context)
        keep_for(context, seen)
        return result

    def processAlgorithm(self, parameters, context, feedback):
        try:
            from vectoradjust.errors import CancelledError, VectorAdjustError
        except ImportError as exc:
            raise QgsProcessingException(_missing_core(exc)) from exc
        from ..gdal_log import gdal_messages, kept_for

        try:
            with gdal_messages(feedback, kept_for(context)):  # GDAL's warnings into the log
                return self.run_algorithm(parameters, context, feedback)
        except CancelledError as exc:
            raise QgsProcessingException(f"Cancelled: {exc}") from None
        except VectorAdjustError as exc:
            raise QgsProcessingException(self.dialog_message(str(exc))) from None
        except ImportError as exc:
            raise QgsProcessingException(_missing_core(exc)) from exc

    def run_algorithm(self, parameters, context, feedback):  # pragma: no cover - abstract
        raise NotImplementedError


def _missing_core(exc):
    return (f"vectoradjust cannot run because a Python module is missing ({exc}). The plugin "
            "needs numpy and scipy in QGIS's Python (Debian/Ubuntu: apt install python3-scipy; "
            "OSGeo4W: the python3-scipy package) and the vectoradjust core (bundled in the "
            "plugin zip, or pip install vectoradjust).")


def progress_callback(feedback, start=0.0, span=100.0):
    """A core ``progress(fraction, message)`` reporting to ``feedback`` (percent).

    The bar never moves backwards (the core's passes may restart lower).
    """
    last = {"msg": None, "pct": start}

    def report(fraction, message=""):
        pct = start + span * min(max(float(fraction), 0.0), 1.0)
        if pct > last["pct"]:
            last["pct"] = pct
            feedback.setProgress(pct)
        if message and message != last["msg"]:
            feedback.setProgressText(message)
            last["msg"] = message

    return report


def cancel_callback(feedback):
    """A core ``is_cancelled()`` polling ``feedback``."""
    return lambda: bool(feedback is not None and feedback.isCanceled())


def check_cancelled(feedback):
    """Raise the core's CancelledError when the user pressed Cancel."""
    if feedback is not None and feedback.isCanceled():
        from vectoradjust.errors import CancelledError

        raise CancelledError("The run was cancelled", "Run it again when ready")
