"""``adjust-many``'s merged output: one GeoPackage per database, on a LocalCluster."""

from __future__ import annotations

import csv
import json
import re

import pytest

pytest.importorskip("geopandas")
pytest.importorskip("dask")
pa = pytest.importorskip("pyarrow")

from pyogrio import list_layers, read_arrow  # noqa: E402

from vectoradjust.files.many import adjust_many  # noqa: E402
from vectoradjust.files.many_merge import PROJECT_COLUMN, MergedOutput  # noqa: E402
from vectoradjust.simulate import make_scenario, write_project  # noqa: E402

pytestmark = pytest.mark.io

SEEDS = (5, 6, 7)


@pytest.fixture(scope="module")
def county(tmp_path_factory):
    """Three tiny stereo models (OSM and TIGER) and a broken project file."""
    root = tmp_path_factory.mktemp("county")
    good = []
    for seed in SEEDS:
        d = root / f"model{seed}"
        write_project(make_scenario(seed, grid=(2, 2), databases=("OSM", "TIGER")), d)
        toml = d / "project.toml"
        body = toml.read_text(encoding="utf-8")  # the project's name (the first), not
        toml.write_text(re.sub(r'^name = .*$', f'name = "model{seed}"', body, count=1,
                               flags=re.M), encoding="utf-8")  # a [[vectors]] one
        good.append(toml)
    broken = root / "broken.toml"
    broken.write_text('crs = "EPSG:32616"\n[camera]\nfocal_length = "x"\n', encoding="utf-8")
    return good, broken


def _layer(path, layer):
    return read_arrow(path, layer=layer)


def _check_merged(out, rows, good):
    """Every row of every project's layers in merged_<db>.gpkg, with the project's name
    and the per-project layer's fields and types."""
    names = [r["name"] for r in rows if r["status"] == "ok"]
    assert names == [f"model{s}" for s in SEEDS]
    doc = json.loads((out / "many_summary.json").read_text(encoding="utf-8"))
    assert sorted(doc["merged"]) == ["OSM", "TIGER"] and doc["merge_notes"] == []
    for db in ("OSM", "TIGER"):
        path = out / f"merged_{db}.gpkg"
        assert sorted(list_layers(path)[:, 0]) == ["features", "shape_points"]
        for layer in ("shape_points", "features"):
            meta, merged = _layer(path, layer)
            assert merged.column_names[0] == PROJECT_COLUMN
            total = 0
            for name in names:
                own_meta, own = _layer(out / name / "adjusted.gpkg", layer)
                own = own.filter(pa.compute.equal(own["Database"], db))
                assert own.num_rows > 0
                mine = merged.filter(pa.compute.equal(merged[PROJECT_COLUMN], name))
                assert mine.drop_columns([PROJECT_COLUMN]).equals(own)  # rows, fields, types
                total += own.num_rows
            assert merged.num_rows == total == doc["merged_rows"][f"{db}/{layer}"]
            assert meta["geometry_type"] == own_meta["geometry_type"]
            assert meta["crs"] == own_meta["crs"] == "EPSG:32616"
        assert merged.schema.field("osm_id").type == pa.int64()  # features: int64 ids
    with open(out / "many_summary.csv", newline="", encoding="utf-8") as fh:
        table = {r["name"]: r for r in csv.DictReader(fh)}
    for r in rows:
        assert int(table[r["name"]]["merged_rows"] or 0) == (r["merged_rows"] or 0)
    assert not list(out.glob(".merged_*"))  # the staged files moved into place


def test_two_worker_local_cluster_merges_every_row_and_lists_the_failure(county, tmp_path):
    pytest.importorskip("distributed")
    good, broken = county
    rows = adjust_many([good[0], broken, *good[1:]], tmp_path, workers=2, bands=False,
                       report=False, memory_limit="1GB")
    assert [r["status"] for r in rows] == ["ok", "failed", "ok", "ok"], [r["error"] for r in rows]
    assert "focal_length" in rows[1]["error"] and rows[1]["merged_rows"] is None
    doc = json.loads((tmp_path / "many_summary.json").read_text(encoding="utf-8"))
    assert doc["failed"] == ["broken"] and "focal_length" in doc["failures"][0]["error"]
    _check_merged(tmp_path, [r for r in rows if r["status"] == "ok"], good)
    assert all(r["merged_rows"] > 0 for r in rows if r["status"] == "ok")


def test_local_scheduler_merges_as_each_project_arrives(county, tmp_path):
    good, broken = county
    rows = adjust_many([*good, broken], tmp_path, scheduler="sync", bands=False,
                       report=False)
    _check_merged(tmp_path, rows[:3], good)
    assert rows[3]["status"] == "failed" and "_layers" not in rows[0]


def test_no_merge_writes_no_merged_file(county, tmp_path):
    rows = adjust_many(county[0][:1], tmp_path, scheduler="sync", bands=False,
                       report=False, merge=False)
    assert rows[0]["status"] == "ok" and rows[0]["merged_rows"] is None
    assert not list(tmp_path.glob("*merged*"))
    doc = json.loads((tmp_path / "many_summary.json").read_text(encoding="utf-8"))
    assert "merged" not in doc


def _table(ids, extra=None):
    cols = {"point_id": pa.array(ids, pa.int64()), "Database": pa.array(["OSM"] * len(ids)),
            "geom": pa.array([bytes.fromhex("0101000000" + "00" * 16)] * len(ids))}
    cols.update(extra or {})
    return pa.table(cols)


def test_a_later_project_s_other_fields_are_conformed_and_noted(tmp_path):
    merged = MergedOutput(tmp_path)
    meta = {"crs": "EPSG:32616", "geometry_type": "Point", "geometry_name": "geom"}
    first = _table([2**53 + 1, 2], {"name": pa.array(["a", "b"])})
    later = _table([3], {"width": pa.array([7.5])})  # no "name", a "width" of its own
    assert merged.add("m1", [("OSM", "shape_points", first, meta)]) == 2
    assert merged.add("m2", [("OSM", "shape_points", later, meta)]) == 1
    (tmp_path / "merged_TNM.gpkg").write_text("an earlier run's", encoding="utf-8")
    files = merged.commit()
    assert not (tmp_path / "merged_TNM.gpkg").exists()  # no TNM rows in this run
    _, back = read_arrow(files["OSM"], layer="shape_points")
    assert back["point_id"].to_pylist() == [2**53 + 1, 2, 3]  # int64 kept exactly
    assert back["name"].to_pylist() == ["a", "b", None]
    assert "width" not in back.column_names
    assert len(merged.notes) == 1 and "m2" in merged.notes[0] and "width" in merged.notes[0]


def test_the_bands_are_merged_on_request(county, tmp_path):
    rows = adjust_many(county[0][:1], tmp_path, scheduler="sync", report=False,
                       merge_layers=("shape_points", "features", "uncertainty_bands"))
    assert rows[0]["status"] == "ok"
    for db in ("OSM", "TIGER"):
        _, merged = _layer(tmp_path / f"merged_{db}.gpkg", "uncertainty_bands")
        _, own = _layer(tmp_path / "model5" / "adjusted.gpkg", "uncertainty_bands")
        own = own.filter(pa.compute.equal(own["database"], db))
        assert merged.num_rows == own.num_rows > 0
        assert set(merged[PROJECT_COLUMN].to_pylist()) == {"model5"}


def test_a_project_whose_layers_cannot_be_read_is_adjusted_but_not_merged(county, tmp_path,
                                                                           monkeypatch):
    import vectoradjust.files.many_merge as mm

    real = mm.project_layers

    def flaky(out_dir, name, *args):
        if name == "model6":
            raise OSError("unreadable adjusted.gpkg")
        return real(out_dir, name, *args)

    monkeypatch.setattr(mm, "project_layers", flaky)
    rows = adjust_many(county[0][:2], tmp_path, scheduler="sync", bands=False,
                       report=False)
    assert [r["status"] for r in rows] == ["ok", "ok"]
    assert "not merged" in rows[1]["error"] and "unreadable" in rows[1]["error"]
    _, merged = _layer(tmp_path / "merged_OSM.gpkg", "shape_points")
    assert set(merged[PROJECT_COLUMN].to_pylist()) == {"model5"}
    assert rows[0]["merged_rows"] > 0 and rows[1]["merged_rows"] is None
