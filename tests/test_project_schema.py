"""The project file's schema: every table's keys are known, a misspelt key is named with
the nearest known one, and README's "The project file" documents every key."""

from __future__ import annotations

import copy
import re
import sys
from pathlib import Path

import pytest

from vectoradjust.errors import ProjectError
from vectoradjust.files.project import PROJECT_SCHEMA, load_project, parse_project

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python < 3.11
    import tomli as tomllib

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "resources" / "sample"


@pytest.fixture()
def raw() -> dict:
    """The sample project as parsed TOML (a fresh copy to break)."""
    with open(SAMPLE / "project.toml", "rb") as fh:
        return copy.deepcopy(tomllib.load(fh))


def _parse(raw: dict):
    return parse_project(raw, base_dir=SAMPLE, path=SAMPLE / "project.toml")


def test_the_sample_parses_and_uses_only_known_keys(raw):
    spec = load_project(SAMPLE / "project.toml")
    assert [v.name for v in spec.vectors] == ["OSM", "TNM", "TIGER"]
    assert set(raw) <= set(PROJECT_SCHEMA["top level"])
    for v in raw["vectors"]:
        assert set(v) <= set(PROJECT_SCHEMA["[[vectors]]"])


# (where in the raw table, misspelt key, the key it should be, how the table is named)
MISSPELT = [
    ((), "crss", "crs", "unknown top-level key 'crss'"),
    ((), "adjustement", "adjustment", "unknown top-level key 'adjustement'"),
    (("camera",), "focal_lenght", "focal_length", "[camera]: unknown key"),
    (("corrections",), "refractoin", "refraction", "[corrections]: unknown key"),
    (("images", 1), "sigma_positon", "sigma_position", "[[images]] entry 2 ('R'): unknown key"),
    (("measurements",), "fiducial", "fiducials", "[measurements]: unknown key"),
    (("control",), "pth", "path", "[control]: unknown key"),
    (("vectors", 1), "id_feild", "id_field", "[[vectors]] entry 2 ('TNM'): unknown key"),
    (("vectors", 0), "sigmas", "sigma", "[[vectors]] entry 1 ('OSM'): unknown key"),
    (("vectors", 2), "identification_sigmas", "identification_sigma",
     "[[vectors]] entry 3 ('TIGER'): unknown key"),
    (("vectors", 0), "wehre", "where", "[[vectors]] entry 1 ('OSM'): unknown key"),
    (("vectors", 0), "Layer", "layer", "[[vectors]] entry 1 ('OSM'): unknown key"),
    (("adjustment",), "max_iteration", "max_iterations", "[adjustment]: unknown key"),
    (("adjustment",), "covariance_scal", "covariance_scale", "[adjustment]: unknown key"),
    (("truth",), "width", "widths", "[truth]: unknown key"),
    (("qa",), "map_scal", "map_scale", "[qa]: unknown key"),
]


@pytest.mark.parametrize("where,key,meant,named", MISSPELT)
def test_a_misspelt_key_is_named_with_its_table_and_the_nearest_key(raw, where, key, meant,
                                                                   named):
    raw.setdefault("qa", {"product": "topographic map"})
    table = raw
    for part in where:
        table = table[part]
    table[key] = 1
    said = rf"{re.escape(repr(key))} \(did you mean {re.escape(repr(meant))}\?\)"
    with pytest.raises(ProjectError, match=said) as exc:
        _parse(raw)
    msg = str(exc.value)
    assert named in msg and repr(key) in msg, msg
    assert f"did you mean {meant!r}?" in msg, msg
    assert exc.value.details["suggestions"] == {key: meant}


def test_several_unknown_keys_and_one_without_a_guess(raw):
    raw["vectors"][0].update({"id_feild": "x", "zzzzzz": 1})
    with pytest.raises(ProjectError, match=r"unknown keys 'id_feild' \(did you mean 'id_field'\?\)"
                                           r", 'zzzzzz'\. Check the spelling") as exc:
        _parse(raw)
    assert "the keys of [[vectors]] are name, path, layer, where" in str(exc.value)


def test_camera_inline_and_by_path_are_checked_alike(raw):
    raw["camera"]["pixel_sise"] = 0.012  # next to path = "rc10.toml"
    with pytest.raises(ProjectError, match=r"\[camera\]: unknown key 'pixel_sise' \(did you "
                                           r"mean 'pixel_size'\?\)"):
        _parse(raw)
    raw["camera"] = {"focal_length": 152.4, "distortion": {"model": "smac", "convension": "x"}}
    with pytest.raises(ProjectError, match=r"\[camera.distortion\]: unknown key 'convension' "
                                           r"\(did you mean 'convention'\?\)"):
        _parse(raw)
    raw["camera"]["distortion"] = {"model": "smac", "k1": 1e-8}  # a coefficient, any case
    assert _parse(raw).camera.calibration.distortion_coefficients == {"K1": 1e-8}


def test_tables_of_the_wrong_shape(raw):
    raw["vectors"] = raw["vectors"][0]
    with pytest.raises(ProjectError, match=r"vectors is a single table.*Write \[\[vectors\]\]"):
        _parse(raw)
    raw["vectors"] = []
    raw["adjustment"] = 3
    with pytest.raises(ProjectError, match=r"adjustment must be a table \(\[adjustment\]\)"):
        _parse(raw)
    del raw["adjustment"]
    del raw["truth"]["path"]
    with pytest.raises(ProjectError, match=r"\[truth\] has no path"):
        _parse(raw)


def test_layer_and_where_reach_the_vector_spec(raw):
    raw["vectors"][0].update(layer="lines", where="highway IN ('primary', 'residential') ")
    spec = _parse(raw)
    assert spec.vectors[0].layer == "lines"
    assert spec.vectors[0].where == "highway IN ('primary', 'residential')"
    assert spec.vectors[1].where is None and spec.vectors[1].layer is None
    raw["vectors"][0]["where"] = ""
    with pytest.raises(ProjectError, match=r"\[\[vectors\]\] entry 1 \('OSM'\): where must be a "
                                           "non-empty text"):
        _parse(raw)


def _readme_section() -> str:
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    start = text.index("## The project file")
    return text[start:text.index("\n## ", start + 5)]


def test_readme_documents_every_table_and_key():
    doc = _readme_section()
    for table, keys in PROJECT_SCHEMA.items():
        if table != "top level":
            assert table in doc, f"README does not show the table {table}"
        for key in keys:
            k = re.escape(key)
            assert re.search(rf"(^|\s){k}\s*=|`{k}`|\[{k}\]", doc), \
                f"README's 'The project file' does not document {table} {key}"


def test_readmes_example_is_valid_toml_with_known_keys():
    """The example, its commented-out keys included, uses only keys of the schema."""
    from vectoradjust.files.project import check_keys

    block = _readme_section().split("```toml\n", 1)[1].split("```", 1)[0]
    text = re.sub(r"(?m)^# (\w+ = )", r"\1", block)
    raw = tomllib.loads(text)
    check_keys(raw, PROJECT_SCHEMA["top level"], "README", "")
    for name in ("camera", "corrections", "measurements", "control", "adjustment", "truth",
                 "qa", "conflation"):
        check_keys(raw[name], PROJECT_SCHEMA[f"[{name}]"], "README", f"[{name}]")
    for name in ("images", "vectors"):
        for entry in raw[name]:
            check_keys(entry, PROJECT_SCHEMA[f"[[{name}]]"], "README", f"[[{name}]]")
    documented = {k for t in ("camera", "corrections", "measurements", "control", "adjustment",
                              "truth", "qa", "conflation") for k in raw[t]}
    documented |= set(raw) | set(raw["images"][0]) | set(raw["vectors"][0])
    every = {k for keys in PROJECT_SCHEMA.values() for k in keys}
    assert every <= documented, f"not in README's example: {sorted(every - documented)}"


@pytest.mark.io
def test_every_simulated_project_parses(tmp_path):
    """Projects the simulator writes (the sample's kind, scanned film, GeoPackage layers)."""
    from vectoradjust.sensor.camera import CameraCalibration
    from vectoradjust.simulate import make_scenario, write_project

    scan = {"scan": True, "effects": ("distortion", "refraction"),
            "calibration": CameraCalibration.from_file(SAMPLE / "rc10.toml")}
    for k, (kwargs, fmt) in enumerate((({}, "shp"), (scan, "gpkg"))):
        d = tmp_path / f"p{k}"
        write_project(make_scenario(k, **kwargs), d, format=fmt, reweight="two-pass")
        spec = load_project(d / "project.toml")
        assert [v.name for v in spec.vectors] == ["OSM", "TNM", "TIGER"]
