"""The ``vectoradjust`` Processing provider."""

import os

from qgis.core import QgsProcessingProvider
from qgis.PyQt.QtGui import QIcon

from .algorithms.accuracy_control import AccuracyControl
from .algorithms.adjust import AdjustRoadVectors
from .algorithms.buffer_test import BufferAccuracyTest
from .algorithms.compare import CompareRoadDatabases
from .algorithms.dtm_accuracy import DtmAccuracy
from .algorithms.equal_error_map import EqualErrorMap
from .algorithms.extract_shape_points import ExtractShapePoints
from .algorithms.gcp_study import GcpStudy
from .algorithms.measure_images import MeasureOnImages
from .algorithms.smart_conflation import SmartConflation
from .algorithms.uncertainty_bands import UncertaintyBands

PLUGIN_DIR = os.path.dirname(os.path.abspath(__file__))


class VectorAdjustProvider(QgsProcessingProvider):
    """Provider id ``vectoradjust``: algorithms ``vectoradjust:<name>``."""

    def id(self):
        return "vectoradjust"

    def name(self):
        return "vectoradjust"

    def longName(self):
        return "vectoradjust - photogrammetric adjustment of road vectors"

    def icon(self):
        return QIcon(os.path.join(PLUGIN_DIR, "icon.png"))

    def loadAlgorithms(self):
        for alg in (ExtractShapePoints(), AdjustRoadVectors(), CompareRoadDatabases(),
                    BufferAccuracyTest(), AccuracyControl(), UncertaintyBands(),
                    EqualErrorMap(), GcpStudy(), MeasureOnImages(), DtmAccuracy(),
                    SmartConflation()):
            self.addAlgorithm(alg)
