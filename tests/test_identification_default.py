"""An identification error no user has to guess (issue 30): estimated from the data
where they determine it, else a conservative default from the image scale."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from vectoradjust.accuracy.identification import (
    DEFAULT_PIXELS,
    choose_identification,
    default_identification,
)
from vectoradjust.adjust.shapepoints import lookup
from vectoradjust.pipeline import run
from vectoradjust.simulate import DatabaseModel, make_scenario


def _coverage(out, truth):
    """CE90 coverage of the true vertices and the median CE90, over all databases."""
    inside, n, ce = 0, 0, []
    for d in out.databases:
        tid, txyz = truth[d.name]
        ti = lookup(tid, d.shape.vertex_ids)
        sel = (d.vertices["Adjusted"] == 1) & (ti >= 0)
        err = np.hypot(d.vertices["AdjX"][sel] - txyz[ti[sel], 0],
                       d.vertices["AdjY"][sel] - txyz[ti[sel], 1])
        inside += int((err <= d.vertices["CE90"][sel]).sum())
        n += int(sel.sum())
        ce.append(d.vertices["CE90"][sel])
    return inside / n, float(np.median(np.concatenate(ce)))


@pytest.fixture(scope="module")
def two_databases():
    a = DatabaseModel("A", "a_id", "a", 20.0, 0.5, (3.0, 2.0), 0.0, 0.0, 1.5)
    b = DatabaseModel("B", "b_id", "b", 25.0, 0.5, (-1.0, 1.0), 0.0, 0.0, 2.0)
    return make_scenario(2, databases=(a, b), n_shape_points=2000, pointing_sigma=0.5,
                         shape_sigma=(3.0, 3.0, 3.0))


def test_unstated_identification_is_estimated_and_used(two_databases):
    """0.5 m simulated, not stated, no truth: the common intersections give it; CE90
    covers >= 85 % and its median is at most 1.5 times that of the stated run."""
    data = two_databases.to_project_data()
    truth = dict(data.truth)
    stated = run(data)
    unstated = replace(data, truth={}, vectors=[
        (replace(s, identification_sigma=None), lay) for s, lay in data.vectors])
    out = run(unstated)
    cov_s, med_s = _coverage(stated, truth)
    cov_u, med_u = _coverage(out, truth)
    assert cov_u >= 0.85 and med_u <= 1.5 * med_s, (cov_u, med_u, med_s)
    for entry in out.summary["databases"]:
        used = entry["identification_sigma_used"]
        assert entry["identification_sigma"] is None
        assert used["source"] == "common intersections A/B"
        assert used["horizontal"] == pytest.approx(used["estimate"] + used["se"])
        assert 0.35 < used["horizontal"] < 0.65
    said = [w for w in out.warnings if "identification_sigma is not given" in w]
    assert len(said) == 2 and "was used (estimated from common intersections" in said[0]
    assert "identification_sigma_used" not in stated.summary["databases"][0]


def test_without_estimate_the_default_is_ten_pixels():
    """One database, no truth: nothing determines it; 10 pixels on the ground."""
    sc = make_scenario(3, databases=("OSM",), pointing_sigma=0.5)
    data = sc.to_project_data()
    data = replace(data, truth={}, vectors=[(replace(s, identification_sigma=None), lay)
                                            for s, lay in data.vectors])
    out = run(data)
    used = out.summary["databases"][0]["identification_sigma_used"]
    assert used["source"].startswith(f"default: {DEFAULT_PIXELS:g} pixels of ")
    cal = data.camera.calibration
    px = np.mean(cal.pixel_size) if getattr(cal, "pixel_size", None) is not None else \
        float(np.median(data.measurements.sigma))
    scale = (np.median(out.result.eo[:, 2]) - np.median(
        out.result.xyz[out.point_kind == "shape", 2])) / data.camera.focal_length
    assert used["horizontal"] == pytest.approx(DEFAULT_PIXELS * px * scale, rel=1e-6)
    assert used["vertical"] == 0.0
    assert any("the data do not determine it; the conservative default" in w
               for w in out.warnings)


def test_choice_rules():
    est = {"databases": {"A": {"source": "truth", "count": 3, "horizontal": 0.5,
                               "horizontal_se": 0.01, "vertical": None,
                               "vertical_se": None}},
           "pairs": [{"source": "common intersections A/B", "count": 40, "horizontal": 0.4,
                      "horizontal_se": 0.05, "vertical": 0.1, "vertical_se": 0.2}]}
    c = choose_identification("A", est)  # the truth rests on 3 points only: the pair
    assert c["source"] == "common intersections A/B" and c["horizontal"] == pytest.approx(0.45)
    assert c["vertical"] == 0.0  # 0.1 +- 0.2: not determined
    est["databases"]["A"]["count"] = 30  # from truth: the estimate itself (unbiased)
    c = choose_identification("A", est)
    assert c["source"] == "truth" and c["horizontal"] == pytest.approx(0.5)
    est["databases"]["A"]["count"] = 3
    est["pairs"][0]["horizontal_se"] = 0.3  # not determined either
    assert choose_identification("A", est) is None
    assert default_identification(None)["horizontal"] == 1.0
    assert default_identification(0.05)["horizontal"] == pytest.approx(0.5)
