"""``vectoradjust compare`` with a database that has no measured shape point: that one is
reported with the reason, the others are compared (it used to stop the whole command)."""

from __future__ import annotations

import csv
import shutil
from pathlib import Path

import pytest

pytest.importorskip("geopandas")
pytestmark = pytest.mark.io

from vectoradjust.cli.commands import main  # noqa: E402

SAMPLE = Path(__file__).resolve().parents[1] / "resources" / "sample"


def _project_with_unmeasured_database(tmp_path: Path) -> Path:
    for p in SAMPLE.iterdir():
        if p.is_file():  # (the satellite sample is a folder of its own)
            shutil.copy(p, tmp_path / p.name)
    text = (tmp_path / "project.toml").read_text()
    # a copy of the OSM layer with feature-index ids: no measurement names them
    extra = '\n[[vectors]]\nname = "EXTRA"\npath = "osm_roads.shp"\ndem = "dem.tif"\n'
    text = text.replace("\n[adjustment]", extra + "\n[adjustment]", 1)
    (tmp_path / "project.toml").write_text(text)
    return tmp_path / "project.toml"


@pytest.mark.slow
def test_compare_goes_on_past_a_database_without_measurements(tmp_path, capsys):
    project = _project_with_unmeasured_database(tmp_path)
    rc = main(["compare", str(project), "--out", str(tmp_path / "out"), "-q"])
    assert rc == 0
    rows = list(csv.DictReader(open(tmp_path / "out" / "compare.csv", encoding="utf-8")))
    names = [r["database"] for r in rows]
    assert names == ["OSM", "TNM", "TIGER", "EXTRA"]
    extra = rows[-1]
    assert extra["adjusted"] == "0" and "EXTRA" in extra["error"]
    assert all(not r["error"] for r in rows[:3])
    assert "EXTRA: not adjusted" in capsys.readouterr().out
