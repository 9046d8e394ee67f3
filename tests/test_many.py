"""``adjust-many``: independent projects on Dask (local scheduler and a LocalCluster)."""

from __future__ import annotations

import csv
import json
import sys

import pytest

pytest.importorskip("geopandas")
dask = pytest.importorskip("dask")

from vectoradjust.cli.commands import main  # noqa: E402
from vectoradjust.errors import VectorAdjustError  # noqa: E402
from vectoradjust.files.many import MANY_COLUMNS, adjust_many, project_names  # noqa: E402
from vectoradjust.files.project import load_project  # noqa: E402
from vectoradjust.files.readers import load_project_data  # noqa: E402
from vectoradjust.pipeline import run  # noqa: E402
from vectoradjust.simulate import make_scenario, write_project  # noqa: E402


@pytest.fixture(scope="module")
def projects(tmp_path_factory):
    root = tmp_path_factory.mktemp("many")
    out = []
    for seed in (3, 4):
        d = root / f"model{seed}"
        write_project(make_scenario(seed, grid=(2, 2), databases=("OSM",)), d)
        toml = d / "project.toml"  # unnamed: the folder names the output directory
        toml.write_text("".join(line for line in toml.read_text(encoding="utf-8")
                                .splitlines(keepends=True) if not line.startswith("name =")),
                        encoding="utf-8")
        out.append(toml)
    broken = root / "broken.toml"
    broken.write_text('crs = "EPSG:32616"\n[camera]\nfocal_length = "x"\n', encoding="utf-8")
    return out, broken


def _expected(project):
    return run(load_project_data(load_project(project))).summary


def _check_rows(rows, projects, out):
    good, broken = projects
    assert [r["status"] for r in rows] == ["ok", "ok", "failed"]
    assert "focal_length" in rows[2]["error"] and rows[2]["sigma0_squared"] is None
    for r, p in zip(rows[:2], good):
        s = _expected(p)  # the same project adjusted directly, in this process
        assert r["sigma0_squared"] == pytest.approx(s["sigma0_squared"], rel=1e-9)
        assert r["check_rmse_horizontal"] == pytest.approx(
            s["check_points"]["rmse_horizontal"], rel=1e-9)
        assert r["shape_points_measured"] == s["shape_points"]["count"] > 0
        assert r["chi_square_passed"] == s["chi_square"]["passed"]
        assert (out / r["name"] / "adjusted.gpkg").is_file()
        assert (out / r["name"] / "summary.json").is_file()
    with open(out / "many_summary.csv", newline="", encoding="utf-8") as fh:
        table = list(csv.DictReader(fh))
    assert list(table[0]) == MANY_COLUMNS and len(table) == 3
    assert float(table[0]["sigma0_squared"]) == pytest.approx(rows[0]["sigma0_squared"])
    doc = json.loads((out / "many_summary.json").read_text(encoding="utf-8"))
    assert doc["projects"] == 3 and doc["failed"] == [rows[2]["name"]]


def test_adjust_many_on_the_local_process_scheduler(projects, tmp_path):
    good, broken = projects
    calls = []
    rows = adjust_many([*good, broken], tmp_path, scheduler="processes", workers=2,
                       report=False, progress=lambda f, m: calls.append((f, m)))
    _check_rows(rows, projects, tmp_path)
    assert [r["name"] for r in rows] == ["model3", "model4", "broken"]
    assert calls[-1][0] == 1.0 and len(calls) >= 4  # one per project and the end


def test_adjust_many_on_a_distributed_local_cluster(projects, tmp_path):
    distributed = pytest.importorskip("distributed")
    good, broken = projects
    with distributed.LocalCluster(n_workers=1, threads_per_worker=2, processes=False,
                                  dashboard_address=None) as cluster:
        rows = adjust_many([*good, broken], tmp_path, scheduler=cluster.scheduler_address,
                           bands=False, report=False)
    _check_rows(rows, projects, tmp_path)


def test_adjust_many_cli_reports_failures_with_exit_status_1(projects, tmp_path, capsys):
    good, broken = projects
    code = main(["adjust-many", str(good[0]), str(broken), "--out", str(tmp_path),
                 "--scheduler", "sync", "--no-bands", "--no-report"])
    assert code == 1
    out = capsys.readouterr().out
    assert "1 of 2 projects adjusted" in out and "broken" in out
    assert (tmp_path / "model3" / "summary.json").is_file()


def test_project_names_are_unique_and_safe(tmp_path):
    a = tmp_path / "a" / "project.toml"
    a.parent.mkdir()
    a.write_text('name = "Model 1 / west"\n', encoding="utf-8")
    b = tmp_path / "b" / "project.toml"
    b.parent.mkdir()
    b.write_text("", encoding="utf-8")
    assert project_names([a, a, b, tmp_path / "x.toml"]) == ["Model_1_west", "Model_1_west-2",
                                                             "b", "x"]


def test_missing_dask_is_a_clear_error(monkeypatch, tmp_path):
    monkeypatch.setitem(sys.modules, "dask", None)
    with pytest.raises(VectorAdjustError, match="dask"):
        adjust_many(["p.toml"], tmp_path)


def test_unreachable_scheduler_is_a_clear_error(projects, tmp_path):
    pytest.importorskip("distributed")
    with pytest.raises(VectorAdjustError, match="scheduler"):
        adjust_many(projects[0], tmp_path, scheduler=42)


def test_a_memory_limit_dask_cannot_read_is_a_clear_error_before_any_worker(tmp_path):
    pytest.importorskip("dask")
    from vectoradjust.errors import VectorAdjustError
    from vectoradjust.files.many import adjust_many

    with pytest.raises(VectorAdjustError, match="'banana' is not a memory size") as info:
        adjust_many(["p.toml"], tmp_path / "out", memory_limit="banana")
    assert "--memory-limit 1GB" in info.value.mend
    assert not (tmp_path / "out").exists()  # nothing started, nothing written
