"""Drone images into a project (:mod:`vectoradjust.files.drone`).

Synthetic images whose EXIF GDAL writes (the JPEG driver writes a real EXIF block from
``EXIF_*`` metadata items; XMP goes into TIFFs) so the tests run without shared data;
then the four DJI Phantom 4 RTK images of ``../shared/data/aerial/dji_uav`` against the
OpenSfM solution there (skipped when the folder is absent).
"""

from __future__ import annotations

import json
import math
import warnings
from pathlib import Path

import numpy as np
import pytest

from vectoradjust.errors import CameraError, CRSError, InputFileError, ProjectError
from vectoradjust.files.drone import (
    camera_from_exif,
    import_images,
    read_image_exif,
    read_opensfm_camera,
    utm_crs,
    write_drone_project,
)
from vectoradjust.files.project import load_project
from vectoradjust.sensor.camera import CameraCalibration
from vectoradjust.sensor.collinearity import project, rotation_matrix
from vectoradjust.sensor.refine import distort

pytestmark = pytest.mark.io

SHARED = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "aerial" / "dji_uav"


def _dms(value: float) -> str:
    a = abs(value)
    d = int(a)
    m = int((a - d) * 60)
    s = (a - d - m / 60) * 3600
    return f"({d}) ({m}) ({s:.6f})"


def write_image(path: Path, lon: float, lat: float, alt: float, *, model: str = "FC6310R",
                focal: float = 8.8, f35: float | None = 24, size=(120, 80), xmp: str = "",
                when: str = "2019:04:11 11:01:21", gps: bool = True) -> Path:
    """An image with EXIF (and XMP for TIFFs) written by GDAL; no .aux.xml left."""
    import rasterio
    import rasterio.shutil
    from rasterio.io import MemoryFile

    tags = {"EXIF_Make": "DJI", "EXIF_Model": model, "EXIF_FocalLength": f"({focal})",
            "EXIF_DateTimeOriginal": when}
    if f35:
        tags["EXIF_FocalLengthIn35mmFilm"] = str(int(f35))
    if gps:
        tags.update({"EXIF_GPSLatitude": _dms(lat), "EXIF_GPSLatitudeRef": "N" if lat >= 0
                     else "S", "EXIF_GPSLongitude": _dms(lon),
                     "EXIF_GPSLongitudeRef": "E" if lon >= 0 else "W",
                     "EXIF_GPSAltitude": f"({abs(alt)})",
                     "EXIF_GPSAltitudeRef": "0x00" if alt >= 0 else "0x01"})
    driver = "JPEG" if path.suffix.lower() in (".jpg", ".jpeg") else "GTiff"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with MemoryFile() as mf:
            with mf.open(driver="GTiff", width=size[0], height=size[1], count=1,
                         dtype="uint8") as m:
                m.write(np.full((1, size[1], size[0]), 100, "uint8"))
                m.update_tags(**tags)
                if xmp:
                    m.update_tags(ns="xml:XMP", **{"xml:XMP": xmp})
            with mf.open() as m:
                rasterio.shutil.copy(m, str(path), driver=driver)
    aux = path.with_name(path.name + ".aux.xml")
    if aux.exists():
        aux.unlink()
    return path


def dji_xmp(yaw: float, pitch: float, relative: float = 100.0) -> str:
    return ('<x:xmpmeta xmlns:x="adobe:ns:meta/"><rdf:RDF xmlns:rdf="http://www.w3.org/1999/'
            '02/22-rdf-syntax-ns#"><rdf:Description xmlns:drone-dji="http://www.dji.com/'
            f'drone-dji/1.0/" drone-dji:GimbalYawDegree="{yaw:+.2f}" drone-dji:'
            f'GimbalPitchDegree="{pitch:+.2f}" drone-dji:GimbalRollDegree="+0.00" '
            f'drone-dji:RelativeAltitude="{relative:+.2f}"/></rdf:RDF></x:xmpmeta>')


def _lonlat(crs: str, e, n):
    from pyproj import Transformer

    return Transformer.from_crs(crs, "EPSG:4326", always_xy=True).transform(e, n)


@pytest.fixture()
def strip(tmp_path):
    """Four JPEGs along a line flown east in UTM 33N (a known place, grid coordinates)."""
    folder = tmp_path / "flight"
    folder.mkdir()
    east = 500000.0 + 40.0 * np.arange(4)
    lon, lat = _lonlat("EPSG:32633", east, np.full(4, 5300000.0))
    for k in range(4):
        write_image(folder / f"DJI_{k:04d}.JPG", lon[k], lat[k], 150.0 + k,
                    when=f"2020:06:01 10:00:{10 * k:02d}")
    (folder / "notes.txt").write_text("not an image")
    return folder, east


# ------------------------------------------------------------------------- EXIF
def test_exif_of_a_jpeg_written_by_gdal(tmp_path):
    path = write_image(tmp_path / "a.jpg", -70.25, -33.5, -12.5)
    assert b"Exif\x00\x00" in path.read_bytes()[:200]  # a real EXIF block, not a side file
    info = read_image_exif(path)
    assert info["longitude"] == pytest.approx(-70.25, abs=1e-8)
    assert info["latitude"] == pytest.approx(-33.5, abs=1e-8)
    assert info["altitude"] == -12.5  # GPSAltitudeRef 1: below the reference
    assert info["focal_length"] == 8.8 and info["focal_length_35mm"] == 24
    assert (info["make"], info["model"]) == ("DJI", "FC6310R")
    assert (info["width"], info["height"]) == (120, 80)
    assert info["datetime"] == "2019-04-11T11:01:21"
    assert info["gimbal_yaw"] is None and info["xmp"] == {}


def test_xmp_of_a_tiff(tmp_path):
    info = read_image_exif(write_image(tmp_path / "a.tif", 10, 50, 300,
                                       xmp=dji_xmp(92.9, -60.0, 99.96)))
    assert info["gimbal_yaw"] == 92.9 and info["gimbal_pitch"] == -60.0
    assert info["gimbal_roll"] == 0.0 and info["relative_altitude"] == 99.96
    assert info["xmp"]["GimbalYawDegree"] == "+92.90"


def test_camera_from_the_35mm_equivalent_and_the_table(tmp_path):
    info = read_image_exif(write_image(tmp_path / "a.jpg", 10, 50, 300, size=(120, 80)))
    cam = camera_from_exif(info)
    # diagonal 43.27 * 8.8 / 24 = 15.866 mm at 3:2 -> 13.20 x 8.80 mm (the 1" sensor)
    assert cam["pixel_size"] * 120 == pytest.approx(13.2, abs=0.005)
    assert cam["focal_length"] == 8.8 and cam["image_size"] == [120, 80]
    CameraCalibration.from_dict(cam)  # a valid camera table
    no35 = read_image_exif(write_image(tmp_path / "b.jpg", 10, 50, 300, f35=None))
    assert camera_from_exif(no35)["pixel_size"] == pytest.approx(13.2 / 120)
    assert camera_from_exif(no35, sensor_width=6.0)["pixel_size"] == pytest.approx(0.05)
    other = read_image_exif(write_image(tmp_path / "c.jpg", 10, 50, 300, f35=None,
                                        model="XYZ9"))
    with pytest.raises(CameraError, match="'XYZ9' is not in the table of sensor sizes"):
        camera_from_exif(other)


# ------------------------------------------------------------------------- import
def test_import_positions_crs_and_flight_direction(strip):
    folder, east = strip
    res = import_images(folder)
    assert res.crs == "EPSG:32633" == utm_crs(15.0, 47.8)
    assert [im["id"] for im in res.images] == [f"DJI_{k:04d}" for k in range(4)]
    xyz = np.array([im["position"] for im in res.images])
    assert np.abs(xyz[:, 0] - east).max() < 0.002  # EXIF keeps about 3 mm (1e-6 ")
    assert np.abs(xyz[:, 1] - 5300000.0).max() < 0.002
    assert np.array_equal(xyz[:, 2], 150.0 + np.arange(4))
    assert all(im["sigma_position"] == [3.0, 3.0, 5.0] for im in res.images)
    att = np.array([im["attitude"] for im in res.images])
    assert np.allclose(att[:, :2], 0) and np.allclose(att[:, 2], -90.0, atol=0.01)
    assert set(res.attitude_source.values()) == {"nadir, kappa from the flight direction"}
    # kappa's meaning: a ground point ahead (east) of the camera is at the image's top
    eo = np.r_[xyz[1], np.radians(att[1])]
    xy = project(eo, xyz[1] + [30.0, 0.0, -100.0], 8.8)
    assert xy[1] > 2.0 and abs(xy[0]) < 1e-3  # kappa is written to 1e-4 degrees
    assert "unknown" not in res.notes[0] or "NOT known" in res.notes[0]


def test_gimbal_angles_point_the_camera(tmp_path):
    folder = tmp_path / "g"
    folder.mkdir()
    lon, lat = _lonlat("EPSG:32633", [500000.0], [5300000.0])
    write_image(folder / "a.tif", lon[0], lat[0], 200.0, xmp=dji_xmp(90.0, -60.0))
    res = import_images(folder, crs="EPSG:32633")
    assert res.attitude_source["a"] == "gimbal yaw and pitch (XMP), roll 0"
    c = np.array(res.images[0]["position"])
    eo = np.r_[c, np.radians(res.images[0]["attitude"])]
    # 60 degrees below the horizon towards grid east: that ground point is the centre
    ahead = c + [100.0 / math.tan(math.radians(60.0)), 0.0, -100.0]
    assert np.abs(project(eo, ahead, 8.8)).max() < 1e-3  # attitude written to 1e-4 deg
    # and a point farther east lies towards the top of the image, north to its left
    assert project(eo, ahead + [20.0, 0, 0], 8.8)[1] > 0.1
    assert project(eo, ahead + [0, 20.0, 0], 8.8)[0] < -0.1


def test_import_errors(tmp_path, strip):
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(InputFileError, match="holds no images"):
        import_images(empty)
    with pytest.raises(InputFileError, match="is not a folder"):
        import_images(tmp_path / "missing")
    folder, _ = strip
    write_image(folder / "DJI_0100.JPG", 15.0, 47.8, 100, gps=False)
    with pytest.raises(InputFileError, match=r"1 of the 5 images .* no GPS .*: DJI_0100\.JPG"):
        import_images(folder)
    (folder / "DJI_0100.JPG").unlink()
    write_image(folder / "DJI_0200.JPG", 15.0, 47.8, 100, model="FC330", focal=3.6)
    with pytest.raises(CameraError, match="taken with 2 cameras .*FC330 f = 3.6 mm"):
        import_images(folder)
    (folder / "DJI_0200.JPG").unlink()
    with pytest.raises(CRSError, match="not a projected CRS"):
        import_images(folder, crs="EPSG:4326")
    with pytest.raises(CRSError, match="not a CRS PROJ knows"):
        import_images(folder, crs="EPSG:999999")
    with pytest.raises(ProjectError, match="height = 'msl' is unknown"):
        import_images(folder, height="msl")
    with pytest.raises(ProjectError, match="not two positive numbers"):
        import_images(folder, gnss_sigma=(3.0, -1.0))


# ------------------------------------------------------------------------- OpenSfM
OPENSFM = {"projection_type": "brown", "width": 120, "height": 80, "focal_x": 0.66,
           "focal_y": 0.67, "c_x": 0.01, "c_y": -0.02, "k1": -0.26, "k2": 0.1,
           "k3": -0.025, "p1": 0.003, "p2": -0.002}


def _opensfm_pixel(cam: dict, ray: np.ndarray) -> np.ndarray:
    """OpenSfM's own projection of camera-frame rays (x right, y down, z forward)."""
    x, y = ray[:, 0] / ray[:, 2], ray[:, 1] / ray[:, 2]
    r2 = x * x + y * y
    rad = 1 + cam["k1"] * r2 + cam["k2"] * r2 ** 2 + cam["k3"] * r2 ** 3
    xd = x * rad + 2 * cam["p1"] * x * y + cam["p2"] * (r2 + 2 * x * x)
    yd = y * rad + cam["p1"] * (r2 + 2 * y * y) + 2 * cam["p2"] * x * y
    s = max(cam["width"], cam["height"])
    return np.column_stack([s * (cam["focal_x"] * xd + cam["c_x"]) + (cam["width"] - 1) / 2,
                            s * (cam["focal_y"] * yd + cam["c_y"]) + (cam["height"] - 1) / 2])


def test_opensfm_camera_projects_as_opensfm_does(tmp_path):
    path = tmp_path / "reconstruction.json"
    path.write_text(json.dumps([{"cameras": {"cam1": OPENSFM}, "shots": {}}]))
    table = read_opensfm_camera(path, pixel_size=0.0024)
    cam = CameraCalibration.from_dict(table)
    assert cam.distortion_model == "brown"
    assert cam.focal_length == pytest.approx(0.66 * 120 * 0.0024)
    rng = np.random.default_rng(1)
    ray = np.column_stack([rng.uniform(-0.5, 0.5, 50), rng.uniform(-0.35, 0.35, 50),
                           np.ones(50)])
    want = _opensfm_pixel(OPENSFM, ray)
    # ideal photo coordinates about the principal point: x right, y up
    ideal = np.column_stack([cam.focal_length * ray[:, 0], -cam.focal_length * ray[:, 1]])
    got = distort(ideal, cam, unit="pixel")
    assert np.abs(got - want).max() < 1e-9
    nominal = read_opensfm_camera(path)
    assert "nominal pixel 0.001 mm" in nominal["name"]
    half = read_opensfm_camera(path, pixel_size=0.0048, image_size=(60, 40))
    assert half["focal_length"] == pytest.approx(table["focal_length"])


def test_opensfm_camera_errors(tmp_path):
    two = tmp_path / "cameras.json"
    two.write_text(json.dumps({"a": OPENSFM, "b": OPENSFM}))
    with pytest.raises(CameraError, match="holds 2 cameras"):
        read_opensfm_camera(two)
    assert read_opensfm_camera(two, camera_id="b")["distortion"]["k1"] == -0.26
    fish = tmp_path / "fish.json"
    fish.write_text(json.dumps({"a": {**OPENSFM, "projection_type": "fisheye"}}))
    with pytest.raises(CameraError, match="is a 'fisheye' camera"):
        read_opensfm_camera(fish)
    with pytest.raises(CameraError, match="another aspect ratio"):
        read_opensfm_camera(two, camera_id="a", image_size=(100, 100))
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(CameraError, match="cannot be read as JSON"):
        read_opensfm_camera(bad)


# ------------------------------------------------------------------------- the project
def test_written_project_loads(strip, tmp_path):
    folder, east = strip
    cams = tmp_path / "cameras.json"
    cams.write_text(json.dumps({"c": {**OPENSFM, "width": 120, "height": 80}}))
    res = import_images(folder, height="ellipsoidal", gnss_sigma=(2.0, 4.0),
                        camera_json=cams)
    out = write_drone_project(res, tmp_path / "proj" / "drone.toml")
    (out.parent / "image_points.csv").write_text("point_id,image_id,x,y\n")
    spec = load_project(out)
    assert spec.crs == "EPSG:32633" and spec.heights == "ellipsoidal"
    assert [im.id for im in spec.images] == [f"DJI_{k:04d}" for k in range(4)]
    assert np.allclose([im.position[0] for im in spec.images], east, atol=0.002)
    assert all(im.sigma_position == (2.0, 2.0, 4.0) and im.sigma_attitude is None
               for im in spec.images)
    cal = spec.camera.calibration
    assert cal.distortion_model == "brown" and cal.brown_coefficients[0] == -0.26
    assert cal.pixel_size[0] == pytest.approx(13.2 / 120, abs=1e-4)  # EXIF pixel size
    assert spec.measurements["unit"] == "pixel"
    text = out.read_text()
    assert "2 m horizontal, 4 m vertical" in text and "drone_camera.toml" in text
    assert (out.parent / spec.raw["images"][0]["path"]).resolve() == \
        (folder / "DJI_0000.JPG").resolve()
    geoid = write_drone_project(import_images(folder, height="geoid"), tmp_path / "g.toml")
    (tmp_path / "image_points.csv").write_text("point_id,image_id,x,y\n")
    assert load_project(geoid).heights is None
    assert "above the geoid" in geoid.read_text()


# ------------------------------------------------------------------------- real images
def _shared() -> Path:
    if not (SHARED / "images").is_dir():
        pytest.skip(f"shared drone images not found: {SHARED / 'images'}")
    return SHARED


def _opensfm_centres(rec: dict) -> dict:
    """OpenSfM's camera centres (-R' t, topocentric ENU) in UTM 51N, and its rotations
    turned into our camera axes (x right, y up, z back) in grid axes."""
    from pyproj import Transformer
    from scipy.spatial.transform import Rotation

    ref = rec["reference_lla"]
    lat, lon = math.radians(ref["latitude"]), math.radians(ref["longitude"])
    x0 = np.array(Transformer.from_crs("EPSG:4979", "EPSG:4978", always_xy=True).transform(
        ref["longitude"], ref["latitude"], ref["altitude"]))
    enu = np.array([[-math.sin(lon), math.cos(lon), 0],
                    [-math.sin(lat) * math.cos(lon), -math.sin(lat) * math.sin(lon),
                     math.cos(lat)],
                    [math.cos(lat) * math.cos(lon), math.cos(lat) * math.sin(lon),
                     math.sin(lat)]])
    to_utm = Transformer.from_crs("EPSG:4978", "EPSG:32651", always_xy=True)
    geo = Transformer.from_crs("EPSG:4326", "EPSG:32651", always_xy=True)
    e, n = geo.transform([ref["longitude"]] * 2, [ref["latitude"], ref["latitude"] + 1e-4])
    g = math.atan2(e[1] - e[0], n[1] - n[0])  # grid azimuth of true north
    to_grid = np.array([[math.cos(g), math.sin(g), 0], [-math.sin(g), math.cos(g), 0],
                        [0, 0, 1]])
    out = {}
    for sid, shot in rec["shots"].items():
        r = Rotation.from_rotvec(shot["rotation"]).as_matrix()
        centre = -r.T @ np.array(shot["translation"])
        utm = np.array(to_utm.transform(*(x0 + enu.T @ centre)))
        out[sid] = (utm, np.diag([1.0, -1.0, -1.0]) @ r @ to_grid.T)
    return out


def test_shared_dji_images_against_opensfm():
    d = _shared()
    res = import_images(d / "images", height="ellipsoidal",
                        camera_json=d / "opensfm" / "reconstruction.json")
    assert res.crs == "EPSG:32651" and len(res.images) == 4
    sfm = _opensfm_centres(json.loads((d / "opensfm" / "reconstruction.json").read_text())[0])
    for im in res.images:
        centre, m_sfm = sfm[im["id"]]
        diff = np.array(im["position"]) - centre
        # measured: 2.04, 2.15, 2.45, 2.13 m horizontally, 0.01 m in height (OpenSfM
        # aligns its block to these GPS positions; four images leave it ~2 m off)
        assert np.hypot(diff[0], diff[1]) < 3.0 and abs(diff[2]) < 0.05, (im["id"], diff)
        m = rotation_matrix(*np.radians(im["attitude"]))
        angle = math.degrees(math.acos(np.clip((np.trace(m @ m_sfm.T) - 1) / 2, -1, 1)))
        assert angle < 2.0, (im["id"], angle)  # measured 0.46-1.25 degrees (gimbal, roll 0)
    cam = CameraCalibration.from_dict(res.camera)
    assert cam.focal_length == pytest.approx(8.798, abs=0.001)
    assert cam.image_size == (1368, 912) and cam.pixel_size[0] == pytest.approx(13.2 / 1368,
                                                                                 rel=1e-3)


def test_shared_dji_exif_camera_and_heights():
    d = _shared()
    info = read_image_exif(d / "images" / "100_0005_0018.tif")
    # EXIF GPSAltitude is DJI's AbsoluteAltitude; the take-off point is 86.6 m in it
    assert info["altitude"] == info["absolute_altitude"] == 186.57
    assert info["altitude"] - info["relative_altitude"] == pytest.approx(86.61)
    assert info["rtk_flag"] == 50  # RTK fixed: DJI writes ellipsoidal heights then
    cam = camera_from_exif(info)
    assert cam["pixel_size"] * 1368 == pytest.approx(13.2, abs=0.01)
    assert info["exif_size"] == (5472, 3648)
