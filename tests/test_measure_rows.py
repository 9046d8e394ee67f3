"""files/measure_rows.py: the measurement layer's rows, the transfer's terrain height and
the RPC bias line that the command line and the QGIS algorithm share."""

from __future__ import annotations

import doctest
from types import SimpleNamespace

import numpy as np

from vectoradjust.files import measure_rows
from vectoradjust.files.measure_rows import (
    control_height,
    height_from_samples,
    measurement_rows,
    rpc_bias_line,
)


class _Geometry:
    """pixel -> mm: 0.01 mm pixels, the principal point at (100, 100) px."""

    def pixel_to_measured_mm(self, px):
        px = np.asarray(px, float)
        return np.column_stack([(px[:, 0] - 100) * 0.01, (100 - px[:, 1]) * 0.01])


def _pred():
    return {"point_id": np.array(["a", "b"]), "image_id": np.array(["L", "R"]),
            "kind": np.array(["control", "shape"]), "col": np.array([10.0, 20.0]),
            "row": np.array([30.0, 40.0]), "x": np.array([1.0, 2.0]), "y": np.array([3.0, 4.0]),
            "win_major": np.array([5.0, 6.0]), "win_minor": np.array([1.0, 2.0]),
            "win_angle": np.array([0.0, 90.0])}


def test_rows_of_every_source_in_order_with_their_fields():
    geoms = {"L": _Geometry(), "R": _Geometry()}
    measured = {"point_id": ["a"], "image_id": ["L"], "col": [110.0], "row": [90.0]}
    transferred = {"point_id": ["a"], "image_id": ["R"], "col": [150.0], "row": [100.0],
                   "ncc": [0.93], "rho": [0.95], "sigma_col": [0.02], "sigma_row": [0.05],
                   "flag_text": [""], "accepted": [True]}
    automatic = {"point_id": ["j1"], "image_id": ["L"], "col": [np.nan], "row": [np.nan],
                 "rms": [0.7], "flag_text": ["no_edge"], "accepted": [False]}
    rows = measurement_rows(geoms, _pred(), measured, transferred, automatic)
    assert [r["source"] for r in rows] == ["predicted", "predicted", "manual", "transferred",
                                           "automatic"]
    assert [r["accepted"] for r in rows] == [0, 0, 1, 1, 0]
    assert rows[1]["win_angle"] == 90.0 and rows[1]["kind"] == "shape"
    assert rows[2]["x_mm"] == 0.1 and rows[2]["y_mm"] == 0.1  # from the pixel position
    assert rows[3]["sigma_px"] == 0.05  # the larger of the two LSM sigmas
    assert rows[3]["x_mm"] == 0.5 and rows[3]["ncc"] == 0.93
    assert rows[4]["sigma_px"] == 0.7 and np.isnan(rows[4]["ncc"])  # a junction: its RMS
    assert "x_mm" not in rows[4] and rows[4]["flags"] == "no_edge"  # no position, no mm


def test_height_fills_what_the_dem_lacks():
    dem = height_from_samples(lambda xy: np.where(xy[:, 0] > 0, 5.0, np.nan))
    assert dem(np.array([[1.0, 0], [-1.0, 0], [2.0, 0]])).tolist() == [5.0, 5.0, 5.0]
    assert dem(np.array([[-1.0, 0]])).tolist() == [0.0]  # nothing found: 0
    fixed = height_from_samples(lambda xy: np.full(len(xy), np.nan), fallback=42.0)
    assert fixed([[0.0, 0.0], [1.0, 1.0]]).tolist() == [42.0, 42.0]  # any (n, 2) input


def test_control_height_and_none_without_control():
    assert control_height(SimpleNamespace(xyz=np.array([[0, 0, 1.0], [0, 0, 3.0]]))) == 2.0
    assert control_height(None) is None
    assert control_height(SimpleNamespace(xyz=np.zeros((0, 3)))) is None


def test_rpc_bias_line_takes_the_column_and_row_shift():
    g = SimpleNamespace(bias=np.array([0.5, 9, 9, 1.5, 9, 9]),
                        bias_cov=np.diag([0.01, 1, 1, 0.04, 1, 1]) - np.eye(6) * 1e-18,
                        bias_source="the adjustment")
    line = rpc_bias_line("S2", g, digits=".3g")
    assert line == ("RPC image S2: bias 0.50, 1.50 px (column, row shift), sigma 0.1, 0.2 px "
                    "from the adjustment")


def test_doctests_of_the_module():
    result = doctest.testmod(measure_rows)
    assert result.attempted >= 4 and result.failed == 0


def test_cell_window_covers_the_bilinear_neighbours_of_every_point():
    """adjust/dem.py::cell_window (the plugin's window read of a large DEM): the window's
    cells interpolate every point as the whole grid does."""
    from vectoradjust.adjust import dem

    rng = np.random.default_rng(3)
    grid = rng.normal(size=(60, 80))
    gt = (1000.0, 5.0, 0.0, 2000.0, 0.0, -5.0)
    xy = np.column_stack([rng.uniform(1100, 1300, 20), rng.uniform(1800, 1900, 20)])
    r0, r1, c0, c1 = dem.cell_window(gt, grid.shape, np.vstack([xy, [np.nan, np.nan]]))
    window = grid[r0:r1 + 1, c0:c1 + 1]
    wgt = (gt[0] + c0 * gt[1], gt[1], 0.0, gt[3] + r0 * gt[5], 0.0, gt[5])
    assert np.allclose(dem.bilinear(window, wgt, xy), dem.bilinear(grid, gt, xy))
    assert dem.cell_window(gt, grid.shape, [[np.nan, 0.0]]) is None
    assert dem.cell_window(gt, grid.shape, [[-1e6, 1e6]]) == (0, 0, 0, 0)  # clipped
    doctest_result = doctest.testmod(dem)
    assert doctest_result.attempted >= 2 and doctest_result.failed == 0
