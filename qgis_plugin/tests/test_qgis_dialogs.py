"""Every algorithm run the way a user runs it from its dialog: the dialog is built by
Processing's GUI (``processing.gui.AlgorithmDialog``), only what a user must choose is
set (the project file, the layers), every other value is what the dialog's widgets give
(``createProcessingParameters()``: untouched tables, empty numbers, NULL fields, outputs
to temporary files), and the algorithm run with those parameters must succeed."""

import pytest

pytest.importorskip("qgis.core")

pytestmark = pytest.mark.qgis

ALGORITHMS = ("extractshapepoints", "adjustroadvectors", "compareroaddatabases",
              "bufferaccuracytest", "accuracycontrol", "uncertaintybands", "equalerrormap",
              "gcpstudy", "measureonimages", "dtmaccuracy", "smartconflation")


@pytest.fixture(scope="module")
def layers(qgis_app, sample):
    """The sample's road layers loaded in the QGIS project, as a user has them."""
    from qgis.core import QgsProject, QgsVectorLayer

    out = {}
    for name in ("osm_roads", "tnm_roads", "tiger_roads", "truth_roads"):
        lyr = QgsVectorLayer(str(sample / f"{name}.shp"), name, "ogr")
        assert lyr.isValid(), name
        out[name] = lyr
    QgsProject.instance().addMapLayers(list(out.values()))
    yield out
    QgsProject.instance().removeMapLayers([lyr.id() for lyr in out.values()])


def dialog_parameters(alg_id, user):
    """The parameters the dialog of ``vectoradjust:alg_id`` gives when the user set ``user``."""
    from processing.gui.AlgorithmDialog import AlgorithmDialog
    from qgis.core import QgsApplication

    alg = QgsApplication.processingRegistry().algorithmById(f"vectoradjust:{alg_id}")
    assert alg is not None, alg_id
    dialog = AlgorithmDialog(alg.create(), False, None)
    try:
        dialog.setParameters(user)
        return dialog.mainWidget().createProcessingParameters()
    finally:
        dialog.deleteLater()


def user_choices(alg_id, sample, layers):
    """What a user must choose in each dialog for the sample."""
    if alg_id == "smartconflation":  # adjusted features (test_smart_conflation_alg.py)
        from .test_smart_conflation_alg import adjusted_layers

        return {"LAYERS": adjusted_layers(sample)}
    project = str(sample / "project.toml")
    osm = layers["osm_roads"]
    return {
        "extractshapepoints": {"INPUT": osm},
        "adjustroadvectors": {"INPUT": osm, "PROJECT": project},
        "compareroaddatabases": {"PROJECT": project, "LAYERS": [
            layers["osm_roads"], layers["tnm_roads"], layers["tiger_roads"]]},
        "bufferaccuracytest": {"INPUT": osm, "REFERENCE": layers["truth_roads"]},
        # the sample project has no [qa] table: the product and its scale are the user's
        "accuracycontrol": {"PROJECT": project, "PRODUCT": 0, "SCALE": 2000.0,
                            "CONTOUR_INTERVAL": 1.0},
        "uncertaintybands": {"INPUT": osm, "PROJECT": project},
        "equalerrormap": {"PROJECT": project},
        "gcpstudy": {"PROJECT": project},
        # the sample has no image files: the default run predicts positions only
        "measureonimages": {"PROJECT": project},
        "dtmaccuracy": {"PROJECT": project},
    }[alg_id]


def test_every_algorithm_has_a_dialog_test(qgis_app):
    from qgis.core import QgsApplication

    provider = QgsApplication.processingRegistry().providerById("vectoradjust")
    assert sorted(a.name() for a in provider.algorithms()) == sorted(ALGORITHMS)


def test_untouched_images_table_is_null(qgis_app, sample, layers):
    """The dialog gives the untouched Images table as ``[NULL]`` (what the fix handles)."""
    params = dialog_parameters("adjustroadvectors", user_choices("adjustroadvectors", sample,
                                                                 layers))
    assert len(params["IMAGES"]) <= 1


@pytest.mark.parametrize("alg_id", ALGORITHMS)
def test_dialog_defaults_run(qgis_app, sample, layers, alg_id):
    import processing
    from qgis.core import QgsProcessingContext, QgsProcessingFeedback, QgsProject

    params = dialog_parameters(alg_id, user_choices(alg_id, sample, layers))
    context = QgsProcessingContext()
    context.setProject(QgsProject.instance())
    out = processing.run(f"vectoradjust:{alg_id}", params, context=context,
                         feedback=QgsProcessingFeedback())
    assert out
    if "OUTPUT" in out and alg_id not in ("equalerrormap", "dtmaccuracy"):  # rasters
        layer = out["OUTPUT"]
        if isinstance(layer, str):
            layer = context.getMapLayer(layer)
        assert layer is not None and layer.featureCount() > 0


def test_messages_name_the_dialog_parameters(qgis_app, sample, layers):
    """A core message that names a command-line flag names the dialog's parameter instead."""
    import processing
    from qgis.core import QgsProcessingException

    params = dialog_parameters("equalerrormap", dict(
        user_choices("equalerrormap", sample, layers), SPACING=100000.0))
    with pytest.raises(QgsProcessingException,
                       match=r"do not overlap.*Choose a stereo pair with overlap") as exc:
        processing.run("vectoradjust:equalerrormap", params)
    msg = str(exc.value)
    assert "do not overlap" in msg
    assert "--images" not in msg and "'Stereo pair'" in msg
