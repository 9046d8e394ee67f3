"""Progress and cancel while the outputs and the report are written (CLI and QGIS call
these with their progress bar / feedback)."""

from __future__ import annotations

import pytest

pytest.importorskip("geopandas")
pytest.importorskip("matplotlib")
pytestmark = pytest.mark.io

from vectoradjust.errors import CancelledError  # noqa: E402
from vectoradjust.files.outputs import write_outputs  # noqa: E402
from vectoradjust.files.report import write_report  # noqa: E402
from vectoradjust.pipeline import run  # noqa: E402
from vectoradjust.simulate import make_scenario  # noqa: E402


@pytest.fixture(scope="module")
def small_run():
    return run(make_scenario(3, grid=(2, 2), databases=("OSM",)).to_project_data())


def _recorder():
    calls = []
    return calls, lambda f, m: calls.append((f, m))


def test_write_outputs_reports_every_table_and_layer(small_run, tmp_path):
    calls, progress = _recorder()
    write_outputs(small_run, tmp_path, progress=progress, bands=False)
    msgs = [m for _, m in calls]
    for name in ("shape_points", "features", "control_points"):
        assert f"building the {name} table" in msgs
        assert f"writing the {name} layer" in msgs
    assert msgs[-1] == "outputs written" and calls[-1][0] == 1.0
    fractions = [f for f, _ in calls]
    assert fractions == sorted(fractions)


def test_write_outputs_can_be_cancelled_and_leaves_nothing(small_run, tmp_path):
    n = {"polls": 0}

    def cancelled():
        n["polls"] += 1
        return n["polls"] > 3  # after three tables

    with pytest.raises(CancelledError, match="Writing the outputs was cancelled"):
        write_outputs(small_run, tmp_path / "out", is_cancelled=cancelled, bands=False)
    assert not list((tmp_path / "out").glob("adjusted.gpkg"))
    assert not list((tmp_path / "out").glob("summary.json"))


def test_write_report_reports_each_section_and_can_be_cancelled(small_run, tmp_path):
    calls, progress = _recorder()
    path = write_report(small_run, tmp_path / "report.html", progress=progress)
    assert path.is_file()
    sections = [m for _, m in calls if m.startswith("report: ")]
    assert "report: Summary" in sections and "report: Warnings" in sections
    assert len(sections) >= 10 and calls[-1] == (1.0, "report written")
    with pytest.raises(CancelledError, match="Writing the report was cancelled"):
        write_report(small_run, tmp_path / "cancelled.html", is_cancelled=lambda: True)
    assert not (tmp_path / "cancelled.html").exists()
