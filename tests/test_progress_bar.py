"""The console progress bar in a log (stderr not a terminal): a line per stage, and
within a long stage one line every few seconds - never silent, never flooding."""

from __future__ import annotations

import io

from vectoradjust.cli import progress as progress_mod
from vectoradjust.cli.progress import ProgressBar


def test_log_lines_per_stage_and_throttled_within_a_stage(monkeypatch):
    clock = [0.0]
    monkeypatch.setattr(progress_mod.time, "perf_counter", lambda: clock[0])
    out = io.StringIO()
    bar = ProgressBar("write", stream=out)
    bar(0.0, "building the shape_points table")
    for i in range(100):  # 100 chunks in 1 s: one line
        clock[0] += 0.01
        bar(0.3 + 0.005 * i, f"uncertainty bands: OSM {i} %")
    clock[0] += 2.5  # a slow chunk: shown
    bar(0.85, "uncertainty bands: OSM 100 %")
    clock[0] += 0.1
    bar(0.87, "uncertainty bands: OSM 100 %")  # repeated: not again
    bar(0.9, "uncertainty bands: TNM 0 %")  # the next database: a new stage, shown
    bar(0.91, "uncertainty bands: TNM 1 %")  # same words, other numbers: held back
    bar(0.95, "writing the features layer")  # a new stage: shown at once
    bar(1.0, "outputs written")
    lines = out.getvalue().splitlines()
    assert [ln.split("s ", 1)[1] for ln in lines] == [
        "building the shape_points table", "uncertainty bands: OSM 0 %",
        "uncertainty bands: OSM 100 %", "uncertainty bands: TNM 0 %",
        "writing the features layer", "outputs written"]


def test_reading_a_project_reports_each_file(sample_dir):
    import pytest

    pytest.importorskip("geopandas")
    from vectoradjust.files.readers import load_project_data

    calls = []
    load_project_data(sample_dir / "project.toml", progress=lambda f, m: calls.append((f, m)))
    fractions = [f for f, _ in calls]
    assert fractions == sorted(fractions) and 0.0 <= fractions[0] and fractions[-1] <= 1.0
    messages = [m for _, m in calls]
    assert messages[0] == "reading the image measurements"
    assert "reading the road layer TIGER" in messages and "reading the truth of OSM" in messages
    assert messages[-1] == "refining the image coordinates"
