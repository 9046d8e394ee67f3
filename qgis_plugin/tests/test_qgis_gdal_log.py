"""GDAL's messages while an algorithm runs go to the Processing log, each distinct message
once with its count, instead of stderr once per feature and reading (issue 36)."""

import json

import pytest

pytest.importorskip("qgis.core")

from .test_qgis_algorithms import run  # noqa: E402

pytestmark = pytest.mark.qgis

#: GDAL's GeoJSON driver says this (a CE_Failure) each time it reads the third feature
BAD_Y = "Invalid 'y' coordinate"


def _bad_lines(path):
    """Three lines, the last with a text coordinate (GDAL: an error message per reading,
    the feature kept without geometry)."""
    feats = [[[500000, 4000000 + 10 * i], [500100, 4000000 + 10 * i]] for i in range(2)]
    feats.append([[500000, 4000020], [500100, 4000020], [500200, "x"]])
    path.write_text(json.dumps({
        "type": "FeatureCollection",
        "crs": {"type": "name", "properties": {"name": "urn:ogc:def:crs:EPSG::32616"}},
        "features": [{"type": "Feature", "properties": {"id": i},
                      "geometry": {"type": "LineString", "coordinates": c}}
                     for i, c in enumerate(feats)]}), encoding="utf-8")
    return path


def _warnings():
    from qgis.core import QgsProcessingFeedback

    class Recorder(QgsProcessingFeedback):
        def __init__(self):
            super().__init__()
            self.warnings = []

        def pushWarning(self, text):  # noqa: N802 - the QGIS name
            self.warnings.append(text)
            super().pushWarning(text)

    return Recorder()


def test_gdal_messages_reach_the_log_folded(qgis_app, tmp_path, capfd):
    lines = str(_bad_lines(tmp_path / "bad.geojson"))
    fb = _warnings()
    out = run("bufferaccuracytest", {"INPUT": lines, "REFERENCE": lines, "WIDTHS": "1",
                                     "OUTPUT": "TEMPORARY_OUTPUT"}, feedback=fb)
    assert out["OUTPUT"]
    gdal = [w for w in fb.warnings if w.startswith("GDAL")]
    assert len(gdal) == 1, fb.warnings  # one line for the repeated message
    assert gdal[0].startswith(f"GDAL error: {BAD_Y}")
    assert gdal[0].endswith(" times)") and int(gdal[0].rsplit("(", 1)[1].split()[0]) >= 2
    assert BAD_Y not in capfd.readouterr().err  # not on stderr any more


def test_fold_counts_and_caps():
    from qgis_plugin.gdal_log import MAX_DISTINCT, fold

    seen = {(2, "a"): 3, (3, "b"): 1}
    assert fold(seen) == ["GDAL warning: a (3 times)", "GDAL error: b"]
    many = {(2, f"m{k}"): 2 for k in range(MAX_DISTINCT + 5)}
    lines = fold(many)
    assert len(lines) == MAX_DISTINCT + 1
    assert lines[-1] == "GDAL: 5 more distinct messages (10 in all)"


def test_the_handler_is_removed_after_the_run(qgis_app, tmp_path):
    """After the run GDAL's handler is the one before it: a message outside a run is not
    collected by a finished run's handler."""
    from osgeo import gdal

    from qgis_plugin.gdal_log import gdal_messages

    with gdal_messages(None) as seen:
        gdal.Error(gdal.CE_Warning, 1, "inside")
    gdal.PushErrorHandler("CPLQuietErrorHandler")
    try:
        gdal.Error(gdal.CE_Warning, 1, "outside")
    finally:
        gdal.PopErrorHandler()
    assert seen == {(2, "inside"): 1}
