"""Automatic tie points between frame images (vectoradjust.measure.ties) on a rendered pair.

The pair (simulate/measure_scene.py: real texture, lens distortion, different gain,
offset, gamma and noise per image) is rendered with the *true* orientation; the tie
points are measured from a perturbed one (0.3 m, 0.01 degrees). The truth of a tie is
independent of the matcher: the ray of its reference pixel in the true geometry, cut
with the true terrain and projected into the other image.
"""

from __future__ import annotations

from functools import cache

import numpy as np
import pytest

from vectoradjust.adjust.intersection import ray_intersection
from vectoradjust.errors import MeasurementError
from vectoradjust.measure.ties import (
    TIE_FLAGS,
    ArrayReader,
    texture_points,
    tie_points,
)


@cache
def _pair():
    from vectoradjust.simulate.measure_scene import stereo_pair

    return stereo_pair(400, seed=2, sigma_position=0.3, sigma_attitude=0.01)


@cache
def _ties(back_tolerance: float = 0.5):
    p = _pair()
    geoms = [p.approx["L"], p.approx["R"]]
    return tie_points(geoms, [p.images["L"], p.images["R"]], p.scene.height, spacing=24,
                      sigma_height=2.0, back_tolerance=back_tolerance)


def _true_errors(p, tp) -> np.ndarray:
    """Distance (px) of every matched measurement from its true position."""
    err = []
    for pid in np.unique(tp.point_id):
        m = tp.point_id == pid
        ref = pid.split("-")[0]
        ims, px = tp.image_id[m], tp.px[m]
        ground = p.true[ref].to_ground(px[ims == ref], p.scene.height)
        for k in np.flatnonzero(ims != ref):
            err.append(np.hypot(*(p.true[ims[k]].to_pixel(ground)[0] - px[k])))
    return np.array(err)


def test_ties_land_on_the_true_pixels():
    p, tp = _pair(), _ties()
    err = _true_errors(p, tp)
    assert len(err) >= 150  # measured 248 of 450 candidates
    assert np.mean(err < 0.3) >= 0.95  # measured 0.996
    assert err.max() < 1.0  # measured 0.31
    assert np.nanmax(tp.back_error) <= 0.5


def test_table_is_one_row_per_point_and_image_in_photo_mm():
    p, tp = _pair(), _ties()
    tab = tp.table()
    assert set(tab) == {"point_id", "image_id", "x", "y"}
    key = np.char.add(np.char.add(tab["point_id"], "|"), tab["image_id"])
    assert len(np.unique(key)) == len(key)
    _, counts = np.unique(tab["point_id"], return_counts=True)
    assert counts.min() == 2 and counts.max() == 2  # two images: every point on both
    for iid, g in (("L", p.approx["L"]), ("R", p.approx["R"])):
        m = tab["image_id"] == iid
        xy = np.column_stack([tab["x"][m], tab["y"][m]])
        assert np.allclose(xy, g.pixel_to_photo(tp.px[m]), atol=1e-12)
    # the rays of the table through the TRUE orientation meet on the true terrain: the
    # photo coordinates (mm, refined) are the collinearity equations' x, y
    op, ids = tp.indices()
    eo = np.array([p.true["L"].eo, p.true["R"].eo])
    xyz = ray_intersection(eo, op, tp.image, tp.xy, len(ids), p.true["L"].camera.focal_length)
    dz = xyz[:, 2] - p.scene.height(xyz[:, :2])
    assert np.median(np.abs(dz)) < 0.1 and np.abs(dz).max() < 1.0


def test_pair_counts_add_up():
    tp = _ties()
    for c in tp.pairs.values():
        assert c["candidates"] >= c["predicted"] >= c["matched"] >= c["accepted"] > 50
        assert c["matched"] - c["accepted"] == c["flags"]["back_mismatch"]
    assert tp.n_points == sum(c["accepted"] for c in tp.pairs.values())


def test_back_matching_is_applied():
    strict = _ties(back_tolerance=1e-9)
    assert strict.n_points == 0
    assert all(c["flags"]["back_mismatch"] == c["matched"] > 0 for c in strict.pairs.values())


def test_an_unrelated_target_gives_no_ties():
    p = _pair()
    rng = np.random.default_rng(5)
    from scipy.ndimage import gaussian_filter

    other = gaussian_filter(rng.normal(size=(400, 400)), 1.5) * 40 + 120
    tp = tie_points([p.approx["L"], p.approx["R"]], [p.images["L"], other], p.scene.height,
                    spacing=48, sigma_height=2.0)
    assert tp.n_points == 0
    c = tp.pairs[("L", "R")]
    assert c["predicted"] > 20
    assert c["flags"]["low_correlation"] > 0.8 * c["predicted"]


def test_texture_check():
    flat = np.full((200, 200), 100.0)
    assert len(texture_points(flat, spacing=32)[0]) == 0
    edge = np.where(np.arange(200)[None, :] < 101, 50.0, 200.0) * np.ones((200, 1))
    assert len(texture_points(edge, spacing=32)[0]) == 0  # an edge is no corner
    blob = flat.copy()
    blob[70:76, 120:126] = 250.0
    px, w = texture_points(ArrayReader(blob), spacing=32)
    best = px[np.argmax(w)]
    assert abs(best[0] - 122.5) < 5 and abs(best[1] - 72.5) < 5


def test_tie_point_input_errors():
    p = _pair()
    with pytest.raises(MeasurementError, match="at least two images"):
        tie_points([p.approx["L"]], [p.images["L"]], 200.0)
    with pytest.raises(MeasurementError, match="2 image geometries but 1 images"):
        tie_points([p.approx["L"], p.approx["R"]], [p.images["L"]], 200.0)
    with pytest.raises(MeasurementError, match="image ids repeat"):
        tie_points([p.approx["L"], p.approx["L"]], [p.images["L"], p.images["L"]], 200.0)
    with pytest.raises(MeasurementError, match="must have 2 dimensions"):
        ArrayReader(np.zeros((3, 4, 5)))


def test_flags_extend_the_matching_flags():
    assert TIE_FLAGS["back_mismatch"] == 256 and TIE_FLAGS["off_image"] == 512
    bits = [b for k, b in TIE_FLAGS.items()]
    assert len(set(bits)) == len(bits)
