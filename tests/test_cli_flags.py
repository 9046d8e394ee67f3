"""Every documented command-line flag, run once through ``vectoradjust.cli.main`` (issue 35).

Each test passes flags through the console script's entry point and asserts what the
flag does - a file written, a number that follows from it, a value in the output - not
only the exit status. Flags that other test files already pass through ``main`` are
mostly not repeated here; :func:`test_every_flag_is_passed_through_main_by_some_test` reads the
test sources and fails on a flag of the parser that no test passes through ``main``, and
:func:`test_the_readme_flags_are_the_parser_s` on a flag README names that the parser
does not have.

Runtime: the sample project (copied) adjusted a handful of times. The commands that
adjust only to derive something (``propagate``, ``equal-error``, ``two-step``, ``qa``)
reuse one adjustment per project (module-scoped cache in place of the adjustment they
would repeat); the figures of ``report.html`` are not rendered to PNG here.
"""

from __future__ import annotations

import ast
import csv
import json
import math
import os
import re
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from vectoradjust.cli import main

pytestmark = pytest.mark.io  # reads and writes geodata and GeoTIFFs

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "resources" / "sample"


# --------------------------------------------------------------------------- projects
def _tables(text: str) -> list:
    """``[(header, lines)]`` of a TOML text: the preamble (header ``""``), then one entry
    per table or array-of-tables header."""
    out = [("", [])]
    for line in text.splitlines():
        if re.match(r"\s*\[", line):
            out.append((line.split("#")[0].strip(), []))
        out[-1][1].append(line)
    return out


def _project(folder: Path, name: str, vectors, conflation: bool) -> Path:
    """A copy of the sample's project.toml with only the ``vectors`` entries, without
    truth (per-vertex and ``[truth]``), conflation on or off."""
    keep = []
    for header, lines in _tables((folder / "project.toml").read_text(encoding="utf-8")):
        if header == "[truth]":
            continue
        if header == "[[vectors]]":
            if not any(re.match(rf'name = "({"|".join(vectors)})"', ln) for ln in lines):
                continue
            lines = [ln for ln in lines if not ln.startswith("truth")]
        keep += lines
    keep += ["", "[conflation]", f"enabled = {'true' if conflation else 'false'}", ""]
    path = folder / name
    path.write_text("\n".join(keep), encoding="utf-8")
    return path


@pytest.fixture(scope="module")
def work(tmp_path_factory):
    """The sample copied, with ``fast.toml`` (OSM and TNM, no truth, no conflation) and
    ``osm.toml`` (OSM alone, no truth, conflation on)."""
    root = tmp_path_factory.mktemp("cli_flags")
    shutil.copytree(SAMPLE, root / "sample")
    d = root / "sample"
    _project(d, "fast.toml", ["OSM", "TNM"], conflation=False)
    _project(d, "osm.toml", ["OSM"], conflation=True)
    return d


@pytest.fixture(scope="module")
def strip(tmp_path_factory):
    """A simulated strip of three images I01, I02, I03 (80 % overlap: every pair has
    common points, so "every pair" differs from "consecutive pairs")."""
    from vectoradjust.simulate import make_scenario, write_project

    out = tmp_path_factory.mktemp("strip")
    return write_project(make_scenario(3, n_images=3, grid=(2, 2), databases=("OSM",)), out)


@pytest.fixture(scope="module", autouse=True)
def _no_report_figures():
    """The report's figures are not rendered here (the flags do not change them)."""
    pytest.importorskip("geopandas")  # (here: deselected with -m "not io", not skipped)
    pytest.importorskip("rasterio")
    from vectoradjust.files.report import listings, page, sections

    with pytest.MonkeyPatch.context() as mp:
        for mod in (sections, listings, page):  # where the report looks _img up
            mp.setattr(mod, "_img", lambda fig, alt, caption: "<p>figure</p>")
        yield


@pytest.fixture(scope="module")
def adjusted():
    """One adjustment per project for the commands that derive quantities from it:
    ``propagate``, ``equal-error`` and ``two-step`` call ``cli.propagate._adjust``."""
    from vectoradjust.cli import propagate

    memo: dict = {}
    original = propagate._adjust

    def once(project, quiet):
        key = str(Path(project).resolve())
        if key not in memo:
            memo[key] = original(project, True)
        return memo[key]

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(propagate, "_adjust", once)
        yield memo


def _json(path: Path) -> dict:
    return json.loads(path.read_text(encoding="utf-8"))


def _rows(path: Path) -> list:
    with open(path, newline="", encoding="utf-8") as fh:
        return list(csv.DictReader(fh))


def _ok(argv: list) -> Path:
    """Run ``vectoradjust`` with ``argv`` (exit status 0); its output directory."""
    assert main([str(a) for a in argv]) == 0, argv
    return Path(argv[argv.index("-o") + 1])


# ----------------------------------------------------------------------------- adjust
def test_adjust_datum_free_runs_a_free_network(work, tmp_path):
    out = tmp_path / "free"
    assert main(["adjust", str(work / "osm.toml"), "-o", str(out), "-q", "--no-bands",
                 "--datum", "free"]) == 0
    summary = json.loads((out / "summary.json").read_text(encoding="utf-8"))
    assert summary["datum"]["kind"] == "free network"
    assert "relative" in summary["datum"]["note"]


def test_adjust_conflation_raster_writes_the_field(work, tmp_path):
    import geopandas as gpd
    import rasterio

    out = tmp_path / "a"
    assert main(["adjust", str(work / "osm.toml"), "-o", str(out), "-q", "--no-bands",
                 "--conflation-raster"]) == 0
    tif = out / "conflation_OSM.tif"
    assert tif.is_file() and [p.name for p in out.glob("conflation_*")] == [tif.name]
    with rasterio.open(tif) as ds:
        assert ds.count == 5 and ds.crs.to_epsg() == 32616
        assert ds.descriptions == ("dX (m)", "dY (m)", "dZ (m)", "CE90 (m)", "LE90 (m)")
        bands = ds.read(masked=True)
        bounds = ds.bounds
    ok = ~bands.mask.any(axis=0)
    assert ok.sum() > 1000
    osm = gpd.read_file(work / "osm_roads.shp")
    x0, y0, x1, y1 = osm.total_bounds  # the grid covers the database
    assert bounds.left <= x0 and bounds.right >= x1 and bounds.bottom <= y0 and bounds.top >= y1
    # the field is adjusted - database: its trend is minus the database's estimated offset
    # (database - images), so the grid's median displacement is that offset reversed
    entry = next(e for e in _json(out / "summary.json")["databases"] if e["name"] == "OSM")
    off = entry["offset"]["values"]
    assert math.hypot(*off) > 1.0
    for band, o in zip((0, 1), off):
        assert float(np.median(bands.data[band][ok])) == pytest.approx(-o, abs=0.05)
    assert np.all(bands.data[3][ok] > 0) and np.all(bands.data[4][ok] > 0)  # CE90, LE90


# ---------------------------------------------------------------------------- compare
def test_compare_format_shp_writes_shapefiles(work, tmp_path):
    assert main(["compare", str(work / "osm.toml"), "-o", str(tmp_path), "-q",
                 "--format", "shp"]) == 0
    names = {p.name for p in (tmp_path / "OSM").iterdir()}
    assert {"shape_points.shp", "features.shp", "control_points.shp"} <= names
    assert not any(n.endswith(".gpkg") for n in names)
    assert (tmp_path / "compare.csv").is_file()


# ------------------------------------------------------------------------------- demo
def test_demo_format_shp_quietly(work, tmp_path, monkeypatch, capsys):
    """``demo --format shp -q`` on the sample cut to OSM (the demo's own project stands
    in for the packaged one: same command, smaller input)."""
    from vectoradjust.cli import demo as cli_demo

    demo = work.parent / "demo_sample"
    if not demo.exists():
        shutil.copytree(work, demo)
        shutil.copy(work / "osm.toml", demo / "project.toml")
    monkeypatch.setattr(cli_demo, "sample_project_dir", lambda: demo)
    assert main(["demo", "-o", str(tmp_path), "--format", "shp", "-q"]) == 0
    for part in ("all", "compare/OSM", "satellite"):
        names = {p.name for p in (tmp_path / part).iterdir()}
        assert "shape_points.shp" in names and not any(n.endswith(".gpkg") for n in names)
    out, err = capsys.readouterr()
    assert "vectoradjust demo:" in out and "satellite triplet" in out
    # -q: no progress lines (stderr is no terminal: they would be plain lines) and no
    # adjustment summary
    assert err == "" and "vectoradjust adjust:" not in out


# ------------------------------------------------------------------------------- qa
_QA_RUNS: dict = {}


@pytest.fixture
def qa_once(monkeypatch):
    """``qa`` adjusts with ``pipeline.run``: once per project and --vectors here."""
    import vectoradjust.pipeline as pipeline

    original = pipeline.run

    def once(data, vectors=None, **kw):
        key = (str(data.source), tuple(vectors or ()))
        if key not in _QA_RUNS:
            _QA_RUNS[key] = original(data, vectors=vectors)
        return _QA_RUNS[key]

    monkeypatch.setattr(pipeline, "run", once)


def _qa(argv: list) -> dict:
    return _json(_ok(argv) / "qa.json")


def _stage(doc, name) -> dict:
    return next(s for s in doc["stages"] if s["name"] == name)


def test_qa_topographic_map_flags(work, tmp_path, qa_once):
    doc = _qa(["qa", work / "fast.toml", "-o", tmp_path, "-q", "--product", "topographic-map",
               "--scale", "1:5000", "--contour-interval", "2.5", "--pixel-size", "0.015",
               "--point-rule", "mean", "--vectors", "OSM"])
    spec = doc["specification"]
    assert (spec["product"], spec["map_scale"], spec["contour_interval"]) == \
        ("topographic map", 5000.0, 2.5)
    block = doc["tolerances"]["block"]
    # PHOTOMOD: 0.2 mm (control) and 0.3 mm (check) at map scale in XY, 0.15 contour
    # intervals for control in Z
    assert block["gcp_xy"] == pytest.approx(0.2e-3 * 5000)
    assert block["check_xy"] == pytest.approx(0.3e-3 * 5000)
    assert block["gcp_z"] == pytest.approx(0.15 * 2.5)
    # --pixel-size 0.015 mm: the parallaxes in pixels of that size
    assert doc["pixel_size_mm"] == 0.015 and "--pixel-size" in doc["pixel_size_source"]
    pair = doc["stereo_pairs"][0]
    assert pair["mean_px"] == pytest.approx(pair["mean_um"] / 15.0)
    assert doc["tolerances"]["relative_orientation"]["mean_mm"] == pytest.approx(0.5 * 0.015)
    # --point-rule mean: a point fails over the mean tolerance itself (limit: twice it)
    gcp = _stage(doc, "block: GCP XY")
    assert gcp["point_tolerance"] == gcp["tolerance"] == pytest.approx(1.0)
    # --vectors OSM: TNM's measured shape points are not in the adjustment
    ro = _stage(doc, "relative orientation L-R: mean |py|")
    ids = [p["id"] for p in ro["points"]]
    assert any(i.startswith("4134") for i in ids) and not any(i.startswith("TNM-") for i in ids)
    measured = {r["point_id"] for r in _rows(work / "image_points.csv")}
    assert any(i.startswith("TNM-") for i in measured)


def test_qa_terrain_sets_the_orthomosaic_tolerances(work, tmp_path, qa_once):
    # PHOTOMOD: orthomosaic 0.5 mm (flat, hilly) / 0.7 mm (mountainous) at its scale,
    # seamlines 0.7 / 1.0 mm
    for terrain, xy_mm, seam_mm in (("flat", 0.5, 0.7), ("mountainous", 0.7, 1.0)):
        doc = _qa(["qa", work / "fast.toml", "-o", tmp_path / terrain, "-q", "--product",
                   "orthomosaic", "--scale", "2000", "--terrain", terrain, "--vectors", "OSM"])
        assert doc["specification"]["terrain"] == terrain
        assert doc["specification"]["orthophoto_scale"] == 2000.0
        om = doc["tolerances"]["orthomosaic"]
        assert om["xy_m"] == pytest.approx(xy_mm * 1e-3 * 2000)
        assert _stage(doc, "orthomosaic: seamlines")["tolerance"] == \
            pytest.approx(seam_mm * 1e-3 * 2000)
        gcp = _stage(doc, "block: GCP XY")
        assert gcp["point_tolerance"] == pytest.approx(2 * gcp["tolerance"])  # limit rule


def test_qa_pairs_all_takes_every_overlapping_pair(strip, tmp_path, qa_once):
    pairs = {}
    for which in ("consecutive", "all"):
        doc = _qa(["qa", strip, "-o", tmp_path / which, "-q", "--product", "topographic map",
                   "--scale", "2000", "--contour-interval", "1", "--pairs", which])
        pairs[which] = {(p["left"], p["right"]) for p in doc["stereo_pairs"]}
    assert pairs["consecutive"] == {("I01", "I02"), ("I02", "I03")}
    assert pairs["all"] == pairs["consecutive"] | {("I01", "I03")}


# -------------------------------------------------------------------------- propagate
def _propagate(argv: list) -> dict:
    return _json(_ok(argv) / "propagate.json")


@pytest.fixture(scope="module")
def fast_run(work, adjusted):
    """The adjustment of fast.toml that ``propagate`` reuses."""
    from vectoradjust.cli import propagate

    return propagate._adjust(str(work / "fast.toml"), True)


def _osm_points(run, k):
    db = next(d for d in run.databases if d.name == "OSM")
    return [str(i) for i in db.shape.vertex_ids[db.vertex_point >= 0][:k]]


def test_propagate_distance_2d_and_3d(work, tmp_path, fast_run):
    proj = work / "fast.toml"
    a, b = _osm_points(fast_run, 1)[0], "GCP05"
    d2 = _propagate(["propagate", proj, "-o", tmp_path / "2", "-q", "--distance", a, b])
    d3 = _propagate(["propagate", proj, "-o", tmp_path / "3", "-q", "--distance", a, b, "--3d"])
    d2, d3 = d2["results"][0], d3["results"][0]
    xyz = fast_run.result.xyz[d2["points"]]
    assert d3["points"] == d2["points"] and d2["point_ids"] == [a, b]
    dx, dy, dz = xyz[1] - xyz[0]
    assert d2["value"] == pytest.approx(math.hypot(dx, dy), rel=1e-12)
    assert d3["value"] == pytest.approx(math.sqrt(dx * dx + dy * dy + dz * dz), rel=1e-12)
    assert abs(dz) > 0.1 and d3["value"] > d2["value"]
    assert d3["sigma"] != d2["sigma"]


def test_propagate_length_and_mean_height(work, tmp_path, fast_run):
    proj = work / "fast.toml"
    a, b, c = _osm_points(fast_run, 3)
    ln = _propagate(["propagate", proj, "-o", tmp_path / "l", "-q", "--length", a, b, c])
    mh = _propagate(["propagate", proj, "-o", tmp_path / "h", "-q", "--mean-height", a, b, c])
    ln, mh = ln["results"][0], mh["results"][0]
    xyz = fast_run.result.xyz[ln["points"]]
    assert ln["point_ids"] == [a, b, c]
    assert ln["value"] == pytest.approx(np.hypot(*np.diff(xyz[:, :2], axis=0).T).sum(),
                                        rel=1e-12)
    assert mh["quantity"] == "mean height" and mh["points"] == ln["points"]
    assert mh["value"] == pytest.approx(float(np.mean(xyz[:, 2])), rel=1e-12)
    # the points are correlated: the full covariance gives another sigma than without
    assert mh["sigma"] > 0 and mh["sigma"] != pytest.approx(mh["sigma_no_cov"], rel=1e-3)


def test_propagate_profile_of_a_database(work, tmp_path, fast_run, capsys):
    proj = work / "fast.toml"
    db = next(d for d in fast_run.databases if d.name == "OSM")
    fid = str(db.shape.layer.feature_ids[0])
    prof = _propagate(["propagate", proj, "-o", tmp_path, "-q", "--profile", fid,
                       "--database", "OSM"])["profile"]
    assert prof["database"] == "OSM" and prof["feature_id"] == fid
    assert len(prof["vertices"]) == int(np.sum(db.shape.layer.vertex_feature == 0))
    capsys.readouterr()
    # the same feature looked for in TNM: not there
    assert main(["propagate", str(proj), "-o", str(tmp_path / "t"), "-q", "--profile", fid,
                 "--database", "TNM"]) == 1
    err = capsys.readouterr().err
    assert "TNM" in err and repr(fid) in err


# ------------------------------------------------------------------ equal-error, two-step
def test_equal_error_images_flat_and_spacing(strip, tmp_path, adjusted):
    assert main(["equal-error", str(strip), "-o", str(tmp_path / "a"), "-q", "--images",
                 "I01", "I03", "--flat", "--spacing", "40"]) == 0
    assert main(["equal-error", str(strip), "-o", str(tmp_path / "b"), "-q", "--spacing",
                 "20"]) == 0
    a, b = _json(tmp_path / "a" / "equal_error.json"), _json(tmp_path / "b" / "equal_error.json")
    assert a["images"] == ["I01", "I03"] and b["images"] == ["I01", "I02"]  # default: first two
    assert a["heights"] == "mean" and b["heights"].endswith("dem.tif")
    assert a["transform"][0] == 40.0 and b["transform"][0] == 20.0
    assert a["transform"][4] == -40.0 and b["transform"][4] == -20.0
    # I01-I03 is the longer base (two image spacings): better heights than I01-I02
    assert a["sigma_z"]["min"] < b["sigma_z"]["min"]


def test_two_step_images_and_method(strip, tmp_path, adjusted):
    assert main(["two-step", str(strip), "-o", str(tmp_path / "a"), "-q", "--images",
                 "I02", "I03", "--method", "coplanarity"]) == 0
    assert main(["two-step", str(strip), "-o", str(tmp_path / "b"), "-q"]) == 0
    a, b = _json(tmp_path / "a" / "two_step.json"), _json(tmp_path / "b" / "two_step.json")
    assert a["images"] == ["I02", "I03"] and a["method"] == "coplanarity"
    assert b["images"] == ["I01", "I02"] and b["method"] == "collinearity"
    assert a["n_points"] > 0 and a["relative_s0"] != b["relative_s0"]


# ------------------------------------------------------------------------ buffer-test
# ------------------------------------------------------------------------------- dtm
def _dtm(argv: list) -> tuple:
    out = _ok(argv)
    return _json(out / "dtm.json"), out


def test_dtm_cell_interpolation_contour_interval(work, tmp_path, fast_run):
    import geopandas as gpd
    import rasterio

    proj = work / "fast.toml"
    a, out_a = _dtm(["dtm", proj, "-o", tmp_path / "a", "-q", "--cell", "10",
                     "--interpolation", "tin", "--contour-interval", "2"])
    b, out_b = _dtm(["dtm", proj, "-o", tmp_path / "b", "--quiet", "--cell", "20",
                     "--interpolation", "bicubic", "--contour-interval", "0.5"])
    assert (a["summary"]["method"], b["summary"]["method"]) == ("tin", "bicubic")
    with rasterio.open(out_a / "dtm_accuracy.tif") as ra, \
            rasterio.open(out_b / "dtm_accuracy.tif") as rb:
        assert ra.res == (10.0, 10.0) and rb.res == (20.0, 20.0) and ra.count == 5
        sig = ra.read(2, masked=True)
        assert float(np.ma.median(sig)) == pytest.approx(a["summary"]["sigma"]["median"],
                                                         rel=1e-5)
    lv = {k: gpd.read_file(o / "dtm_contours.gpkg", layer="contours")["level"]
          for k, o in (("a", out_a), ("b", out_b))}
    assert np.allclose(np.mod(lv["a"], 2.0), 0.0) and a["contours"]["interval"] == 2.0
    assert np.any(~np.isclose(np.mod(lv["b"], 1.0), 0.0))  # the half-metre levels
    # --cell: the terrain term uses max(cell, mean TIN edge); the cells count falls 4 x
    assert a["summary"]["cells"] > 3 * b["summary"]["cells"]


def test_dtm_source_dem_node_sigma_correlation_length(work, tmp_path, fast_run):
    proj = work / "fast.toml"
    ind, _ = _dtm(["dtm", proj, "-o", tmp_path / "i", "-q", "--source", "dem",
                   "--interpolation", "bilinear", "--node-sigma", "0.3"])
    cor, _ = _dtm(["dtm", proj, "-o", tmp_path / "c", "-q", "--source", "dem",
                   "--interpolation", "bilinear", "--node-sigma", "0.3",
                   "--correlation-length", "1000"])
    assert ind["summary"]["source"] == "dem" and ind["summary"]["node_sigma"] == 0.3
    # 5 m cells centred between four 5 m DEM nodes: independent nodes give sigma / 2,
    # nodes correlated over 1000 m nearly sigma itself
    assert ind["summary"]["sigma_interpolation"]["median"] == pytest.approx(0.15, rel=1e-6)
    assert cor["summary"]["correlation_length"] == 1000.0
    assert cor["summary"]["sigma_interpolation"]["median"] == pytest.approx(0.3, rel=0.01)


def test_dtm_profile_volume_reference_height(work, tmp_path, fast_run):
    proj = work / "fast.toml"
    poly = ["506300", "4474900", "506400", "4474900", "506400", "4475000"]
    low, _ = _dtm(["dtm", proj, "-o", tmp_path / "l", "-q", "--cell", "10", "--volume", *poly,
                   "--profile", "506200", "4475000", "506500", "4475100"])
    high, _ = _dtm(["dtm", proj, "-o", tmp_path / "h", "-q", "--cell", "10", "--volume", *poly,
                    "--reference-height", "190"])
    prof = low["profile"]
    assert prof["chainage"][-1] == pytest.approx(math.hypot(300, 100))
    assert prof["x"][0] == 506200 and prof["y"][-1] == 4475100
    assert all(s > 0 for s in prof["sigma"]) and len(prof["sigma_step"]) == len(prof["x"]) - 1
    v_low, v_high = low["volume"], high["volume"]
    assert v_high["reference"] == 190.0 and v_high["cells"] == v_low["cells"] > 10
    # the volume is linear in the reference plane; its sigma does not depend on it
    assert v_low["volume"] - v_high["volume"] == pytest.approx(
        v_low["area"] * (190.0 - v_low["reference"]), rel=1e-9)
    assert v_high["sigma"] == pytest.approx(v_low["sigma"], rel=1e-12)
    assert "profile" not in high


def test_buffer_test_layers_and_exact(tmp_path):
    """A tested line crossing the reference's round end cap at distance 1 from its end:
    the exact share inside a buffer of width 2 is 2 sqrt(2^2 - 1^2) / 10."""
    import geopandas as gpd
    from shapely.geometry import LineString

    path = tmp_path / "lines.gpkg"
    for name, geom in (("decoy", LineString([(500, 500), (600, 500)])),
                       ("tested", LineString([(11, -5), (11, 5)])),
                       ("reference", LineString([(0, 0), (10, 0)]))):  # decoy is the default
        gpd.GeoDataFrame({"id": [1]}, geometry=[geom], crs="EPSG:32616").to_file(
            path, layer=name, driver="GPKG")
    assert main(["buffer-test", str(path), str(path), "--tested-layer", "tested",
                 "--reference-layer", "reference", "--widths", "2,1.5", "--exact",
                 "-o", str(tmp_path / "exact.csv")]) == 0
    assert main(["buffer-test", str(path), str(path), "--tested-layer", "tested",
                 "--reference-layer", "reference", "--widths", "2,1.5",
                 "-o", str(tmp_path / "polygon.csv")]) == 0
    share = {m: {float(r["width"]): float(r["share"]) for r in _rows(tmp_path / f"{m}.csv")}
             for m in ("exact", "polygon")}

    def inside(radius):  # share of the tested line within ``radius`` of the end point
        return 2 * math.sqrt(radius * radius - 1) / 10

    for w in (2.0, 1.5):
        assert share["exact"][w] == pytest.approx(inside(w), rel=1e-12)
        # polygons are narrower on round caps, by at most 0.03 % of the width (README)
        assert inside(w * (1 - 0.0003)) <= share["polygon"][w] < inside(w) - 1e-6


# ------------------------------------------------------------------------------ study
def test_study_gcp_random_repeats_seed_vectors(work, tmp_path):
    assert main(["study", "gcp", str(work / "fast.toml"), "-o", str(tmp_path), "-q",
                 "--random", "4", "--repeats", "2", "--seed", "7", "--vectors", "OSM"]) == 0
    rows = _rows(tmp_path / "gcp_study.csv")
    assert [(r["label"], r["repeat"]) for r in rows] == [("4 random", "1"), ("4 random", "2")]
    control = [r["point_id"] for r in _rows(work / "gcps.csv") if r["role"] == "control"]

    def drawn(seed, r):  # the documented draw: default_rng([seed, k, repeat])
        pick = np.sort(np.random.default_rng([seed, 4, r]).choice(len(control), 4,
                                                                     replace=False))
        return " ".join(control[i] for i in pick)

    assert [r["control_ids"] for r in rows] == [drawn(7, 0), drawn(7, 1)]
    assert [drawn(0, 0), drawn(0, 1)] != [drawn(7, 0), drawn(7, 1)]  # the seed matters
    assert all(int(r["n_check"]) == 6 + 24 - 4 for r in rows)  # held out become checks
    assert "OSM_rmse" in rows[0] and "TNM_rmse" not in rows[0]  # --vectors OSM
    assert all(float(r["OSM_rmse"]) > 0 for r in rows)


def test_study_shift_dx_dy_is_recovered(work, tmp_path):
    assert main(["study", "shift", str(work / "fast.toml"), "-o", str(tmp_path), "-q",
                 "--dx", "7", "--dy", "-4", "--vectors", "OSM"]) == 0
    (row,) = _rows(tmp_path / "shift_study.csv")
    assert row["database"] == "OSM" and (float(row["dx"]), float(row["dy"])) == (7.0, -4.0)
    # V = adjusted - database: shifting the database by (dx, dy) moves V by -(dx, dy)
    assert float(row["recovered_dx"]) == pytest.approx(7.0, abs=0.1)
    assert float(row["recovered_dy"]) == pytest.approx(-4.0, abs=0.1)
    assert float(row["adjusted_moved_max"]) < 1.0  # the images hold the adjusted points


def test_study_identification_seed_repeats_reweight_stated_sigma(tmp_path):
    from vectoradjust.files.study import identification_study

    assert main(["study", "identification", "-o", str(tmp_path), "-q", "--errors", "1",
                 "--databases", "TNM", "--seed", "3", "--repeats", "2", "--reweight", "none",
                 "--no-stated-sigma"]) == 0
    rows = _rows(tmp_path / "identification_study.csv")
    assert [(r["seed"], r["database"]) for r in rows] == [("3", "TNM"), ("4", "TNM")]

    def first(**kw):
        return identification_study([1.0], seed=3, repeats=1, databases=["TNM"], **kw)[0]

    same = first(reweight="none", state_sigma=False)
    for key in ("rmse", "adj_truth_rmse", "within_ce90", "estimated_identification"):
        assert float(rows[0][key]) == pytest.approx(same[key], rel=1e-9), key
    # --reweight none: the two-pass reweighting (the default) adjusts otherwise
    two_pass = first(reweight="two-pass", state_sigma=False)
    assert abs(two_pass["adj_truth_rmse"] - same["adj_truth_rmse"]) > 1e-4
    # --no-stated-sigma: not stated, the run estimates it (from the simulation's truth
    # here) and uses it; stated, the simulated 1 m itself
    stated = first(reweight="none", state_sigma=True)
    assert same["within_ce90"] > 0.8 and stated["within_ce90"] > 0.8
    assert same["adj_truth_rmse"] != stated["adj_truth_rmse"]  # another sigma was used


# ------------------------------------------------------------------------ adjust-many
def test_adjust_many_workers_format_quiet(work, tmp_path, monkeypatch, capsys):
    dask = pytest.importorskip("dask")
    seen = []
    compute = dask.compute

    def spy(*args, **kw):
        seen.append(kw)
        return compute(*args, **kw)

    monkeypatch.setattr(dask, "compute", spy)
    assert main(["adjust-many", str(work / "osm.toml"), "-o", str(tmp_path), "--scheduler",
                 "threads", "--workers", "1", "--format", "shp", "--no-bands", "--no-report",
                 "-q"]) == 0
    assert [kw.get("num_workers") for kw in seen] == [1]  # --workers reaches Dask
    (row,) = _rows(tmp_path / "many_summary.csv")
    assert row["status"] == "ok"
    names = {p.name for p in (tmp_path / row["name"]).iterdir()}
    assert "shape_points.shp" in names and not any(n.endswith(".gpkg") for n in names)
    out, err = capsys.readouterr()
    assert out == "" and err == ""  # -q


# ---------------------------------------------------------------------------- measure
@pytest.fixture(scope="module")
def pair_project(tmp_path_factory):
    """A rendered stereo pair (400 px, as test_measure_cli's 1000 px one) as a project,
    the left image's control points measured (``measured.csv``), ``true.json`` (a
    summary.json with the true orientation) and ``noR.toml`` (image R's file missing)."""
    from test_measure_cli import _write_project

    from vectoradjust.simulate.measure_scene import stereo_pair

    tmp = tmp_path_factory.mktemp("pair")
    pair = stereo_pair(400, seed=1, sigma_position=0.5, sigma_attitude=0.02, supersample=1)
    proj = _write_project(tmp, pair)
    images = [{"id": k, "position": [float(v) for v in g.eo[:3]],
               "attitude": [float(v) for v in np.degrees(g.eo[3:])],
               "sigma_position": 0.01, "sigma_attitude": 0.0001}
              for k, g in pair.true.items()]
    (tmp / "true.json").write_text(json.dumps({"images": images}), encoding="utf-8")
    text = proj.read_text(encoding="utf-8")
    assert 'path = "R.tif"' in text
    (tmp / "noR.toml").write_text(text.replace('path = "R.tif"', 'path = "gone.tif"'),
                                  encoding="utf-8")
    return proj


def _transfer(argv: list) -> list:
    return _rows(_ok(argv) / "transfer.csv")


def _off(rows) -> float:
    """Median distance (px) between the matched and the predicted position."""
    return float(np.median([math.hypot(float(r["col"]) - float(r["pred_col"]),
                                       float(r["row"]) - float(r["pred_row"])) for r in rows]))


def test_measure_transfer_flags(pair_project, tmp_path):
    p, m = pair_project, pair_project.parent / "measured.csv"
    base = _transfer(["measure", "transfer", p, "-o", tmp_path / "0", "-q", "--measured", m])
    assert len(base) == 12 and sum(r["flag_text"] == "" for r in base) >= 10
    flagged = {
        "low_correlation": _transfer(["measure", "transfer", p, "-o", tmp_path / "1", "-q",
                                      "--measured", m, "--min-ncc", "0.9999"]),
        "poor_precision": _transfer(["measure", "transfer", p, "-o", tmp_path / "2", "-q",
                                     "--measured", m, "--max-sigma", "0.0001"]),
        "window_clipped": _transfer(["measure", "transfer", p, "-o", tmp_path / "3", "-q",
                                     "--measured", m, "--max-radius", "3"]),
        # the height's uncertainty widens the search window along the base: past the
        # largest radius (40 px)
        "window_clipped ": _transfer(["measure", "transfer", p, "-o", tmp_path / "4", "-q",
                                      "--measured", m, "--sigma-height", "300"]),
    }
    for flag, rows in flagged.items():
        assert [r["point_id"] for r in rows] == [r["point_id"] for r in base]
        assert all(flag.strip() in r["flag_text"] for r in rows), (flag, rows)
        assert not any(flag.strip() in r["flag_text"] for r in base)
    # --orientation: the true orientation predicts the points within a fraction of a pixel
    true = _transfer(["measure", "transfer", p, "-o", tmp_path / "5", "-q", "--measured", m,
                      "--orientation", p.parent / "true.json"])
    assert _off(true) < 0.3 < _off(base)


def test_measure_transfer_image_override(pair_project, tmp_path, capsys):
    no_r, m = pair_project.parent / "noR.toml", pair_project.parent / "measured.csv"
    assert main(["measure", "transfer", str(no_r), "-o", str(tmp_path), "-q", "--measured",
                 str(m)]) == 1
    assert "gone.tif" in capsys.readouterr().err
    rows = _transfer(["measure", "transfer", no_r, "-o", tmp_path, "-q", "--measured", m,
                      "--image", f"R={pair_project.parent / 'R.tif'}"])
    assert sum(r["flag_text"] == "" for r in rows) >= 10 and {r["image_id"] for r in rows} == {"R"}


def test_measure_predict_road_width(pair_project, tmp_path):
    located = {}
    for width in ("6", "30"):
        out = tmp_path / width
        assert main(["measure", "predict", str(pair_project), "-o", str(out), "-q", "--roads",
                     "--chips", "none", "--road-width", width]) == 0
        rows = _rows(out / "automatic_points.csv")
        located[width] = sum(r["accepted"] == "True" for r in rows)
    # the pair's roads are 6 m wide: a 30 m road is not found at the junctions
    assert located["6"] >= 10 > located["30"]


# ------------------------------------------------------------------ exit status, --version
def test_interrupt_exits_130(work, tmp_path):
    """Ctrl-C (SIGINT) during ``adjust``: one line on stderr, exit status 130."""
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(
        [str(ROOT / "core"), os.environ.get("PYTHONPATH", "")]), VECTORADJUST_WORKERS="1")
    out = tmp_path / "o"
    proc = subprocess.Popen([sys.executable, "-m", "vectoradjust", "adjust",
                             str(work / "fast.toml"), "-o", str(out), "--no-bands"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env, text=True)
    try:
        first = proc.stderr.readline()  # the progress bar's first line: the command runs
        assert first.startswith("adjust ["), first
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 130, err
    assert err.rstrip().endswith("vectoradjust: interrupted") and "Traceback" not in err
    assert not (out / "summary.json").exists()


def test_keyboard_interrupt_and_cancel_inside_a_command(work, tmp_path, monkeypatch, capsys):
    import vectoradjust.pipeline as pipeline
    from vectoradjust.errors import CancelledError

    def interrupted(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(pipeline, "run", interrupted)
    assert main(["qa", str(work / "fast.toml"), "-o", str(tmp_path), "-q", "--product",
                 "orthophoto", "--scale", "2000"]) == 130
    assert capsys.readouterr().err.strip() == "vectoradjust: interrupted"

    def cancelled(*a, **k):
        raise CancelledError("The adjustment was cancelled", "Run it again when ready")

    monkeypatch.setattr(pipeline, "run", cancelled)
    assert main(["adjust", str(work / "fast.toml"), "-o", str(tmp_path), "-q",
                 "--no-bands"]) == 130
    assert "cancelled: The adjustment was cancelled" in capsys.readouterr().err
    assert not (tmp_path / "summary.json").exists()


def test_version(capsys):
    from vectoradjust import __version__

    with pytest.raises(SystemExit, match="^0$"):
        main(["--version"])
    assert capsys.readouterr().out.strip() == f"vectoradjust {__version__}"


# ------------------------------------------------------------ every flag has its test
def _parser_flags() -> dict:
    """``{"study gcp": {"--random", ...}, ...}`` from the console script's parser."""
    import argparse

    from vectoradjust.cli.commands import build_parser

    out: dict = {}

    def walk(p, path):
        for a in p._actions:
            if isinstance(a, argparse._SubParsersAction):
                for name, sp in a.choices.items():
                    walk(sp, [*path, name])
            elif a.option_strings and not isinstance(a, argparse._HelpAction):
                out.setdefault(" ".join(path), set()).update(a.option_strings)

    walk(build_parser(), [])
    return out


def _main_calls() -> dict:
    """Flags passed to ``main([...])`` per command, in the test files that import ``main``
    from ``vectoradjust.cli`` or ``vectoradjust.cli.commands``; a call of a function of
    the file that calls ``main`` with the list it is given counts too (``_ok([...])``)."""
    commands = sorted(_parser_flags(), key=len, reverse=True)
    seen: dict = {}
    for path in sorted((ROOT / "tests").glob("test_*.py")):
        tree = ast.parse(path.read_text(encoding="utf-8"))
        if not any(isinstance(n, ast.ImportFrom) and n.module in (
                "vectoradjust.cli", "vectoradjust.cli.commands")
                and any(a.name == "main" and a.asname in (None, "main") for a in n.names)
                for n in ast.walk(tree)):
            continue
        callers, grew = {"main"}, True
        while grew:  # the file's functions that call main, directly or through another
            found = {f.name for f in ast.walk(tree) if isinstance(f, ast.FunctionDef)
                     and any(isinstance(c, ast.Call) and isinstance(c.func, ast.Name)
                             and c.func.id in callers for c in ast.walk(f))}
            grew = not found <= callers
            callers |= found
        for n in ast.walk(tree):
            if not (isinstance(n, ast.Call) and isinstance(n.func, ast.Name)
                    and n.func.id in callers and n.args and isinstance(n.args[0], ast.List)):
                continue
            words = [e.value for e in n.args[0].elts
                     if isinstance(e, ast.Constant) and isinstance(e.value, str)]
            cmd = next((c for c in commands if c and words[:len(c.split())] == c.split()), "")
            seen.setdefault(cmd, set()).update(w for w in words if w.startswith("-"))
    return seen


def test_every_flag_is_passed_through_main_by_some_test():
    seen = _main_calls()
    missing = []
    for cmd, flags in sorted(_parser_flags().items()):
        if cmd == "":  # --version (test_version, SystemExit)
            continue
        for f in sorted(flags):
            aliases = {f}
            if f in ("-o", "--out"):
                aliases = {"-o", "--out"}
            if f in ("-q", "--quiet"):
                aliases = {"-q", "--quiet"}
            if not aliases & seen.get(cmd, set()):
                missing.append(f"{cmd} {f}")
    assert not missing, "flags no test passes through vectoradjust.cli.main: " + ", ".join(
        missing)


def test_the_readme_flags_are_the_parser_s():
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    block = readme.split("## Command line", 1)[1].split("```", 2)[1]
    flags = _parser_flags()
    unknown = []
    lines = [ln for ln in block.splitlines() if ln.startswith("vectoradjust ")]
    assert len(lines) >= 14
    for line in lines:
        words = line.split()[1:]
        cmd = next(c for c in sorted(flags, key=len, reverse=True)
                   if c and words[:len(c.split())] == c.split())
        for f in re.findall(r"(?<![\w-])(--?[a-z0-9][\w-]*)", line):
            if f not in flags[cmd]:
                unknown.append(f"{cmd} {f}")
    assert not unknown, unknown


# ------------------------------------------------------------------ import-images (drone)
def _drone_folder(folder: Path) -> Path:
    """Three JPEGs with EXIF GPS (written by GDAL) flown north in UTM 33N."""
    import warnings

    import rasterio
    import rasterio.shutil
    from pyproj import Transformer
    from rasterio.io import MemoryFile

    folder.mkdir()
    lon, lat = Transformer.from_crs("EPSG:32633", "EPSG:4326", always_xy=True).transform(
        [500000.0] * 3, [5300000.0, 5300050.0, 5300100.0])
    for k in range(3):
        tags = {"EXIF_Make": "DJI", "EXIF_Model": "FC6310R", "EXIF_FocalLength": "(8.8)",
                "EXIF_FocalLengthIn35mmFilm": "24", "EXIF_GPSLatitudeRef": "N",
                "EXIF_GPSLongitudeRef": "E", "EXIF_GPSAltitude": "(150)",
                "EXIF_GPSLatitude": f"({lat[k]:.9f})", "EXIF_GPSLongitude": f"({lon[k]:.9f})",
                "EXIF_DateTimeOriginal": f"2020:06:01 10:00:0{k}"}
        with warnings.catch_warnings(), MemoryFile() as mf:
            warnings.simplefilter("ignore")
            with mf.open(driver="GTiff", width=60, height=40, count=1, dtype="uint8") as m:
                m.write(np.zeros((1, 40, 60), "uint8"))
                m.update_tags(**tags)
            with mf.open() as m:
                rasterio.shutil.copy(m, str(folder / f"IMG_{k}.jpg"), driver="JPEG")
    return folder


def test_import_images_flags(tmp_path, capsys):
    from vectoradjust.files.project import load_project

    folder = _drone_folder(tmp_path / "images")
    cams = tmp_path / "reconstruction.json"
    cams.write_text(json.dumps([{"cameras": {"c": {
        "projection_type": "brown", "width": 60, "height": 40, "focal_x": 0.66,
        "focal_y": 0.66, "c_x": 0.0, "c_y": 0.0, "k1": -0.26, "k2": 0.1, "k3": 0.0,
        "p1": 0.001, "p2": 0.0}}}]))
    plain = tmp_path / "plain" / "p.toml"
    assert main(["import-images", str(folder), "-o", str(plain)]) == 0
    assert "3 images" in capsys.readouterr().out
    tuned = tmp_path / "tuned" / "p.toml"
    assert main(["import-images", str(folder), "--out", str(tuned), "--crs", "EPSG:32634",
                 "--height", "ellipsoidal", "--gnss-sigma", "2", "4", "--camera-json",
                 str(cams), "--quiet"]) == 0
    assert capsys.readouterr().out == ""  # --quiet
    for p in (plain, tuned):
        (p.parent / "image_points.csv").write_text("point_id,image_id,x,y\n")
    a, b = load_project(plain), load_project(tuned)
    assert a.crs == "EPSG:32633" and b.crs == "EPSG:32634"  # --crs
    assert abs(a.images[0].position[0] - 500000.0) < 0.01
    assert abs(b.images[0].position[0] - 500000.0) > 1000  # another zone's eastings
    assert a.heights is None and "NOT known" in plain.read_text()
    assert b.heights == "ellipsoidal"  # --height
    assert a.images[0].sigma_position == (3.0, 3.0, 5.0)  # --gnss-sigma: [h, h, v]
    assert b.images[0].sigma_position == (2.0, 2.0, 4.0)
    assert a.camera.calibration.distortion_model == "none"
    assert b.camera.calibration.distortion_model == "brown"  # --camera-json
    assert b.camera.calibration.brown_coefficients[0] == -0.26
    assert a.images[1].attitude[2] == 0.0  # flown north: kappa 0


def test_measure_transfer_anisotropy_and_back_tolerance(pair_project, tmp_path):
    """--max-anisotropy (issue 28, on by default at 5) and --back-tolerance (the match
    matched back to the reference image)."""
    p, m = pair_project, pair_project.parent / "measured.csv"
    loose = _transfer(["measure", "transfer", p, "-q", "--measured", m, "-o", tmp_path / "a",
                       "--max-sigma", "0.03", "--max-anisotropy", "inf"])
    tight = _transfer(["measure", "transfer", p, "-q", "--measured", m, "-o", tmp_path / "b",
                       "--max-sigma", "0.03", "--max-anisotropy", "1.0"])
    ok = [r["flag_text"] == "" for r in loose]
    assert sum(ok) >= 8
    # a ratio of 1 flags every match whose sigmas differ (above max_sigma / 3)
    assert sum(r["flag_text"] == "" for r in tight) < sum(ok)
    assert all("poor_precision" in r["flag_text"] for r, o in zip(tight, ok)
               if o and r["flag_text"] != "")
    base = _transfer(["measure", "transfer", p, "-q", "--measured", m, "-o", tmp_path / "c"])
    err = [float(r["back_error"]) for r in base if r["flag_text"] == ""]
    assert len(err) >= 8 and max(err) <= 0.5  # accepted: back within 0.5 px
    strict = _transfer(["measure", "transfer", p, "-q", "--measured", m, "-o",
                        tmp_path / "d", "--back-tolerance", "1e-6"])
    assert all("back_mismatch" in r["flag_text"] for r, b in zip(strict, base)
               if b["flag_text"] == "")
    off = _transfer(["measure", "transfer", p, "-q", "--measured", m, "-o", tmp_path / "e",
                     "--back-tolerance", "inf"])
    assert all(r["back_error"] == "" for r in off)


# ------------------------------------------------------------------ conflate (issue 34)
def test_conflate_databases_max_distance_min_overlap_by_quiet(work, tmp_path, capsys):
    """``conflate``: ``--databases`` picks and orders the databases, ``--max-distance``
    below the roads' offsets leaves every feature unmatched, ``--min-overlap 1`` keeps
    fewer matches, ``--by rmse`` lets the smaller RMSE win every match, ``--quiet``
    prints nothing."""
    adj = _ok(["adjust", work / "fast.toml", "-o", tmp_path / "adj", "--no-bands", "-q"])
    capsys.readouterr()
    out = _ok(["conflate", adj, "-o", tmp_path / "c1", "--databases", "TNM", "OSM"])
    s = _json(out / "summary.json")
    assert list(s["databases"]) == ["TNM", "OSM"] and s["matched"] == 26
    assert "TNM" in capsys.readouterr().out
    rows = _rows(out / "conflated.csv")
    assert all(float(r["CE90"]) <= 1.01 * float(r["LoserCE90"]) for r in rows)
    out = _ok(["conflate", adj, "-o", tmp_path / "c2", "--max-distance", "0.01", "--quiet"])
    assert capsys.readouterr().out == ""
    s = _json(out / "summary.json")
    assert s["matched"] == 0 and s["features"] == 52 and s["max_distance"] == 0.01
    out = _ok(["conflate", adj, "-o", tmp_path / "c3", "--min-overlap", "1", "-q"])
    assert _json(out / "summary.json")["matched"] < 26
    out = _ok(["conflate", adj, "-o", tmp_path / "c4", "--by", "rmse", "-q"])
    rows = _rows(out / "conflated.csv")
    assert _json(out / "summary.json")["by"] == "rmse" and len(rows) == 26
    assert all(float(r["RMSE"]) <= float(r["LoserRMSE"]) for r in rows)
    assert main(["conflate", str(adj), "-o", str(adj)]) == 1  # would overwrite its summary


# ------------------------------------------------- qa production checks (issue 34, h2)
def test_qa_free_model_and_no_free_model(strip, tmp_path, qa_once):
    """``--free-model`` adds the free-model stages (sigma0, image residual RMS) and their
    ``free_model`` entry; ``--no-free-model`` leaves them out and says so."""
    on = _qa(["qa", strip, "-o", tmp_path / "on", "-q", "--product", "topographic map",
              "--scale", "2000", "--contour-interval", "1", "--pixel-size", "0.012",
              "--free-model"])
    assert on["free_model"]["sigma0"] > 0 and on["free_model"]["dof"] > 0
    assert _stage(on, "free model: sigma0")["measured"] == on["free_model"]["sigma0"]
    off = _qa(["qa", strip, "-o", tmp_path / "off", "-q", "--product", "topographic map",
               "--scale", "2000", "--contour-interval", "1", "--pixel-size", "0.012",
               "--no-free-model"])
    assert off["free_model"] == {"skipped": "--no-free-model"}
    assert not any(s["name"].startswith("free model") for s in off["stages"])
    assert any("--no-free-model" in n for n in off["notes"])
    # the zones of both stereo pairs and the triplet are there either way
    assert [z["images"] for z in off["tie_zones"]] == [["I01", "I02"], ["I02", "I03"]]
    assert [z["images"] for z in off["triplet_zones"]] == [["I01", "I02", "I03"]]


# ------------------------------------------ shared options, -o/--out, help (issue 33, h4)
CLI_DIR = ROOT / "core" / "vectoradjust" / "cli"
#: commands whose help is not yet in the style of cli/options.py (none: ``measure``'s
#: generated flags are put in the style by cli/measure.py::_help_style)
_HELP_NOT_YET: set = set()
#: option strings two commands take with different meanings (deliberately not shared)
_OTHER_MEANINGS = {
    "--profile": "propagate: a feature's height profile; dtm: a polyline X1 Y1 X2 Y2 ...",
    "--databases": "conflate: names (nargs); study identification: databases simulated",
}
#: the arguments each command with ``-o/--out`` needs besides it
_OUT_ARGV = {
    "demo": [], "adjust": ["p.toml"], "compare": ["p.toml"], "qa": ["p.toml"],
    "propagate": ["p.toml", "--distance", "A", "B"], "equal-error": ["p.toml"],
    "two-step": ["p.toml"], "buffer-test": ["a.gpkg", "b.gpkg"], "study gcp": ["p.toml"],
    "study shift": ["p.toml"], "study identification": [], "adjust-many": ["p.toml"],
    "measure predict": ["p.toml"], "measure transfer": ["p.toml", "--measured", "m.csv"],
    "import-images": ["images"], "dtm": ["p.toml"], "conflate": ["adjusted"],
}


def _subparsers(parser, path=()):
    """``[(command words, parser)]`` of every subcommand, nested ones included."""
    import argparse

    out = []
    for a in parser._actions:
        if isinstance(a, argparse._SubParsersAction):
            for name, sp in a.choices.items():
                out.append((" ".join((*path, name)), sp))
                out += _subparsers(sp, (*path, name))
    return out


def test_every_command_that_writes_takes_o_and_out():
    from vectoradjust.cli import build_parser

    with_out = {}
    for cmd, sp in _subparsers(build_parser()):
        for a in sp._actions:
            if "--out" in a.option_strings:
                with_out[cmd] = a.option_strings
    assert set(with_out) == set(_OUT_ARGV)  # a new command with --out: add it above
    assert all(v == ["-o", "--out"] for v in with_out.values()), with_out


@pytest.mark.parametrize("cmd", sorted(_OUT_ARGV))
def test_o_is_out(cmd):
    """``-o DIR`` and ``--out DIR`` give the same namespace for every command."""
    from vectoradjust.cli import build_parser

    short, long = (vars(build_parser().parse_args([*cmd.split(), *_OUT_ARGV[cmd], flag,
                                                    "where"])) for flag in ("-o", "--out"))
    assert short["out"] == "where" and short == long and callable(short["func"])


def test_o_and_out_write_the_same_table(tmp_path):
    """A real run: ``buffer-test -o`` and ``--out`` write the same CSV."""
    import geopandas as gpd
    from shapely.geometry import LineString

    path = tmp_path / "lines.gpkg"
    gpd.GeoDataFrame({"id": [1, 2]}, geometry=[LineString([(0, 0), (10, 0)]),
                                               LineString([(0, 5), (10, 5)])],
                     crs="EPSG:32616").to_file(path, driver="GPKG")
    assert main(["buffer-test", str(path), str(path), "-o", str(tmp_path / "a.csv")]) == 0
    assert main(["buffer-test", str(path), str(path), "--out", str(tmp_path / "b.csv")]) == 0
    rows = _rows(tmp_path / "a.csv")
    assert [float(r["share"]) for r in rows] == [1.0, 1.0, 1.0]  # widths 1, 2, 5: itself
    assert rows == _rows(tmp_path / "b.csv")


def _declared(sources: dict) -> dict:
    """``{option string: [file, ...]}``: where each ``-x``/``--xx`` literal is passed to
    an ``add_argument`` call in ``sources`` (``{file name: source text}``)."""
    seen: dict = {}
    for name, text in sources.items():
        for n in ast.walk(ast.parse(text)):
            if (isinstance(n, ast.Call) and isinstance(n.func, ast.Attribute)
                    and n.func.attr == "add_argument"):
                for a in n.args:
                    if (isinstance(a, ast.Constant) and isinstance(a.value, str)
                            and a.value.startswith("-")):
                        seen.setdefault(a.value, []).append(name)
    return seen


def test_no_option_is_declared_twice_outside_options():
    """An option several commands take is declared once, in cli/options.py: no option
    string is passed to ``add_argument`` twice in the other cli modules."""
    # the check finds what it should (the former commands.py declared --quiet twice)
    twice = 'p.add_argument("-q", "--quiet")\nq.add_argument("--quiet", "-q")\n'
    assert _declared({"x.py": twice})["--quiet"] == ["x.py", "x.py"]
    sources = {p.name: p.read_text(encoding="utf-8") for p in sorted(CLI_DIR.glob("*.py"))
               if p.name != "options.py"}
    assert {"adjust.py", "measure.py"} <= set(sources) and len(sources) >= 14
    seen = _declared(sources)
    twice = {k: v for k, v in seen.items() if len(v) > 1 and k not in _OTHER_MEANINGS}
    assert not twice, f"declare these once in cli/options.py: {twice}"
    assert all(len(seen.get(k, [])) <= 2 for k in _OTHER_MEANINGS)
    for shared in ("-o", "--out", "-q", "--quiet", "--format", "--vectors", "--no-bands"):
        assert shared not in seen, shared  # only through options.add_*
    assert len(_declared({"options.py": (CLI_DIR / "options.py").read_text(
        encoding="utf-8")})["--out"]) == 1


def test_help_is_in_one_style(capsys):
    """Every subcommand and option has help: lower case start (an acronym may lead), no
    trailing period, a default stated as ``(default: ...)``; ``--help`` shows the
    defaults there are and none that is None or False."""
    import argparse

    from vectoradjust.cli import build_parser

    bad = []
    for cmd, sp in _subparsers(build_parser()):
        if cmd.split()[0] in _HELP_NOT_YET:
            continue
        texts = {"(description)": sp.description}
        texts.update({"/".join(a.option_strings) or a.dest: a.help for a in sp._actions
                      if not isinstance(a, (argparse._HelpAction, argparse._SubParsersAction))})
        for what, text in texts.items():
            first = (text or "?").split()[0]
            if (not text or (first[0].isupper() and first[1:].islower())
                    or (text.endswith(".") and not text.endswith("..."))
                    or text.count("(default") != text.count("(default: ")):
                bad.append(f"{cmd} {what}: {text!r}")
        shown = sp.format_help()
        assert "(default: None)" not in shown and "(default: False)" not in shown, cmd
    assert not bad, "\n".join(bad)
    with pytest.raises(SystemExit, match="^0$"):
        main(["dtm", "--help"])
    shown = " ".join(capsys.readouterr().out.split())
    assert "cell size in m (default: 5.0)" in shown and "(default: tin)" in shown
    assert "errors in m (default: 0.0)" in shown  # a zero default is a default
    with pytest.raises(SystemExit, match="^0$"):
        main(["study", "gcp", "--help"])
    assert "random subsets (default: 0)" in " ".join(capsys.readouterr().out.split())


# ----------------------------------- measure transfer: every matching threshold (issue 28)
@pytest.fixture(scope="module")
def measure_sample(tmp_path_factory):
    """The small-image measurement sample (``resources/sample/measure``), copied."""
    d = tmp_path_factory.mktemp("msample") / "measure"
    shutil.copytree(SAMPLE / "measure", d, ignore=shutil.ignore_patterns("out", "__pycache__"))
    return d


def test_measure_transfer_every_matching_threshold(measure_sample, tmp_path):
    """Every ``MatchSettings`` flag set to a value other than its default: the thresholds
    the transfer used (``transfer_settings.json``) are the flags' values, field for
    field, and the run on the sample still accepts most transfers; ``--min-grey-levels``
    above any template's count flags every transfer ``no_texture``, ``--half-template``
    changes the templates' measured texture and ``--quadratic`` turns the term back on."""
    import dataclasses

    from vectoradjust.measure.transfer import MatchSettings

    p, m = measure_sample / "project.toml", measure_sample / "measured_L.csv"
    out = _ok(["measure", "transfer", p, "-o", tmp_path / "all", "-q", "--measured", m,
               "--half-template", "15", "--retry-template", "1.0",
               "--min-grey-levels", "6", "--min-entropy", "2.0",
               "--max-blockiness", "6.0", "--min-roundness", "0.05", "--max-radius", "30",
               "--window-k", "4.0", "--pyramid-levels", "1", "--pyramid-radius", "2.0",
               "--min-ncc", "0.75", "--distinct-factor", "1.5", "--distinct-gap", "0.15",
               "--ambiguity", "0.03", "--no-quadratic", "--grey-step", "2.0",
               "--lsm-tol-sigma", "0.1", "--max-lsm-move", "2.0", "--max-sigma", "0.1",
               "--min-sigma", "0.02", "--max-anisotropy", "inf", "--back-tolerance", "0.6",
               "--back-k", "2.5", "--max-ray-misfit", "1.5", "--sigma-height", "3"])
    want = dict(half_template=15, retry_template=1.0, min_grey_levels=6, min_entropy=2.0,
                max_blockiness=6.0,
                min_roundness=0.05, max_radius=30.0, k=4.0, pyramid_levels=1,
                pyramid_radius=2.0, min_ncc=0.75, distinct_factor=1.5, distinct_gap=0.15,
                ambiguity=0.03, quadratic=False, grey_step=2.0, lsm_tol_sigma=0.1,
                max_lsm_move=2.0, max_sigma=0.1, min_sigma=0.02, max_anisotropy="inf",
                back_tolerance=0.6, back_k=2.5, max_ray_misfit=1.5, sigma_height=3.0)
    got = _json(out / "transfer_settings.json")
    assert got == want
    default = dataclasses.asdict(MatchSettings())
    assert set(default) | {"sigma_height"} == set(got)  # every field has its flag
    assert all(str(default[k]) != str(v) for k, v in got.items() if k in default)
    rows = _rows(out / "transfer.csv")
    assert len(rows) >= 20 and sum(r["accepted"] == "True" for r in rows) >= 0.6 * len(rows)
    out = _ok(["measure", "transfer", p, "-o", tmp_path / "flat", "-q", "--measured", m,
               "--min-grey-levels", "100000", "--quadratic", "--half-template", "5"])
    flat = _rows(out / "transfer.csv")
    assert [r["point_id"] for r in flat] == [r["point_id"] for r in rows]
    assert all("no_texture" in r["flag_text"] for r in flat)
    assert _json(out / "transfer_settings.json")["quadratic"] is True
    # the texture is measured on the 11 x 11 template, not on the 31 x 31 one
    ent = np.array([[float(r["entropy"]), float(f["entropy"])] for r, f in zip(rows, flat)])
    assert np.mean(np.abs(ent[:, 1] - ent[:, 0]) > 0.05) > 0.8, ent


def test_measure_transfer_help_is_the_dataclass_docstring(capsys):
    """The help of a generated flag is the MatchSettings docstring's description and the
    field's default."""
    with pytest.raises(SystemExit, match="^0$"):
        main(["measure", "transfer", "--help"])
    shown = " ".join(capsys.readouterr().out.split())
    assert "--pyramid-levels N coarse-to-fine search: the peak is found at 1 / " in shown
    assert "fewest distinct grey values in the reference template (a flat JPEG block " \
        "holds two or three) (default: 8)" in shown
    assert "--quadratic, --no-quadratic" in shown and "(default: 3.7169)" in shown


# ------------------------------------------------------- adjust-many: merged output
def test_adjust_many_memory_limit_and_no_merge(work, tmp_path, monkeypatch):
    distributed = pytest.importorskip("distributed")
    seen = []

    class Spy(distributed.LocalCluster):  # in-process workers: quick, limits the same
        def __init__(self, **kw):
            super().__init__(**{**kw, "processes": False})
            seen.append((kw, [w["memory_limit"] for w in
                              self.scheduler_info["workers"].values()]))

    monkeypatch.setattr(distributed, "LocalCluster", Spy)
    project = str(work / "osm.toml")
    assert main(["adjust-many", project, "-o", str(tmp_path / "a"), "--workers", "1",
                 "--memory-limit", "700MB", "--no-bands", "--no-report", "-q"]) == 0
    (kw, limits), = seen
    assert kw["memory_limit"] == "700MB" and kw["threads_per_worker"] == 1
    assert limits == [700_000_000]  # --memory-limit reaches every worker
    (row,) = _rows(tmp_path / "a" / "many_summary.csv")
    assert int(row["merged_rows"]) > 0 and (tmp_path / "a" / "merged_OSM.gpkg").is_file()
    assert main(["adjust-many", project, "-o", str(tmp_path / "b"), "--scheduler", "sync",
                 "--no-merge", "--no-bands", "--no-report", "-q"]) == 0
    (row,) = _rows(tmp_path / "b" / "many_summary.csv")
    assert row["status"] == "ok" and row["merged_rows"] == ""  # --no-merge: nothing merged
    assert not list((tmp_path / "b").glob("merged_*"))
