"""One runner for every command (issue 33): ``vectoradjust adjust`` and ``vectoradjust
adjust-many`` (one project) go through :func:`vectoradjust.run_project` and write the
same folder for the same project.

Compared, file by file: the same file names; ``adjusted.gpkg`` with the same layers,
columns, rows and geometries; every CSV with the same header and cells; ``summary.json``
and ``qa.json`` key by key. Numbers agree within 1e-9 (relative or absolute), text
exactly. Left out, because they must differ: ``run_manifest.json``'s ``command``,
``started``/``finished`` times and the files' sizes and checksums (their names are
compared; ``report.html`` carries the minute it was written, so its size and checksum may
differ: its text is compared with that minute taken out).
"""

from __future__ import annotations

import csv
import json
import math
import re
from pathlib import Path

import pytest

pytest.importorskip("geopandas")
pytestmark = pytest.mark.io

#: run_manifest.json keys that differ between two runs of the same project
MANIFEST_VOLATILE = ("command", "started", "finished", "files")


def _same_number(a: float, b: float) -> bool:
    if math.isnan(a) or math.isnan(b):
        return math.isnan(a) and math.isnan(b)
    return math.isclose(a, b, rel_tol=1e-9, abs_tol=1e-9)


def _cell(text: str):
    try:
        return float(text)
    except ValueError:
        return text


def _diff_values(a, b, where: str, out: list) -> None:
    """Every difference of two JSON values into ``out`` (numbers within 1e-9)."""
    if isinstance(a, dict) and isinstance(b, dict):
        if set(a) != set(b):
            out.append(f"{where}: keys {sorted(set(a) ^ set(b))}")
        for k in set(a) & set(b):
            _diff_values(a[k], b[k], f"{where}.{k}", out)
    elif isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            out.append(f"{where}: {len(a)} != {len(b)} items")
        for i, (x, y) in enumerate(zip(a, b)):
            _diff_values(x, y, f"{where}[{i}]", out)
    elif (isinstance(a, (int, float)) and isinstance(b, (int, float))
          and not isinstance(a, bool) and not isinstance(b, bool)):
        if not _same_number(float(a), float(b)):
            out.append(f"{where}: {a!r} != {b!r}")
    elif a != b:
        out.append(f"{where}: {a!r} != {b!r}")


def _diff_csv(a: Path, b: Path, out: list) -> None:
    with open(a, newline="", encoding="utf-8") as fa, open(b, newline="", encoding="utf-8") as fb:
        ra, rb = list(csv.reader(fa)), list(csv.reader(fb))
    if not ra or ra[0] != rb[0]:
        out.append(f"{a.name}: header {ra[:1]} != {rb[:1]}")
        return
    _diff_values([[_cell(c) for c in r] for r in ra[1:]], [[_cell(c) for c in r] for r in rb[1:]],
                 a.name, out)


def _diff_layers(a: Path, b: Path, out: list) -> list:
    """The layers of two GeoPackages compared; their names."""
    import numpy as np
    import pyogrio
    import shapely

    names = [n for n, _ in pyogrio.list_layers(a)]
    if names != [n for n, _ in pyogrio.list_layers(b)]:
        out.append(f"{a.name}: layers {names} != {list(pyogrio.list_layers(b)[:, 0])}")
        return names
    for name in names:
        fa, fb = (pyogrio.read_dataframe(p, layer=name) for p in (a, b))
        if list(fa.columns) != list(fb.columns) or len(fa) != len(fb):
            out.append(f"{name}: columns/rows {list(fa.columns)}/{len(fa)} != "
                       f"{list(fb.columns)}/{len(fb)}")
            continue
        for col in fa.columns:
            x, y = fa[col].to_numpy(), fb[col].to_numpy()
            if col == "geometry":
                same = shapely.equals_exact(shapely.normalize(x), shapely.normalize(y), 1e-9)
            elif np.issubdtype(x.dtype, np.number) and np.issubdtype(y.dtype, np.number):
                same = np.isclose(x.astype(float), y.astype(float), rtol=1e-9, atol=1e-9,
                                  equal_nan=True)
            else:
                same = np.array([u == v or (u != u and v != v) for u, v in zip(x, y)])
            if not np.all(same):
                out.append(f"{name}.{col}: {int(np.sum(~np.asarray(same, bool)))} rows differ")
    return names


def _unstamped(text: str) -> str:
    """A report without the minute it was written in."""
    return re.sub(r"\d{4}-\d\d-\d\d \d\d:\d\d</p>", "</p>", text)


def compare_folders(a: Path, b: Path) -> tuple:
    """(differences, files compared, layers compared) of two run folders."""
    names = sorted(p.relative_to(a).as_posix() for p in a.rglob("*") if p.is_file())
    other = sorted(p.relative_to(b).as_posix() for p in b.rglob("*") if p.is_file())
    out: list = [] if names == other else [f"files {names} != {other}"]
    layers: list = []
    for rel in (n for n in names if n in other):
        pa, pb = a / rel, b / rel
        if rel.endswith(".gpkg"):
            layers += _diff_layers(pa, pb, out)
        elif rel.endswith(".csv"):
            _diff_csv(pa, pb, out)
        elif rel == "run_manifest.json":
            ja, jb = (json.loads(p.read_text(encoding="utf-8")) for p in (pa, pb))
            if sorted(ja["files"]) != sorted(jb["files"]):
                out.append(f"run_manifest.json: files {sorted(ja['files'])} != "
                           f"{sorted(jb['files'])}")
            _diff_values({k: v for k, v in ja.items() if k not in MANIFEST_VOLATILE},
                         {k: v for k, v in jb.items() if k not in MANIFEST_VOLATILE},
                         rel, out)
        elif rel.endswith(".json"):
            _diff_values(*(json.loads(p.read_text(encoding="utf-8")) for p in (pa, pb)),
                         rel, out)
        elif rel.endswith(".html"):
            if _unstamped(pa.read_text(encoding="utf-8")) != \
                    _unstamped(pb.read_text(encoding="utf-8")):
                out.append(f"{rel}: the text differs")
        elif pa.read_bytes() != pb.read_bytes():
            out.append(f"{rel}: the bytes differ")
    return out, names, layers


def test_compare_folders_sees_a_changed_value(tmp_path):
    """The comparison can fail: a CSV cell and a JSON number changed beyond 1e-9."""
    for d, v in (("a", "1.0"), ("b", "1.00001")):
        (tmp_path / d).mkdir()
        (tmp_path / d / "t.csv").write_text(f"x,name\n{v},OSM\n", encoding="utf-8")
        (tmp_path / d / "summary.json").write_text(json.dumps({"s": {"v": float(v)}}),
                                                   encoding="utf-8")
    diffs, names, _ = compare_folders(tmp_path / "a", tmp_path / "b")
    assert names == ["summary.json", "t.csv"]
    assert diffs == ["summary.json.s.v: 1.0 != 1.00001", "t.csv[0][0]: 1.0 != 1.00001"]


def test_adjust_and_adjust_many_write_the_same_folder(sample_dir, tmp_path, monkeypatch):
    pytest.importorskip("dask")
    from vectoradjust.cli import main
    from vectoradjust.files.many import project_names

    project = str(sample_dir / "project.toml")
    monkeypatch.setenv("VECTORADJUST_WORKERS", "2")  # adjust: bands and report forked
    assert main(["adjust", project, "--out", str(tmp_path / "adjust"), "-q"]) == 0
    assert main(["adjust-many", project, "--out", str(tmp_path / "many"), "-q",
                 "--scheduler", "sync"]) == 0
    many = tmp_path / "many" / project_names([project])[0]
    diffs, names, layers = compare_folders(tmp_path / "adjust", many)
    assert diffs == []
    # what adjust-many wrote before the runner too: the truth tables are there now
    assert {"adjusted.gpkg", "summary.json", "report.html", "run_manifest.json",
            "truth_points.csv", "truth_line_points.csv", "feature_accuracy.csv"} <= set(names)
    assert layers == ["shape_points", "features", "control_points", "uncertainty_bands"]
    manifest = [json.loads((d / "run_manifest.json").read_text(encoding="utf-8"))["command"]
                for d in (tmp_path / "adjust", many)]
    assert manifest == ["adjust", "adjust-many"]


def test_the_package_docstring_example_runs(tmp_path, monkeypatch):
    """The suite runs no doctests: the example of ``vectoradjust``'s docstring (read the
    sample, run it into a folder, a wrong project's message) is run here."""
    import doctest
    import tempfile

    import vectoradjust

    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))  # its mkdtemp() in here
    runner = doctest.DocTestRunner(optionflags=doctest.ELLIPSIS)
    for test in doctest.DocTestFinder().find(vectoradjust, "vectoradjust"):
        runner.run(test)
    failed, attempted = runner.summarize(verbose=False)
    assert attempted >= 9 and failed == 0


def test_the_public_api_is_at_the_package_top():
    import vectoradjust
    from vectoradjust import errors
    from vectoradjust.runner import project_run

    assert vectoradjust.run_project is project_run.run_project
    assert vectoradjust.RunOptions().fmt == "gpkg" and vectoradjust.RunOptions().bands
    assert vectoradjust.ProjectError is errors.ProjectError
    assert issubclass(vectoradjust.ProjectError, vectoradjust.VectorAdjustError)
    assert set(vectoradjust.__all__) <= set(dir(vectoradjust))
    with pytest.raises(AttributeError, match="no attribute 'nothing_here'"):
        vectoradjust.nothing_here  # noqa: B018


def test_run_project_with_stage_progress_and_a_cancel(sample_dir, tmp_path):
    """``progress`` as one callable gets the stages' shares in order, from 0 to 1; a
    ``cancel`` that says yes leaves no folder behind."""
    import vectoradjust

    said = []
    done = vectoradjust.run_project(
        sample_dir / "project.toml", tmp_path / "out",
        vectoradjust.RunOptions(bands=False, report=False, background=False),
        progress=lambda f, m: said.append((f, m)))
    assert done.out == tmp_path / "out" and done.qa is None
    assert set(done.written) == {p.name for p in (tmp_path / "out").iterdir()
                                 if p.name != "run_manifest.json"}
    fractions = [f for f, _ in said]
    assert fractions[0] == 0.0 and fractions[-1] == pytest.approx(0.97)  # the end of write
    assert {m.split(":")[0] for _, m in said} >= {"adjust", "truth", "truth tables", "write"}
    with pytest.raises(vectoradjust.CancelledError, match="cancelled"):
        vectoradjust.run_project(sample_dir / "project.toml", tmp_path / "never",
                                 vectoradjust.RunOptions(background=False),
                                 cancel=lambda: True)
    assert not (tmp_path / "never").exists()
