"""Projects with RPC images (satellite triplet) in the QGIS plugin.

"Adjust road vectors" is run the way a user runs it (the dialog's defaults, only the road
layer and the project chosen) on the satellite sample (resources/sample/satellite) and
compared with the command line: the core pipeline run in this process on the same files
(roads read with GDAL's own bindings, RPCs and ground frame through the core's
``read_rpc_images`` with pyproj, as ``vectoradjust adjust`` reads them) and, where the
headless venv is there, ``vectoradjust adjust`` itself. Also: the RPCs read through QGIS's
GDAL (embedded GeoTIFF tags, side files, the real QuickBird image against rasterio), the
QGIS ground frame against pyproj's (ellipsoidal and orthometric heights, the missing-geoid
error) and that the plugin runs without rasterio or pyproj importable.
"""

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("qgis.core")

from .conftest import REPO, run_headless, venv_python  # noqa: E402
from .util import as_float, columns, compare_summaries  # noqa: E402

pytestmark = pytest.mark.qgis

SATELLITE = REPO / "resources" / "sample" / "satellite"
OSM_ROADS = SATELLITE.parent / "osm_roads.shp"  # the project's [[vectors]] OSM entry
RPC_DATA = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "rpc"
#: "the results equal the command line's": AdjX, AdjY, CE90 ... within this (m)
TOL_M = 1e-6
SHAPE_COMPARED = ("AdjX", "AdjY", "AdjZ", "Vx", "Vy", "CE90", "LE90", "SigmaX", "SigmaY")


@pytest.fixture(scope="module")
def satellite():
    """The satellite sample project (skips when it is missing)."""
    project = SATELLITE / "project.toml"
    if not project.is_file():
        pytest.skip(f"the satellite sample is missing ({project}); write it with "
                    "python -m vectoradjust.simulate.satellite_sample")
    return project


class LogFeedback:
    """A QgsProcessingFeedback that keeps what the algorithm says."""

    def __new__(cls):
        from qgis.core import QgsProcessingFeedback

        class _Feedback(QgsProcessingFeedback):
            def __init__(self):
                super().__init__()
                self.lines = []

            def pushInfo(self, info):  # noqa: N802 (QGIS API)
                self.lines.append(info)
                super().pushInfo(info)

            def pushWarning(self, warning):  # noqa: N802
                self.lines.append(warning)
                super().pushWarning(warning)

        return _Feedback()


def _dialog_run(satellite, extra=None):
    """Adjust road vectors with the dialog's values: the OSM layer and the project chosen."""
    import processing
    from qgis.core import QgsProcessingContext, QgsProject, QgsVectorLayer

    from .test_qgis_dialogs import dialog_parameters

    osm = QgsVectorLayer(str(OSM_ROADS), "osm_roads", "ogr")
    assert osm.isValid()
    QgsProject.instance().addMapLayer(osm)
    params = dialog_parameters("adjustroadvectors", {"INPUT": osm, "PROJECT": str(satellite)})
    params.update(extra or {})
    context = QgsProcessingContext()
    context.setProject(QgsProject.instance())
    feedback = LogFeedback()
    out = processing.run("vectoradjust:adjustroadvectors", params, context=context,
                         feedback=feedback)
    layers = {}
    for key in ("SHAPE_POINTS", "FEATURES", "CONTROL_POINTS", "RESIDUALS"):
        lyr = out.get(key)
        layers[key] = context.getMapLayer(lyr) if isinstance(lyr, str) else lyr
    return {"out": out, "layers": layers, "log": feedback.lines, "input": osm,
            "params": params}


@pytest.fixture(scope="module")
def dialog_run(qgis_app, satellite):
    return _dialog_run(satellite)


@pytest.fixture(scope="module")
def reference(qgis_app, satellite):
    """``vectoradjust adjust PROJECT --vectors OSM`` in this process: the core's readers
    for the tables, RPCs and ground frame (pyproj), GDAL's bindings for the roads."""
    pytest.importorskip("pyproj", reason="the in-process reference needs pyproj (the core's "
                        "ground frame); Debian's python3-qgis depends on python3-pyproj")
    from vectoradjust.files.project import load_project
    from vectoradjust.files.readers import read_rpc_images
    from vectoradjust.pipeline import run as run_pipeline

    from .plain_reference import project_data

    data = project_data(satellite, names=["OSM"])
    read_rpc_images(data, load_project(satellite), "EPSG:32616")
    return run_pipeline(data, vectors=["OSM"])


@pytest.fixture(scope="module")
def headless(satellite, tmp_path_factory):
    """``vectoradjust adjust`` itself in the headless venv (skips without it)."""
    out = tmp_path_factory.mktemp("satellite_cli")
    run_headless(["-m", "vectoradjust.cli", "adjust", str(satellite), "--out", str(out),
                  "--format", "gpkg", "--vectors", "OSM", "-q"])
    with open(out / "summary.json", encoding="utf-8") as fh:
        return {"dir": out, "summary": json.load(fh)}


# --------------------------------------------------------------------------- adjust
def test_dialog_defaults_adjust_every_feature(dialog_run):
    """The dialog's defaults run, the ground frame is said, every input feature comes out."""
    layers = dialog_run["layers"]
    assert all(layers[k] is not None for k in layers), layers
    src = columns(dialog_run["input"])
    feats = columns(layers["FEATURES"])
    assert len(feats["osm_id"]) == len(src["osm_id"]) == dialog_run["input"].featureCount()
    assert sorted(map(str, feats["osm_id"])) == sorted(map(str, src["osm_id"]))
    for f in ("name", "highway"):
        assert feats[f] == src[f], f
    pts = columns(layers["SHAPE_POINTS"])
    assert len(pts["point_id"]) == 225 and all(a == 1 for a in pts["Adjusted"])
    assert layers["CONTROL_POINTS"].featureCount() == 30
    assert layers["RESIDUALS"].featureCount() == 225
    assert any(line.startswith("ground frame: WGS 84 / UTM zone 16N, ellipsoidal heights")
               for line in dialog_run["log"]), dialog_run["log"]
    # no summary and no report chosen: no corrected RPC files, and the log says so
    assert any("corrected RPCs" in line for line in dialog_run["log"])


def test_dialog_defaults_equal_the_command_line(dialog_run, reference):
    out = dialog_run["out"]
    s = reference.summary
    assert abs(out["SIGMA0_SQUARED"] - s["sigma0_squared"]) <= 1e-9
    # (one less than before issue 30: the DEM heights' own height offset)
    assert out["DEGREES_OF_FREEDOM"] == s["degrees_of_freedom"] == 1515
    assert out["ITERATIONS"] == s["iterations"]
    assert abs(out["RMSE"] - s["shape_points"]["rmse_horizontal"]) <= TOL_M
    assert abs(out["RMSE_CHECK"] - s["check_points"]["rmse_horizontal"]) <= TOL_M
    v = reference.databases[0].vertices
    mine = columns(dialog_run["layers"]["SHAPE_POINTS"])
    assert mine["point_id"] == v["point_id"].tolist()
    for f in SHAPE_COMPARED:
        d = np.abs(as_float(mine[f]) - np.asarray(v[f], float))
        assert d.max() <= TOL_M, (f, d.max())
    c = columns(dialog_run["layers"]["CONTROL_POINTS"])
    assert c["point_id"] == reference.control_points["point_id"].tolist()
    for f in ("AdjX", "AdjY", "AdjZ", "CE90", "LE90"):
        d = np.abs(as_float(c[f]) - np.asarray(reference.control_points[f], float))
        assert np.nanmax(d) <= TOL_M, (f, np.nanmax(d))


def test_bias_in_the_log(dialog_run, reference):
    """Each image's estimated bias (px) is in the log, as the command line's summary has it."""
    rpc = [im for im in reference.summary["images"] if im.get("model") == "rpc"]
    assert [im["id"] for im in rpc] == ["S1", "S2", "S3"]
    for im in rpc:
        b, sd = im["bias"], im["sigma_bias"]
        expected = (f"{im['id']}: bias (shift) a0 = {b['a0']:.3f} +- {sd['a0']:.3f}, "
                    f"b0 = {b['b0']:.3f} +- {sd['b0']:.3f} px; significant")
        assert expected in dialog_run["log"], (expected, dialog_run["log"])
    # the simulated shifts (truth_bias.csv) are recovered within 4 sigma
    with open(SATELLITE / "truth_bias.csv", encoding="utf-8") as fh:
        head = fh.readline().strip().split(",")
        truth = {r[0]: dict(zip(head, r)) for r in (ln.strip().split(",") for ln in fh)}
    for im in rpc:
        for k in ("a0", "b0"):
            err = abs(im["bias"][k] - float(truth[im["id"]][k]))
            assert err <= 4 * im["sigma_bias"][k], (im["id"], k, err)


def test_summary_and_corrected_rpcs_equal_the_command_line(qgis_app, satellite, tmp_path,
                                                             reference):
    """With a summary chosen: summary.json as the command line's (1e-9; buffer shares 1e-6)
    and the corrected RPC files beside it, byte for byte."""
    from vectoradjust.files.rpc import write_corrected_rpcs

    run = _dialog_run(satellite, {"SUMMARY": str(tmp_path / "summary.json")})
    with open(tmp_path / "summary.json", encoding="utf-8") as fh:
        mine = json.load(fh)
    ref_dir = tmp_path / "ref"
    ref_dir.mkdir()
    written = write_corrected_rpcs(reference, ref_dir)
    assert sorted(written) == ["S1_rpc.txt", "S2_rpc.txt", "S3_rpc.txt"]
    for name in written:
        assert (tmp_path / name).read_bytes() == (ref_dir / name).read_bytes(), name
        assert f"wrote the corrected RPCs {tmp_path / name}" in run["log"]
    assert [im["corrected_rpc"]["file"] for im in mine["images"]] == written
    for k in ("sigma0_squared", "degrees_of_freedom", "shape_points", "check_points"):
        compare_summaries(mine[k], reference.summary[k], k)
    for a, b in zip(mine["images"], reference.summary["images"]):
        compare_summaries({k: a[k] for k in ("bias", "sigma_bias", "significance")},
                          {k: b[k] for k in ("bias", "sigma_bias", "significance")}, a["id"])


def test_summary_equals_vectoradjust_adjust(qgis_app, satellite, tmp_path, headless):
    """Against ``vectoradjust adjust`` itself (the headless venv): the whole summary."""
    run = _dialog_run(satellite, {"SUMMARY": str(tmp_path / "summary.json")})
    assert run["out"]["SUMMARY"]
    with open(tmp_path / "summary.json", encoding="utf-8") as fh:
        mine = json.load(fh)
    compare_summaries(mine, headless["summary"])
    for name in ("S1_rpc.txt", "S2_rpc.txt", "S3_rpc.txt"):
        assert (tmp_path / name).read_bytes() == (headless["dir"] / name).read_bytes()


def test_corrected_rpcs_never_replace_the_inputs(qgis_app, satellite, tmp_path):
    """A summary written into the folder of the RPC files does not overwrite them."""
    import shutil

    folder = tmp_path / "sat"
    shutil.copytree(SATELLITE, folder)
    project = _project_copy(satellite, folder / "project.toml",
                            {iid: folder / f"{iid}_rpc.txt" for iid in ("S1", "S2", "S3")})
    before = {p.name: p.read_bytes() for p in folder.glob("*_rpc.txt")}
    run = _dialog_run(project, {"SUMMARY": str(folder / "summary.json")})
    assert {p.name: p.read_bytes() for p in folder.glob("*_rpc.txt")} == before
    assert any("corrected RPCs are not written" in line for line in run["log"])
    with open(folder / "summary.json", encoding="utf-8") as fh:
        assert all("corrected_rpc" not in im for im in json.load(fh)["images"])


def _project_copy(satellite, path, rpc=None, extra_top=""):
    """The satellite project with absolute paths, RPC files replaced by ``rpc`` (id -> path)."""
    import re

    text = satellite.read_text(encoding="utf-8")
    text = re.sub(r'^(\s*(?:path|dem|truth)\s*=\s*)"([^"]+)"',
                  lambda m: m.group(1) + json.dumps(str((satellite.parent / m.group(2))
                                                        .resolve())), text, flags=re.M)
    text = re.sub(r'^(\s*rpc\s*=\s*)"(S\d)_rpc.txt"',
                  lambda m: m.group(1) + json.dumps(str((rpc or {}).get(
                      m.group(2), satellite.parent / f"{m.group(2)}_rpc.txt"))),
                  text, flags=re.M)
    if extra_top:
        text = text.replace('heights = "ellipsoidal"', extra_top)
    path.write_text(text, encoding="utf-8")
    return path


def _tagged_geotiff(path, rpc):
    """A small GeoTIFF with ``rpc`` in its RPC tags (QGIS's GDAL)."""
    from osgeo import gdal

    ds = gdal.GetDriverByName("GTiff").Create(str(path), 16, 16, 1, gdal.GDT_Byte)
    ds.SetMetadata({k: str(v) for k, v in rpc.to_gdal().items()}, "RPC")
    ds.FlushCache()
    ds = None
    return path


def test_embedded_rpc_tags_give_the_side_files_results(qgis_app, satellite, tmp_path,
                                                       dialog_run):
    """Images with their RPCs in GeoTIFF tags (read by QGIS's GDAL) adjust as the side
    files do (GeoTIFF tags keep 15 significant digits)."""
    from qgis_plugin.rpc_io import read_rpc
    from vectoradjust.files.rpc import read_rpc as core_read_rpc

    images = {}
    for iid in ("S1", "S2", "S3"):
        side = core_read_rpc(SATELLITE / f"{iid}_rpc.txt")
        tif = _tagged_geotiff(tmp_path / f"{iid.lower()}_image.tif", side)
        got = read_rpc(tif)
        assert got.source == str(tif)
        for k, v in side.to_gdal().items():
            a = np.asarray(str(got.to_gdal()[k]).split(), float)
            b = np.asarray(str(v).split(), float)
            assert np.allclose(a, b, rtol=1e-14, atol=0.0), k
        images[iid] = tif
    project = _project_copy(satellite, tmp_path / "project.toml", images)
    run = _dialog_run(project)
    mine = columns(run["layers"]["SHAPE_POINTS"])
    ref = columns(dialog_run["layers"]["SHAPE_POINTS"])
    assert mine["point_id"] == ref["point_id"]
    for f in SHAPE_COMPARED:
        d = np.abs(as_float(mine[f]) - as_float(ref[f]))
        assert d.max() <= TOL_M, (f, d.max())


def test_rpc_reading_errors_name_the_file(qgis_app, tmp_path):
    from qgis_plugin.rpc_io import read_rpc
    from vectoradjust.errors import InputFileError

    plain = tmp_path / "plain.tif"
    from osgeo import gdal

    gdal.GetDriverByName("GTiff").Create(str(plain), 4, 4, 1, gdal.GDT_Byte).FlushCache()
    with pytest.raises(InputFileError, match="the image has no RPCs.*plain_rpc.txt"):
        read_rpc(plain)
    bad = tmp_path / "bad.tif"
    bad.write_text("not an image")
    with pytest.raises(InputFileError, match="cannot be read as an image"):
        read_rpc(bad)
    with pytest.raises(InputFileError, match="does not exist"):
        read_rpc(tmp_path / "missing.tif")


def test_side_file_next_to_an_image_is_its_source(qgis_app, tmp_path):
    """GDAL's rule: a ``<name>_rpc.txt`` beside the image wins over its tags; the model's
    source names it (as the command line's rasterio reading does)."""
    import dataclasses

    from qgis_plugin.rpc_io import read_rpc
    from vectoradjust.files.rpc import read_rpc as core_read_rpc
    from vectoradjust.files.rpc import write_rpc

    side_model = core_read_rpc(SATELLITE / "S1_rpc.txt")
    tif = _tagged_geotiff(tmp_path / "img.tif",
                          dataclasses.replace(side_model, samp_off=side_model.samp_off + 7.0))
    side = write_rpc(side_model, tif)
    got = read_rpc(tif)
    assert got.source == str(side)
    assert got == side_model


def test_quickbird_rpcs_equal_rasterio(qgis_app):
    """The real QuickBird image: QGIS's GDAL gives the RPCs rasterio gives (headless venv)."""
    from qgis_plugin.rpc_io import read_rpc

    image = RPC_DATA / "quickbird2" / "qb2_basic1b.tif"
    if not image.is_file():
        pytest.skip(f"real RPC data not found: {image}")
    if venv_python() is None:
        pytest.skip("the headless test venv (rasterio) is missing: set VECTORADJUST_VENV_PYTHON")
    proc = run_headless(["-c", "import json, sys; from vectoradjust.files.rpc import read_rpc; "
                         "m = read_rpc(sys.argv[1]); print(json.dumps([m.to_gdal(), m.source]))",
                         str(image)])
    ref, source = json.loads(proc.stdout)
    got = read_rpc(image)
    assert got.source == source
    assert got.to_gdal() == ref


# --------------------------------------------------------------------------- ground frame
def _points(n=10000, seed=1):
    rng = np.random.default_rng(seed)
    return np.column_stack([rng.uniform(490000, 510000, n), rng.uniform(3990000, 4010000, n),
                            rng.uniform(0.0, 500.0, n)])


@pytest.mark.parametrize("heights,vertical", [("ellipsoidal", None),
                                              ("orthometric", "EPSG:5773")])
def test_ground_frame_equals_pyproj(qgis_app, heights, vertical):
    """QGIS's frame (QgsCoordinateTransform; osr with the geoid) gives the core's pyproj
    frame's lon, lat, h and Jacobian; 10^4 points in well under a second."""
    pytest.importorskip("pyproj")
    from qgis.core import QgsCoordinateReferenceSystem

    from qgis_plugin.rpc_io import ground_frame
    from vectoradjust.errors import CRSError
    from vectoradjust.files.rpc import crs_frame

    near = (-87.05, 36.13)
    try:
        ref = crs_frame("EPSG:32616", heights=heights, geoid=vertical, near=near)
    except CRSError as exc:
        pytest.skip(f"PROJ has no EGM96 grid here: {exc}")
    frame = ground_frame(QgsCoordinateReferenceSystem("EPSG:32616"), heights, vertical,
                         near=near)
    xyz = _points()
    t = time.perf_counter()
    llh, jac = frame.to_geodetic(xyz)
    elapsed = time.perf_counter() - t
    llh_ref, jac_ref = ref.to_geodetic(xyz)
    dlon, dlat, dh = np.abs(llh - llh_ref).max(axis=0)
    assert dlon <= 1e-11 and dlat <= 1e-11 and dh <= 1e-6, (dlon, dlat, dh)
    assert np.abs(jac - jac_ref).max() <= 1e-9 * np.abs(jac_ref).max()
    assert np.abs(frame.from_geodetic(llh) - xyz).max() <= 1e-6
    if heights == "orthometric":
        assert np.abs(llh[:, 2] - xyz[:, 2]).min() > 1.0  # the geoid is applied
    assert elapsed < 2.0, elapsed


def test_missing_geoid_is_a_clear_error(qgis_app):
    from qgis.core import QgsCoordinateReferenceSystem

    from qgis_plugin.rpc_io import ground_frame
    from vectoradjust.errors import CRSError

    crs = QgsCoordinateReferenceSystem("EPSG:32616")
    try:
        ground_frame(crs, "orthometric", "EGM2008", near=(-87.05, 36.13))
    except CRSError as exc:
        msg = str(exc)
        assert "EGM2008 height" in msg and "geoid grid" in msg and "projsync" in msg
    else:
        pytest.skip("this PROJ has the EGM2008 grid: nothing is missing")
    with pytest.raises(CRSError, match="needs the vertical datum"):
        ground_frame(crs, "orthometric", None)
    with pytest.raises(CRSError, match="not a vertical CRS"):
        ground_frame(crs, "orthometric", "EPSG:4326", near=(-87.05, 36.13))


def test_points_outside_the_crs_are_named(qgis_app):
    from qgis.core import QgsCoordinateReferenceSystem

    from qgis_plugin.rpc_io import ground_frame
    from vectoradjust.errors import CRSError

    frame = ground_frame(QgsCoordinateReferenceSystem("EPSG:32616"))
    xyz = _points(5)
    xyz[3] = (np.nan, 4.0e6, 0.0)
    with pytest.raises(CRSError, match=r"point\(s\) cannot be transformed.*X=nan"):
        frame.to_geodetic(xyz)


def test_orthometric_project_runs_with_the_geoid(qgis_app, satellite, tmp_path, dialog_run):
    """heights = "orthometric" with vertical_crs (EGM96): accepted, the heights converted
    (the adjusted positions move by the geoid's tilt only: under 1 m here)."""
    project = _project_copy(satellite, tmp_path / "project.toml",
                            extra_top='heights = "orthometric"\nvertical_crs = "EPSG:5773"')
    try:
        run = _dialog_run(project)
    except Exception as exc:  # QgsProcessingException
        if "geoid grid" in str(exc):
            pytest.skip(f"QGIS's PROJ has no EGM96 grid here: {exc}")
        raise
    assert any("orthometric heights in EGM96 height" in line for line in run["log"])
    a = columns(run["layers"]["SHAPE_POINTS"])
    b = columns(dialog_run["layers"]["SHAPE_POINTS"])
    assert a["point_id"] == b["point_id"]
    assert np.abs(as_float(a["AdjX"]) - as_float(b["AdjX"])).max() < 1.0


# --------------------------------------------------------------------------- other algorithms
def test_measure_on_images_predicts_on_rpc_images(qgis_app, satellite):
    import processing

    feedback = LogFeedback()
    out = processing.run("vectoradjust:measureonimages",
                         {"PROJECT": str(satellite), "OUTPUT": "TEMPORARY_OUTPUT"},
                         feedback=feedback)
    cols = columns(out["OUTPUT"])
    assert sorted(set(cols["image_id"])) == ["S1", "S2", "S3"]
    assert out["PREDICTED"] == len(cols["image_id"]) > 0
    assert np.isfinite(as_float(cols["col"])).all()
    assert sum(line.startswith("RPC image S") for line in feedback.lines) == 3


def test_equal_error_map_refuses_rpc_images_clearly(qgis_app, satellite, tmp_path):
    import processing
    from qgis.core import QgsProcessingException

    with pytest.raises(QgsProcessingException, match="RPC image has neither"):
        processing.run("vectoradjust:equalerrormap",
                       {"PROJECT": str(satellite), "OUTPUT": str(tmp_path / "ee.tif")})


# --------------------------------------------------------------------------- no second GDAL
_NO_SECOND_GDAL = r"""
import os, sys
BLOCKED = ("rasterio", "pyproj", "fiona", "pyogrio", "geopandas", "shapely")


class Block:
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in BLOCKED:
            raise ImportError(f"{name} is blocked in this test")
        return None


sys.meta_path.insert(0, Block())
os.environ["QT_QPA_PLATFORM"] = "offscreen"
os.environ["GDAL_PAM_ENABLED"] = "NO"
from qgis.core import QgsApplication
app = QgsApplication([], False)
app.initQgis()
sys.path.append(sys.argv[1])
from processing.core.Processing import Processing
Processing.initialize()
from qgis_plugin.provider import VectorAdjustProvider
provider = VectorAdjustProvider()
QgsApplication.processingRegistry().addProvider(provider)
import processing
out = processing.run("vectoradjust:adjustroadvectors", {
    "INPUT": sys.argv[3], "PROJECT": sys.argv[2], "SHAPE_POINTS": "TEMPORARY_OUTPUT",
    "FEATURES": "TEMPORARY_OUTPUT", "SUMMARY": sys.argv[4]})
measured = processing.run("vectoradjust:measureonimages", {
    "PROJECT": sys.argv[5], "OUTPUT": "TEMPORARY_OUTPUT"})
print("RESULT", out["SHAPE_POINTS"].featureCount(), out["SIGMA0_SQUARED"],
      measured["PREDICTED"])
print("LOADED", sorted(m for m in sys.modules if m.split(".")[0] in BLOCKED))
"""


def test_rpc_projects_need_neither_rasterio_nor_pyproj(qgis_app, satellite, tmp_path,
                                                      reference):
    """A fresh QGIS where rasterio, pyproj and the other second-GDAL/PROJ/GEOS packages
    cannot be imported adjusts the satellite project (RPCs in GeoTIFF tags, read by QGIS's
    GDAL) to the in-process reference's numbers, and predicts on the sample's images."""
    from vectoradjust.files.rpc import read_rpc as core_read_rpc

    from .conftest import _processing_plugins_dir

    images = {iid: _tagged_geotiff(tmp_path / f"{iid}.tif",
                                   core_read_rpc(SATELLITE / f"{iid}_rpc.txt"))
              for iid in ("S1", "S2", "S3")}
    project = _project_copy(satellite, tmp_path / "project.toml", images)
    script = tmp_path / "no_second_gdal.py"
    script.write_text(_NO_SECOND_GDAL, encoding="utf-8")
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(REPO / "core"), str(REPO)]))
    proc = subprocess.run(
        [sys.executable, str(script), _processing_plugins_dir(), str(project),
         str(OSM_ROADS), str(tmp_path / "out" / "summary.json"), str(satellite)],
        capture_output=True, text=True, env=env, timeout=600, cwd=str(tmp_path))
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    lines = {ln.split(" ", 1)[0]: ln.split(" ", 1)[1] for ln in proc.stdout.splitlines()
             if ln.startswith(("RESULT", "LOADED"))}
    assert lines["LOADED"] == "[]", lines
    count, sigma0, predicted = lines["RESULT"].split()
    assert int(count) == 225 and int(predicted) > 0
    assert abs(float(sigma0) - reference.summary["sigma0_squared"]) <= 1e-9
    assert (tmp_path / "out" / "S1_rpc.txt").is_file()  # corrected RPCs beside the summary
