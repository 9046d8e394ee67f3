"""summary.json stays bounded: the per-feature accuracy statements go to
feature_accuracy.csv beside it, with the same numbers, and summary.json says where."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

pytest.importorskip("geopandas")

from vectoradjust.files.jsonfile import FEATURE_ACCURACY_CSV, move_feature_statements  # noqa: E402
from vectoradjust.files.outputs import write_outputs  # noqa: E402
from vectoradjust.files.readers import load_project_data  # noqa: E402
from vectoradjust.pipeline import run  # noqa: E402


@pytest.fixture(scope="module")
def sample_run(sample_dir):
    return run(load_project_data(sample_dir / "project.toml"))


def test_feature_statements_move_to_a_csv(sample_run, tmp_path):
    feats = sample_run.summary["accuracy"]["features"]
    n = sum(len(v) for v in feats.values())
    assert n > 0
    written = write_outputs(sample_run, tmp_path, bands=False)
    assert FEATURE_ACCURACY_CSV in written
    doc = json.loads((tmp_path / "summary.json").read_text(encoding="utf-8"))
    pointer = doc["accuracy"]["features"]
    assert pointer["file"] == FEATURE_ACCURACY_CSV
    assert pointer["count"] == {k: len(v) for k, v in feats.items()}
    # the contract's keys (docs/method.md section 9) are all still there
    for key in ("sigma0_squared", "degrees_of_freedom", "iterations", "converged",
                "chi_square", "shape_points", "check_points", "images"):
        assert key in doc
    assert doc["accuracy"]["databases"] and "definitions" in doc["accuracy"]
    with open(tmp_path / FEATURE_ACCURACY_CSV, newline="", encoding="utf-8") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == n and list(rows[0])[:3] == ["database", "feature_id", "count"]
    assert list(rows[0]) == pointer["columns"]
    first_db = next(k for k, v in feats.items() if v)
    ref = feats[first_db][0]
    got = next(r for r in rows if r["database"] == first_db
               and r["feature_id"] == ref["feature_id"])
    assert int(got["count"]) == ref["count"]
    assert float(got["rmse_horizontal"]) == pytest.approx(ref["rmse"]["horizontal"], rel=1e-15)
    assert float(got["ager_ce90_exact"]) == pytest.approx(ref["ager"]["ce90_exact"], rel=1e-15)
    # the run in memory keeps its rows (the report lists them)
    assert sample_run.summary["accuracy"]["features"] is feats


def test_nothing_moves_without_feature_statements(tmp_path):
    s = {"sigma0_squared": 1.0, "accuracy": {"features": {}}}
    assert move_feature_statements(s, tmp_path) == (s, None)
    assert move_feature_statements({"a": 1}, tmp_path) == ({"a": 1}, None)
    assert not (tmp_path / FEATURE_ACCURACY_CSV).exists()


def test_a_rerun_without_statements_removes_the_old_csv(sample_run, tmp_path):
    write_outputs(sample_run, tmp_path, bands=False)
    assert (tmp_path / FEATURE_ACCURACY_CSV).is_file()
    summary = sample_run.summary
    try:  # the same run without per-feature statements, into the same folder
        sample_run.summary = {**summary, "accuracy": {**summary["accuracy"], "features": {}}}
        written = write_outputs(sample_run, tmp_path, bands=False)
    finally:
        sample_run.summary = summary
    assert FEATURE_ACCURACY_CSV not in written
    assert not (tmp_path / FEATURE_ACCURACY_CSV).exists()
    (tmp_path / "x").mkdir()
    (tmp_path / "x" / FEATURE_ACCURACY_CSV).write_text("old", encoding="utf-8")
    move_feature_statements({"accuracy": {"features": {}}}, tmp_path / "x")
    assert not (tmp_path / "x" / FEATURE_ACCURACY_CSV).exists()


def test_json_cells_of_numbers_text_and_flags():
    from vectoradjust.files.jsonfile import _json_cells

    f = _json_cells([1.5, None, float("inf"), 2])
    assert f.dtype == float and f[0] == 1.5 and f[3] == 2.0 and np.isnan(f[1:3]).all()
    assert _json_cells([3, 4]).tolist() == [3, 4]  # whole numbers stay whole numbers
    assert _json_cells([True, None]).tolist() == [True, None]  # flags are not numbers
    assert _json_cells(["a", 1.0]).tolist() == ["a", 1.0]


def _flat(row, prefix=""):
    out = {}
    for k, v in row.items():
        out.update(_flat(v, f"{prefix}{k}_") if isinstance(v, dict) else {f"{prefix}{k}": v})
    return out


def test_feature_statements_keep_the_columns_of_their_rows(sample_run):
    import pickle

    from vectoradjust.accuracy.statements import FeatureStatements

    feats = sample_run.summary["accuracy"]["features"]
    some = [v for v in feats.values() if len(v)]
    assert some and all(isinstance(v, FeatureStatements) for v in some)
    for rows in some:
        cols = rows.columns()
        assert len(rows) == len(cols["feature_id"])
        for i, row in enumerate(rows):
            flat = _flat(row)
            assert list(flat) == list(cols)  # the same keys, in the same order
            for k, v in flat.items():
                c = cols[k][i]
                if v is None:
                    assert isinstance(c, float) and not np.isfinite(c)
                else:
                    assert type(v) in (str, int, float) and v == c
        # a plain list for json, and pickled with its columns (forked and Dask workers)
        assert json.loads(json.dumps(rows, allow_nan=False)) == list(rows)
        back = pickle.loads(pickle.dumps(rows))
        assert back == rows and list(back.columns()) == list(cols)
        ids = [r["feature_id"] for r in rows]
        ask = [ids[-1], "no such feature", ids[0]]
        assert rows.index_of(ask).tolist() == [len(ids) - 1, -1, 0]


def test_the_csv_from_columns_is_the_csv_from_dicts(sample_run, tmp_path):
    feats = sample_run.summary["accuracy"]["features"]
    plain = {k: [dict(r) for r in v] for k, v in feats.items()}  # no columns kept
    paths = []
    for name, f in (("columns", feats), ("dicts", plain)):
        summary = {"accuracy": {"features": f}}
        out, path = move_feature_statements(summary, tmp_path / name)
        assert out["accuracy"]["features"]["count"] == {k: len(v) for k, v in f.items()}
        paths.append(path)
    assert paths[0].read_bytes() == paths[1].read_bytes()
