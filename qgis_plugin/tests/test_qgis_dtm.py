"""The "DTM accuracy" algorithm through ``processing.run``: its dialog's defaults, the same
raster and contours as the headless ``vectoradjust dtm`` (numpy 1.24 / scipy 1.10 here,
the venv's versions there), the DEM source and its messages."""

import json

import numpy as np
import pytest

pytest.importorskip("qgis.core")

from .conftest import run_headless  # noqa: E402
from .test_qgis_dialogs import dialog_parameters  # noqa: E402

pytestmark = pytest.mark.qgis


def run(params, context=None):
    import processing
    from qgis.core import QgsProcessingContext, QgsProcessingFeedback, QgsProject

    if context is None:
        context = QgsProcessingContext()
        context.setProject(QgsProject.instance())
    return processing.run("vectoradjust:dtmaccuracy", params, context=context,
                          feedback=QgsProcessingFeedback()), context


def _raster(path):
    from osgeo import gdal  # QGIS's own GDAL

    ds = gdal.Open(str(path))
    assert ds is not None, path
    bands = [ds.GetRasterBand(i) for i in range(1, ds.RasterCount + 1)]
    return {"gt": ds.GetGeoTransform(), "count": ds.RasterCount,
            "desc": [b.GetDescription() for b in bands],
            "nodata": bands[0].GetNoDataValue(),
            "data": np.stack([b.ReadAsArray() for b in bands]).astype(float)}


def _layer(out, key, context):
    layer = out[key]
    return context.getMapLayer(layer) if isinstance(layer, str) and context.getMapLayer(
        layer) is not None else layer


@pytest.fixture(scope="module")
def headless_dtm(sample, tmp_path_factory):
    out = tmp_path_factory.mktemp("headless_dtm")
    run_headless(["-m", "vectoradjust.cli", "dtm", str(sample / "project.toml"), "--out",
                  str(out), "-q"])
    with open(out / "dtm.json", encoding="utf-8") as fh:
        return out, json.load(fh)


def test_dialog_defaults_match_the_headless_command(qgis_app, sample, headless_dtm, tmp_path):
    params = dialog_parameters("dtmaccuracy", {"PROJECT": str(sample / "project.toml")})
    assert params["CELL"] == 5.0 and params["CONTOUR_INTERVAL"] == 1.0
    assert params["INTERPOLATION"] == 0 and params["SOURCE"] == 0  # tin, the points
    params["OUTPUT"] = str(tmp_path / "dtm.tif")
    out, context = run(params)
    ref_dir, ref = headless_dtm
    mine, theirs = _raster(out["OUTPUT"]), _raster(ref_dir / "dtm_accuracy.tif")
    assert mine["count"] == theirs["count"] == 5 and mine["desc"] == theirs["desc"]
    assert mine["gt"] == pytest.approx(theirs["gt"], abs=1e-9)
    a, b = mine["data"], theirs["data"]
    nod = theirs["nodata"]
    assert np.array_equal(a == nod, b == nod) and (a != nod).any()
    ok = b != nod
    # float32 storage: the same values to a float32 step
    assert np.all(np.abs(a[ok] - b[ok]) <= np.maximum(1e-9, 2 * np.spacing(
        np.abs(b[ok]).astype(np.float32))))
    assert out["CELLS"] == ref["summary"]["cells"]
    assert out["SIGMA_MEDIAN"] == pytest.approx(ref["summary"]["sigma"]["median"], rel=1e-6)
    assert out["SEGMENTS"] == ref["contours"]["segments"] > 100
    lines = _layer(out, "CONTOURS", context)
    assert lines.featureCount() == out["SEGMENTS"]
    levels = {f["level"] for f in lines.getFeatures()}
    assert all(abs(lv - round(lv)) < 1e-9 for lv in levels)
    buffers = _layer(out, "CONTOUR_BUFFERS", context)
    assert buffers.featureCount() == len(levels)
    for f in buffers.getFeatures():
        assert f.geometry().area() > 0 and f["max_sigma_xy"] >= f["mean_sigma_xy"] > 0


def test_dem_source_with_independent_nodes(qgis_app, sample, tmp_path):
    params = dialog_parameters("dtmaccuracy", {
        "PROJECT": str(sample / "project.toml"), "SOURCE": 1, "INTERPOLATION": 1,
        "NODE_SIGMA": 0.3, "CONTOUR_INTERVAL": 2.0})
    params["OUTPUT"] = str(tmp_path / "dem.tif")
    out, context = run(params)
    r = _raster(out["OUTPUT"])
    sig_int = r["data"][3][r["data"][3] != r["nodata"]]
    # 5 m cells centred between four 5 m DEM nodes: sigma_n / 2 from the interpolation
    assert np.median(sig_int) == pytest.approx(0.15, rel=1e-5)
    levels = {f["level"] for f in _layer(out, "CONTOURS", context).getFeatures()}
    assert levels and all(abs(lv / 2.0 - round(lv / 2.0)) < 1e-9 for lv in levels)


def test_dem_source_refuses_a_tin(qgis_app, sample, tmp_path):
    from qgis.core import QgsProcessingException

    params = dialog_parameters("dtmaccuracy", {
        "PROJECT": str(sample / "project.toml"), "SOURCE": 1, "INTERPOLATION": 0})
    params["OUTPUT"] = str(tmp_path / "x.tif")
    with pytest.raises(QgsProcessingException, match=r"a DEM is a grid") as exc:
        run(params)
    assert "--source" not in str(exc.value)
