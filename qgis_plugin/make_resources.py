"""Regenerate the plugin's QML styles and icon with the QGIS API.

Run with the Python that has QGIS (Debian: ``/usr/bin/python3``)::

    QT_QPA_PLATFORM=offscreen python3 qgis_plugin/make_resources.py

writes ``resources/styles/*.qml`` (styles QGIS 3.22 and later load) and
``qgis_plugin/icon.png``. The files are committed; this script documents how they
were made and remakes them after a change.
"""

import os
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
STYLES = os.path.join(os.path.dirname(HERE), "resources", "styles")

# (lower, upper, colour, label): green (certain) to red (uncertain)
CE90_CLASSES = [
    (0.0, 0.1, "#1a9641", "CE90 < 0.10 m"),
    (0.1, 0.2, "#a6d96a", "0.10 - 0.20 m"),
    (0.2, 0.5, "#ffffbf", "0.20 - 0.50 m"),
    (0.5, 1.0, "#fdae61", "0.50 - 1.00 m"),
    (1.0, 1e9, "#d7191c", "CE90 >= 1.00 m"),
]
RMSE_CLASSES = [
    (0.0, 1.0, "#1a9641", "RMSE < 1 m"),
    (1.0, 2.5, "#a6d96a", "1 - 2.5 m"),
    (2.5, 5.0, "#ffffbf", "2.5 - 5 m"),
    (5.0, 10.0, "#fdae61", "5 - 10 m"),
    (10.0, 1e9, "#d7191c", "RMSE >= 10 m"),
]


def _memory_layer(geom, fields):
    from qgis.core import QgsVectorLayer

    spec = "&".join(f"field={n}:{t}" for n, t in fields)
    return QgsVectorLayer(f"{geom}?crs=EPSG:32616&{spec}", "style", "memory")


def _graduated(attr, classes, make_symbol):
    from qgis.core import QgsGraduatedSymbolRenderer, QgsRendererRange
    from qgis.PyQt.QtGui import QColor

    ranges = [QgsRendererRange(lo, hi, make_symbol(QColor(c)), label)
              for lo, hi, c, label in classes]
    return QgsGraduatedSymbolRenderer(attr, ranges)


def _marker(color, shape="circle", size=2.4, outline="#333333"):
    from qgis.core import QgsMarkerSymbol

    return QgsMarkerSymbol.createSimple({"name": shape, "color": color.name() if hasattr(
        color, "name") else color, "size": str(size), "outline_color": outline,
        "outline_width": "0.2"})


def _labels(layer, field, size=7.0, color="#202020"):
    from qgis.core import (
        QgsPalLayerSettings,
        QgsTextBufferSettings,
        QgsTextFormat,
        QgsVectorLayerSimpleLabeling,
    )
    from qgis.PyQt.QtGui import QColor

    s = QgsPalLayerSettings()
    s.fieldName = field
    fmt = QgsTextFormat()
    fmt.setSize(size)
    fmt.setColor(QColor(color))
    buf = QgsTextBufferSettings()
    buf.setEnabled(True)
    buf.setSize(0.7)
    buf.setColor(QColor("white"))
    fmt.setBuffer(buf)
    s.setFormat(fmt)
    s.dist = 1.0
    layer.setLabeling(QgsVectorLayerSimpleLabeling(s))
    layer.setLabelsEnabled(True)


def residual_arrows():
    from qgis.core import QgsArrowSymbolLayer, QgsLineSymbol, QgsSingleSymbolRenderer
    from qgis.PyQt.QtGui import QColor

    layer = _memory_layer("LineStringZ", [("point_id", "string"), ("V", "double")])
    arrow = QgsArrowSymbolLayer()
    arrow.setIsCurved(False)
    arrow.setIsRepeated(False)
    arrow.setArrowWidth(0.35)
    arrow.setArrowStartWidth(0.35)
    arrow.setHeadLength(1.8)
    arrow.setHeadThickness(1.0)
    arrow.subSymbol().setColor(QColor("#c0392b"))
    symbol = QgsLineSymbol()
    symbol.changeSymbolLayer(0, arrow)
    layer.setRenderer(QgsSingleSymbolRenderer(symbol))
    return layer


def shape_points_ce90():
    layer = _memory_layer("PointZ", [("point_id", "string"), ("CE90", "double")])
    layer.setRenderer(_graduated("CE90", CE90_CLASSES, lambda c: _marker(c, size=2.2)))
    return layer


def control_points_role():
    from qgis.core import QgsCategorizedSymbolRenderer, QgsRendererCategory
    from qgis.PyQt.QtGui import QColor

    layer = _memory_layer("PointZ", [("point_id", "string"), ("role", "string")])
    cats = [
        QgsRendererCategory("control", _marker(QColor("#e31a1c"), "triangle", 3.6, "#000000"),
                            "control point"),
        QgsRendererCategory("check", _marker(QColor("#1f78b4"), "diamond", 3.6, "#000000"),
                            "check point"),
        QgsRendererCategory(None, _marker(QColor("#bdbdbd"), "circle", 2.4), "other"),
    ]
    layer.setRenderer(QgsCategorizedSymbolRenderer("role", cats))
    _labels(layer, "point_id")
    return layer


def features_rmse():
    from qgis.core import QgsLineSymbol

    layer = _memory_layer("MultiLineStringZ", [("RMSE", "double")])

    def line(c):
        return QgsLineSymbol.createSimple({"line_color": c.name(), "line_width": "0.8"})

    layer.setRenderer(_graduated("RMSE", RMSE_CLASSES, line))
    return layer


def extracted_shape_points():
    from qgis.core import QgsSingleSymbolRenderer
    from qgis.PyQt.QtGui import QColor

    layer = _memory_layer("PointZ", [("point_id", "string")])
    layer.setRenderer(QgsSingleSymbolRenderer(_marker(QColor("#ff7f00"), "cross2", 3.0,
                                                      "#ff7f00")))
    _labels(layer, "point_id", 6.5)
    return layer


def make_icon(path):
    """A 64 px icon: a road with its shape points pulled to the adjusted line."""
    from qgis.PyQt.QtCore import QPointF, Qt
    from qgis.PyQt.QtGui import QBrush, QColor, QImage, QPainter, QPen

    img = QImage(64, 64, QImage.Format_ARGB32)
    img.fill(Qt.transparent)
    p = QPainter(img)
    p.setRenderHint(QPainter.Antialiasing)
    true_line = [QPointF(6, 50), QPointF(24, 34), QPointF(40, 30), QPointF(58, 12)]
    db_line = [QPointF(10, 58), QPointF(28, 44), QPointF(46, 40), QPointF(60, 24)]
    p.setPen(QPen(QColor("#9e9e9e"), 3, Qt.DashLine, Qt.RoundCap))
    for a, b in zip(db_line, db_line[1:]):
        p.drawLine(a, b)
    p.setPen(QPen(QColor("#2b6cb0"), 5, Qt.SolidLine, Qt.RoundCap, Qt.RoundJoin))
    for a, b in zip(true_line, true_line[1:]):
        p.drawLine(a, b)
    p.setPen(QPen(QColor("#c0392b"), 2))
    for a, b in zip(db_line, true_line):
        p.drawLine(a, b)
    p.setBrush(QBrush(QColor("#c0392b")))
    p.setPen(Qt.NoPen)
    for a in true_line:
        p.drawEllipse(a, 3.2, 3.2)
    p.end()
    img.save(path)


def main():
    from qgis.core import QgsApplication, QgsMapLayer

    app = QgsApplication([], False)
    app.initQgis()
    os.makedirs(STYLES, exist_ok=True)
    for name, make in (("residual_arrows", residual_arrows),
                       ("shape_points_ce90", shape_points_ce90),
                       ("control_points_role", control_points_role),
                       ("features_rmse", features_rmse),
                       ("extracted_shape_points", extracted_shape_points)):
        layer = make()
        path = os.path.join(STYLES, name + ".qml")
        msg, ok = layer.saveNamedStyle(path, QgsMapLayer.Symbology | QgsMapLayer.Labeling)
        print(path, "ok" if ok else msg)
    make_icon(os.path.join(HERE, "icon.png"))
    print(os.path.join(HERE, "icon.png"))
    app.exitQgis()
    return 0


if __name__ == "__main__":
    sys.exit(main())
