"""Progress and Cancel in the long stages: the ``[truth]`` buffer test after Adjust and
the Buffer accuracy test report progress per database and per chunk of lines and stop
with a cancellation (not a result) when the dialog's Cancel is pressed during them."""

import sys

import pytest

pytest.importorskip("qgis.core")

from .test_qgis_algorithms import adjust_params, run  # noqa: E402

pytestmark = pytest.mark.qgis


def _feedback(cancel_on=None):
    """A QgsProcessingFeedback that records setProgress/setProgressText and presses Cancel
    when a progress text starts with ``cancel_on``."""
    from qgis.core import QgsProcessingFeedback

    class Recording(QgsProcessingFeedback):
        def __init__(self):
            super().__init__()
            self.calls = []

        def setProgress(self, value):  # noqa: N802 - the QGIS name
            self.calls.append(("progress", float(value)))
            super().setProgress(value)

        def setProgressText(self, text):  # noqa: N802
            self.calls.append(("text", text))
            if cancel_on is not None and text.startswith(cancel_on):
                self.cancel()
            super().setProgressText(text)

        def texts(self):
            return [v for k, v in self.calls if k == "text"]

        def values(self):
            return [v for k, v in self.calls if k == "progress"]

    return Recording()


@pytest.fixture
def small_chunks(qgis_app, monkeypatch):
    """Chunks of 3 lines (the ``[truth]`` test: the core's TRUTH_CHUNK) and of 20 segments
    (the Buffer accuracy test), so the sample's few roads give several steps."""
    from qgis.core import QgsApplication

    from vectoradjust.files import truth

    alg = QgsApplication.processingRegistry().algorithmById("vectoradjust:bufferaccuracytest")
    module = sys.modules[type(alg).__module__]
    monkeypatch.setattr(module, "CHUNK", 3)
    monkeypatch.setattr(module, "SEGMENT_CHUNK", 20)
    monkeypatch.setattr(truth, "TRUTH_CHUNK", 3)
    return module


def test_adjust_reports_the_truth_buffer_stage(qgis_app, sample, small_chunks):
    fb = _feedback()
    out = run("adjustroadvectors", adjust_params(sample), feedback=fb)
    assert out["SHAPE_POINTS"]
    texts = fb.texts()
    assert "buffer test: reading the true centrelines" in texts
    assert "buffer test: indexing the true centrelines" in texts
    assert any(t.startswith("buffer test: OSM") for t in texts)
    # per chunk: several increasing values inside the stage's 80 .. 85 %
    stage = [v for v in fb.values() if 80.0 < v <= 85.0]
    assert len(stage) >= 3 and stage == sorted(stage)
    assert texts.index("buffer test: done") < texts.index("writing the outputs")


def test_cancel_during_the_truth_buffer_stops_adjust(qgis_app, sample, small_chunks):
    from qgis.core import QgsProcessingException

    fb = _feedback(cancel_on="buffer test: OSM")
    with pytest.raises(QgsProcessingException, match="[Cc]ancelled"):
        run("adjustroadvectors", adjust_params(sample), feedback=fb)
    texts = fb.texts()
    assert "buffer test: done" not in texts and "writing the outputs" not in texts


def test_cancel_while_reading_the_true_centrelines(qgis_app, sample):
    from qgis.core import QgsProcessingException

    fb = _feedback(cancel_on="buffer test: reading")
    with pytest.raises(QgsProcessingException, match="[Cc]ancelled"):
        run("adjustroadvectors", adjust_params(sample), feedback=fb)
    assert not any(t.startswith("buffer test: indexing") for t in fb.texts())


def _buffer_params(sample):
    return {"INPUT": str(sample / "osm_roads.shp"), "REFERENCE": str(sample / "truth_roads.shp"),
            "WIDTHS": "1, 2", "OUTPUT": "TEMPORARY_OUTPUT"}


def test_buffer_accuracy_test_reports_progress_per_chunk(qgis_app, sample, small_chunks):
    fb = _feedback()
    run("bufferaccuracytest", _buffer_params(sample), feedback=fb)
    assert "intersecting the tested lines" in fb.texts()
    inner = [v for v in fb.values() if 10.0 < v < 95.0 + 1e-9]
    assert len(inner) >= 3 and inner == sorted(inner)
    assert fb.values()[-1] == 100.0


def test_cancel_during_the_buffer_accuracy_test(qgis_app, sample, small_chunks):
    from qgis.core import QgsProcessingException

    fb = _feedback(cancel_on="intersecting the tested lines")
    with pytest.raises(QgsProcessingException, match="[Cc]ancelled"):
        run("bufferaccuracytest", _buffer_params(sample), feedback=fb)
    assert 100.0 not in fb.values()


# --------------------------------------------------------------- reading, sinks, report
def test_cancel_while_reading_a_line_layer(qgis_app, sample):
    from qgis.core import QgsProcessingContext, QgsProcessingFeedback, QgsVectorLayer

    from qgis_plugin import qgis_io
    from vectoradjust.errors import CancelledError

    layer = QgsVectorLayer(str(sample / "osm_roads.shp"), "osm", "ogr")
    fb = QgsProcessingFeedback()
    fb.cancel()
    with pytest.raises(CancelledError, match="The run was cancelled"):
        qgis_io.read_line_source(layer, "OSM", None, layer.crs(), QgsProcessingContext(),
                                 "osm", fb)


def test_cancel_while_writing_the_sinks_stops_adjust(qgis_app, sample):
    """Cancel while the features are written: a cancellation, not a partial result."""
    from qgis.core import QgsProcessingException

    fb = _feedback(cancel_on="writing the outputs")
    with pytest.raises(QgsProcessingException, match="[Cc]ancelled"):
        run("adjustroadvectors", adjust_params(sample), feedback=fb)


def test_cancel_before_the_report_stops_adjust(qgis_app, sample, tmp_path):
    from qgis.core import QgsProcessingException

    fb = _feedback(cancel_on="writing the report")
    report = tmp_path / "report.html"
    with pytest.raises(QgsProcessingException, match="[Cc]ancelled"):
        run("adjustroadvectors", adjust_params(sample, REPORT=str(report)), feedback=fb)
    assert not report.exists()


def _compare_params(sample, folder):
    return {"LAYERS": [str(sample / f"{n}_roads.shp") for n in ("osm", "tnm", "tiger")],
            "PROJECT": str(sample / "project.toml"), "OUTPUT": "TEMPORARY_OUTPUT",
            "SHAPE_POINTS": "TEMPORARY_OUTPUT", "RESIDUALS": "TEMPORARY_OUTPUT",
            "OUTPUT_FOLDER": str(folder)}


def test_compare_reports_and_cancels_the_truth_buffer_stage(qgis_app, sample, tmp_path):
    from qgis.core import QgsProcessingException

    fb = _feedback(cancel_on="buffer test: TNM")
    with pytest.raises(QgsProcessingException, match="[Cc]ancelled"):
        run("compareroaddatabases", _compare_params(sample, tmp_path / "c"), feedback=fb)
    texts = fb.texts()
    assert any(t.startswith("buffer test: OSM") for t in texts)  # the first run's stage
    assert "writing the outputs" not in texts
    assert not (tmp_path / "c").exists()


def test_cancel_while_compare_writes_the_folder(qgis_app, sample, tmp_path):
    """Cancel after the sinks: the per-database GeoPackages are not all written."""
    from qgis.core import QgsProcessingException

    fb = _feedback()
    folder = tmp_path / "c"
    orig = fb.pushInfo

    def push(text):  # the table rows are echoed just before the sinks and the folder
        if text.startswith("name ") or "rmse" in text.lower():
            fb.cancel()
        orig(text)

    fb.pushInfo = push
    with pytest.raises(QgsProcessingException, match="[Cc]ancelled"):
        run("compareroaddatabases", _compare_params(sample, folder), feedback=fb)
    assert not (folder / "compare.json").exists()


def test_report_sections_are_reported_and_cancel_stops_between_them(qgis_app, sample,
                                                                     tmp_path):
    """The HTML report reports each finished section, and Cancel pressed while it is
    built (after its Summary section) stops Adjust without a report file."""
    from qgis.core import QgsProcessingException

    fb = _feedback()
    run("adjustroadvectors", adjust_params(sample, REPORT=str(tmp_path / "r.html")),
        feedback=fb)
    texts = fb.texts()
    assert "report: Summary" in texts and "report: Warnings" in texts
    fb = _feedback(cancel_on="report: Summary")
    report = tmp_path / "cancelled.html"
    with pytest.raises(QgsProcessingException, match="[Cc]ancelled"):
        run("adjustroadvectors", adjust_params(sample, REPORT=str(report)), feedback=fb)
    assert not report.exists()
