"""Plausibility checks before the adjustment (issue 31): a gross mistake is named by its
cause, not by its symptom.

Each test copies the sample project, makes one mistake the way a user would make it and
runs ``vectoradjust adjust`` through :func:`vectoradjust.cli.commands.main`. Before
:mod:`vectoradjust.adjust.plausibility`, these runs ended in the symptom (the message
each gave is in the test's docstring): "N object point(s) cannot be determined", "The
reduced normal equations are singular", "The adjustment diverged", or a message about
the first point that failed. The fast tests at the end call the checks directly on the
sample's data.
"""

from __future__ import annotations

import contextlib
import copy
import io
import re
import shutil
from pathlib import Path

import numpy as np
import pytest

from vectoradjust.adjust.classify import classify_measurements
from vectoradjust.adjust.plausibility import check_classified, check_inputs, format_half_size
from vectoradjust.cli.commands import main
from vectoradjust.errors import ProjectError
from vectoradjust.model import Camera

pd = pytest.importorskip("pandas")


# --------------------------------------------------------------------------- helpers
@pytest.fixture
def project(sample_dir, tmp_path) -> Path:
    """A copy of the sample project (without the satellite sub-project)."""
    d = tmp_path / "p"
    shutil.copytree(sample_dir, d, ignore=shutil.ignore_patterns("satellite"))
    return d


def adjust(d: Path) -> tuple[int, str]:
    """``vectoradjust adjust`` on the project in ``d``: exit status and the message."""
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        rc = main(["adjust", str(d / "project.toml"), "-o", str(d.parent / "out"), "-q"])
    return rc, " ".join(err.getvalue().split())


def refused(d: Path, *patterns: str) -> str:
    """The run fails with a message that matches every pattern; the message."""
    rc, msg = adjust(d)
    assert rc == 1, msg
    assert "cannot be determined" not in msg and "diverged" not in msg, msg
    for p in patterns:
        assert re.search(p, msg), f"{p!r} not in: {msg}"
    return msg


def edit_toml(d: Path, old: str, new: str, count: int = 1) -> None:
    p = d / "project.toml"
    text = p.read_text()
    assert text.count(old) >= count, old
    p.write_text(text.replace(old, new, count))


def edit_csv(path: Path, change) -> None:
    t = pd.read_csv(path, dtype={"point_id": str, "image_id": str})
    changed = change(t)
    (t if changed is None else changed).to_csv(path, index=False, float_format="%.8f")


def gcps_to(d: Path, epsg: int, order: str = "xy") -> None:
    """The control points transformed from the project's zone 16 to another CRS."""
    pyproj = pytest.importorskip("pyproj")
    t = pyproj.Transformer.from_crs(32616, epsg, always_xy=True)

    def change(c):
        x, y = t.transform(c.X.to_numpy(), c.Y.to_numpy())
        c["X"], c["Y"] = (x, y) if order == "xy" else (y, x)

    edit_csv(d / "gcps.csv", change)


def turn_camera(d: Path, kappa: str) -> None:
    """The camera turned by 90 degrees in its mount (photo x along ground -Y); the
    approximate attitude written with ``kappa``."""
    def change(t):
        t["x"], t["y"] = t.y.copy(), -t.x.copy()

    edit_csv(d / "image_points.csv", change)
    edit_toml(d, "attitude = [0.0, 0.0, 0.0]", f"attitude = [0.0, 0.0, {kappa}]", 2)


# --------------------------------------------------------------------------- image coordinates
def test_image_coordinates_in_micrometres(project):
    """Before: "10 object point(s) cannot be determined (e.g. point index 560): a point
    without a coordinate prior must be measured on at least two images"."""
    def change(t):
        t[["x", "y"]] *= 1000.0

    edit_csv(project / "image_points.csv", change)
    refused(project, r"image_points\.csv: the image coordinates of image\(s\) 'L', 'R' lie "
            r"outside the camera format of \+-110\.0 x 110\.0 mm",
            r"likely cause: they are about 1000 times too large: micrometres",
            r"Divide x and y .* by 1000")


def test_image_coordinates_in_pixels(project):
    """Scanner pixels (column, row from the corner, 30 um) where mm are expected. Before:
    "10 object point(s) cannot be determined (e.g. point index 560) ..."."""
    def change(t):
        t["x"], t["y"] = (t.x + 115.0) / 0.03, (115.0 - t.y) / 0.03

    edit_csv(project / "image_points.csv", change)
    refused(project, r"outside the camera format",
            r"likely cause: they are pixels \(column, row\), not millimetres: \d+ px x 0\.03 mm",
            r'unit = "pixel"')


def test_mirrored_image_coordinates(project):
    """y pointing down. Before: "The adjustment diverged at iteration 3 ..."."""
    def change(t):
        t["y"] = -t.y

    edit_csv(project / "image_points.csv", change)
    refused(project, r"the image coordinates of image 'L' are mirrored", r"negate y")


def test_measurements_of_one_image_only(project):
    """An export of image L's measurements only. Before: "image_points.csv, line 32: point
    'T01' is measured on only one image and is neither a control/check point nor a shape
    point ..." (the first point that failed, not why)."""
    edit_csv(project / "image_points.csv", lambda t: t[t.image_id == "L"])
    refused(project, r"all 576 measurements are on image 'L'; image\(s\) 'R' of \[\[images\]\] "
            r"have none", r"Add the measurements of image\(s\) 'R'")


# --------------------------------------------------------------------------- ground coordinates
def test_control_with_x_and_y_swapped(project):
    """Before: "24 object point(s) cannot be determined (e.g. point index 0) ..."."""
    def change(t):
        t["X"], t["Y"] = t.Y.copy(), t.X.copy()

    edit_csv(project / "gcps.csv", change)
    refused(project, r"gcps\.csv: the 30 control points measured on the images lie \d+ km "
            r"south-east of the images' footprint", r"'GCP01' at X = 4474572\.118",
            r"likely cause: X and Y are swapped", r"Swap the columns X and Y")


def test_control_in_degrees(project):
    """Longitude and latitude in X and Y. Before: "24 object point(s) cannot be determined
    (e.g. point index 0) ..."."""
    gcps_to(project, 4326)
    refused(project, r"likely cause: they look like degrees \(longitude, latitude\)",
            r'Give \[control\] crs = "EPSG:4326"')


def test_control_in_degrees_latitude_first(project):
    """Latitude in X, longitude in Y. Before: "24 object point(s) cannot be determined
    ..."."""
    gcps_to(project, 4326, order="yx")
    refused(project, r"degrees \(latitude, longitude\)", r"Swap the columns X and Y")


@pytest.mark.parametrize("epsg, side", [(32617, "west"), (32615, "east")])
def test_control_in_the_neighbouring_utm_zone(project, epsg, side):
    """Before: "The reduced normal equations are singular: the exterior orientation is
    not determined (datum defect) ..."."""
    gcps_to(project, epsg)
    refused(project, rf"lie 509 km {side} of the images' footprint",
            rf"neighbouring UTM zone {epsg - 32600} \(EPSG:{epsg}\), not of zone 16",
            rf'Give \[control\] crs = "EPSG:{epsg}"')


def test_road_layer_with_the_prj_of_another_zone(project):
    """The OSM shapefile's .prj says zone 15 though its coordinates are zone 16. Before:
    "dem.tif: measured shape point '41341773_0' (feature '41341773' of osm_roads.shp) has
    no height: the DEM does not cover it"."""
    prj = project / "osm_roads.prj"
    prj.write_text(prj.read_text().replace("Zone_16N", "Zone_15N").replace("-87.0", "-93.0"))
    refused(project, r"OSM \(.*osm_roads\.shp\): the road vertices lie 509 km west of the "
            r"images' footprint", r"the CRS its file states \(WGS 84 / UTM zone 15N\) is not "
            r"the one its coordinates are in", r"\.prj")


def test_dem_that_misses_the_roads(project):
    """A DEM cropped to a corner away from the roads. Before: "dem.tif: measured shape
    point '41341773_0' ... has no height: the DEM does not cover it"."""
    rasterio = pytest.importorskip("rasterio")
    from rasterio.windows import Window

    src = project / "dem.tif"
    with rasterio.open(src) as r:
        w = Window(0, 0, 40, 40)
        profile = r.profile.copy()
        data = r.read(1, window=w)
        profile.update(width=40, height=40, transform=r.window_transform(w))
    src.unlink()
    with rasterio.open(src, "w", **profile) as out:
        out.write(data, 1)
    refused(project, r"dem\.tif: the DEM gives no height to 536 of the 536 measured shape "
            r"points of OSM, TNM, TIGER: it covers none of them",
            r"the DEM covers E 505780 to 505980, N 4475325 to 4475525",
            r"likely cause: a DEM of another area")


def test_dem_without_data_at_the_roads(project):
    """A DEM whose cells are nodata everywhere but in its north-west corner. Before:
    "dem.tif: measured shape point '41341773_0' ... has no height: the DEM does not cover
    it"."""
    rasterio = pytest.importorskip("rasterio")
    with rasterio.open(project / "dem.tif") as r:
        profile, grid = r.profile, r.read(1)
    grid[40:, :] = profile["nodata"]
    grid[:, 40:] = profile["nodata"]
    with rasterio.open(project / "dem.tif", "w", **profile) as out:
        out.write(grid, 1)
    refused(project, r"dem\.tif: the DEM gives no height to 536 of the 536 measured shape "
            r"points", r"inside its extent; likely cause: the DEM has no data \(nodata cells\) "
            r"where the roads are")


# --------------------------------------------------------------------------- orientation
def test_same_position_for_both_images(project):
    """R's position copied from L. Before: "10 object point(s) cannot be determined (e.g.
    point index 560) ..."."""
    edit_toml(project, "position = [506497.0, 4475000.0, 799.0]",
              "position = [506303.0, 4475003.0, 799.0]")
    refused(project, r"images 'L' and 'R' have the same approximate position",
            r"the rays of the 10 tie point\(s\) measured on both \(e\.g\. 'T01'\) are parallel",
            r"Give each image its own approximate position")


@pytest.mark.parametrize("zl", ["0.0", "-799.0"])
def test_images_under_the_ground(project, zl):
    """ZL left at 0 or given with the wrong sign (refraction and earth curvature off, whose
    correction would refuse it first). Before: "The adjustment diverged at iteration 5
    (2 for -799) ..."."""
    edit_toml(project, "refraction = true\nearth_curvature = true",
              "refraction = false\nearth_curvature = false")
    edit_toml(project, "799.0]", f"{zl}]", 2)
    refused(project, rf"\[\[images\]\] 'L', 'R': the approximate position ZL = {float(zl):g} m "
            r"puts the camera under the ground \(187\.2 m, the median height of the 30 "
            r"measured control points\)", r"Give ZL as the height of the projection centre")


def test_attitude_in_radians(project):
    """The camera turned by 90 deg, kappa written in radians. Before: "1 object point(s)
    cannot be determined (e.g. point index 565) ..."."""
    turn_camera(project, "1.5708")
    refused(project, r"\[\[images\]\] 'L': attitude = \[0, 0, 1\.5708\] looks like radians",
            r"turned by 88 deg", r"attitude = \[0, 0, 90\]")


def test_kappa_of_the_other_sign(project):
    """kappa = -90 deg for a camera turned by +90 deg. Before: "The adjustment diverged at
    iteration 3 ..."."""
    turn_camera(project, "-90.0")
    refused(project, r"image 'L': its measured control points are turned by 180 deg",
            r"the points fit kappa = 90 deg", r"sigma_attitude = 5 deg")


def test_camera_turned_by_90_degrees_is_not_refused(project):
    """The valid project of the two tests above (kappa = 90 deg) adjusts."""
    turn_camera(project, "90.0")
    rc, msg = adjust(project)
    assert rc == 0, msg


# --------------------------------------------------------------------------- direct calls
@pytest.fixture(scope="module")
def sample_data(sample_dir):
    from vectoradjust.files.readers import load_project_data

    return load_project_data(str(sample_dir / "project.toml"))


def _all(data) -> set:
    return {spec.name for spec, _ in data.vectors}


def test_the_sample_passes_without_a_warning(sample_data):
    warnings: list = []
    check_inputs(sample_data, _all(sample_data), warnings)
    cls = classify_measurements(sample_data, _all(sample_data), [])
    check_classified(sample_data, cls, _all(sample_data), warnings)
    assert warnings == []


def test_one_control_point_far_away_is_a_warning(sample_data):
    data = copy.deepcopy(sample_data)
    data.control.xyz[3, 0] += 50_000.0  # a typo in one easting
    warnings: list = []
    check_inputs(data, _all(data), warnings)
    assert len(warnings) == 1
    assert re.search(r"control point 'GCP04' \(.*gcps\.csv, line 5\) lies 4[89]\.\d km outside "
                     r"the images' footprint", warnings[0]), warnings


def test_a_few_image_coordinates_outside_the_format_are_a_warning(sample_data):
    data = copy.deepcopy(sample_data)
    data.measurements.xy[0] = (510.0, 20.0)  # a typo in line 2: 510 for 51.0
    warnings: list = []
    check_inputs(data, _all(data), warnings)
    assert warnings == [
        "image 'L': 1 of 576 measurement(s) lie outside the camera format (+-110.0 x 110.0 mm, "
        f"the calibrated fiducials): {data.measurements.source}, line(s) 2; a typo, or a point "
        "of another image?"]


def test_same_position_without_tie_points_is_a_warning(sample_data):
    data = copy.deepcopy(sample_data)
    data.images[1].position = data.images[0].position.copy()
    meas = data.measurements
    keep = np.array([not re.fullmatch(r"T\d+", p) for p in meas.point_id])
    for name in ("point_id", "image_id", "xy", "sigma", "rows"):
        setattr(meas, name, getattr(meas, name)[keep])
    warnings: list = []
    check_inputs(data, _all(data), warnings)
    cls = classify_measurements(data, _all(data), [])
    check_classified(data, cls, _all(data), warnings)
    assert len(warnings) == 1 and "have the same approximate position" in warnings[0], warnings


def test_kappa_far_off_without_a_prior_is_a_warning(sample_data):
    """Free angles (no sigma_attitude): the adjustment may still find kappa."""
    data = copy.deepcopy(sample_data)
    for im in data.images:
        im.attitude = np.array([0.0, 0.0, 60.0])
        im.sigma_attitude = None
    warnings: list = []
    check_inputs(data, _all(data), warnings)
    assert len(warnings) == 2
    assert re.search(r"image 'L': its measured control points are turned by -60 deg .*"
                     r"kappa is off by about 60 deg .* the points fit kappa = 0 deg",
                     warnings[0]), warnings


def test_images_far_from_control_and_roads_are_named(sample_data):
    """Both positions swapped (northing, easting): the control and the roads agree, so
    the images' positions are the mistake."""
    data = copy.deepcopy(sample_data)
    for im in data.images:
        im.position = im.position[[1, 0, 2]]
    with pytest.raises(ProjectError, match=r"the approximate positions of the images "
                       r"\(\[\[images\]\] position\) lie \d+ km south-east of the control "
                       r"points and the roads .* likely cause: X and Y are swapped"):
        check_inputs(data, _all(data), [])


def test_format_half_size():
    cal = type("Cal", (), {"image_size": (1000, 800), "pixel_size": (0.01, 0.01),
                           "fiducials": None})()
    assert format_half_size(Camera(100.0, calibration=cal)) == pytest.approx(
        (5.0, 4.0, "[camera] image_size x pixel_size"))
    assert format_half_size(Camera(100.0))[:2] == (150.0, 150.0)
