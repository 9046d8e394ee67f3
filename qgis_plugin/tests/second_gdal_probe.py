"""Run the plugin inside a fresh offscreen QGIS and report which geodata packages it loaded.

Started by ``test_qgis_zz_no_second_gdal.py`` with the Python of a venv made with
``--system-site-packages`` over QGIS's Python, into which rasterio, pyogrio, fiona,
pyproj and geopandas (each wheel with its own GDAL/PROJ) were pip-installed: so an
``import pyogrio`` reached from the plugin, even an optional one in a ``try``, would
succeed here and show up in ``sys.modules``::

    python second_gdal_probe.py OUT.json SAMPLE_DIR WORK_DIR

needs ``PYTHONPATH=<repo>/core:<repo>`` and ``QT_QPA_PLATFORM=offscreen``. It starts
QGIS and Processing, then imports the plugin, registers its provider and runs every
algorithm on the sample project (``resources/sample``) and its RPC satellite project
with their defaults. It writes OUT.json with the banned packages loaded before the
plugin was imported and after the last algorithm, where each was first imported from
(a stack, from a recording import hook) and where each would have been found. It
asserts nothing itself: the test does.
"""

import importlib.util
import json
import os
import sys
import time
import traceback

# geopandas, rasterio, fiona and pyogrio: a second GDAL; shapely, pyproj: a second GEOS/PROJ
SECOND_GDAL = ("geopandas", "rasterio", "fiona", "pyogrio")
BANNED = SECOND_GDAL + ("shapely", "pyproj")


class ImportRecorder:
    """A ``sys.meta_path`` finder that finds nothing: it notes who first imports a banned
    package (its stack) and lets the other finders import it."""

    def __init__(self, names):
        self.names = set(names)
        self.stacks = {}

    def find_spec(self, fullname, path=None, target=None):
        top = fullname.split(".")[0]
        if top in self.names and top not in self.stacks:
            frames = [f for f in traceback.extract_stack()[:-1]
                      if "importlib" not in f.filename and f.filename != __file__
                      and not f.filename.endswith(os.path.join("qgis", "utils.py"))]
            # down to the first frame inside a banned package (who reached it, and how)
            inside = [i for i, f in enumerate(frames)
                      if any(f"{os.sep}{n}{os.sep}" in f.filename for n in self.names)]
            frames = frames[:inside[0] + 1] if inside else frames
            self.stacks[top] = "".join(traceback.format_list(frames[-8:]))
        return None


def loaded(names):
    """The loaded modules of the packages ``names``, sorted."""
    return sorted(m for m in sys.modules if m.split(".")[0] in names)


def start_qgis():
    """An initialised offscreen QgsApplication with Processing."""
    from qgis.core import QgsApplication

    app = QgsApplication([], False)
    app.initQgis()
    for d in (os.path.join(QgsApplication.pkgDataPath(), "python", "plugins"),
              "/usr/share/qgis/python/plugins"):
        if os.path.isdir(os.path.join(d, "processing")):
            sys.path.append(d)
            break
    from processing.core.Processing import Processing

    Processing.initialize()
    return app


def load_plugin():
    """Import the plugin as QGIS does (``classFactory``) and register its provider."""
    from qgis.core import QgsApplication

    import qgis_plugin

    plugin = qgis_plugin.classFactory(None)
    plugin.initProcessing()
    provider = QgsApplication.processingRegistry().providerById("vectoradjust")
    if provider is None:
        raise RuntimeError("the vectoradjust provider was not registered")
    return plugin, sorted(a.id() for a in provider.algorithms())


def runs(s, w):
    """(algorithm id, parameters) of every algorithm; the rest are the defaults."""
    tmp = "TEMPORARY_OUTPUT"
    sat = f"{s}/satellite/project.toml"
    return [
        ("vectoradjust:extractshapepoints", {
            "INPUT": f"{s}/osm_roads.shp", "ID_FIELD": "osm_id", "DEM": f"{s}/dem.tif",
            "OUTPUT": tmp}),
        ("vectoradjust:adjustroadvectors", {
            "INPUT": f"{s}/tnm_roads.shp", "PROJECT": f"{s}/project.toml", "SHAPE_POINTS": tmp,
            "FEATURES": tmp, "CONTROL_POINTS": tmp, "RESIDUALS": tmp,
            "SUMMARY": f"{w}/summary.json", "REPORT": f"{w}/report.html"}),
        ("vectoradjust:compareroaddatabases", {
            "LAYERS": [f"{s}/osm_roads.shp", f"{s}/tiger_roads.shp"],
            "PROJECT": f"{s}/project.toml", "OUTPUT": tmp, "SHAPE_POINTS": tmp,
            "RESIDUALS": tmp, "OUTPUT_FOLDER": f"{w}/compare", "REPORT": f"{w}/compare.html"}),
        # the per-database GeoPackages compare wrote: adjusted features with CE90
        ("vectoradjust:smartconflation", {
            "LAYERS": [f"{w}/compare/OSM/adjusted.gpkg|layername=features",
                       f"{w}/compare/TIGER/adjusted.gpkg|layername=features"],
            "OUTPUT": tmp}),
        ("vectoradjust:bufferaccuracytest", {
            "INPUT": f"{s}/tiger_roads.shp", "REFERENCE": f"{s}/truth_roads.shp",
            "OUTPUT": tmp}),
        ("vectoradjust:accuracycontrol", {
            "PROJECT": f"{s}/project.toml", "PRODUCT": 0, "SCALE": 2000,
            "CONTOUR_INTERVAL": 1, "OUTPUT": tmp, "QA_JSON": f"{w}/qa.json",
            "CONTROL_POINTS": tmp}),
        ("vectoradjust:uncertaintybands", {
            "INPUT": f"{s}/osm_roads.shp", "PROJECT": f"{s}/project.toml", "OUTPUT": tmp}),
        ("vectoradjust:equalerrormap", {
            "PROJECT": f"{s}/project.toml", "OUTPUT": f"{w}/ee.tif"}),
        ("vectoradjust:dtmaccuracy", {
            "PROJECT": f"{s}/project.toml", "OUTPUT": f"{w}/dtm.tif", "CONTOURS": tmp}),
        ("vectoradjust:gcpstudy", {
            "PROJECT": f"{s}/project.toml", "NUMBERS": "24,6", "OUTPUT": tmp,
            "CONFIG_POINTS": tmp, "OUTPUT_FOLDER": f"{w}/study"}),
        # RPC images: their RPCs and the ground frame through QGIS's GDAL and PROJ
        ("vectoradjust:adjustroadvectors", {
            "INPUT": f"{s}/osm_roads.shp", "PROJECT": sat, "SHAPE_POINTS": tmp,
            "SUMMARY": f"{w}/rpc/summary.json"}),
        ("vectoradjust:measureonimages", {"PROJECT": sat, "OUTPUT": tmp}),
    ]


def main(out, sample, work):
    """Start QGIS, load the plugin, run every algorithm and write the report ``out``."""
    os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")
    os.environ["GDAL_PAM_ENABLED"] = "NO"  # no .aux.xml next to the sample data
    recorder = ImportRecorder(BANNED)
    sys.meta_path.insert(0, recorder)
    app = start_qgis()
    baseline = loaded(BANNED)
    _plugin, algorithms = load_plugin()
    import processing

    seconds = []
    for alg, params in runs(sample, work):
        t0 = time.perf_counter()
        processing.run(alg, params)
        seconds.append([alg, round(time.perf_counter() - t0, 2)])
    sys.meta_path.remove(recorder)
    import numpy

    report = {
        "python": sys.executable, "numpy": [numpy.__version__, numpy.__file__],
        "baseline": baseline, "loaded": loaded(BANNED), "stacks": recorder.stacks,
        "findable": {n: getattr(importlib.util.find_spec(n), "origin", None) for n in BANNED},
        "pyplot": "matplotlib.pyplot" in sys.modules, "algorithms": algorithms,
        "seconds": seconds,
        "outputs": sorted(os.path.relpath(os.path.join(d, f), work)
                          for d, _, fs in os.walk(work) for f in fs),
    }
    with open(out, "w", encoding="utf-8") as fh:
        json.dump(report, fh, indent=1)
    app.exitQgis()


if __name__ == "__main__":
    main(*sys.argv[1:4])
