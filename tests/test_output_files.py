"""Output files: field names that never clash with the input's, quiet writing, file modes."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

pytestmark = pytest.mark.io
gpd = pytest.importorskip("geopandas")

from vectoradjust.cli.commands import main  # noqa: E402
from vectoradjust.files.outputs import (  # noqa: E402
    FEATURE_FIELDS,
    renamed_input_fields,
    write_outputs,
)
from vectoradjust.files.readers import load_project_data  # noqa: E402
from vectoradjust.pipeline import run  # noqa: E402
from vectoradjust.simulate import make_scenario, write_project  # noqa: E402


@pytest.fixture(scope="module")
def project_dir(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("project")
    write_project(make_scenario(0), d)
    return d


@pytest.fixture(scope="module")
def clashing(project_dir, tmp_path_factory) -> Path:
    """The project with OSMnx-like input fields ``length``, ``RMSE`` and ``npts`` in OSM."""
    d = tmp_path_factory.mktemp("clash") / "p"
    shutil.copytree(project_dir, d)
    g = gpd.read_file(d / "osm_roads.shp")
    g["length"] = g.geometry.length
    g["RMSE"] = 1.5
    g["npts"] = 7
    g.to_file(d / "osm_roads.shp")
    return d


def test_renaming_rule():
    assert renamed_input_fields(["name", "length", "RMSE", "npts", "geometry"]) == {
        "length": "in_length", "RMSE": "in_RMSE", "npts": "in_npts",
        "geometry": "in_geometr"}
    # shapefile-safe (<= 10 characters) and unique, case-insensitively
    got = renamed_input_fields(["lengthsdnc", "LengthSDnc", "in_lengths", "IN_LENGTH1"])
    new = list(got.values())
    assert all(len(n) <= 10 for n in new)
    lowered = [n.lower() for n in new] + ["in_lengths", "in_length1"]
    assert len(set(lowered)) == len(lowered)
    assert not {n.lower() for n in new} & {f.lower() for f in FEATURE_FIELDS}
    assert renamed_input_fields(["name", "highway"]) == {}


@pytest.mark.parametrize("fmt", ["gpkg", "shp"])
def test_input_fields_named_like_ours_are_kept_renamed(clashing, tmp_path, fmt):
    data = load_project_data(clashing / "project.toml", vectors=["OSM"])
    r = run(data, vectors=["OSM"])
    src = gpd.read_file(clashing / "osm_roads.shp")
    out = write_outputs(r, tmp_path / "o", fmt=fmt, bands=False)
    feats = gpd.read_file(out["adjusted.gpkg"], layer="features") if fmt == "gpkg" else \
        gpd.read_file(out["features.shp"])
    cols = list(feats.columns)
    for f in FEATURE_FIELDS:  # the product's names are fixed
        assert f in cols
    assert "Length_1" not in cols
    assert list(feats["in_length"]) == pytest.approx(list(src["length"]))
    assert set(feats["in_RMSE"]) == {1.5} and set(feats["in_npts"]) == {7}
    assert list(feats["NPts"]) == list(r.databases[0].features["NPts"])
    summary = json.loads(Path(out["summary.json"]).read_text())
    assert summary["renamed_input_fields"] == {"length": "in_length", "RMSE": "in_RMSE",
                                               "npts": "in_npts"}


def test_compare_with_clashing_input_fields(clashing, tmp_path, capsys):
    assert main(["compare", str(clashing / "project.toml"), "--out", str(tmp_path), "-q"]) == 0
    assert (tmp_path / "compare.csv").is_file()
    feats = gpd.read_file(tmp_path / "OSM" / "adjusted.gpkg", layer="features")
    assert {"in_length", "Length", "in_RMSE", "RMSE", "in_npts", "NPts"} <= set(feats.columns)
