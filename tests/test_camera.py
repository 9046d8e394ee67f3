"""Tests of vectoradjust.sensor.camera: parsing the [camera] table and camera TOML files."""

from __future__ import annotations

import numpy as np
import pytest

from vectoradjust.errors import CameraError, VectorAdjustError
from vectoradjust.sensor.camera import CameraCalibration, load_camera_file

RC10_FILE = """\
name = "Wild RC10 test"
focal_length = 152.4
principal_point = [0.003, -0.001]
pixel_size = 0.012
image_size = [19200, 19200]

[fiducials]
1 = [-106.0, -106.0]
2 = [106.0, 106.0]
3 = [-106.0, 106.0]
4 = [106.0, -106.0]

[distortion]
model = "smac"
K0 = -0.2165e-3
K1 = 0.4230e-7
P1 = -0.1483e-6
"""


def test_contract_keys_alone_are_a_camera():
    cam = CameraCalibration.from_dict({"focal_length": 152.4, "principal_point": [0.01, -0.02]})
    assert cam.focal_length == 152.4
    assert cam.principal_point == (0.01, -0.02)
    assert cam.fiducials is None
    assert cam.distortion_model == "none"
    assert not cam.has_distortion
    assert cam.pixel_size is None and cam.image_size is None
    np.testing.assert_array_equal(cam.radial_coefficients, np.zeros(5))
    np.testing.assert_array_equal(cam.decentering_coefficients, np.zeros(4))


def test_principal_point_defaults_to_origin():
    cam = CameraCalibration.from_dict({"focal_length": 100})
    assert cam.principal_point == (0.0, 0.0)


def test_missing_focal_length_is_a_camera_error():
    with pytest.raises(CameraError, match="focal_length"):
        CameraCalibration.from_dict({"principal_point": [0, 0]})


@pytest.mark.parametrize("bad", [0, -152.4, "abc", True])
def test_bad_focal_length(bad):
    with pytest.raises(CameraError, match="focal_length"):
        CameraCalibration.from_dict({"focal_length": bad})


def test_unknown_distortion_model_names_value_and_accepted_names():
    with pytest.raises(CameraError, match=r"unknown distortion model 'kannala'\. Use one") as exc:
        CameraCalibration.from_dict(
            {"focal_length": 152.4, "distortion": {"model": "kannala", "K1": 1e-8}}
        )
    msg = str(exc.value)
    assert "'kannala'" in msg
    for name in ("none", "smac", "polynomial", "brown"):
        assert name in msg
    assert isinstance(exc.value, VectorAdjustError)


def test_unknown_distortion_model_as_string_shorthand():
    with pytest.raises(CameraError, match="'fisheye'"):
        CameraCalibration.from_dict({"focal_length": 152.4, "distortion": "fisheye"})
    cam = CameraCalibration.from_dict({"focal_length": 152.4, "distortion": "none"})
    assert cam.distortion_model == "none"


def test_coefficient_not_in_model_is_named():
    with pytest.raises(CameraError, match="'K5'"):
        CameraCalibration.from_dict(
            {"focal_length": 152.4, "distortion": {"model": "smac", "K5": 1.0}}
        )
    # the polynomial model has no K0 term
    with pytest.raises(CameraError, match="'k0'"):
        CameraCalibration.from_dict(
            {"focal_length": 152.4, "distortion": {"model": "polynomial", "k0": 1.0}}
        )


def test_coefficients_without_model_are_an_error():
    with pytest.raises(CameraError, match="model"):
        CameraCalibration.from_dict({"focal_length": 152.4, "distortion": {"K1": 1e-8}})


def test_unknown_convention_is_an_error():
    with pytest.raises(CameraError, match="convention"):
        CameraCalibration.from_dict(
            {"focal_length": 152.4, "distortion": {"model": "smac", "convention": "plus"}}
        )


def test_unknown_camera_key_is_named():
    with pytest.raises(CameraError, match="'focal_lenght'"):
        CameraCalibration.from_dict({"focal_length": 152.4, "focal_lenght": 152.4})


def test_smac_and_polynomial_coefficients():
    cam = CameraCalibration.from_dict(
        {
            "focal_length": 152.4,
            "distortion": {"model": "smac", "K0": 1.0, "K2": 3.0, "P1": 5.0, "P4": 8.0},
        }
    )
    np.testing.assert_array_equal(cam.radial_coefficients, [1, 0, 3, 0, 0])
    np.testing.assert_array_equal(cam.decentering_coefficients, [5, 0, 0, 8])
    assert cam.has_distortion
    assert cam.distortion_sign == 1.0
    # polynomial: dr = k1 r^3 + ... is the SMAC radial form with K0 = 0; keys are
    # accepted in either case
    poly = CameraCalibration.from_dict(
        {
            "focal_length": 152.4,
            "distortion": {"model": "Polynomial", "K1": 2.0, "k4": 4.0, "convention": "distortion"},
        }
    )
    assert poly.distortion_model == "polynomial"
    np.testing.assert_array_equal(poly.radial_coefficients, [0, 2, 0, 0, 4])
    assert poly.distortion_sign == -1.0


def test_symmetry_center_defaults_to_principal_point():
    cam = CameraCalibration.from_dict({"focal_length": 152.4, "principal_point": [0.1, 0.2]})
    assert cam.symmetry_center == (0.1, 0.2)
    cam = CameraCalibration.from_dict(
        {
            "focal_length": 152.4,
            "principal_point": [0.1, 0.2],
            "distortion": {"model": "smac", "center": [0.05, -0.05], "K1": 1e-8},
        }
    )
    assert cam.symmetry_center == (0.05, -0.05)


def test_pixel_size_forms_and_units():
    cam = CameraCalibration.from_dict({"focal_length": 100, "pixel_size": 0.012})
    assert cam.pixel_size == (0.012, 0.012)
    cam = CameraCalibration.from_dict({"focal_length": 100, "pixel_size": [0.01, 0.012]})
    assert cam.pixel_size == (0.01, 0.012)
    with pytest.raises(CameraError, match="0.012"):  # 12 given in micrometres
        CameraCalibration.from_dict({"focal_length": 100, "pixel_size": 12})
    with pytest.raises(CameraError, match="pixel_size"):
        CameraCalibration.from_dict({"focal_length": 100, "pixel_size": -0.01})


def test_image_size_validation():
    cam = CameraCalibration.from_dict({"focal_length": 100, "image_size": [6000, 4000]})
    assert cam.image_size == (6000, 4000)
    for bad in ([6000.5, 4000], [6000], ["a", 4000], [0, 10]):
        with pytest.raises(CameraError, match="image_size"):
            CameraCalibration.from_dict({"focal_length": 100, "image_size": bad})


def test_fewer_than_three_calibrated_fiducials():
    with pytest.raises(CameraError, match="only 2 calibrated fiducial"):
        CameraCalibration.from_dict(
            {"focal_length": 100, "fiducials": {"1": [0, 0], "2": [1, 1]}}
        )


def test_collinear_calibrated_fiducials():
    with pytest.raises(CameraError, match="one line"):
        CameraCalibration.from_dict(
            {"focal_length": 100, "fiducials": {"a": [0, 0], "b": [1, 1], "c": [2, 2]}}
        )


def test_bad_fiducial_value_is_named():
    with pytest.raises(CameraError, match="fiducial 3"):
        CameraCalibration.from_dict(
            {"focal_length": 100, "fiducials": {"1": [0, 0], "2": [1, 0], "3": [1]}}
        )


def test_camera_file_by_path_with_inline_overrides(tmp_path):
    (tmp_path / "cams").mkdir()
    (tmp_path / "cams" / "rc10.toml").write_text(RC10_FILE)
    table = {
        "path": "cams/rc10.toml",
        "principal_point": [0.0, 0.0],  # inline overrides the file
        "fiducials": {"4": [106.002, -105.999]},  # merged key by key
        "distortion": {"K1": 0.5e-7},
    }
    cam = CameraCalibration.from_dict(table, base_dir=tmp_path)
    assert cam.name == "Wild RC10 test"
    assert cam.focal_length == 152.4
    assert cam.principal_point == (0.0, 0.0)
    assert cam.pixel_size == (0.012, 0.012)
    assert cam.image_size == (19200, 19200)
    assert cam.fiducials["1"] == (-106.0, -106.0)
    assert cam.fiducials["4"] == (106.002, -105.999)
    assert cam.distortion_model == "smac"
    np.testing.assert_allclose(cam.radial_coefficients, [-0.2165e-3, 0.5e-7, 0, 0, 0])
    np.testing.assert_allclose(cam.decentering_coefficients, [-0.1483e-6, 0, 0, 0])
    assert cam.source is not None and cam.source.endswith("rc10.toml")


def test_camera_file_alone_and_from_file(tmp_path):
    p = tmp_path / "rc10.toml"
    p.write_text(RC10_FILE)
    a = CameraCalibration.from_dict({"path": str(p)})
    b = CameraCalibration.from_file(p)
    assert a.to_dict() == b.to_dict()


def test_camera_file_with_camera_table(tmp_path):
    p = tmp_path / "cam.toml"
    p.write_text("[camera]\nfocal_length = 88.0\nprincipal_point = [0.1, 0.0]\n")
    cam = CameraCalibration.from_dict({"path": "cam.toml"}, base_dir=tmp_path)
    assert cam.focal_length == 88.0 and cam.principal_point == (0.1, 0.0)


def test_missing_camera_file_is_named(tmp_path):
    with pytest.raises(CameraError, match="nothere.toml") as exc:
        CameraCalibration.from_dict({"path": "nothere.toml"}, base_dir=tmp_path)
    assert exc.value.path is not None


def test_invalid_toml_camera_file(tmp_path):
    p = tmp_path / "bad.toml"
    p.write_text("focal_length = = 152\n")
    with pytest.raises(CameraError, match="not valid TOML"):
        load_camera_file(p)


def test_camera_file_may_not_chain(tmp_path):
    p = tmp_path / "a.toml"
    p.write_text('path = "b.toml"\nfocal_length = 1.0\n')
    with pytest.raises(CameraError, match="another file"):
        CameraCalibration.from_dict({"path": "a.toml"}, base_dir=tmp_path)


def test_missing_focal_length_in_file_names_file(tmp_path):
    p = tmp_path / "nof.toml"
    p.write_text("principal_point = [0.0, 0.0]\n")
    with pytest.raises(CameraError, match="nof.toml.*focal_length"):
        CameraCalibration.from_dict({"path": "nof.toml"}, base_dir=tmp_path)


def test_to_dict_round_trip(tmp_path):
    p = tmp_path / "rc10.toml"
    p.write_text(RC10_FILE)
    cam = CameraCalibration.from_file(p)
    again = CameraCalibration.from_dict(cam.to_dict())
    assert again.to_dict() == cam.to_dict()
    assert again.fiducials == cam.fiducials


def test_direct_construction_is_validated():
    with pytest.raises(CameraError, match="'zernike'"):
        CameraCalibration(focal_length=100.0, distortion_model="zernike")
    with pytest.raises(CameraError, match="principal_point"):
        CameraCalibration(focal_length=100.0, principal_point=(1.0,))
    with pytest.raises(CameraError, match="pixel_origin"):
        CameraCalibration(focal_length=100.0, pixel_origin="middle")
