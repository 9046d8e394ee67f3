"""Nothing lost in the QGIS sinks (issue 31): the adjust algorithm's features sink carries
every input field with its QGIS type and value (int64 beyond 2^53 exact, dates, date and
time, booleans, unicode, NULLs), in a memory layer and a GeoPackage; a shapefile sink
writes what the format can hold (64-bit integers that read back as integers, wider ones
and dates with times as text) and names every changed field among the warnings. Ids above
2^53 in a shapefile whose id field QGIS reads as reals are read exactly from a project's
entry, and refused with a clear message from a layer loaded without the option.

The road layer is built with the QGIS API (QGIS's Python has no pyarrow): the sample's
OSM roads, their geometries and ``osm_id`` values, plus a field of every kind."""

import json
import re
import shutil

import pytest

pytest.importorskip("qgis.core")

pytestmark = pytest.mark.qgis

SINKS = ("SHAPE_POINTS", "FEATURES", "CONTROL_POINTS", "RESIDUALS")
OFFSET = 2 ** 60
FIELDS = ["osm_id", "name", "highway", "big", "i32", "flt", "txt", "day", "stamp", "flag",
          "empty"]


def run(alg, params):
    import processing

    return processing.run(f"vectoradjust:{alg}", params)


def _values(n):
    """Per-feature values of the added fields (None = NULL)."""
    import datetime as dt

    big = [2 ** 53 + 1 + 7 * i for i in range(n)]
    big[1], big[2], big[3] = -(2 ** 62) - 3, None, 2 ** 63 - 1
    i32 = [i - 5 for i in range(n)]
    i32[3], i32[4], i32[5] = None, -(2 ** 31) + 1, 2 ** 31 - 1  # QGIS refuses -2^31
    flt = [0.1 * i for i in range(n)]
    flt[4] = None
    txt = [f"Straße ✓ 東京 ﷺ 🚗 {i}" for i in range(n)]
    txt[5] = None
    day = [dt.date(2020, 1, 1) + dt.timedelta(days=i) for i in range(n)]
    day[6], day[7] = None, dt.date(1850, 2, 3)
    stamp = [dt.datetime(2021, 3, 4, 5, 6, 7) + dt.timedelta(hours=i) for i in range(n)]
    stamp[8] = None
    flag = [bool(i % 2) for i in range(n)]
    flag[9] = None
    return {"big": big, "i32": i32, "flt": flt, "txt": txt, "day": day, "stamp": stamp,
            "flag": flag, "empty": [None] * n}


def _write(layer_fields, rows, geoms, path, driver):
    from qgis.core import (
        QgsCoordinateReferenceSystem,
        QgsCoordinateTransformContext,
        QgsFeature,
        QgsGeometry,
        QgsVectorFileWriter,
        QgsWkbTypes,
    )

    opts = QgsVectorFileWriter.SaveVectorOptions()
    opts.driverName = driver
    opts.fileEncoding = "UTF-8"
    w = QgsVectorFileWriter.create(str(path), layer_fields, QgsWkbTypes.MultiLineString,
                                   QgsCoordinateReferenceSystem("EPSG:32616"),
                                   QgsCoordinateTransformContext(), opts)
    assert w.hasError() == QgsVectorFileWriter.NoError, w.errorMessage()
    for values, g in zip(rows, geoms):
        f = QgsFeature(layer_fields)
        f.setAttributes(values)
        g = QgsGeometry(g)
        g.convertToMultiType()
        f.setGeometry(g)
        assert w.addFeature(f), (w.errorMessage(), values)
    del w


def _typed_project(sample, tmp):
    """The sample with its OSM layer as a GeoPackage holding a field of every kind."""
    from qgis.core import QgsField, QgsFields, QgsVectorLayer
    from qgis.PyQt.QtCore import QDate, QDateTime, QVariant

    d = tmp / "sample_gpkg"
    shutil.copytree(sample, d)
    src = QgsVectorLayer(str(sample / "osm_roads.shp"), "osm", "ogr")
    feats = list(src.getFeatures())
    vals = _values(len(feats))
    fields = QgsFields()
    for name, t in (("osm_id", QVariant.LongLong), ("name", QVariant.String),
                    ("highway", QVariant.String), ("big", QVariant.LongLong),
                    ("i32", QVariant.Int), ("flt", QVariant.Double), ("txt", QVariant.String),
                    ("day", QVariant.Date), ("stamp", QVariant.DateTime),
                    ("flag", QVariant.Bool), ("empty", QVariant.LongLong)):
        fields.append(QgsField(name, t))
    rows = []
    for i, f in enumerate(feats):
        v = {k: vals[k][i] for k in vals}
        rows.append([int(f["osm_id"]), f["name"], f["highway"], v["big"], v["i32"], v["flt"],
                     v["txt"], None if v["day"] is None else QDate(v["day"]),
                     None if v["stamp"] is None else QDateTime(v["stamp"]), v["flag"], None])
    _write(fields, rows, [f.geometry() for f in feats], d / "osm_roads.gpkg", "GPKG")
    toml = (d / "project.toml").read_text(encoding="utf-8")
    (d / "project.toml").write_text(toml.replace("osm_roads.shp", "osm_roads.gpkg"),
                                    encoding="utf-8")
    return d


def _plain(v):
    from qgis.PyQt.QtCore import QDate, QDateTime, QVariant

    if v is None or (isinstance(v, QVariant) and v.isNull()):
        return None
    if isinstance(v, QDateTime):
        return v.toPyDateTime()
    if isinstance(v, QDate):
        return v.toPyDate()
    return v


def _layer_columns(layer):
    """``{field: values}`` and ``{field: QVariant type}`` of a layer, by osm_id."""
    names = layer.fields().names()
    rows = sorted(([_plain(v) for v in f.attributes()] for f in layer.getFeatures()),
                  key=lambda r: int(r[names.index("osm_id")]))
    return ({n: [r[k] for r in rows] for k, n in enumerate(names)},
            {f.name(): f.type() for f in layer.fields()})


def _adjust(project, features, tmp, name):
    summary = tmp / f"{name}.json"
    p = {"INPUT": str(project / "osm_roads.gpkg"), "PROJECT": str(project / "project.toml"),
         "SUMMARY": str(summary)}
    for k in SINKS:
        p[k] = "TEMPORARY_OUTPUT"
    p["FEATURES"] = features
    out = run("adjustroadvectors", p)
    return out, json.loads(summary.read_text(encoding="utf-8"))


def _as_layer(dest, name="features"):
    from qgis.core import QgsVectorLayer

    if not isinstance(dest, str):
        return dest
    layer = QgsVectorLayer(dest, name, "ogr")
    assert layer.isValid(), dest
    return layer


@pytest.fixture(scope="module")
def typed(qgis_app, sample, tmp_path_factory):
    from qgis.core import QgsVectorLayer

    tmp = tmp_path_factory.mktemp("qgis_rt")
    project = _typed_project(sample, tmp)
    given = QgsVectorLayer(str(project / "osm_roads.gpkg"), "given", "ogr")
    return tmp, project, _layer_columns(given)


@pytest.mark.parametrize("dest", ["TEMPORARY_OUTPUT", "features.gpkg"])
def test_sink_keeps_every_field_type_and_value(typed, dest):
    from qgis.PyQt.QtCore import QVariant

    tmp, project, (given, given_types) = typed
    target = dest if dest == "TEMPORARY_OUTPUT" else str(tmp / dest)
    out, summary = _adjust(project, target, tmp, dest.split(".")[0])
    got, got_types = _layer_columns(_as_layer(out["FEATURES"]))
    for c in FIELDS:
        assert got_types[c] == given_types[c], c
        assert got[c] == given[c], c
    assert got_types["big"] == QVariant.LongLong and got_types["i32"] == QVariant.Int
    assert got_types["day"] == QVariant.Date and got_types["stamp"] == QVariant.DateTime
    assert got_types["flag"] == QVariant.Bool
    assert -(2 ** 62) - 3 in got["big"] and 2 ** 63 - 1 in got["big"]
    assert got["empty"] == [None] * len(got["empty"])
    assert not [w for w in summary.get("warnings", []) if "field '" in w]
    sp = _layer_columns_plain(out["SHAPE_POINTS"])
    assert set(sp["feature_id"]) == {str(v) for v in given["osm_id"]}


def _layer_columns_plain(layer):
    names = layer.fields().names()
    cols = {n: [] for n in names}
    for f in layer.getFeatures():
        for n, v in zip(names, f.attributes()):
            cols[n].append(_plain(v))
    return cols


def test_shapefile_sink_writes_what_it_can_and_warns(typed):
    from qgis.PyQt.QtCore import QVariant

    tmp, project, (given, given_types) = typed
    out, summary = _adjust(project, str(tmp / "features.shp"), tmp, "shp")
    got, got_types = _layer_columns(_as_layer(out["FEATURES"]))
    for c in ("osm_id", "name", "highway", "txt", "day"):
        assert got_types[c] == given_types[c], c
        assert got[c] == given[c], c
    assert got_types["osm_id"] == QVariant.LongLong  # not reals (QGIS's default width 20)
    assert got_types["NPts"] == QVariant.LongLong
    assert got_types["big"] == QVariant.String
    assert got["big"] == [None if v is None else str(v) for v in given["big"]]
    assert got_types["stamp"] == QVariant.String
    assert got["stamp"] == [None if v is None else v.isoformat() for v in given["stamp"]]
    assert got["i32"] == given["i32"]  # 11 characters: read back as 64-bit
    assert got["flag"] == [None if v is None else int(v) for v in given["flag"]]
    warned = {m.group(1): w for w in summary["warnings"]
              if (m := re.match(r"features \(features\.shp\): field '(\w+)' ", w))}
    assert {"big", "stamp", "i32", "flag"} <= set(warned), summary["warnings"]
    assert "every digit kept" in warned["big"] and "write a GeoPackage" in warned["big"]
    assert "ISO 8601" in warned["stamp"]


# --------------------------------------------------------------------------- ids > 2^53
def _big_id_project(sample, tmp):
    """The sample with osm_id + 2^60 in a shapefile QGIS writes 20 digits wide (read as
    reals by default), the measurements and truth renamed."""
    from qgis.core import QgsField, QgsFields, QgsVectorLayer
    from qgis.PyQt.QtCore import QVariant

    d = tmp / "big_ids"
    shutil.copytree(sample, d)
    src = QgsVectorLayer(str(sample / "osm_roads.shp"), "osm", "ogr")
    feats = list(src.getFeatures())
    old = {str(int(f["osm_id"])) for f in feats}
    fields = QgsFields()
    for name, t in (("osm_id", QVariant.LongLong), ("name", QVariant.String),
                    ("highway", QVariant.String)):
        fields.append(QgsField(name, t))
    for f in d.glob("osm_roads.*"):
        f.unlink()
    _write(fields, [[int(f["osm_id"]) + OFFSET, f["name"], f["highway"]] for f in feats],
           [f.geometry() for f in feats], d / "osm_roads.shp", "ESRI Shapefile")
    for name in ("image_points.csv", "truth_osm.csv"):
        text = (d / name).read_text(encoding="utf-8")
        text = re.sub(r"^(\d+)_", lambda m: f"{int(m.group(1)) + OFFSET}_" if m.group(1) in old
                      else m.group(0), text, flags=re.M)
        (d / name).write_text(text, encoding="utf-8")
    return d, sorted(int(o) + OFFSET for o in old)


def test_ids_above_2_53_from_a_project_entry_are_exact(qgis_app, sample, tmp_path):
    from qgis.core import QgsVectorLayer
    from qgis.PyQt.QtCore import QVariant

    from qgis_plugin.qgis_io import shapefile_uri

    project, ids = _big_id_project(sample, tmp_path)
    plain = QgsVectorLayer(str(project / "osm_roads.shp"), "plain", "ogr")
    assert plain.fields().field("osm_id").type() == QVariant.Double  # what this is about
    layer = QgsVectorLayer(shapefile_uri(project / "osm_roads.shp"), "roads", "ogr")
    assert layer.fields().field("osm_id").type() == QVariant.LongLong
    p = {"INPUT": layer, "PROJECT": str(project / "project.toml")}
    for k in SINKS:
        p[k] = "TEMPORARY_OUTPUT"
    out = run("adjustroadvectors", p)
    got = _layer_columns_plain(out["FEATURES"])
    assert sorted(got["osm_id"]) == ids
    sp = _layer_columns_plain(out["SHAPE_POINTS"])
    assert set(sp["feature_id"]) == {str(v) for v in ids}
    assert sum(sp["Adjusted"]) > 0


def test_ids_read_as_reals_beyond_2_53_are_refused(qgis_app, sample, tmp_path):
    from qgis.core import QgsProcessingException, QgsVectorLayer

    project, _ = _big_id_project(sample, tmp_path)
    plain = QgsVectorLayer(str(project / "osm_roads.shp"), "plain", "ogr")
    p = {"INPUT": plain, "PROJECT": str(project / "project.toml"),
         "SHAPE_POINTS": "TEMPORARY_OUTPUT"}
    with pytest.raises(QgsProcessingException,
                       match=r"ids of field 'osm_id' are read as real numbers beyond 2\^53.*"
                             r"ADJUST_TYPE=YES"):
        run("adjustroadvectors", p)
