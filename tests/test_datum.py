"""Datums of the inputs: ``[control] crs`` / ``vertical_crs`` and the top-level
``vertical_crs`` (the control heights and the DEMs); the transformation used and its
accuracy are reported, a ballpark one is a warning, a missing geoid grid a clear error."""

from __future__ import annotations

import csv
import re
import shutil
from pathlib import Path

import numpy as np
import pytest

from vectoradjust.errors import ProjectError
from vectoradjust.files.project import parse_project

io = pytest.mark.io


def _raw(**control) -> dict:
    return {"crs": "EPSG:32616", "camera": {"focal_length": 152.4},
            "images": [{"id": "L", "position": [0, 0, 800]}],
            "measurements": {"path": "m.csv"}, "control": {"path": "g.csv", **control}}


def test_schema_accepts_the_datum_keys():
    raw = _raw(crs=" EPSG:4326 ", vertical_crs="EPSG:5703")
    raw["vertical_crs"] = "EPSG:5703"
    spec = parse_project(raw, base_dir=".")
    assert spec.control["crs"] == "EPSG:4326"
    assert spec.control["vertical_crs"] == "EPSG:5703"
    assert spec.vertical_crs == "EPSG:5703"
    assert parse_project(_raw(), base_dir=".").vertical_crs is None


def test_schema_rejects_an_empty_datum():
    with pytest.raises(ProjectError, match=r"\[control\]: crs must be a non-empty text"):
        parse_project(_raw(crs=""), base_dir=".")
    raw = _raw()
    raw["vertical_crs"] = 5703
    with pytest.raises(ProjectError, match="vertical_crs must be a non-empty text"):
        parse_project(raw, base_dir=".")


# --------------------------------------------------------------------------- with pyproj
@pytest.fixture()
def sample(sample_dir, tmp_path) -> Path:
    """A private copy of the sample project."""
    pytest.importorskip("geopandas")
    d = tmp_path / "sample"
    shutil.copytree(sample_dir, d)
    return d


def _set(project: Path, table: str, **keys) -> None:
    """Add ``keys`` to ``[table]`` (``""``: the top level) of the project file."""
    text = project.read_text(encoding="utf-8")
    lines = "".join(f'{k} = "{v}"\n' for k, v in keys.items())
    if table:
        text = text.replace(f"[{table}]\n", f"[{table}]\n{lines}", 1)
    else:
        text = re.sub(r'(?m)^crs = "[^"]*"\n', "", text, count=1)
        text = lines + text
    project.write_text(text, encoding="utf-8")


def _gcps_to(d: Path, crs: str) -> None:
    """Rewrite the sample's gcps.csv (UTM 16N) in ``crs`` (X = longitude, Y = latitude)."""
    from pyproj import Transformer

    t = Transformer.from_crs("EPSG:32616", crs, always_xy=True)
    with open(d / "gcps.csv", newline="") as fh:
        rows = list(csv.reader(fh))
    for r in rows[1:]:
        x, y = t.transform(float(r[1]), float(r[2]))
        r[1], r[2] = f"{x:.12f}", f"{y:.12f}"
    with open(d / "gcps.csv", "w", newline="") as fh:
        csv.writer(fh).writerows(rows)


@io
def test_gcps_in_lon_lat_give_the_same_adjustment(sample):
    from vectoradjust.files.readers import load_project_data
    from vectoradjust.pipeline import run

    before = load_project_data(sample / "project.toml")
    ref = run(before)
    _gcps_to(sample, "EPSG:4326")
    _set(sample / "project.toml", "control", crs="EPSG:4326")
    data = load_project_data(sample / "project.toml")
    info = data.control.reading["crs"]
    assert info["source_crs"] == "WGS 84" and "UTM zone 16N" in info["transformation"]
    assert info["accuracy_m"] == 0.0 and info["warning"] is None
    np.testing.assert_allclose(data.control.xyz, before.control.xyz, atol=1e-6)
    np.testing.assert_array_equal(data.control.sigma, before.control.sigma)
    out = run(data)
    for a, b in zip(out.summary["images"], ref.summary["images"]):
        for k, v in b.items():
            if isinstance(v, float):
                assert a[k] == pytest.approx(v, abs=1e-5), k
    assert out.summary["sigma0_squared"] == pytest.approx(ref.summary["sigma0_squared"])


@io
def test_a_ballpark_control_transformation_warns(sample):
    from vectoradjust.files.readers import load_project_data

    _gcps_to(sample, "EPSG:4267")  # NAD27: without the NADCON grid only a ballpark shift
    _set(sample / "project.toml", "control", crs="EPSG:4267")
    info = load_project_data(sample / "project.toml").control.reading["crs"]
    if info["accuracy_m"] is not None and info["accuracy_m"] <= 1.0:
        pytest.skip("the NAD27 grid is installed here")
    assert "NAD27" in info["warning"]
    assert re.search("ballpark|unknown accuracy", info["warning"])


def _project_in_navd88(d: Path, **top) -> None:
    _set(d / "project.toml", "", crs="EPSG:32616+5703", **top)


@io
def test_same_vertical_datum_leaves_the_heights(sample):
    from vectoradjust.files.readers import load_project_data

    before = load_project_data(sample / "project.toml")
    _project_in_navd88(sample, vertical_crs="EPSG:5703")
    data = load_project_data(sample / "project.toml")
    np.testing.assert_allclose(data.control.xyz, before.control.xyz, atol=1e-9)
    assert data.control.reading["crs"] is None  # nothing to transform
    for (_, a), (_, b) in zip(data.vectors, before.vectors):
        np.testing.assert_array_equal(a.coords, b.coords)
        assert a.reading["dem"]["heights"] is None
    # lon/lat with NAVD88 heights into UTM + NAVD88: XY transformed, Z unchanged
    _gcps_to(sample, "EPSG:4326")
    _set(sample / "project.toml", "control", crs="EPSG:4326")
    data = load_project_data(sample / "project.toml")
    np.testing.assert_allclose(data.control.xyz, before.control.xyz, atol=1e-6)
    v = data.control.reading["crs"]["vertical"]
    assert v == {"source": "NAVD88 height", "target": "NAVD88 height", "transformed": False}


def _no_grid_here(source: str, target: str) -> None:
    from pyproj import Transformer

    if "ballpark" not in Transformer.from_crs(source, target).description.lower():
        pytest.skip("PROJ has the grid here")


@io
@pytest.mark.parametrize("control, pair", [
    ({"vertical_crs": "EPSG:5702"}, ("NGVD29 height", "NAVD88 height")),
    ({"crs": "EPSG:4979"}, ("ellipsoidal height", "NAVD88 height")),
])
def test_control_heights_without_a_grid_are_a_clear_error(sample, control, pair):
    from vectoradjust.errors import CRSError
    from vectoradjust.files.readers import load_project_data

    source = control.get("crs", "EPSG:32616+5702")
    _no_grid_here(source, "EPSG:32616+5703")
    _project_in_navd88(sample)
    _set(sample / "project.toml", "control", **control)
    with pytest.raises(CRSError,
                       match=r"to NAVD88 height: PROJ has no grid-based.*Install the grid") as exc:
        load_project_data(sample / "project.toml")
    msg, mend = str(exc.value), exc.value.mend if hasattr(exc.value, "mend") else str(exc.value)
    assert "[control]" in msg and all(p in msg for p in pair), msg
    assert "0 m" in msg and "grid" in msg
    assert "proj-data" in (mend + msg) and "NAVD88 height" in (mend + msg)


@io
def test_dem_heights_without_a_grid_are_a_clear_error(sample):
    from vectoradjust.errors import CRSError
    from vectoradjust.files.readers import load_project_data

    _no_grid_here("EPSG:32616+5702", "EPSG:32616+5703")
    _project_in_navd88(sample, vertical_crs="EPSG:5702")
    _set(sample / "project.toml", "control", vertical_crs="EPSG:5703")
    with pytest.raises(CRSError, match=r"'OSM' dem: the heights cannot be transformed from "
                                       "NGVD29 height"):
        load_project_data(sample / "project.toml")


FT_US = 1200.0 / 3937.0  # m


@io
def test_heights_in_another_vertical_crs_are_transformed(sample):
    """NAVD88 height in US survey feet (EPSG:6360) to the project's NAVD88 metres: a
    datum change PROJ can make without a grid, for the control points and the DEMs."""
    from vectoradjust.files.readers import load_project_data

    _project_in_navd88(sample)
    before = load_project_data(sample / "project.toml")
    with open(sample / "gcps.csv", newline="") as fh:
        rows = list(csv.reader(fh))
    for r in rows[1:]:
        r[3] = f"{float(r[3]) / FT_US:.9f}"
    with open(sample / "gcps.csv", "w", newline="") as fh:
        csv.writer(fh).writerows(rows)
    _set(sample / "project.toml", "control", vertical_crs="EPSG:6360")
    data = load_project_data(sample / "project.toml")
    np.testing.assert_allclose(data.control.xyz, before.control.xyz, atol=1e-6)
    np.testing.assert_array_equal(data.control.sigma, before.control.sigma)
    v = data.control.reading["crs"]["vertical"]
    assert v == {"source": "NAVD88 height (ftUS)", "target": "NAVD88 height",
                 "transformed": True}
    # the DEM (in metres) said to be in feet: its heights are scaled to metres
    project = sample / "project.toml"
    project.write_text(project.read_text(encoding="utf-8").replace(
        '[control]\nvertical_crs = "EPSG:6360"', '[control]\nvertical_crs = "EPSG:5703"'),
        encoding="utf-8")
    _project_in_navd88(sample, vertical_crs="EPSG:6360")
    data = load_project_data(sample / "project.toml")
    for (_, a), (_, b) in zip(data.vectors, before.vectors):
        np.testing.assert_allclose(a.coords[:, 2], b.coords[:, 2] * FT_US, rtol=1e-9)
        assert a.reading["dem"]["heights"]["vertical"]["transformed"] is True


@io
def test_heights_of_a_stated_datum_kept_in_a_2d_project_warn(sample):
    """Ellipsoidal heights (EPSG:4979) into a project crs without a vertical datum: XY
    transformed, the heights kept as given, and the run says so."""
    from vectoradjust.files.readers import load_project_data

    before = load_project_data(sample / "project.toml")
    _gcps_to(sample, "EPSG:4326")
    _set(sample / "project.toml", "control", crs="EPSG:4979")
    info = load_project_data(sample / "project.toml").control.reading["crs"]
    assert info["vertical"]["transformed"] is False
    assert "the heights stay in ellipsoidal height (untransformed)" in info["warning"]
    assert "states no vertical datum" in info["warning"]
    data = load_project_data(sample / "project.toml")
    np.testing.assert_allclose(data.control.xyz, before.control.xyz, atol=1e-6)


def test_the_control_transformation_reaches_the_summary(sample):
    """summary.json ``control_input`` holds the transformation; a ballpark one is one of
    the run's warnings (console, report, QGIS log)."""
    from vectoradjust.files.readers import load_project_data
    from vectoradjust.pipeline import run

    _gcps_to(sample, "EPSG:4267")
    _set(sample / "project.toml", "control", crs="EPSG:4267")
    data = load_project_data(sample / "project.toml")
    if (data.control.reading["crs"]["accuracy_m"] or 99) <= 1.0:
        pytest.skip("the NAD27 grid is installed here")
    out = run(data)
    assert out.summary["control_input"]["crs"]["warning"]
    assert any(w.startswith("control points: the transformation") and "NAD27" in w
               for w in out.summary["warnings"])
