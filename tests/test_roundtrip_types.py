"""Nothing lost (issue 31): every input attribute comes out of ``vectoradjust adjust`` with
its type and value, and every feature id with its value.

The sample project is copied and its OSM road layer replaced by a GeoPackage (or a
GeoJSON, or a shapefile) with the same geometries and ``osm_id`` values plus fields of
every kind: int64 beyond 2^53 and negative, int32, real, unicode text, date, date and
time, boolean, NULLs, a field that is NULL everywhere. The ``features`` layer must carry
each field with the OGR type (and subtype) it was read with and the same values; the
``shape_points`` ids must be the exact ids. A shapefile output writes what the format
can hold and names every field it changes among the run's warnings. Ids above 2^53 (an
OSM id plus 2^60) keep their value whether the input is a GeoPackage or a shapefile
whose id field GDAL reads as reals by default.
"""

from __future__ import annotations

import datetime as dt
import json
import math
import re
import shutil
from pathlib import Path

import pytest

pytestmark = pytest.mark.io
gpd = pytest.importorskip("geopandas")
pa = pytest.importorskip("pyarrow")
pyogrio = pytest.importorskip("pyogrio")

from vectoradjust.cli.commands import main  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "resources" / "sample"
OFFSET = 2 ** 60  # ids above 2^53: osm_id + 2^60
FIELDS = ["osm_id", "name", "highway", "big", "i32", "flt", "txt", "day", "stamp", "flag",
          "empty"]


def _sample() -> Path:
    if not (SAMPLE / "project.toml").is_file():
        pytest.skip(f"the sample project is missing: {SAMPLE}")
    return SAMPLE


def _read(path, layer=None):
    """``{field: values}`` (plain Python through Arrow: int64 exact, dates as dates, a date
    and time as the text GDAL reads, ISO 8601) and ``{field: (OGR type, subtype)}``."""
    kw = {"layer": layer} if layer else {}
    table = pyogrio.read_arrow(str(path), read_geometry=False, datetime_as_string=True,
                               **kw)[1]
    info = pyogrio.read_info(str(path), **kw)
    types = {f: (t, s) for f, t, s in zip(info["fields"], info["ogr_types"],
                                           info["ogr_subtypes"])}
    return {c: table.column(c).to_pylist() for c in table.column_names}, types


def _column(values, arrow_type):
    import pandas as pd

    return pd.arrays.ArrowExtensionArray(pa.array(values, type=arrow_type, from_pandas=True))


def _typed_frame(geojson: bool = False):
    """The sample's OSM roads with a field of every kind (NULLs in each)."""
    roads = pyogrio.read_dataframe(SAMPLE / "osm_roads.shp")
    n = len(roads)
    # GDAL's GeoJSON reader takes negative integers of 19 digits for reals: at most 18
    low = -(2 ** 53) - 7 if geojson else -(2 ** 62) - 3
    high = 2 ** 62 + 5 if geojson else 2 ** 63 - 1  # GDAL warns of 2^63 - 1 in a GeoJSON
    big = [2 ** 53 + 1 + 7 * i for i in range(n)]
    big[1], big[2], big[3] = low, None, high
    i32 = [i - 5 for i in range(n)]
    i32[3], i32[4], i32[5] = None, -(2 ** 31), 2 ** 31 - 1
    flt = [0.1 * i for i in range(n)]
    flt[4], flt[6] = None, 1e-20
    txt = [f"Straße ✓ 東京 ﷺ 🚗 {i}" for i in range(n)]
    txt[5] = None
    day = [dt.date(2020, 1, 1) + dt.timedelta(days=i) for i in range(n)]
    day[6], day[7] = None, dt.date(1850, 2, 3)
    stamp = [dt.datetime(2021, 3, 4, 5, 6, 7, 123000) + dt.timedelta(hours=i) for i in range(n)]
    stamp[8] = None
    flag = [bool(i % 2) for i in range(n)]
    flag[9] = None
    cols = {"osm_id": _column(roads["osm_id"].astype("int64").tolist(), pa.int64()),
            "name": _column(roads["name"].tolist(), pa.string()),
            "highway": _column(roads["highway"].tolist(), pa.string()),
            "big": _column(big, pa.int64()), "i32": _column(i32, pa.int32()),
            "flt": _column(flt, pa.float64()), "txt": _column(txt, pa.string()),
            "day": _column(day, pa.date32()), "stamp": _column(stamp, pa.timestamp("ms")),
            "flag": _column(flag, pa.bool_()), "empty": _column([None] * n, pa.int64())}
    return gpd.GeoDataFrame(cols, geometry=roads.geometry.values, crs=roads.crs)


def _project(tmp: Path, ext: str) -> Path:
    """The sample in ``tmp`` with its OSM layer as ``osm_roads.<ext>`` of every kind."""
    d = tmp / f"sample_{ext}"
    shutil.copytree(_sample(), d)
    for f in d.glob("osm_roads.*"):
        f.unlink()
    frame = _typed_frame(geojson=ext == "geojson")
    driver = {"gpkg": "GPKG", "geojson": "GeoJSON"}[ext]
    pyogrio.write_dataframe(frame, d / f"osm_roads.{ext}", driver=driver, use_arrow=True,
                            promote_to_multi=False)
    toml = (d / "project.toml").read_text(encoding="utf-8")
    (d / "project.toml").write_text(toml.replace("osm_roads.shp", f"osm_roads.{ext}"),
                                    encoding="utf-8")
    return d


def _adjust(project: Path, out: Path, fmt: str) -> dict:
    assert main(["adjust", str(project / "project.toml"), "--out", str(out), "--vectors", "OSM",
                 "--format", fmt, "--no-bands", "-q"]) == 0
    return json.loads((out / "summary.json").read_text(encoding="utf-8"))


def _features(out: Path, fmt: str):
    return _read(out / "adjusted.gpkg", "features") if fmt == "gpkg" else _read(
        out / "features.shp")


def _shape_points(out: Path, fmt: str):
    return _read(out / "adjusted.gpkg", "shape_points")[0] if fmt == "gpkg" else _read(
        out / "shape_points.shp")[0]


def _by_id(values: dict) -> dict:
    """The columns re-ordered by osm_id."""
    order = sorted(range(len(values["osm_id"])), key=lambda i: int(values["osm_id"][i]))
    return {k: [v[i] for i in order] for k, v in values.items()}


@pytest.fixture(scope="module")
def gpkg_project(tmp_path_factory):
    return _project(tmp_path_factory.mktemp("rt"), "gpkg")


@pytest.fixture(scope="module")
def gpkg_run(gpkg_project, tmp_path_factory):
    out = tmp_path_factory.mktemp("rt_gpkg_out")
    return out, _adjust(gpkg_project, out, "gpkg")


@pytest.fixture(scope="module")
def shp_run(gpkg_project, tmp_path_factory):
    out = tmp_path_factory.mktemp("rt_shp_out")
    return out, _adjust(gpkg_project, out, "shp")


# --------------------------------------------------------------------------- reading
def test_the_reader_gives_every_value_with_its_type(gpkg_project):
    from pyproj import CRS

    from vectoradjust.files.readers import read_line_layer

    layer = read_line_layer(str(gpkg_project / "osm_roads.gpkg"), "OSM", "big",
                            CRS("EPSG:32616"), where="big IS NOT NULL AND i32 IS NOT NULL")
    a = layer.attributes
    frame = _typed_frame()
    expected = {c: pa.array(frame[c].array).to_pylist() for c in FIELDS}
    kept = [i for i, (b, k) in enumerate(zip(expected["big"], expected["i32"]))
            if b is not None and k is not None]
    for c in FIELDS:
        assert a[c] == [expected[c][i] for i in kept], c
    assert layer.feature_ids.tolist() == [str(expected["big"][i]) for i in kept]
    assert "-4611686018427387907" in layer.feature_ids.tolist()
    # the filtered feature's id, exact (its i32 is NULL; the one without an id has none)
    assert layer.reading["excluded_feature_ids"] == [str(2 ** 63 - 1)]
    assert type(a["day"][0]) is dt.date and type(a["stamp"][0]) is dt.datetime
    assert type(a["big"][0]) is int and type(a["flag"][0]) is bool
    assert layer.reading["fields"] == {
        "osm_id": "int64", "name": "string", "highway": "string", "big": "int64",
        "i32": "int32", "flt": "double", "txt": "string", "day": "date32[day]",
        "stamp": "timestamp[ms]", "flag": "bool", "empty": "int64"}


def test_ids_read_as_reals_beyond_2_53_are_an_error(tmp_path):
    """GDAL reads a GeoJSON's negative integers of 19 digits as reals: such ids are not
    used rounded."""
    from pyproj import CRS

    from vectoradjust.errors import LayerError
    from vectoradjust.files.readers import read_line_layer

    path = tmp_path / "roads.geojson"
    path.write_text(json.dumps({"type": "FeatureCollection", "features": [
        {"type": "Feature", "properties": {"rid": v},
         "geometry": {"type": "LineString", "coordinates": [[506000, 4475000 + k],
                                                            [506100, 4475000 + k]]}}
        for k, v in enumerate([-4611686018427387907, -4611686018427387906, 12])]}))
    with pytest.raises(LayerError, match=r"roads\.geojson: the ids of field 'rid' are read "
                                         r"as real numbers, and 2 of them lie beyond 2\^53.*"
                                         r"Store the ids as text"):
        read_line_layer(str(path), "R", "rid", CRS("EPSG:32616"))


def test_attribute_array_keeps_the_stated_type():
    from vectoradjust.files.outputs import attribute_array, input_field_types

    assert attribute_array([None, None], "int32").type == pa.int32()
    assert attribute_array([None, None], "timestamp[ms, tz=UTC]").type == pa.timestamp(
        "ms", "UTC")
    assert attribute_array([2 ** 63 - 1, None], "int64").to_pylist() == [2 ** 63 - 1, None]
    assert attribute_array([1.5, float("nan")]).to_pylist() == [1.5, None]
    assert attribute_array([dt.date(2020, 1, 2), "x"], "date32[day]").to_pylist() == [
        "2020-01-02", "x"]  # no common type: text
    assert input_field_types.__doc__


def test_field_change_names_what_a_shapefile_cannot_hold():
    from vectoradjust.files.outputs import field_change

    assert field_change("int64", [2 ** 53 + 1, -(2 ** 53)], "shp") is None
    as_text, what = field_change("int64", [1, -(2 ** 62)], "shp")
    assert as_text and "wider than 18 characters (e.g. -4611686018427387904)" in what
    assert field_change("int64", [2 ** 62], "gpkg") is None
    assert field_change("datetime", [dt.datetime(2020, 1, 1)], "shp")[0] is True
    assert field_change("datetime", [dt.datetime(2020, 1, 1)], "gpkg") is None
    assert field_change("time", [dt.time(1, 2)], "gpkg")[0] is True
    as_text, what = field_change("int32", [2 ** 31 - 1], "shp")
    assert not as_text and "read back as 64-bit integers" in what
    as_text, what = field_change("float64", [0.1, 0.1 * 3, 1e-20, None], "shp")
    assert not as_text and "2 of its 3 values with more than 15 decimals" in what
    assert field_change("date", [dt.date(1850, 1, 1)], "shp") is None
    assert field_change("bool", [True, None], "shp") is None


# --------------------------------------------------------------------------- GeoPackage
def test_gpkg_output_keeps_every_field_type_and_value(gpkg_project, gpkg_run):
    out, summary = gpkg_run
    given, given_types = _read(gpkg_project / "osm_roads.gpkg")
    got, got_types = _features(out, "gpkg")
    given, got = _by_id(given), _by_id(got)
    for c in FIELDS:
        assert got_types[c] == given_types[c], c
        assert got[c] == given[c], c
    assert got_types["big"] == ("OFTInteger64", "OFSTNone")
    assert got_types["day"][0] == "OFTDate" and got_types["stamp"][0] == "OFTDateTime"
    assert got_types["flag"] == ("OFTInteger", "OFSTBoolean")
    assert got_types["empty"][0] == "OFTInteger64" and set(got["empty"]) == {None}
    assert -(2 ** 62) - 3 in got["big"] and 2 ** 63 - 1 in got["big"]
    assert not [w for w in summary.get("warnings", []) if "field '" in w]
    assert summary["databases"][0]["input"]["fields"]["big"] == "int64"


def test_gpkg_shape_points_carry_the_exact_ids(gpkg_project, gpkg_run):
    out, _ = gpkg_run
    given, _ = _read(gpkg_project / "osm_roads.gpkg")
    sp = _shape_points(out, "gpkg")
    assert set(sp["feature_id"]) == {str(v) for v in given["osm_id"]}
    assert all(p.startswith(f"{f}_") for p, f in zip(sp["point_id"], sp["feature_id"]))


def test_geojson_input_keeps_every_field_type_and_value(tmp_path):
    project = _project(tmp_path, "geojson")
    out = tmp_path / "out"
    _adjust(project, out, "gpkg")
    given, given_types = _read(project / "osm_roads.geojson")
    got, got_types = _features(out, "gpkg")
    given, got = _by_id(given), _by_id(got)
    assert given_types["big"][0] == "OFTInteger64"  # what the test is about
    assert given_types["day"][0] == "OFTDate" and given_types["stamp"][0] == "OFTDateTime"
    for c in FIELDS:
        assert got_types[c] == given_types[c], c
        assert got[c] == given[c], c
    assert 2 ** 62 + 5 in got["big"] and -(2 ** 53) - 7 in got["big"]


# --------------------------------------------------------------------------- shapefile
def test_shapefile_output_writes_what_it_can_and_warns(gpkg_project, shp_run):
    out, summary = shp_run
    given, given_types = _read(gpkg_project / "osm_roads.gpkg")
    got, got_types = _features(out, "shp")
    given, got = _by_id(given), _by_id(got)
    for c in ("osm_id", "name", "highway", "txt", "day", "flag", "empty"):
        assert got_types[c] == given_types[c], c
        assert got[c] == given[c], c
    # int64 wider than 18 characters: text, every digit
    assert got_types["big"][0] == "OFTString"
    assert got["big"] == [None if v is None else str(v) for v in given["big"]]
    # no date-time type: ISO 8601 text
    assert got_types["stamp"][0] == "OFTString"
    assert got["stamp"] == given["stamp"]
    assert got["stamp"][0] == "2021-03-04T05:06:07.123"
    # 32-bit integers of 10 or 11 characters: read back as 64-bit, values unchanged
    assert got_types["i32"][0] == "OFTInteger64" and got["i32"] == given["i32"]
    # reals: 15 decimals
    assert got_types["flt"][0] == "OFTReal"
    assert got["flt"] == [None if v is None else float(f"{v:.15f}") for v in given["flt"]]
    warned = {m.group(1): w for w in summary["warnings"]
              if (m := re.match(r"features\.shp: field '(\w+)' ", w))}
    assert set(warned) == {"big", "stamp", "i32", "flt"}, summary["warnings"]
    assert "written as text, every digit kept" in warned["big"]
    assert "--format gpkg" in warned["big"] and "ISO 8601" in warned["stamp"]
    assert "values with more than 15 decimals (e.g. 0.30000000000000004 is written as 0.3)" \
        in warned["flt"]
    sp = _shape_points(out, "shp")
    assert set(sp["feature_id"]) == {str(v) for v in given["osm_id"]}


# --------------------------------------------------------------------------- ids > 2^53
def _big_id_project(tmp: Path) -> Path:
    """The sample with osm_id + 2^60 as a shapefile (GDAL widens the DBF field to 19+
    digits, which it reads as reals by default) and the measurements and truth renamed."""
    d = tmp / "big_ids"
    shutil.copytree(_sample(), d)
    roads = pyogrio.read_dataframe(d / "osm_roads.shp")
    old = {str(v) for v in roads["osm_id"]}
    roads["osm_id"] = roads["osm_id"].astype("int64") + OFFSET
    for f in d.glob("osm_roads.*"):
        f.unlink()
    pyogrio.write_dataframe(roads, d / "osm_roads.shp", use_arrow=True)
    for name in ("image_points.csv", "truth_osm.csv"):
        text = (d / name).read_text(encoding="utf-8")
        text = re.sub(r"^(\d+)_", lambda m: f"{int(m.group(1)) + OFFSET}_" if m.group(1) in old
                      else m.group(0), text, flags=re.M)
        (d / name).write_text(text, encoding="utf-8")
    return d


def test_ids_above_2_53_keep_their_value(tmp_path):
    project = _big_id_project(tmp_path)
    ids = [int(v) for v in pyogrio.read_dataframe(SAMPLE / "osm_roads.shp")["osm_id"]]
    assert pyogrio.read_info(project / "osm_roads.shp")["ogr_types"][0] == "OFTReal"
    out = tmp_path / "out"
    summary = _adjust(project, out, "gpkg")
    got, types = _features(out, "gpkg")
    assert types["osm_id"][0] == "OFTInteger64"
    assert sorted(got["osm_id"]) == sorted(v + OFFSET for v in ids)
    sp = _shape_points(out, "gpkg")
    assert set(sp["feature_id"]) == {str(v + OFFSET) for v in ids}
    measured = {line.split(",")[0] for line in (project / "image_points.csv").read_text(
        encoding="utf-8").splitlines()[1:] if re.match(r"\d{19}_", line)}
    assert measured and measured <= set(sp["point_id"])  # every measured id is a vertex
    assert sum(sp["Adjusted"]) >= len(measured)  # measured, and shared by a measured one
    db = summary["databases"][0]
    assert db["input"]["fields"]["osm_id"] == "int64"
    assert math.isfinite(summary["sigma0_squared"])


def test_where_filter_on_a_geojson_with_an_id_field(tmp_path):
    """pyogrio's Arrow path indexes such a file by (fid, id) pairs: the reader falls back
    to NumPy there, so the kept and excluded features stay right (found by fuzzing)."""
    import json

    from pyproj import CRS

    from vectoradjust.files.readers import read_line_layer

    feats = [{"type": "Feature", "properties": {"id": i, "name": n},
              "geometry": {"type": "LineString", "coordinates": [[0, k], [1, k + 1]]}}
             for k, (i, n) in enumerate([(1, "a"), (0, "b"), (5, "c")])]
    path = tmp_path / "roads.geojson"
    path.write_text(json.dumps({"type": "FeatureCollection", "features": feats}))
    by_index = read_line_layer(str(path), "X", None, CRS("EPSG:4326"), where="id > 0")
    assert by_index.feature_ids.tolist() == ["0", "2"]
    assert by_index.reading["excluded_feature_ids"] == ["1"]
    by_name = read_line_layer(str(path), "X", "name", CRS("EPSG:4326"), where="id > 0")
    assert by_name.feature_ids.tolist() == ["a", "c"]
    assert by_name.reading["excluded_feature_ids"] == ["b"]
    # an "id" field with another field "Id" beside it: the id values are still read
    path2 = tmp_path / "ids.geojson"
    path2.write_text(json.dumps({"type": "FeatureCollection", "features": [
        {"type": "Feature", "properties": {"id": k, "Id": None},
         "geometry": {"type": "LineString", "coordinates": [[0, k], [1, k + 1]]}}
        for k in (0, 3)]}))
    by_id = read_line_layer(str(path2), "X", "id", CRS("EPSG:4326"), where="id > 0")
    assert by_id.feature_ids.tolist() == ["3"]
    assert by_id.reading["excluded_feature_ids"] == ["0"]
