"""The provider, the plugin entry points, metadata, styles and the plugin zip."""

import configparser
import re
import zipfile
from pathlib import Path

import pytest

pytest.importorskip("qgis.core")

pytestmark = pytest.mark.qgis

PLUGIN = Path(__file__).resolve().parents[1]
REPO = PLUGIN.parent
ALGORITHMS = {
    "vectoradjust:extractshapepoints": "Extract shape points",
    "vectoradjust:adjustroadvectors": "Adjust road vectors",
    "vectoradjust:compareroaddatabases": "Compare road databases",
    "vectoradjust:bufferaccuracytest": "Buffer accuracy test",
    "vectoradjust:accuracycontrol": "Accuracy control",
    "vectoradjust:uncertaintybands": "Uncertainty bands",
    "vectoradjust:equalerrormap": "Equal-error map",
    "vectoradjust:gcpstudy": "GCP study (number and location of control points)",
    "vectoradjust:measureonimages": "Measure on the images",
    "vectoradjust:dtmaccuracy": "DTM accuracy",
    "vectoradjust:smartconflation": "Smart conflation",
}


def test_provider_and_algorithms(qgis_app):
    from qgis.core import QgsApplication

    provider = QgsApplication.processingRegistry().providerById("vectoradjust")
    assert provider is not None and provider.name() == "vectoradjust"
    assert not provider.icon().isNull()
    algs = {a.id(): a for a in provider.algorithms()}
    assert {k: a.displayName() for k, a in algs.items()} == ALGORITHMS
    for alg in algs.values():
        text = alg.shortHelpString()
        assert "<h3>Needs</h3>" in text and "<h3>Writes</h3>" in text, alg.id()
        assert alg.shortDescription()
        assert alg.group() == "Road vector adjustment"
        for p in alg.parameterDefinitions():
            assert p.description(), (alg.id(), p.name())


def test_adjust_parameters_and_outputs(qgis_app):
    from qgis.core import QgsApplication

    alg = QgsApplication.processingRegistry().algorithmById("vectoradjust:adjustroadvectors")
    params = {p.name(): p for p in alg.parameterDefinitions()}
    for name in ("INPUT", "ID_FIELD", "DEM", "MEASUREMENTS", "CONTROL", "PROJECT",
                 "FOCAL_LENGTH", "PRINCIPAL_POINT_X", "PRINCIPAL_POINT_Y", "IMAGES",
                 "SHAPE_POINTS", "FEATURES", "CONTROL_POINTS", "RESIDUALS", "SUMMARY",
                 "REPORT"):
        assert name in params, name
    assert params["ID_FIELD"].parentLayerParameterName() == "INPUT"
    assert params["REPORT"].type() == "fileDestination"
    assert params["REPORT"].flags() & params["REPORT"].FlagOptional
    outputs = {o.name(): o.type() for o in alg.outputDefinitions()}
    assert outputs["SIGMA0_SQUARED"] == "outputNumber"
    assert outputs["CHI_SQUARE_PASSED"] == "outputBoolean"
    assert outputs["RMSE"] == "outputNumber"
    for sink in ("SHAPE_POINTS", "FEATURES", "CONTROL_POINTS", "RESIDUALS"):
        assert outputs[sink] == "outputVector"


def test_new_algorithms_parameters_and_outputs(qgis_app):
    from qgis.core import QgsApplication

    reg = QgsApplication.processingRegistry()
    qa = reg.algorithmById("vectoradjust:accuracycontrol")
    params = {p.name(): p for p in qa.parameterDefinitions()}
    assert params["PRODUCT"].options() == ["topographic map", "orthophoto", "orthomosaic"]
    assert params["TERRAIN"].options() == ["flat", "hilly", "mountainous"]
    for name in ("INPUT", "PRODUCT", "SCALE", "CONTOUR_INTERVAL", "TERRAIN", "PIXEL_SIZE"):
        assert params[name].flags() & params[name].FlagOptional, name
    assert params["OUTPUT"].type() == "sink" and params["QA_JSON"].type() == "fileDestination"
    outputs = {o.name(): o.type() for o in qa.outputDefinitions()}
    assert outputs["PASSED"] == "outputBoolean" and outputs["VERDICT"] == "outputString"
    assert outputs["CONTROL_POINTS"] == "outputVector"
    bands = reg.algorithmById("vectoradjust:uncertaintybands")
    params = {p.name(): p for p in bands.parameterDefinitions()}
    assert params["CONFIDENCE"].defaultValue() == 0.9
    assert not params["INPUT"].flags() & params["INPUT"].FlagOptional
    ee = reg.algorithmById("vectoradjust:equalerrormap")
    params = {p.name(): p for p in ee.parameterDefinitions()}
    assert params["OUTPUT"].type() == "rasterDestination"
    assert params["DEM"].flags() & params["DEM"].FlagOptional
    assert reg.algorithmById("vectoradjust:compareroaddatabases").parameterDefinition(
        "REPORT").type() == "fileDestination"


def test_metadata_complete():
    cp = configparser.ConfigParser()
    cp.read(PLUGIN / "metadata.txt", encoding="utf-8")
    meta = cp["general"]
    # mandatory for the QGIS plugin repository, then recommended
    for key in ("name", "qgisMinimumVersion", "description", "about", "version", "author",
                "email", "repository", "tracker", "homepage", "tags", "icon",
                "hasProcessingProvider"):
        assert meta.get(key), key
    assert re.fullmatch(r"\d+\.\d+\.\d+", meta["version"])
    assert "\n" not in meta["description"].strip()
    assert meta["experimental"] in ("True", "False") and meta["deprecated"] in ("True", "False")
    for key in ("repository", "tracker", "homepage"):
        assert re.fullmatch(r"https://\S+", meta[key]), key
    assert re.fullmatch(r"[^@\s]+@[^@\s]+\.\w+", meta["email"])
    assert meta["qgisMinimumVersion"] == "3.22"
    assert meta["hasProcessingProvider"] == "yes"
    assert (PLUGIN / meta["icon"]).is_file()


def test_class_factory_registers_and_unloads(qgis_app):
    """classFactory -> initProcessing adds the provider; unload removes it."""
    from qgis.core import QgsApplication

    import qgis_plugin
    from qgis_plugin.provider import VectorAdjustProvider

    from . import conftest

    registry = QgsApplication.processingRegistry()
    registry.removeProvider(registry.providerById("vectoradjust"))
    conftest._APP.pop("provider", None)
    try:
        plugin = qgis_plugin.classFactory(None)
        plugin.initProcessing()
        plugin.initProcessing()  # idempotent
        assert registry.providerById("vectoradjust") is plugin.provider
        assert registry.algorithmById("vectoradjust:adjustroadvectors") is not None
        plugin.unload()
        assert registry.providerById("vectoradjust") is None
    finally:
        provider = VectorAdjustProvider()
        assert registry.addProvider(provider)
        conftest._APP["provider"] = provider


@pytest.mark.parametrize("qml,geometry,renderer,attribute", [
    ("residual_arrows.qml", "LineStringZ", "singleSymbol", None),
    ("shape_points_ce90.qml", "PointZ", "graduatedSymbol", "CE90"),
    ("control_points_role.qml", "PointZ", "categorizedSymbol", "role"),
    ("features_rmse.qml", "MultiLineStringZ", "graduatedSymbol", "RMSE"),
    ("extracted_shape_points.qml", "PointZ", "singleSymbol", None),
])
def test_styles_load(qgis_app, qml, geometry, renderer, attribute):
    from qgis.core import QgsVectorLayer

    path = REPO / "resources" / "styles" / qml
    assert path.is_file()
    layer = QgsVectorLayer(f"{geometry}?crs=EPSG:32616&field=point_id:string&field=CE90:double&"
                           "field=role:string&field=RMSE:double", "t", "memory")
    msg, ok = layer.loadNamedStyle(str(path))
    assert ok, msg
    r = layer.renderer()
    assert r.type() == renderer
    if attribute:
        assert r.classAttribute() == attribute
    if qml == "residual_arrows.qml":
        assert r.symbol().symbolLayer(0).layerType() == "ArrowLine"
    if qml == "control_points_role.qml":
        assert {c.value() for c in r.categories()} >= {"control", "check"}


def test_styles_applied_to_loaded_outputs(qgis_app, sample):
    """Outputs loaded into a project (the Processing dialog) get their QML style."""
    import processing
    from qgis.core import (
        QgsProcessingContext,
        QgsProcessingFeedback,
        QgsProcessingOutputLayerDefinition,
        QgsProject,
    )

    project = QgsProject.instance()
    context = QgsProcessingContext()
    context.setProject(project)
    params = {"INPUT": str(sample / "osm_roads.shp"), "PROJECT": str(sample / "project.toml")}
    for k in ("SHAPE_POINTS", "FEATURES", "CONTROL_POINTS", "RESIDUALS"):
        params[k] = QgsProcessingOutputLayerDefinition("TEMPORARY_OUTPUT", project)
    feedback = QgsProcessingFeedback()
    out = processing.run("vectoradjust:adjustroadvectors", params, context=context,
                         feedback=feedback)
    expected = {"SHAPE_POINTS": "graduatedSymbol", "FEATURES": "graduatedSymbol",
                "CONTROL_POINTS": "categorizedSymbol", "RESIDUALS": "singleSymbol"}
    for key, renderer in expected.items():
        # processing.run hands the layer objects back (taken out of the context)
        layer = out[key] if not isinstance(out[key], str) else context.getMapLayer(out[key])
        assert context.willLoadLayerOnCompletion(layer.id()), key
        details = context.layerToLoadOnCompletionDetails(layer.id())
        assert details.postProcessor() is not None, key
        details.postProcessor().postProcessLayer(layer, context, feedback)
        assert layer.renderer().type() == renderer, key


def test_uncertainty_bands_are_styled_when_loaded(qgis_app, sample):
    """The bands layer (the one output without a QML file) gets a translucent fill per
    database when it is loaded into a project."""
    import processing
    from qgis.core import (
        QgsFillSymbol,
        QgsProcessingContext,
        QgsProcessingFeedback,
        QgsProcessingOutputLayerDefinition,
        QgsProject,
    )

    project = QgsProject.instance()
    context = QgsProcessingContext()
    context.setProject(project)
    params = {"INPUT": str(sample / "osm_roads.shp"), "PROJECT": str(sample / "project.toml"),
              "OUTPUT": QgsProcessingOutputLayerDefinition("TEMPORARY_OUTPUT", project)}
    feedback = QgsProcessingFeedback()
    out = processing.run("vectoradjust:uncertaintybands", params, context=context,
                         feedback=feedback)
    layer = out["OUTPUT"] if not isinstance(out["OUTPUT"], str) else \
        context.getMapLayer(out["OUTPUT"])
    assert layer.featureCount() > 0
    details = context.layerToLoadOnCompletionDetails(layer.id())
    assert details.postProcessor() is not None
    details.postProcessor().postProcessLayer(layer, context, feedback)
    r = layer.renderer()
    assert r.type() == "categorizedSymbol" and r.classAttribute() == "database"
    cats = r.categories()  # kept: the symbols belong to these copies
    assert [c.value() for c in cats] == ["OSM"]
    symbol = cats[0].symbol()
    assert isinstance(symbol, QgsFillSymbol)
    assert 0 < symbol.color().alpha() < 255  # translucent: the roads stay visible


def test_build_zip(tmp_path):
    from qgis_plugin import build_zip

    path = Path(build_zip.build(str(tmp_path)))
    assert path.name == f"vectoradjust_qgis-{build_zip.version()}.zip"
    with zipfile.ZipFile(path) as zf:
        names = set(zf.namelist())
    for must in ("vectoradjust_qgis/__init__.py", "vectoradjust_qgis/metadata.txt",
                 "vectoradjust_qgis/icon.png", "vectoradjust_qgis/provider.py",
                 "vectoradjust_qgis/algorithms/adjust.py",
                 "vectoradjust_qgis/algorithms/accuracy_control.py",
                 "vectoradjust_qgis/algorithms/uncertainty_bands.py",
                 "vectoradjust_qgis/algorithms/equal_error_map.py",
                 "vectoradjust_qgis/ext/vectoradjust/files/assemble.py",
                 "vectoradjust_qgis/ext/vectoradjust/accuracy/derived/__init__.py",
                 "vectoradjust_qgis/ext/vectoradjust/qa/verdict/__init__.py",
                 "vectoradjust_qgis/ext/vectoradjust/files/report/__init__.py",
                 "vectoradjust_qgis/styles/residual_arrows.qml",
                 "vectoradjust_qgis/ext/vectoradjust/pipeline.py",
                 "vectoradjust_qgis/ext/vectoradjust/adjust/bundle/__init__.py"):
        assert must in names, must
    # the plugin repository wants the licence in the zip: the GNU GPL version 2
    assert "vectoradjust_qgis/LICENSE" in names
    with zipfile.ZipFile(path) as zf:
        text = zf.read("vectoradjust_qgis/LICENSE").decode("utf-8")
    assert "GNU GENERAL PUBLIC LICENSE" in text and "Version 2, June 1991" in text
    assert not any("/tests/" in n or "__pycache__" in n or n.endswith(".pyc") for n in names)
    assert all(n.startswith("vectoradjust_qgis/") for n in names)


def test_zip_installs_and_runs(qgis_app, sample, tmp_path):
    """The zip's plugin (with its vendored core) loads in a clean Python and lists its
    algorithms: the core it carries is complete."""
    import os
    import subprocess
    import sys

    from qgis_plugin import build_zip

    path = build_zip.build(str(tmp_path / "dist"))
    with zipfile.ZipFile(path) as zf:
        zf.extractall(tmp_path / "plugins")
    code = (
        "import sys\n"
        "from qgis.core import QgsApplication\n"
        "app = QgsApplication([], False); app.initQgis()\n"
        "import vectoradjust_qgis as p\n"
        "plugin = p.classFactory(None); plugin.initProcessing()\n"
        "import vectoradjust, vectoradjust.pipeline, vectoradjust.files.assemble\n"
        "assert vectoradjust.__file__.startswith(sys.argv[1]), vectoradjust.__file__\n"
        "print(sorted(a.id() for a in plugin.provider.algorithms()))\n"
    )
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    env["PYTHONPATH"] = str(tmp_path / "plugins")
    env["QT_QPA_PLATFORM"] = "offscreen"
    proc = subprocess.run([sys.executable, "-c", code, str(tmp_path / "plugins")],
                          capture_output=True, text=True, env=env, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert "vectoradjust:adjustroadvectors" in proc.stdout
