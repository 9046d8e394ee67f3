"""Project files with RPC images: what is accepted, and the messages for mistakes."""

from __future__ import annotations

from pathlib import Path

import pytest

from vectoradjust.errors import InputFileError, ProjectError
from vectoradjust.files.project import parse_project

SAT = Path(__file__).resolve().parents[1] / "resources" / "sample" / "satellite"


def base(**images):
    image = {"id": "S1", "model": "rpc", "rpc": "S1_rpc.txt", **images}
    return {"crs": "EPSG:32616", "heights": "ellipsoidal", "images": [image],
            "measurements": {"path": "image_points.csv", "unit": "pixel"}}


def test_rpc_image_parsed_without_camera():
    spec = parse_project(base(bias="affine", bias_sigma=[5.0, 1.0]), SAT)
    im = spec.images[0]
    assert spec.camera is None and spec.has_rpc and spec.heights == "ellipsoidal"
    assert im.model == "rpc" and im.rpc.bias == "affine"
    assert im.rpc.bias_sigma.tolist() == [5.0, 1.0, 1.0, 5.0, 1.0, 1.0]
    assert im.rpc.path == str(SAT / "S1_rpc.txt")


@pytest.mark.parametrize("change,what,mend", [
    ({"position": [1.0, 2.0, 3.0]}, "position is a frame camera's", "Remove position"),
    ({"sigma_attitude": 1.0}, "sigma_attitude is a frame camera's", 'model = "frame"'),
    ({"rpc": None}, "rpc must be a file path", "relative to the project file"),
    ({"bias": "quadratic"}, "bias = 'quadratic' is unknown", '"shift+drift"'),
    ({"bias_sigma": [1.0, 2.0, 3.0]}, "bias_sigma must be 1, 2 or 6 numbers",
     "[a0, a1, a2, b0, b1, b2]"),
    ({"bias_sigma": -1.0}, "bias_sigma must be a finite positive number", "Correct"),
    ({"model": "pushbroom"}, "model = 'pushbroom' is unknown", 'model = "rpc"'),
])
def test_rpc_image_mistakes_are_named(change, what, mend):
    raw = base()
    raw["images"][0].update(change)
    if change.get("rpc", 1) is None:
        raw["images"][0].pop("rpc")
        what, mend = "has no rpc file", "_rpc.txt"
    with pytest.raises(ProjectError, match=rf"\[\[images\]\] id 'S1': {what}") as e:
        parse_project(raw, SAT)
    assert what in e.value.what and "'S1'" in e.value.what
    assert mend in e.value.mend


def test_frame_image_with_rpc_keys_is_refused():
    raw = base()
    raw["images"][0] = {"id": "L", "position": [0.0, 0.0, 800.0], "rpc": "S1_rpc.txt"}
    raw["camera"] = {"focal_length": 152.4}
    with pytest.raises(ProjectError, match="rpc is given but the image is a frame camera"):
        parse_project(raw, SAT)


def test_heights_must_be_stated_with_rpc_images():
    raw = base()
    raw.pop("heights")
    with pytest.raises(ProjectError, match=r"heights is missing: RPC images.*EPSG:5773") as e:
        parse_project(raw, SAT)
    assert "heights is missing" in e.value.what and "EPSG:5773" in e.value.mend
    raw["heights"] = "orthometric"
    with pytest.raises(ProjectError, match="needs the vertical datum"):
        parse_project(raw, SAT)
    raw["heights"] = "geoidal"
    with pytest.raises(ProjectError, match="heights = 'geoidal' is unknown"):
        parse_project(raw, SAT)


def test_frame_projects_still_need_a_camera():
    raw = base()
    raw["images"][0] = {"id": "L", "position": [0.0, 0.0, 800.0]}
    with pytest.raises(ProjectError, match=r"\[camera\] is missing"):
        parse_project(raw, SAT)


@pytest.mark.io
def test_mm_measurements_on_rpc_images_only_are_refused(tmp_path):
    from vectoradjust.files.readers import load_project_data

    text = (SAT / "project.toml").read_text().replace('unit = "pixel"', 'unit = "mm"')
    text = text.replace('"../', f'"{SAT.parent.as_posix()}/').replace(
        'rpc = "', f'rpc = "{SAT.as_posix()}/').replace(
        'path = "image_points.csv"', f'path = "{(SAT / "image_points.csv").as_posix()}"')
    (tmp_path / "p.toml").write_text(text)
    with pytest.raises(ProjectError, match="every image is an RPC image, measured in pixels"):
        load_project_data(tmp_path / "p.toml")


@pytest.mark.io
def test_missing_rpc_file_is_named(tmp_path):
    from vectoradjust.files.readers import load_project_data

    text = (SAT / "project.toml").read_text()
    text = text.replace('"../', f'"{SAT.parent.as_posix()}/').replace(
        'path = "image_points.csv"', f'path = "{(SAT / "image_points.csv").as_posix()}"')
    (tmp_path / "p.toml").write_text(text)  # the S?_rpc.txt are not in tmp_path
    with pytest.raises(InputFileError, match=r"S1_rpc\.txt: does not exist\. Give the image") as e:
        load_project_data(tmp_path / "p.toml")
    assert "S1_rpc.txt" in e.value.message
