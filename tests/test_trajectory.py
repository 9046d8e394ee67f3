"""GNSS/INS camera positions from a trajectory CSV (``[trajectory]``): the datum without
control points (issue 29)."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from vectoradjust.errors import CSVError, DatumError
from vectoradjust.files.readers import load_project_data
from vectoradjust.pipeline import run

pytestmark = pytest.mark.io  # reads project files (pyogrio, rasterio, pyproj)

SAMPLE = Path(__file__).resolve().parents[1] / "resources" / "sample"
POS = {"L": (506303.0, 4475003.0, 799.0), "R": (506497.0, 4475000.0, 799.0)}


@pytest.fixture()
def project(tmp_path) -> Path:
    """The sample without control points (checks only) and without camera priors."""
    d = tmp_path / "p"
    shutil.copytree(SAMPLE, d)
    lines = (d / "gcps.csv").read_text().splitlines()
    (d / "gcps.csv").write_text("\n".join([lines[0]] + [r for r in lines[1:]
                                                        if r.endswith("check")]) + "\n")
    text = (d / "project.toml").read_text()
    text = "\n".join(t for t in text.splitlines()
                     if not t.startswith(("sigma_position", "sigma_attitude")))
    (d / "project.toml").write_text(text + "\n")
    return d


def _with_trajectory(d: Path, rows: list, header="image_id,X,Y,Z,sigma_X,sigma_Y,sigma_Z",
                     crs=None) -> Path:
    (d / "gnss.csv").write_text(header + "\n" + "\n".join(rows) + "\n")
    table = '\n[trajectory]\npath = "gnss.csv"\n' + (f'crs = "{crs}"\n' if crs else "")
    with open(d / "project.toml", "a", encoding="utf-8") as fh:
        fh.write(table)
    return d / "project.toml"


def test_without_control_or_trajectory_the_datum_is_missing(project):
    with pytest.raises(DatumError, match="move freely in X and Y"):
        run(load_project_data(project / "project.toml"))


def test_trajectory_positions_fix_the_datum(project):
    rows = [f"{k},{x},{y},{z},0.5,0.5,1.0" for k, (x, y, z) in POS.items()]
    data = load_project_data(_with_trajectory(project, rows))
    assert data.images[0].sigma_position == (0.5, 0.5, 1.0)
    out = run(data)
    assert out.summary["datum"]["sources"][0] == "camera position priors on 2 of 2 image(s)"
    sig = np.sqrt(np.diagonal(out.result.eo_cov[:, :3, :3], axis1=1, axis2=2))
    assert (sig[:, :2] < 0.5).all() and (sig[:, :2] > 0.05).all()  # the GNSS, not GCPs


def test_trajectory_in_geographic_coordinates_is_transformed(project):
    from pyproj import Transformer

    to_ll = Transformer.from_crs("EPSG:32616", "EPSG:4326", always_xy=True)
    rows = []
    for k, (x, y, z) in POS.items():
        lon, lat = to_ll.transform(x, y)
        rows.append(f"{k},{lon:.10f},{lat:.10f},{z},2.0,2.0,3.0,0.01,0.01,0.02")
    head = "image_id,X,Y,Z,sigma_X,sigma_Y,sigma_Z,sigma_omega,sigma_phi,sigma_kappa"
    data = load_project_data(_with_trajectory(project, rows, head, crs="EPSG:4326"))
    for im in data.images:
        assert np.allclose(im.position, POS[im.id], atol=1e-3)
        assert im.sigma_attitude == (0.01, 0.01, 0.02)


def test_missing_row_is_a_warning(project):
    x, y, z = POS["L"]
    data = load_project_data(_with_trajectory(project, [f"L,{x},{y},{z},0.5,0.5,1.0"]))
    assert any("no trajectory row for image(s) R" in w for w in data.reading_warnings)


@pytest.mark.parametrize("rows,match", [
    (["Q,1,2,3,0.5,0.5,1"], r"gnss.csv, line 2: image 'Q' is not in the project"),
    (["L,1,2,3,0.5,0.5,1", "L,1,2,3,0.5,0.5,1"], r"image 'L' has more than one row"),
    (["L,1,2,3,0.5,-0.5,1"], r"line 2: sigma_Y must be positive"),
    (["L,1,2,x,0.5,0.5,1"], r"gnss.csv.*line 2.*Z"),
])
def test_bad_rows_are_named(project, rows, match):
    with pytest.raises(CSVError, match=match):
        load_project_data(_with_trajectory(project, rows))
