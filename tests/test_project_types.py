"""No traceback for any project file (issue 31): every table and key of the project is
type-checked and a wrong one is named with its place; encodings are detected (a UTF-8
byte order mark is read, another encoding is named with the line, the byte and how to
save the file as UTF-8); a folder, a missing or an unreadable project says so; the camera,
the CSV tables and the road layers it names fail the same way, with a message."""

from __future__ import annotations

import builtins
import copy
import sys
from pathlib import Path

import pytest

from vectoradjust.errors import CameraError, CSVError, InputFileError, ProjectError
from vectoradjust.files.csv_tables import read_control, read_measurements
from vectoradjust.files.project import load_project, parse_project
from vectoradjust.sensor import camera as camera_module
from vectoradjust.sensor.camera import CameraCalibration

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python < 3.11
    import tomli as tomllib

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "resources" / "sample"
TEXT = (SAMPLE / "project.toml").read_text(encoding="utf-8")


@pytest.fixture()
def project(tmp_path) -> Path:
    """A copy of the sample project's file (and its camera file) to break."""
    for name in ("project.toml", "rc10.toml"):
        (tmp_path / name).write_bytes((SAMPLE / name).read_bytes())
    return tmp_path / "project.toml"


@pytest.fixture()
def raw() -> dict:
    with open(SAMPLE / "project.toml", "rb") as fh:
        out = tomllib.load(fh)
    out["camera"] = dict(tomllib.loads((SAMPLE / "rc10.toml").read_text(encoding="utf-8")))
    return copy.deepcopy(out)


def _parse(raw: dict):
    return parse_project(raw, base_dir=SAMPLE, path=SAMPLE / "project.toml")


# ------------------------------------------------------------------ encodings
def test_a_utf8_byte_order_mark_is_read(project):
    project.write_bytes(b"\xef\xbb\xbf" + TEXT.encode("utf-8"))
    spec = load_project(project)
    assert spec.crs == "EPSG:32616" and [v.name for v in spec.vectors] == ["OSM", "TNM", "TIGER"]


def test_a_latin1_project_names_the_encoding_line_and_byte(project):
    text = TEXT.replace('name = "vectoradjust', 'name = "Sète vectoradjust')
    project.write_bytes(text.encode("latin-1"))
    with pytest.raises(ProjectError, match=r"project\.toml' is not UTF-8 but seems encoded as "
                       r"Latin-1 \(ISO-8859-1\): line 2, column 10 holds the byte 0xE8, 'è' in "
                       r"Latin-1 .*Save it as UTF-8.*iconv -f LATIN1 -t UTF-8") as err:
        load_project(project)
    assert err.value.details["encoding"] == "latin-1" and err.value.details["line"] == 2


def test_a_windows_1252_project_is_named_so(project):
    project.write_bytes(TEXT.replace("seed 35", "seed \u201c35\u201d").encode("cp1252"))
    with pytest.raises(ProjectError, match=r"seems encoded as Windows-1252.*'\u201c' in "
                       r"Windows-1252.*iconv -f WINDOWS-1252"):
        load_project(project)


@pytest.mark.parametrize("encoding, said", [
    ("utf-16", r"is encoded as UTF-16 \(little-endian\), with a byte order mark; TOML files "
               r"must be UTF-8\. Save it as UTF-8"),
    ("utf-16-be", r"seems encoded as UTF-16BE \(UTF-16 without a byte order mark\)"),
    ("utf-16-le", r"seems encoded as UTF-16LE"),
    ("utf-32", r"is encoded as UTF-32 \(little-endian\), with a byte order mark"),
])
def test_a_utf16_or_utf32_project_is_named_so(project, encoding, said):
    project.write_bytes(TEXT.encode(encoding))
    with pytest.raises(ProjectError, match=said):
        load_project(project)


def test_a_binary_file_given_as_the_project_is_said_to_be_one(project):
    project.write_bytes(b"II*\x00" + bytes(64))
    with pytest.raises(ProjectError, match=r"is not a text file: it looks like a TIFF image"):
        load_project(project)
    project.write_bytes(b"crs = 1\n\x00\x01\x02\x00\xff")
    with pytest.raises(ProjectError, match=r"is not a text file \(line 2, column 1 holds the "
                                           r"byte 0x00\)"):
        load_project(project)


def test_a_table_or_layer_given_as_the_project_is_named(tmp_path):
    csv = tmp_path / "gcps.csv"
    csv.write_bytes((SAMPLE / "gcps.csv").read_bytes())
    with pytest.raises(ProjectError, match=r"gcps\.csv: not valid TOML .*line 1: 'point_id,X.*"
                                           r"This is a \.csv, not the project file"):
        load_project(csv)
    with pytest.raises(ProjectError, match=r"osm_roads\.shp' is not a text file: it looks like "
                                           r"a shapefile"):
        load_project(SAMPLE / "osm_roads.shp")


def test_a_latin1_camera_file_names_the_encoding(project):
    cam = project.parent / "rc10.toml"
    cam.write_bytes(cam.read_text(encoding="utf-8").replace("SIMULATED", "SIMULÉ")
                    .encode("latin-1"))
    with pytest.raises(CameraError, match=r"Camera file .*rc10\.toml is not UTF-8 but seems "
                                          r"encoded as Latin-1"):
        load_project(project)


# ------------------------------------------------------- the file itself
def test_a_folder_says_folder_and_lists_its_toml_files(project):
    with pytest.raises(ProjectError, match=r"is a folder, not a file\. Give one of the \.toml "
                       r"files inside it \(project\.toml, rc10\.toml\), e\.g\. .*project\.toml"):
        load_project(project.parent)
    (project.parent / "rc10.toml").unlink()
    with pytest.raises(ProjectError, match=r"is a folder.*Give the \.toml file inside it: "
                                           r".*project\.toml"):
        load_project(project.parent)
    empty = project.parent / "empty"
    empty.mkdir()
    with pytest.raises(ProjectError, match=r"is a folder.*this folder holds no \.toml file"):
        load_project(empty)


def test_a_missing_project_names_the_nearest_file(project):
    with pytest.raises(ProjectError, match=r"projet\.toml' does not exist.*perhaps "
                                           r".*project\.toml"):
        load_project(project.parent / "projet.toml")


def _unreadable(monkeypatch, path: Path) -> None:
    """Opening ``path`` fails as it does without read permission (the tests run as root,
    whom permissions do not stop)."""
    real = builtins.open

    def fake(file, *args, **kwargs):
        if Path(file) == path:
            raise PermissionError(13, "Permission denied", str(file))
        return real(file, *args, **kwargs)

    monkeypatch.setattr(camera_module.camera_file, "open", fake, raising=False)


def test_an_unreadable_project_says_permission_denied(project, monkeypatch):
    _unreadable(monkeypatch, project)
    with pytest.raises(ProjectError, match=r"project\.toml' cannot be read: permission denied\. "
                                           r"Give yourself read permission"):
        load_project(project)


def test_adjust_says_the_project_is_unreadable_not_the_output_folder(project, monkeypatch,
                                                                   capsys):
    from vectoradjust.cli.commands import main

    _unreadable(monkeypatch, project)
    blocker = project.parent / "a_file"
    blocker.write_text("not a folder")
    assert main(["adjust", str(project), "-o", str(blocker / "out"), "-q"]) == 1
    err = capsys.readouterr().err
    assert "cannot be read: permission denied" in err and "project.toml" in err
    assert "output" not in err


# ------------------------------------------------------------------ TOML syntax
def test_a_windows_path_in_double_quotes_is_explained(project):
    project.write_text(TEXT.replace('path = "gcps.csv"', 'path = "C:\\data\\gcps.csv"'),
                       encoding="utf-8")
    with pytest.raises(ProjectError, match=r"not valid TOML .*line \d+: 'path = \"C:.*perhaps "
                                           r"a Windows path in double quotes: write it in single "
                                           r"quotes"):
        load_project(project)


def test_nesting_beyond_the_parser_is_an_error(project):
    project.write_text("crs = " + "[" * 5000 + "]" * 5000 + "\n", encoding="utf-8")
    with pytest.raises(ProjectError, match="nested too deeply"):
        load_project(project)


# ------------------------------------------------------------------ tables and keys
def test_vectors_3_is_not_an_array_of_tables(raw):
    raw["vectors"] = 3
    with pytest.raises(ProjectError, match=r"project\.toml: vectors = 3 must be an array of "
                                           r"tables\. Write one \[\[vectors\]\] table per road"):
        _parse(raw)


def _set(raw: dict, where: tuple, value) -> None:
    node = raw
    for k in where[:-1]:
        node = node[k]
    node[where[-1]] = value


# (where in the raw project, the wrong value, what the message says: the place and the key)
WRONG = [
    (("crs",), 32616, r"project\.toml: crs must be a text, not 32616"),
    (("name",), ["a"], r"project\.toml: name must be a text, not \['a'\]"),
    (("description",), 3, r"description must be a text"),
    (("vertical_crs",), 5703, r"vertical_crs must be a non-empty text, not 5703"),
    (("heights",), ["ellipsoidal"], r"heights = \['ellipsoidal'\] is unknown"),
    (("vectors",), "osm.shp", r"vectors = 'osm\.shp' must be an array of tables"),
    (("images",), 3, r"images = 3 must be an array of tables"),
    (("images", 0), "L", r"\[\[images\]\] entry 1: must be a table, not 'L'"),
    (("images", 0, "id"), ["L"], r"\[\[images\]\] entry 1: id must be a text"),
    (("images", 0, "model"), ["rpc"], r"\[\[images\]\] id 'L': model = \['rpc'\] is unknown"),
    (("images", 0, "position"), "0,0,0", r"id 'L': position must be a list of 3 numbers"),
    (("images", 0, "attitude"), {"omega": 0}, r"id 'L': attitude must be a list of 3"),
    (("images", 0, "sigma_position"), "100", r"id 'L': sigma_position must be a number"),
    (("images", 0, "date"), 5, r"id 'L': date must be a date \(1999-10-05\) or a text, not 5"),
    (("images", 0, "path"), 5, r"id 'L': path must be a file path string, not 5"),
    (("images", 0, "bias"), {"a": 1}, r"id 'L': bias is given but the image is a frame"),
    (("measurements",), "pts.csv", r"measurements must be a table \(\[measurements\]\)"),
    (("measurements", "path"), 3, r"\[measurements\] path must be a file path string, not 3"),
    (("measurements", "unit"), ["mm"], r"\[measurements\]: unit = \['mm'\] is not known"),
    (("measurements", "sigma"), "0.015", r"\[measurements\] sigma \(mm\) must be a number"),
    (("measurements", "fiducials"), 1, r"\[measurements\] fiducials must be a file path"),
    (("control", "path"), ["gcps.csv"], r"\[control\] path must be a file path string"),
    (("control", "crs"), 4326, r"\[control\]: crs must be a non-empty text, not 4326"),
    (("vectors", 0), 1, r"\[\[vectors\]\] entry 1: must be a table, not 1"),
    (("vectors", 0, "name"), {"a": 1}, r"\[\[vectors\]\] entry 1: name must be a text"),
    (("vectors", 0, "path"), 1, r"entry 1 \('OSM'\): path must be a file path string, not 1"),
    (("vectors", 0, "path"), "roads\x00.shp", r"entry 1 \('OSM'\): path must be a file path"),
    (("vectors", 0, "layer"), 1, r"entry 1 \('OSM'\): layer must be a non-empty text"),
    (("vectors", 0, "where"), ["a"], r"entry 1 \('OSM'\): where must be a non-empty text"),
    (("vectors", 0, "id_field"), 5, r"entry 1 \('OSM'\): id_field must be the name of a field"),
    (("vectors", 0, "sigma"), "10", r"entry 1 \('OSM'\): sigma must be a list of 3 numbers"),
    (("vectors", 0, "identification_sigma"), {"h": 1},
     r"entry 1 \('OSM'\): identification_sigma must be a number or \[horizontal, vertical\]"),
    (("vectors", 0, "offset"), ["shift"], r"entry 1 \('OSM'\): offset must be one of"),
    (("vectors", 0, "dem"), 1, r"entry 1 \('OSM'\): dem must be a file path string"),
    (("vectors", 0, "truth"), [], r"entry 1 \('OSM'\): truth must be a file path string"),
    (("adjustment", "max_iterations"), "20", r"\[adjustment\] max_iterations must be a positive"),
    (("adjustment", "alpha"), [0.05], r"\[adjustment\] alpha must be a number"),
    (("adjustment", "reweight"), ["vce"], r"\[adjustment\] reweight = \['vce'\] is not known"),
    (("adjustment", "snooping"), "yes", r"\[adjustment\] snooping must be true or false"),
    (("truth", "path"), 1, r"\[truth\]: path must be a file path string, not 1"),
    (("truth", "widths"), 5, r"\[truth\]: widths must be distances >= 0 in metres, not 5"),
    (("truth", "widths"), [1.0, -2.0], r"\[truth\]: widths must be distances >= 0"),
    (("truth", "widths"), "1,x", r"\[truth\]: widths must be distances >= 0"),
    (("corrections", "refraction"), "yes", r"\[corrections\].*refraction"),
    (("camera", "focal_length"), "long", r"\[camera\]: focal_length must be a number"),
    (("camera", "principal_point"), {"x": 0, "y": 0},
     r"project\.toml \[camera\]: principal_point must be two numbers \[x, y\]"),
    (("camera", "pixel_size"), {"a": 1, "b": 2}, r"\[camera\]: pixel_size must be two numbers"),
    (("camera", "image_size"), {"c": 1, "r": 2}, r"\[camera\]: image_size must be \[columns"),
    (("camera", "image_size"), [1e300, 2], r"\[camera\]: image_size must be two positive whole"),
    (("camera", "name"), ["RC10"], r"\[camera\]: name must be a text"),
    (("camera", "distortion"), ["smac"], r"\[camera\]: distortion must be a table or a model"),
    (("camera", "distortion", "model"), ["smac"], r"distortion model must be a name"),
    (("camera", "distortion", "center"), {"x": 0, "y": 0},
     r"\[camera\]: distortion\.center must be two numbers"),
    (("camera", "fiducials"), [[1, 2], [3, 4], [5, 6]], r"fiducials must be a table of id ="),
    (("camera", "fiducials"), {"1": {"x": -106.0, "y": -106.0}, "2": [1, 0], "3": [0, 1]},
     r"project\.toml \[camera\]: fiducial 1 must be \[x, y\] \(mm\), not a table"),
    (("camera", "fiducials"), {"x": [1, 2], "y": [3, 4], "z": "5, 6"},
     r"\[camera\]: fiducial z must be two numbers \[x, y\], not '5, 6'"),
    (("conflation", "k"), "8", r"\[conflation\] k = '8' is not an integer"),
]


@pytest.mark.parametrize("where, value, said", WRONG, ids=[
    ".".join(map(str, w)) + f"={v!r}"[:20] for w, v, _ in WRONG])
def test_every_key_of_the_wrong_type_is_named_with_its_place(raw, where, value, said):
    raw.setdefault("conflation", {"k": 8})
    raw.setdefault("truth", {"path": "truth_roads.shp"})
    _set(raw, where, value)
    with pytest.raises((ProjectError, CameraError), match=said):
        _parse(raw)


def test_a_long_value_is_cut_in_the_message(raw):
    raw["vectors"][0]["sigma"] = "x" * 10000
    with pytest.raises(ProjectError, match=r"sigma must be a list of 3 numbers") as err:
        _parse(raw)
    assert len(str(err.value)) < 400


def test_a_fiducial_table_of_tables_in_a_camera_file(tmp_path):
    (tmp_path / "cam.toml").write_text("focal_length = 88.0\n[fiducials.1]\nx = 1\ny = 2\n",
                                       encoding="utf-8")
    with pytest.raises(CameraError, match=r"camera file .*cam\.toml with the inline keys of "
                                          r"p\.toml \[camera\]: fiducial 1 must be \[x, y\]"):
        CameraCalibration.from_dict({"path": "cam.toml", "name": "c"}, tmp_path,
                                    where="p.toml [camera]")
    with pytest.raises(CameraError, match=r"camera file .*cam\.toml: fiducial 1 must be"):
        CameraCalibration.from_file(tmp_path / "cam.toml")


def test_the_rpc_keys_and_heights_still_parse():
    spec = load_project(SAMPLE / "satellite" / "project.toml")
    assert spec.heights == "ellipsoidal" and spec.has_rpc
    assert [im.rpc.bias for im in spec.images] == ["shift"] * 3


# ------------------------------------------------------------------ CSV tables
def _csv(tmp_path, name: str, data: bytes) -> str:
    p = tmp_path / name
    p.write_bytes(data)
    return str(p)


HEADER = "point_id,image_id,x,y,sigma_x,sigma_y\n"


def test_a_latin1_csv_names_the_encoding(tmp_path):
    p = _csv(tmp_path, "pts.csv", (HEADER + "Sète,L,1,2,0.01,0.01\n").encode("latin-1"))
    with pytest.raises(CSVError, match=r"pts\.csv is not UTF-8 but seems encoded as Latin-1 "
                                       r"\(ISO-8859-1\): line 2, column 2 holds the byte "
                                       r"0xE8.*Save it as UTF-8"):
        read_measurements(p)


def test_a_utf16_csv_is_named_so(tmp_path):
    p = _csv(tmp_path, "gcps.csv", "point_id,X,Y,Z,sigma_x,sigma_y,sigma_z\n".encode("utf-16"))
    with pytest.raises(CSVError, match=r"encoded as UTF-16 .*CSV tables must be UTF-8"):
        read_control(p)


def test_a_semicolon_csv_is_named_so(tmp_path):
    p = _csv(tmp_path, "pts.csv", HEADER.replace(",", ";").encode() + b"a;L;1,5;2;0,1;0,1\n")
    with pytest.raises(CSVError, match=r"the columns are separated by ';', not by commas"):
        read_measurements(p)


def test_a_csv_folder_unreadable_or_nul_path_is_named(tmp_path, monkeypatch):
    (tmp_path / "pts.csv").mkdir()
    with pytest.raises(InputFileError, match=r"pts\.csv' is a folder, not a file"):
        read_measurements(str(tmp_path / "pts.csv"))
    with pytest.raises(InputFileError, match=r"holds a NUL character"):
        read_control(str(tmp_path / "g\x00.csv"))
    p = Path(_csv(tmp_path, "gcps.csv", b"point_id,X,Y,Z,sigma_x,sigma_y,sigma_z\n"))
    real = Path.read_bytes

    def fake(self):
        if self == p:
            raise PermissionError(13, "Permission denied", str(self))
        return real(self)

    monkeypatch.setattr(Path, "read_bytes", fake)
    with pytest.raises(InputFileError, match=r"gcps\.csv' cannot be read: permission denied"):
        read_control(str(p))


def test_an_unclosed_quote_names_the_line_it_opens(tmp_path):
    rows = "b,L,1,2,0.01,0.01\n" * 20000
    p = _csv(tmp_path, "pts.csv", (HEADER + 'a,L,1,2,0.01,0.01\n"c,L,1,2,0.01,0.01\n'
                                   + rows).encode())
    with pytest.raises(CSVError, match=r"pts\.csv, line 3: cannot be read as a CSV table .*"
                                       r"Check the quotes on that line"):
        read_measurements(p)


def test_ids_holding_the_old_separator_are_no_false_duplicate(tmp_path):
    p = _csv(tmp_path, "pts.csv", (HEADER + "a\x1fb,c,1,2,0.01,0.01\n"
                                   "a,b\x1fc,1,2,0.01,0.01\n").encode())
    m = read_measurements(p)
    assert m.point_id.tolist() == ["a\x1fb", "a"] and m.image_id.tolist() == ["c", "b\x1fc"]
    p = _csv(tmp_path, "dup.csv", (HEADER + "a\x1fb,c,1,2,0.01,0.01\n" * 2).encode())
    with pytest.raises(CSVError, match=r"point 'a\\x1fb' is measured on image 'c' more than "
                                       r"once \(lines 2, 3\)"):
        read_measurements(p)


# ------------------------------------------------------------------ road layers
@pytest.mark.io
def test_a_table_without_geometries_given_as_roads_is_named(tmp_path):
    from pyproj import CRS

    from vectoradjust.errors import LayerError
    from vectoradjust.files.readers import read_line_layer

    p = _csv(tmp_path, "roads.csv", b"id,name\n1,a\n")
    with pytest.raises(LayerError, match=r"roads\.csv \(\[\[vectors\]\] 'OSM'\): the layer has "
                                         r"no geometries \(a table: id, name\)"):
        read_line_layer(p, "OSM", None, CRS.from_epsg(32616))


@pytest.mark.io
def test_a_missing_id_field_with_a_filter_is_named(tmp_path):
    from pyproj import CRS

    from vectoradjust.errors import LayerError
    from vectoradjust.files.readers import read_line_layer

    p = _csv(tmp_path, "roads.geojson", b'{"type": "FeatureCollection", "features": [{"type": '
             b'"Feature", "geometry": {"type": "LineString", "coordinates": [[0, 0], [1, 1]]}, '
             b'"properties": {"highway": "a"}}]}')
    with pytest.raises(LayerError, match=r"id_field 'osm_id' is not a field of the layer "
                                         r"\(fields: highway\)"):
        read_line_layer(p, "OSM", "osm_id", CRS.from_epsg(32616), where="highway = 'a'")
