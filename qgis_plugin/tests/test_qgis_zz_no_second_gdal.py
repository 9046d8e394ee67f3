"""After every algorithm has run, no geospatial library with its own GDAL/PROJ is loaded.

geopandas, rasterio, fiona and pyogrio bring a second GDAL into the QGIS process (a
crash waiting to happen); shapely and pyproj a second GEOS/PROJ. The plugin reads
everything through the QGIS API. (Named ``zz`` so that it runs after the other plugin
tests in the same process; it runs every algorithm itself, so it also holds alone.)
"""

import sys

import pytest

pytest.importorskip("qgis.core")

pytestmark = pytest.mark.qgis

SECOND_GDAL = ("geopandas", "rasterio", "fiona", "pyogrio")
BANNED = SECOND_GDAL + ("shapely", "pyproj")


def _loaded(names):
    return sorted(m for m in sys.modules if m.split(".")[0] in names)


def test_no_second_gdal_after_every_algorithm(qgis_app, sample, tmp_path):
    import processing

    before = set(_loaded(BANNED))  # (other test modules of this process may use pyproj)
    s = str(sample)
    processing.run("vectoradjust:extractshapepoints", {
        "INPUT": f"{s}/osm_roads.shp", "ID_FIELD": "osm_id", "DEM": f"{s}/dem.tif",
        "OUTPUT": "TEMPORARY_OUTPUT"})
    processing.run("vectoradjust:adjustroadvectors", {
        "INPUT": f"{s}/tnm_roads.shp", "PROJECT": f"{s}/project.toml",
        "SHAPE_POINTS": "TEMPORARY_OUTPUT", "FEATURES": "TEMPORARY_OUTPUT",
        "CONTROL_POINTS": "TEMPORARY_OUTPUT", "RESIDUALS": "TEMPORARY_OUTPUT",
        "SUMMARY": str(tmp_path / "summary.json"), "REPORT": str(tmp_path / "report.html")})
    processing.run("vectoradjust:compareroaddatabases", {
        "LAYERS": [f"{s}/osm_roads.shp", f"{s}/tiger_roads.shp"],
        "PROJECT": f"{s}/project.toml", "OUTPUT": "TEMPORARY_OUTPUT",
        "SHAPE_POINTS": "TEMPORARY_OUTPUT", "RESIDUALS": "TEMPORARY_OUTPUT",
        "OUTPUT_FOLDER": str(tmp_path / "compare"),
        "REPORT": str(tmp_path / "compare.html")})
    processing.run("vectoradjust:bufferaccuracytest", {
        "INPUT": f"{s}/tiger_roads.shp", "REFERENCE": f"{s}/truth_roads.shp",
        "OUTPUT": "TEMPORARY_OUTPUT"})
    processing.run("vectoradjust:accuracycontrol", {
        "PROJECT": f"{s}/project.toml", "PRODUCT": 0, "SCALE": 2000, "CONTOUR_INTERVAL": 1,
        "OUTPUT": "TEMPORARY_OUTPUT", "QA_JSON": str(tmp_path / "qa.json"),
        "CONTROL_POINTS": "TEMPORARY_OUTPUT"})
    processing.run("vectoradjust:uncertaintybands", {
        "INPUT": f"{s}/osm_roads.shp", "PROJECT": f"{s}/project.toml",
        "OUTPUT": "TEMPORARY_OUTPUT"})
    processing.run("vectoradjust:equalerrormap", {
        "PROJECT": f"{s}/project.toml", "OUTPUT": str(tmp_path / "ee.tif")})
    # RPC images (their RPCs and the ground frame through QGIS's GDAL and transformations)
    processing.run("vectoradjust:adjustroadvectors", {
        "INPUT": f"{s}/osm_roads.shp", "PROJECT": f"{s}/satellite/project.toml",
        "SHAPE_POINTS": "TEMPORARY_OUTPUT", "SUMMARY": str(tmp_path / "rpc" / "summary.json")})
    processing.run("vectoradjust:measureonimages", {
        "PROJECT": f"{s}/satellite/project.toml", "OUTPUT": "TEMPORARY_OUTPUT"})
    assert (tmp_path / "report.html").is_file() and (tmp_path / "ee.tif").is_file()
    assert (tmp_path / "rpc" / "S1_rpc.txt").is_file()
    # the report's figures: matplotlib's Agg canvas, never pyplot (no GUI backend in QGIS)
    assert "matplotlib.pyplot" not in sys.modules
    assert not _loaded(SECOND_GDAL), f"loaded in the QGIS process: {_loaded(SECOND_GDAL)}"
    new = sorted(set(_loaded(BANNED)) - before)
    assert not new, f"loaded by the algorithms: {new}"
