"""Fuzzing the readers of what a user writes (issue 31): the project file, the camera, the
CSV tables and the road layers. Whatever the input, a reader gives a valid result or a
:class:`~vectoradjust.errors.VectorAdjustError` (a message naming the file and the mend),
never another exception (a traceback).

In the suite each target runs a fixed, reproducible set of examples (``derandomize``;
``max_examples`` 200, 100 for the road layers, which GDAL reads). The long mode searches
afresh for as long as it is given::

    VECTORADJUST_FUZZ_MINUTES=10 pytest tests/test_fuzz_readers.py

shares the 10 minutes among the targets of this file (random examples, new each round).
"""

from __future__ import annotations

import copy
import json
import math
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pytest

hypothesis = pytest.importorskip(
    "hypothesis", reason="hypothesis is not installed (pip install -e '.[test]')")
from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from vectoradjust.errors import VectorAdjustError  # noqa: E402
from vectoradjust.files.csv_tables import (  # noqa: E402
    _read_rows,
    measurements_from_rows,
    read_control,
    read_measurements,
)
from vectoradjust.files.project import PROJECT_SCHEMA, ProjectSpec, load_project, parse_project  # noqa: E402,E501
from vectoradjust.model import ControlPoints, Measurements  # noqa: E402
from vectoradjust.sensor.camera import CameraCalibration  # noqa: E402

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python < 3.11
    import tomli as tomllib

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "resources" / "sample"
SATELLITE = SAMPLE / "satellite"

#: total minutes of the long mode, shared by the targets (0: the suite's fixed examples)
FUZZ_MINUTES = float(os.environ.get("VECTORADJUST_FUZZ_MINUTES") or 0)
TARGETS = 7  # the fuzz tests below
EXAMPLES = 200


def _round(prop, strategy, **options) -> None:
    """One hypothesis run of ``prop`` (one argument) on ``strategy``."""
    def case(value):  # a new function each round: hypothesis decorates it
        prop(value)

    case.__name__ = prop.__name__
    given(strategy)(settings(deadline=None, database=None,
                             suppress_health_check=list(HealthCheck), **options)(case))()


def _fuzz(prop, strategy, examples: int = EXAMPLES) -> int:
    """Run the property ``prop`` on ``strategy``; return the number of examples run.

    The suite: one round of ``examples`` reproducible examples. The long mode
    (``VECTORADJUST_FUZZ_MINUTES``): rounds of random examples until this target's share
    of the minutes is spent.
    """
    if FUZZ_MINUTES <= 0:
        _round(prop, strategy, max_examples=examples, derandomize=True)
        return examples
    stop = time.monotonic() + FUZZ_MINUTES * 60.0 / TARGETS
    rounds = 0
    while time.monotonic() < stop:
        _round(prop, strategy, max_examples=10 * examples)
        rounds += 1
    print(f"\n{prop.__name__}: {rounds} round(s) of {10 * examples} examples, no crash")
    return rounds * 10 * examples


@pytest.fixture(scope="module", autouse=True)
def _workdir():
    """A folder for the files the properties write (one per module run)."""
    with tempfile.TemporaryDirectory(prefix="vectoradjust-fuzz-") as d:
        WORK["dir"] = Path(d)
        yield
    WORK.clear()


WORK: dict = {}


def _write(name: str, data: bytes) -> Path:
    p = WORK["dir"] / name
    p.write_bytes(data)
    return p


# ---------------------------------------------------------------- TOML values
KEYS = sorted({k for keys in PROJECT_SCHEMA.values() for k in keys}
              | {"model", "convention", "center", "K0", "K1", "k1", "P1", "1", "2", "3", "4"})
WORDS = ("frame", "rpc", "smac", "polynomial", "mm", "pixel", "shift", "affine", "EPSG:32616",
         "EPSG:4326", "rc10.toml", "vce", "two-pass", "ellipsoidal", "orthometric", "auto",
         "topographic map", "orthophoto", "1:2000", "1,2,5", "", " ", "osm_id", "C:\\data")
SCALARS = (st.text(max_size=8) | st.sampled_from(WORDS)
           | st.integers(-2**63, 2**63 - 1) | st.integers(-3, 30000)
           | st.floats() | st.booleans() | st.dates() | st.datetimes() | st.times())
VALUES = st.recursive(
    SCALARS,
    lambda inner: st.lists(inner, max_size=6)
    | st.dictionaries(st.sampled_from(KEYS) | st.text(max_size=4), inner, max_size=5),
    max_leaves=12)


def _toml(path: Path) -> dict:
    with open(path, "rb") as fh:
        return tomllib.load(fh)


def _bases() -> list:
    """The projects the mutations start from: the frame sample with every optional table,
    and the satellite (RPC) sample."""
    frame = _toml(SAMPLE / "project.toml")
    frame["camera"] = dict(_toml(SAMPLE / "rc10.toml"))
    frame["camera"]["fiducials"] = {"1": [-106.0, -106.0], "2": [106.0, 106.0],
                                    "3": [-106.0, 106.0]}
    frame["qa"] = {"product": "topographic map", "map_scale": 2000, "contour_interval": 1.0}
    frame["conflation"] = {"k": 8, "model": "auto"}
    frame["truth"] = {"path": "truth_roads.shp", "widths": [1.0, 2.0]}
    return [(frame, SAMPLE), (_toml(SATELLITE / "project.toml"), SATELLITE)]


BASES = _bases()


@st.composite
def mutated_projects(draw):
    """A sample project with 1-4 mutations: a key removed, a value replaced or a key added,
    at any depth."""
    k = draw(st.integers(0, len(BASES) - 1))
    raw, base_dir = copy.deepcopy(BASES[k][0]), BASES[k][1]
    for _ in range(draw(st.integers(1, 4))):
        node = raw
        while node and draw(st.booleans()):
            key = draw(st.sampled_from(sorted(node) if isinstance(node, dict)
                                       else range(len(node))))
            if not isinstance(node[key], (dict, list)):
                break
            node = node[key]
        op = draw(st.integers(0, 2))
        if isinstance(node, list):
            if node:
                node[draw(st.integers(0, len(node) - 1))] = draw(VALUES)
        elif op == 0 and node:
            del node[draw(st.sampled_from(sorted(node)))]
        elif op == 1 and node:
            node[draw(st.sampled_from(sorted(node)))] = draw(VALUES)
        else:
            node[draw(st.sampled_from(KEYS))] = draw(VALUES)
    return raw, base_dir


def _project_then_downstream(spec: ProjectSpec) -> None:
    """What the command line reads from a parsed project before any work: ``[truth]``
    (path and widths) and the ``[qa]`` specification."""
    from vectoradjust.files.truth import project_truth
    from vectoradjust.qa.verdict import spec_from_table

    assert isinstance(spec.crs, str) and spec.crs
    assert spec.images and len({im.id for im in spec.images}) == len(spec.images)
    for im in spec.images:
        assert isinstance(im.id, str)
    for v in spec.vectors:
        assert isinstance(v.name, str) and isinstance(v.path, str)
        assert len(v.sigma) == 3 and all(s > 0 and math.isfinite(s) for s in v.sigma)
    truth = project_truth(spec)
    if truth is not None:
        assert all(w >= 0 and math.isfinite(w) for w in truth[1])
    if spec.raw.get("qa"):
        spec_from_table(spec.raw["qa"], source=str(spec.path))


def _parse_property(case) -> None:
    raw, base_dir = case
    try:
        spec = parse_project(raw, base_dir=base_dir, path=base_dir / "project.toml")
    except VectorAdjustError:
        return
    try:
        _project_then_downstream(spec)
    except VectorAdjustError:
        pass


def test_parse_project_gives_a_spec_or_a_vectoradjust_error():
    assert _fuzz(_parse_property, mutated_projects()) >= 1


# ----------------------------------------------------------- project file bytes
LITERALS = ('3', '"x"', "[1, 2]", "{a = 1}", "1999-10-05", "nan", "inf", "[[1]]", "true",
            '"\u00e9"', "[]", "{}", '""', "-0.0", "1e999", "[[1, 2], [3]]", "'C:\\data'",
            '"C:\\data"', "9223372036854775807", "{ 1 = [0, 0], 2 = [1] }", "[ { a = 1 } ]")
ENCODINGS = ("utf-8", "utf-8-sig", "latin-1", "cp1252", "utf-16", "utf-16-le", "utf-32")


@st.composite
def project_bytes(draw):
    """The sample project's text with lines edited (a value replaced by another TOML literal,
    a line dropped or doubled, random text inserted), in any of several encodings, and
    sometimes cut or with random bytes written over it."""
    text = (SAMPLE / "project.toml").read_text(encoding="utf-8").splitlines()
    for _ in range(draw(st.integers(0, 4))):
        i = draw(st.integers(0, len(text) - 1))
        op = draw(st.integers(0, 3))
        if op == 0 and "=" in text[i]:
            text[i] = text[i].split("=")[0] + "= " + draw(st.sampled_from(LITERALS))
        elif op == 1:
            del text[i]
        elif op == 2:
            text.insert(i, text[i])
        else:
            text.insert(i, draw(st.text(max_size=20)))
    body = "\n".join(text) + "\n"
    data = body.encode(draw(st.sampled_from(ENCODINGS)), errors="replace")
    if draw(st.booleans()):
        at = draw(st.integers(0, len(data)))
        data = data[:at] + draw(st.binary(max_size=12)) + data[at + draw(st.integers(0, 8)):]
    return data


def _load_property(data: bytes) -> None:
    p = WORK["dir"] / "project.toml"
    p.write_bytes(data)
    try:
        spec = load_project(p)
    except VectorAdjustError:
        return
    assert isinstance(spec, ProjectSpec)


def test_load_project_gives_a_spec_or_a_vectoradjust_error():
    for name in ("rc10.toml", "gcps.csv"):  # what the sample's relative paths name
        (WORK["dir"] / name).write_bytes((SAMPLE / name).read_bytes())
    assert _fuzz(_load_property, project_bytes() | st.binary(max_size=200)) >= 1


# ------------------------------------------------------------------ the camera
CAMERA_KEYS = ("name", "focal_length", "principal_point", "fiducials", "distortion",
               "pixel_size", "image_size", "pixel_origin", "path")
CAMERA_VALUES = st.recursive(
    SCALARS | st.none() | st.integers(),
    lambda inner: st.lists(inner, max_size=5) | st.tuples(inner, inner)
    | st.dictionaries(st.sampled_from(KEYS) | st.text(max_size=3), inner, max_size=5),
    max_leaves=16)
GOOD_CAMERA = {"focal_length": 152.4, "principal_point": [0.003, -0.001], "pixel_size": 0.012,
               "image_size": [19200, 19200],
               "fiducials": {"1": [-106.0, -106.0], "2": [106.0, 106.0], "3": [-106.0, 106.0]},
               "distortion": {"model": "smac", "K0": -2e-4, "K1": 4e-8, "P1": -1e-7}}


@st.composite
def camera_tables(draw):
    d = copy.deepcopy(GOOD_CAMERA)
    for key in draw(st.lists(st.sampled_from(CAMERA_KEYS), max_size=3)):
        if draw(st.booleans()):
            d.pop(key, None)
        else:
            d[key] = draw(CAMERA_VALUES)
    return d


def _camera_property(d) -> None:
    try:
        cam = CameraCalibration.from_dict(d, base_dir=WORK["dir"], where="fuzz [camera]")
    except VectorAdjustError:
        return
    assert cam.focal_length > 0 and math.isfinite(cam.focal_length)
    assert all(math.isfinite(v) for v in cam.principal_point)


def test_camera_table_gives_a_calibration_or_a_vectoradjust_error():
    _write("camera.toml", b'focal_length = 88.0\n[fiducials]\n1 = [0, 0]\n2 = [1, 0]\n'
                          b'3 = [0, 1]\n')
    assert _fuzz(_camera_property, camera_tables() | st.dictionaries(
        st.sampled_from(CAMERA_KEYS), CAMERA_VALUES, max_size=6)) >= 1


def _camera_file_property(data: bytes) -> None:
    p = _write("cam_fuzz.toml", data)
    try:
        cam = CameraCalibration.from_file(p)
    except VectorAdjustError:
        return
    assert cam.focal_length > 0


@st.composite
def camera_file_bytes(draw):
    text = (SAMPLE / "rc10.toml").read_text(encoding="utf-8").splitlines()
    for _ in range(draw(st.integers(1, 3))):
        i = draw(st.integers(0, len(text) - 1))
        if "=" in text[i] and draw(st.booleans()):
            text[i] = text[i].split("=")[0] + "= " + draw(st.sampled_from(LITERALS))
        else:
            text.insert(i, draw(st.sampled_from(("[fiducials]", "[distortion]", "[camera]",
                                                  "1 = [1, 2]", "a = 1", "[fiducials.1]"))))
    return ("\n".join(text) + "\n").encode(draw(st.sampled_from(ENCODINGS)), errors="replace")


def test_camera_file_gives_a_calibration_or_a_vectoradjust_error():
    assert _fuzz(_camera_file_property, camera_file_bytes() | st.binary(max_size=100)) >= 1


# ------------------------------------------------------------------ CSV tables
CELLS = (st.sampled_from(("1", "-2.5", "0", "1e3", "1e400", "nan", "inf", "-0", "", " ",
                          "0,5", "a", "P1", "L", "R", "control", "check", "CHECK", "x",
                          "\u00e9", "\x1f", '"q"', "1\r2", "\x00"))
         | st.text(max_size=6) | st.floats(allow_nan=True).map(repr))
MEASUREMENT_HEADER = ("point_id", "image_id", "x", "y", "sigma_x", "sigma_y")
CONTROL_HEADER = ("point_id", "X", "Y", "Z", "sigma_x", "sigma_y", "sigma_z", "role")


@st.composite
def csv_bytes(draw, columns):
    """A CSV table: a header of known (sometimes misspelt, repeated or extra) columns, rows
    of good and bad cells, some ragged or blank, any line ending, BOM and encoding."""
    cols = draw(st.lists(st.sampled_from(columns + ("extra", "Point_ID", "")), min_size=1,
                         max_size=len(columns) + 1))
    if draw(st.booleans()):
        cols = list(columns[:4 + draw(st.integers(0, len(columns) - 4))])
    good = st.sampled_from(("P1", "P2", "P3", "L", "R")) | st.floats(-1e6, 1e6).map(repr)
    rows = draw(st.lists(st.lists(good | CELLS, min_size=len(cols) - 1, max_size=len(cols) + 1)
                         | st.just([]), max_size=8))
    quote = draw(st.booleans())
    lines = [",".join(cols)] + [",".join(f'"{c}"' if quote and c and draw(st.booleans()) else c
                                         for c in r) for r in rows]
    text = draw(st.sampled_from(("\n", "\r\n", "\r"))).join(lines)
    text += draw(st.sampled_from(("", "\n", "\n\n")))
    return text.encode(draw(st.sampled_from(ENCODINGS)), errors="replace")


def _measurements_property(case) -> None:
    data, sigma, unit = case
    p = _write("points.csv", data)
    try:
        m = read_measurements(str(p), sigma, unit)
    except VectorAdjustError as exc:
        fast = exc
    else:
        fast = m
        assert isinstance(m, Measurements)
        assert m.xy.shape == m.sigma.shape == (len(m.point_id), 2)
        assert np.all(np.isfinite(m.xy)) and np.all(m.sigma > 0)
    # the fast reader and the careful one agree (the same result or both an error)
    try:
        header, rows, lines = _read_rows(str(p))
        careful = measurements_from_rows(header, rows, str(p), sigma, unit, lines=lines)
    except VectorAdjustError as exc:
        careful = exc
    assert isinstance(fast, VectorAdjustError) == isinstance(careful, VectorAdjustError)
    if isinstance(fast, Measurements):
        assert fast.point_id.tolist() == careful.point_id.tolist()
        assert fast.image_id.tolist() == careful.image_id.tolist()
        np.testing.assert_array_equal(fast.xy, careful.xy)
        np.testing.assert_array_equal(fast.sigma, careful.sigma)
        np.testing.assert_array_equal(fast.rows, careful.rows)


def test_measurement_csv_gives_measurements_or_a_vectoradjust_error():
    case = st.tuples(csv_bytes(MEASUREMENT_HEADER) | st.binary(max_size=80),
                     st.sampled_from((None, 0.015, 0.5)), st.sampled_from(("mm", "pixel")))
    assert _fuzz(_measurements_property, case) >= 1


def _control_property(data: bytes) -> None:
    p = _write("gcps.csv", data)
    try:
        c = read_control(str(p))
    except VectorAdjustError:
        return
    assert isinstance(c, ControlPoints)
    assert c.xyz.shape == c.sigma.shape == (len(c.point_id), 3)
    assert np.all(np.isfinite(c.xyz)) and np.all(c.sigma > 0)
    assert set(c.role.tolist()) <= {"control", "check"}


def test_control_csv_gives_points_or_a_vectoradjust_error():
    assert _fuzz(_control_property, csv_bytes(CONTROL_HEADER) | st.binary(max_size=80)) >= 1


# ------------------------------------------------------------------ road layers
COORD = (st.floats(-1e7, 1e7) | st.sampled_from((0.0, 1e308, -1e308, 506000.0, 4475000.0))
         | st.floats())
POSITION = st.lists(COORD, min_size=2, max_size=4)
GEOMETRY = st.one_of(
    st.none(),
    st.builds(lambda c: {"type": "LineString", "coordinates": c},
              st.lists(POSITION, max_size=4)),
    st.builds(lambda c: {"type": "MultiLineString", "coordinates": c},
              st.lists(st.lists(POSITION, max_size=3), max_size=3)),
    st.builds(lambda c: {"type": "Point", "coordinates": c}, POSITION),
    st.builds(lambda c: {"type": "Polygon", "coordinates": [c]},
              st.lists(POSITION, min_size=4, max_size=5)),
    st.builds(lambda c: {"type": "GeometryCollection", "geometries": [
        {"type": "LineString", "coordinates": c}]}, st.lists(POSITION, max_size=3)),
    st.dictionaries(st.sampled_from(("type", "coordinates")), VALUES, max_size=2),
)
PROPERTY = (st.integers(-2**63, 2**63 - 1) | st.floats() | st.text(max_size=6) | st.none()
            | st.booleans() | st.sampled_from(("1", "1", "a")))
FEATURE = st.builds(
    lambda g, props: {"type": "Feature", "geometry": g, "properties": props},
    GEOMETRY, st.dictionaries(st.sampled_from(("id", "name", "highway", "Id")), PROPERTY,
                              max_size=3))
CRS_MEMBER = st.sampled_from((None, "urn:ogc:def:crs:EPSG::32616", "urn:ogc:def:crs:OGC:1.3:CRS84",
                              "EPSG:4326", "nonsense", "urn:ogc:def:crs:EPSG::4978"))


@st.composite
def geojson_bytes(draw):
    doc = {"type": "FeatureCollection", "features": draw(st.lists(FEATURE, max_size=5))}
    crs = draw(CRS_MEMBER)
    if crs is not None:
        doc["crs"] = {"type": "name", "properties": {"name": crs}}
    data = json.dumps(doc, allow_nan=True, default=str).encode()
    if draw(st.integers(0, 4)) == 0:  # a damaged file
        at = draw(st.integers(0, len(data)))
        data = data[:at] + draw(st.binary(max_size=6)) + data[at + draw(st.integers(0, 6)):]
    return data


def _layer_property(case) -> None:
    from pyproj import CRS

    from vectoradjust.files.readers import read_line_layer

    data, suffix, id_field, where, layer = case
    p = _write(f"roads{suffix}", data)
    try:
        out = read_line_layer(str(p), "fuzz", id_field, CRS.from_epsg(32616), layer=layer,
                              where=where)
    except VectorAdjustError:
        return
    n = len(out.feature_ids)
    assert len(set(out.feature_ids.tolist())) == n
    assert out.coords.shape[1] == 3 and len(out.vertex_feature) == len(out.coords)
    assert all(len(v) == n for v in out.attributes.values())


@pytest.mark.io
def test_line_layer_gives_a_layer_or_a_vectoradjust_error():
    pytest.importorskip("pyogrio", reason="pyogrio is not installed")
    case = st.tuples(geojson_bytes() | st.binary(max_size=60),
                     st.sampled_from((".geojson", ".geojson", ".json", ".gpkg", ".shp", ".csv")),
                     st.sampled_from((None, None, "id", "name", "missing")),
                     st.sampled_from((None, None, "id > 0", "highway IS NOT NULL", "((",
                                      "nosuchfield = 1")),
                     st.sampled_from((None, None, "roads", "nosuch")))
    assert _fuzz(_layer_property, case, examples=100) >= 1
