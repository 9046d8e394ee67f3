"""The buffer test's flat and square end caps through ``processing.run``: the core's exact
capped buffers (:mod:`vectoradjust.accuracy.capped_buffer`), no GEOS buffering in the
plugin."""

import pytest

pytest.importorskip("qgis.core")

from .util import columns  # noqa: E402

pytestmark = pytest.mark.qgis

CAPS = {"round": 0, "flat": 1, "square": 2}


def run(params):
    import processing

    return processing.run("vectoradjust:bufferaccuracytest", params)


def _memory_lines(wkts, name):
    from qgis.core import QgsFeature, QgsGeometry, QgsVectorLayer

    lyr = QgsVectorLayer("LineString?crs=EPSG:32616&field=id:integer", name, "memory")
    feats = []
    for i, w in enumerate(wkts):
        f = QgsFeature(lyr.fields())
        f.setAttributes([i])
        f.setGeometry(QgsGeometry.fromWkt(w))
        feats.append(f)
    lyr.dataProvider().addFeatures(feats)
    return lyr


@pytest.mark.parametrize("cap, inside", [("round", [0.0, 10 + 2 * 3 ** 0.5, 20.0]),
                                         ("flat", [0.0, 10.0, 10.0]),
                                         ("square", [0.0, 14.0, 20.0])])
def test_caps_by_hand(qgis_app, cap, inside):
    # reference: 10 m east; tested: 20 m parallel to it, 1 m off, from 5 m before its start
    ref = _memory_lines(["LineString (500000 4000000, 500010 4000000)"], "ref")
    tst = _memory_lines(["LineString (499995 4000001, 500015 4000001)"], "tested")
    out = run({"INPUT": tst, "REFERENCE": ref, "WIDTHS": "0.5, 2, 20",
               "CAP_STYLE": CAPS[cap], "OUTPUT": "TEMPORARY_OUTPUT"})
    cols = columns(out["OUTPUT"])
    assert cols["width"] == [0.5, 2.0, 20.0]
    assert cols["inside"] == pytest.approx(inside, abs=1e-9)
    assert cols["total"] == pytest.approx([20.0] * 3, abs=1e-9)


def test_flat_and_square_caps_on_the_sample(qgis_app, sample):
    shares = {}
    for cap, k in CAPS.items():
        out = run({"INPUT": str(sample / "osm_roads.shp"),
                   "REFERENCE": str(sample / "truth_roads.shp"), "WIDTHS": "1, 5, 10",
                   "CAP_STYLE": k, "OUTPUT": "TEMPORARY_OUTPUT"})
        shares[cap] = columns(out["OUTPUT"])["share"]
    for w in range(3):  # a flat buffer lies within the square and the round one
        assert shares["flat"][w] <= shares["square"][w] + 1e-12
        assert shares["flat"][w] <= shares["round"][w] + 1e-12
    assert 0 < shares["flat"][2] < 1
