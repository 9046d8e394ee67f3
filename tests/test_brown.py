"""The Brown (OpenCV/OpenSfM) lens distortion model of :mod:`vectoradjust.sensor.camera`.

Forward (ideal -> recorded) and exact inverse over the whole frame, the sign of the
tangential terms against OpenCV's own formula evaluated in pixel space (``y`` down), the
refinement chain (:func:`vectoradjust.sensor.refine.refine` / ``distort``) with the model
plugged in, and the camera table keys.
"""

from __future__ import annotations

import numpy as np
import pytest

from vectoradjust.errors import CameraError
from vectoradjust.sensor.camera import CameraCalibration, brown_distort, brown_undistort
from vectoradjust.sensor.collinearity import project
from vectoradjust.sensor.refine import distort, refine

#: the OpenSfM solution of the shared DJI Phantom 4 RTK images (normalised by the larger
#: image dimension), with larger tangential terms so that a sign error shows
COLS, ROWS = 5472, 3648
PIXEL = 13.2 / COLS  # mm
F_PX = 0.6664614123723713 * COLS
F_MM = F_PX * PIXEL
K = dict(k1=-0.2640629100413887, k2=0.10188934223670705, k3=-0.02581956399353581,
         p1=0.004, p2=-0.003)
PP_PX = (-0.0015460447606643697 * COLS, 0.004751874732641298 * COLS)  # c_x, c_y (y down)


def _camera(**over) -> CameraCalibration:
    table = {"focal_length": F_MM, "pixel_size": PIXEL, "image_size": [COLS, ROWS],
             "principal_point": [PP_PX[0] * PIXEL, -PP_PX[1] * PIXEL],
             "distortion": {"model": "brown", **K}}
    table.update(over)
    return CameraCalibration.from_dict(table)


def _frame_grid(n: int = 41) -> np.ndarray:
    """Ideal photo coordinates (mm, about the principal point) over the whole frame,
    corners included."""
    hx, hy = COLS * PIXEL / 2, ROWS * PIXEL / 2
    x, y = np.meshgrid(np.linspace(-hx, hx, n), np.linspace(-hy, hy, n))
    return np.column_stack([x.ravel(), y.ravel()])


def _opencv_pixels(cols_rows: np.ndarray, c: dict) -> np.ndarray:
    """OpenCV's distortion written out in pixel space (rows down), point by point."""
    cx = (COLS - 1) / 2 + PP_PX[0]
    cy = (ROWS - 1) / 2 + PP_PX[1]
    out = []
    for u, v in cols_rows:
        xn, yn = (u - cx) / F_PX, (v - cy) / F_PX
        r2 = xn ** 2 + yn ** 2
        rad = 1 + c["k1"] * r2 + c["k2"] * r2 ** 2 + c["k3"] * r2 ** 3
        xd = xn * rad + 2 * c["p1"] * xn * yn + c["p2"] * (r2 + 2 * xn ** 2)
        yd = yn * rad + c["p1"] * (r2 + 2 * yn ** 2) + 2 * c["p2"] * xn * yn
        out.append((cx + F_PX * xd, cy + F_PX * yd))
    return np.array(out)


def test_round_trip_over_the_whole_frame_to_1e_9_mm():
    coef = [K[k] for k in ("k1", "k2", "k3", "p1", "p2")]
    ideal = _frame_grid()
    recorded = brown_distort(ideal, F_MM, coef)
    # the model is strong: about 1.4 mm (570 px) at the corners of the wide-angle frame
    shift = np.hypot(*(recorded - ideal).T)
    assert 1.2 < shift.max() < 1.6
    back = brown_undistort(recorded, F_MM, coef)
    assert np.abs(back - ideal).max() < 1e-9
    # and the other way round: recorded positions over the whole frame
    again = brown_distort(brown_undistort(ideal, F_MM, coef), F_MM, coef)
    assert np.abs(again - ideal).max() < 1e-9


def test_centre_of_symmetry_and_shapes_are_kept():
    coef = [K[k] for k in ("k1", "k2", "k3", "p1", "p2")]
    xy = _frame_grid(5).reshape(5, 5, 2)
    c = (0.05, -0.02)
    out = brown_distort(xy, F_MM, coef, c)
    assert out.shape == (5, 5, 2)
    assert np.allclose(brown_distort(np.array(c), F_MM, coef, c), c, atol=1e-15)
    assert np.abs(brown_undistort(out, F_MM, coef, c) - xy).max() < 1e-9


def test_forward_equals_opencv_formula_in_pixel_space():
    cam = _camera()
    ideal = _frame_grid(15)
    px = distort(ideal, cam, unit="pixel")  # ideal mm about the pp -> recorded pixel
    cx = (COLS - 1) / 2 + PP_PX[0]
    cy = (ROWS - 1) / 2 + PP_PX[1]
    ideal_px = np.column_stack([cx + ideal[:, 0] / PIXEL, cy - ideal[:, 1] / PIXEL])
    want = _opencv_pixels(ideal_px, K)
    assert np.abs(px - want).max() < 1e-7
    # p1, p2 matter here: with either sign flipped the formula is pixels away
    for key in ("p1", "p2"):
        flipped = _opencv_pixels(ideal_px, {**K, key: -K[key]})
        assert np.abs(flipped - want).max() > 5.0
    # and the tangential terms really are in the result (not only the radial ones)
    radial_only = _opencv_pixels(ideal_px, {**K, "p1": 0.0, "p2": 0.0})
    assert np.abs(px - radial_only).max() > 5.0


def test_projected_distorted_and_corrected_lands_on_the_ideal_projection():
    cam = _camera()
    rng = np.random.default_rng(4)
    eo = np.array([1000.0, 2000.0, 100.0, 0.02, -0.03, 0.4])
    ground = np.column_stack([1000 + rng.uniform(-40, 40, 300),
                              2000 + rng.uniform(-30, 30, 300), rng.uniform(-5, 5, 300)])
    ideal = project(eo, ground, cam.focal_length)
    inside = (np.abs(ideal[:, 0]) < 6.5) & (np.abs(ideal[:, 1]) < 4.3)
    ideal = ideal[inside]
    assert len(ideal) > 100
    px = distort(ideal, cam, unit="pixel")
    assert np.all((px > -1) & (px < [COLS, ROWS]))
    corrected = refine(px, cam, unit="pixel")
    assert corrected.summary["corrections"]["distortion"]["model"] == "brown"
    assert corrected.summary["corrections"]["distortion"]["max_um"] > 100
    assert np.abs(corrected.xy - ideal).max() < 1e-9
    # without the distortion step the same pixels miss by hundreds of micrometres
    plain = refine(px, cam, unit="pixel", corrections={"distortion": False}).xy
    assert np.abs(plain - ideal).max() > 0.1


def test_camera_table_keys_and_round_trip():
    cam = _camera()
    assert cam.distortion_model == "brown" and cam.has_distortion
    assert cam.distortion_convention == "distortion"
    assert np.allclose(cam.brown_coefficients, [K[k] for k in ("k1", "k2", "k3", "p1", "p2")])
    assert not np.any(cam.radial_coefficients) and not np.any(cam.decentering_coefficients)
    again = CameraCalibration.from_dict(cam.to_dict())
    assert np.array_equal(again.brown_coefficients, cam.brown_coefficients)
    upper = _camera(distortion={"model": "brown", "K1": -0.2, "P2": 0.001})
    assert np.allclose(upper.brown_coefficients, [-0.2, 0, 0, 0, 0.001])
    assert not _camera(distortion={"model": "brown"}).has_distortion


def test_camera_table_errors():
    with pytest.raises(CameraError, match="'k4' is not part of the 'brown' model"):
        _camera(distortion={"model": "brown", "k1": 0.1, "k4": 0.01})
    with pytest.raises(CameraError, match="convention = 'correction' does not apply"):
        _camera(distortion={"model": "brown", "convention": "correction", "k1": 0.1})
    assert _camera(distortion={"model": "brown", "convention": "distortion",
                               "k1": 0.1}).has_distortion


def test_inverse_that_cannot_converge_says_so():
    # k1 = -1 folds the model back at r = 1/sqrt(3) f: a recorded point beyond its
    # largest radius (2/(3 sqrt 3) f) has no ideal position
    with pytest.raises(CameraError, match="could not be inverted .* 1 point"):
        brown_undistort([[0.0, 0.0], [0.5 * F_MM, 0.0]], F_MM, [-1.0])
    with pytest.raises(CameraError, match="5 coefficients"):
        brown_distort([[0.0, 0.0]], F_MM, [0.0] * 6)


def test_a_measurement_beyond_the_model_names_the_image():
    cam = _camera(distortion={"model": "brown", "k1": -1.0})
    far = np.array([[COLS / 2 + 0.45 * F_PX, ROWS / 2]])  # 0.45 f > 2 / (3 sqrt 3) f
    with pytest.raises(CameraError, match="image 'DJI_7': the brown lens distortion could "
                                          "not be inverted"):
        refine(far, cam, unit="pixel", image_id="DJI_7")
    near = np.array([[COLS / 2 + 0.3 * F_PX, ROWS / 2]])
    assert refine(near, cam, unit="pixel").xy[0, 0] > 0.3 * F_MM
