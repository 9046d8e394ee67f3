"""The QML styles of the outputs and the post-processor that applies them.

Styles live in the repository's ``resources/styles/`` and are copied into the plugin's
``styles/`` folder by ``build_zip.py``; both places are searched.
"""

import os

from qgis.core import QgsProcessingLayerPostProcessorInterface

PLUGIN_DIR = os.path.dirname(os.path.realpath(__file__))
STYLE_DIRS = (
    os.path.join(PLUGIN_DIR, "styles"),
    os.path.join(os.path.dirname(PLUGIN_DIR), "resources", "styles"),
)

#: output kind -> QML file name
STYLES = {
    "residuals": "residual_arrows.qml",
    "shape_points": "shape_points_ce90.qml",
    "control_points": "control_points_role.qml",
    "features": "features_rmse.qml",
    "extracted": "extracted_shape_points.qml",
}

_KEEP = []  # post-processors must outlive processAlgorithm (QGIS calls them later)


def style_path(kind):
    """Path of the QML file for an output kind, or None when it is not installed."""
    name = STYLES.get(kind)
    if name is None:
        return None
    for d in STYLE_DIRS:
        p = os.path.join(d, name)
        if os.path.isfile(p):
            return p
    return None


class StylePostProcessor(QgsProcessingLayerPostProcessorInterface):
    """Loads a QML style into an output layer when QGIS adds it to the project."""

    def __init__(self, qml, name=None):
        super().__init__()
        self.qml = qml
        self.name = name

    def postProcessLayer(self, layer, context, feedback):
        if layer is None or not layer.isValid():
            return
        message, ok = layer.loadNamedStyle(self.qml)
        if not ok:
            feedback.reportError(f"Could not apply the style {self.qml}: {message}", False)
        if self.name:
            layer.setName(self.name)
        layer.triggerRepaint()

    @staticmethod
    def create(qml, name=None):
        proc = StylePostProcessor(qml, name)
        _KEEP.append(proc)
        return proc


def style_output(context, dest_id, kind, name=None):
    """Attach the style of ``kind`` to an output that QGIS will load on completion.

    Returns True when a post-processor was attached (the output is loaded into a
    project, as in the Processing dialog); False otherwise (``qgis_process``,
    ``processing.run`` without a project).
    """
    qml = style_path(kind)
    if not dest_id or qml is None or not context.willLoadLayerOnCompletion(dest_id):
        return False
    details = context.layerToLoadOnCompletionDetails(dest_id)
    details.setPostProcessor(StylePostProcessor.create(qml, name))
    return True


def clear_post_processors():
    """Forget the post-processors (plugin unload)."""
    _KEEP.clear()
