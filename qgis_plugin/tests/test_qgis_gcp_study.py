"""The GCP study algorithm: held-out control points scored as check points, the
configuration layer, the output folder, and user errors named."""

import csv

import pytest

pytest.importorskip("qgis.core")

pytestmark = pytest.mark.qgis


def _run(params):
    import processing
    from qgis.core import QgsProcessingContext, QgsProcessingFeedback, QgsProject

    context = QgsProcessingContext()
    context.setProject(QgsProject.instance())
    out = processing.run("vectoradjust:gcpstudy", params, context=context,
                         feedback=QgsProcessingFeedback())
    return out, context


def _layer(out, key, context):
    layer = out[key]
    return context.getMapLayer(layer) if isinstance(layer, str) else layer


def test_configurations_hold_out_and_score_the_other_gcps(qgis_app, sample, tmp_path):
    out, context = _run({"PROJECT": str(sample / "project.toml"),
                         "CONFIGURATIONS": "3-North,mine=GCP01;GCP02;GCP03",
                         "NUMBERS": "24", "OUTPUT": "memory:", "CONFIG_POINTS": "memory:",
                         "OUTPUT_FOLDER": str(tmp_path / "study")})
    table = _layer(out, "OUTPUT", context)
    rows = {f["label"]: f for f in table.getFeatures()}
    assert sorted(rows) == ["24 spread", "3-North", "mine"]
    assert rows["mine"]["control_ids"] == "GCP01 GCP02 GCP03"
    assert rows["mine"]["n_held_out"] == 21 and rows["3-North"]["n_held_out"] == 21
    assert rows["24 spread"]["n_held_out"] == 0
    # 6 check points of the project + 21 held out
    assert rows["mine"]["n_check"] == 27 and rows["24 spread"]["n_check"] == 6
    assert 0.0 < rows["24 spread"]["check_rmse_h"] < rows["mine"]["check_rmse_h"] < 1.0
    pts = _layer(out, "CONFIG_POINTS", context)
    kept = {}
    for f in pts.getFeatures():
        if f["kept"] == 1:
            kept.setdefault(f["config"], []).append(f["point_id"])
    assert sorted(kept["3-North"]) == sorted(rows["3-North"]["control_ids"].split())
    assert len(kept["24 spread"]) == 24
    with open(tmp_path / "study" / "gcp_study.csv", encoding="utf-8") as fh:
        assert [r["label"] for r in csv.DictReader(fh)] == ["24 spread", "3-North", "mine"]
    assert (tmp_path / "study" / "gcp_summary.csv").is_file()


def test_an_unknown_configuration_is_named(qgis_app, sample):
    from qgis.core import QgsProcessingException

    with pytest.raises(QgsProcessingException, match="3-Up"):
        _run({"PROJECT": str(sample / "project.toml"), "CONFIGURATIONS": "3-Up",
              "OUTPUT": "memory:"})
