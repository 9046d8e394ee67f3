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


#: colours of the bands of successive databases (fill; the outline is a darker shade)
BAND_COLOURS = ("#1f78b4", "#e31a1c", "#33a02c", "#ff7f00", "#6a3d9a", "#b15928")


def band_renderer(layer):
    """The uncertainty bands' style: a translucent fill (35 % opaque) with a thin darker
    outline, one colour per database (field ``database``), so that the roads and the
    other databases' bands stay visible under them."""
    from qgis.core import (
        QgsCategorizedSymbolRenderer,
        QgsFillSymbol,
        QgsRendererCategory,
        QgsSingleSymbolRenderer,
    )
    from qgis.PyQt.QtGui import QColor

    def symbol(k):
        colour = QColor(BAND_COLOURS[k % len(BAND_COLOURS)])
        fill = QColor(colour)
        fill.setAlpha(90)
        return QgsFillSymbol.createSimple({
            "color": fill.name(QColor.HexArgb), "outline_color": colour.darker(140).name(),
            "outline_width": "0.2", "outline_width_unit": "MM", "style": "solid"})

    idx = layer.fields().indexFromName("database") if layer is not None else -1
    names = sorted(str(v) for v in layer.uniqueValues(idx)) if idx >= 0 else []
    if not names:
        return QgsSingleSymbolRenderer(symbol(0))
    return QgsCategorizedSymbolRenderer("database", [
        QgsRendererCategory(name, symbol(k), name)
        for k, name in enumerate(names)])


#: output kind -> a function building its renderer from the layer (no QML file)
BUILT_STYLES = {"bands": band_renderer}


class StylePostProcessor(QgsProcessingLayerPostProcessorInterface):
    """Loads a QML style (or sets a built renderer, ``build(layer)``) into an output
    layer when QGIS adds it to the project."""

    def __init__(self, qml, name=None, build=None):
        super().__init__()
        self.qml = qml
        self.name = name
        self.build = build

    def postProcessLayer(self, layer, context, feedback):
        if layer is None or not layer.isValid():
            return
        if self.build is not None:
            layer.setRenderer(self.build(layer))
        else:
            message, ok = layer.loadNamedStyle(self.qml)
            if not ok:
                feedback.reportError(f"Could not apply the style {self.qml}: {message}", False)
        if self.name:
            layer.setName(self.name)
        layer.triggerRepaint()

    @staticmethod
    def create(qml, name=None, build=None):
        proc = StylePostProcessor(qml, name, build)
        _KEEP.append(proc)
        return proc


def style_output(context, dest_id, kind, name=None):
    """Attach the style of ``kind`` to an output that QGIS will load on completion.

    Returns True when a post-processor was attached (the output is loaded into a
    project, as in the Processing dialog); False otherwise (``qgis_process``,
    ``processing.run`` without a project).
    """
    build = BUILT_STYLES.get(kind)
    qml = style_path(kind)
    if not dest_id or (qml is None and build is None) or \
            not context.willLoadLayerOnCompletion(dest_id):
        return False
    details = context.layerToLoadOnCompletionDetails(dest_id)
    details.setPostProcessor(StylePostProcessor.create(qml, name, build))
    return True


def clear_post_processors():
    """Forget the post-processors (plugin unload)."""
    _KEEP.clear()
