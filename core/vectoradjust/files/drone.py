"""Drone images into a project: EXIF GPS positions, a camera from EXIF or OpenSfM.

:func:`read_image_exif` reads what GDAL exposes of a JPEG's or TIFF's EXIF (``EXIF_*``
metadata items: GPS latitude, longitude and altitude, focal length and its 35 mm
equivalent, make and model) and of DJI's XMP packet (``drone-dji:`` relative and
absolute altitude, gimbal and flight angles). :func:`import_images` turns a folder of
them into ``[[images]]`` entries:

* **position**: EXIF latitude and longitude transformed to the project CRS (the UTM zone
  of the images' mean longitude and latitude when none is given, through PROJ); the
  height is EXIF ``GPSAltitude`` as written. Whether that is above the WGS84 ellipsoid
  or above the geoid depends on the drone and is not in the file: the user says it
  (``height = "ellipsoidal" | "geoid" | "unknown"``) and the written project states it
  (``heights = "ellipsoidal"``, or a comment). DJI's Phantom 4 RTK (camera FC6310R)
  writes ellipsoidal heights with RTK (DJI support); consumer DJI drones a barometric
  altitude that is neither; EXIF ``GPSAltitude`` equals XMP ``AbsoluteAltitude``.
* **attitude** (approximate, degrees): from the XMP gimbal yaw and pitch when present
  (roll taken as 0; the yaw turned from true to grid north by the meridian convergence);
  else nadir (omega = phi = 0) with kappa from the flight direction between consecutive
  images (in time), or 0 for a single image. The source is stated per image.
* **sigma_position**: per axis, ``[h, h, v]`` from the GNSS sigma given as horizontal
  and vertical.
* **camera**: focal length from EXIF; sensor width from the 35 mm equivalent focal
  length (sensor diagonal = 43.27 mm * f / f35 with the image's aspect ratio), else from
  :data:`SENSOR_WIDTHS` by model, else ``sensor_width``; pixel size = sensor width /
  columns; principal point at the centre, no distortion. :func:`read_opensfm_camera`
  reads a Brown camera from OpenSfM's ``reconstruction.json`` or ``cameras.json``
  (OpenDroneMap) instead: focal length and principal point normalised by the larger
  image dimension, ``k1 k2 k3 p1 p2`` (see :mod:`vectoradjust.sensor.camera`).

One project has one camera: images of several cameras (make, model, focal length or
size differ) are an error naming them (import each camera's images as a project).
Images without GPS are an error naming them (add their position by hand to the written
project, or move them out of the folder). rasterio and pyproj are imported inside the
functions.
"""

from __future__ import annotations

import json
import math
import re
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Optional, Union

import numpy as np

from vectoradjust.errors import CameraError, CRSError, InputFileError
from vectoradjust.sensor.collinearity import rotation_to_angles

__all__ = [
    "IMAGE_SUFFIXES",
    "FULL_FRAME_DIAGONAL",
    "SENSOR_WIDTHS",
    "HEIGHT_KINDS",
    "DroneImport",
    "read_image_exif",
    "camera_from_exif",
    "import_images",
    "read_opensfm_camera",
    "utm_crs",
    "write_drone_project",
]

PathLike = Union[str, Path]

#: file suffixes read as images (case-insensitive)
IMAGE_SUFFIXES = (".jpg", ".jpeg", ".tif", ".tiff")
#: diagonal of the 36 x 24 mm frame (mm): the 35 mm equivalent focal length's reference
FULL_FRAME_DIAGONAL = 43.27
#: sensor width (mm) of common drone cameras by EXIF model, when EXIF has no 35 mm
#: equivalent focal length
SENSOR_WIDTHS = {
    "FC6310": 13.2, "FC6310R": 13.2, "FC6310S": 13.2,   # Phantom 4 Pro / RTK / V2
    "FC330": 6.17, "FC300X": 6.17, "FC220": 6.17,       # Phantom 4, 3, Mavic Pro
    "L1D-20C": 13.2, "FC6510": 13.2,                   # Mavic 2 Pro, Zenmuse X4S
    "FC6520": 17.3, "FC3170": 6.4, "FC7303": 6.3,       # X5S, Mavic Air 2, Mini 2
    "M3E": 17.3, "ZENMUSEP1": 35.9,                     # Mavic 3E, Zenmuse P1
}
#: accepted kinds of the EXIF heights
HEIGHT_KINDS = ("ellipsoidal", "geoid", "unknown")

_XMP_FLOATS = {
    "RelativeAltitude": "relative_altitude", "AbsoluteAltitude": "absolute_altitude",
    "GimbalYawDegree": "gimbal_yaw", "GimbalPitchDegree": "gimbal_pitch",
    "GimbalRollDegree": "gimbal_roll", "FlightYawDegree": "flight_yaw",
    "RtkStdHgt": "rtk_sigma_height", "RtkFlag": "rtk_flag",
}


@dataclass
class DroneImport:
    """A folder of drone images read into project entries.

    Attributes
    ----------
    crs : str
        The project CRS (``"EPSG:32651"``).
    height : str
        ``"ellipsoidal"``, ``"geoid"`` or ``"unknown"``: what the EXIF heights are.
    images : list of dict
        ``[[images]]`` entries: ``id``, ``path`` (absolute), ``position`` (m),
        ``attitude`` (degrees), ``sigma_position`` (m), ``date``.
    camera : dict
        The camera table (:class:`vectoradjust.sensor.camera.CameraCalibration` keys).
    attitude_source : dict
        Per image id, where its attitude came from (``"gimbal"``, ``"flight direction"``,
        ``"nadir, kappa 0"``).
    gnss_sigma : tuple of float
        Horizontal and vertical GNSS sigma (m).
    exif : list of dict
        :func:`read_image_exif` of every image, in the order of ``images``.
    notes : list of str
        What the import assumed, for the written project and the console.
    """

    crs: str
    height: str
    images: list
    camera: dict
    attitude_source: dict
    gnss_sigma: tuple
    exif: list = field(default_factory=list)
    notes: list = field(default_factory=list)


# ------------------------------------------------------------------------- EXIF / XMP
def _numbers(text: Any) -> list:
    """The numbers of a GDAL EXIF value: ``"(24) (40) (49.0009)"``, ``"8.8"``, ``"88/10"``."""
    out = []
    for tok in re.findall(r"[-+]?\d+(?:\.\d*)?(?:[eE][-+]?\d+)?(?:/\d+)?", str(text)):
        num, _, den = tok.partition("/")
        out.append(float(num) / float(den) if den and float(den) else float(num))
    return out


def _first(tags: dict, key: str) -> Optional[float]:
    vals = _numbers(tags.get(key, ""))
    return vals[0] if vals and math.isfinite(vals[0]) else None


def _degrees(tags: dict, key: str) -> Optional[float]:
    """A GPS latitude or longitude in signed degrees (``S``/``W`` negative)."""
    vals = _numbers(tags.get(key, ""))
    if not vals:
        return None
    deg = sum(v / 60.0 ** i for i, v in enumerate(vals[:3]))
    ref = str(tags.get(key + "Ref", "")).strip().upper()
    return -deg if ref.startswith(("S", "W")) else deg


def _xmp(text: str) -> dict:
    """``{name: value}`` of the XMP packet's ``prefix:Name="value"`` attributes and
    ``<prefix:Name>value</prefix:Name>`` elements (the prefix dropped)."""
    found = {m.group(2): m.group(3) for m in re.finditer(
        r'\b([A-Za-z][\w.-]*):([A-Za-z]\w*)\s*=\s*"([^"]*)"', text)}
    found.update({m.group(2): m.group(3).strip() for m in re.finditer(
        r"<([A-Za-z][\w.-]*):([A-Za-z]\w*)>([^<]*)</\1:\2>", text)})
    return found


def read_image_exif(path: PathLike) -> dict:
    """What a drone image's EXIF and XMP say about where it was taken and by what camera.

    Parameters
    ----------
    path : str or Path
        A JPEG or TIFF image.

    Returns
    -------
    dict
        ``path``, ``width`` and ``height`` (pixels of the file), ``make``, ``model``,
        ``focal_length`` (mm), ``focal_length_35mm``, ``latitude`` and ``longitude``
        (signed degrees), ``altitude`` (m, EXIF GPSAltitude, negative below the
        reference), ``datetime`` (EXIF DateTimeOriginal as ISO text), ``exif_size``
        (PixelX/YDimension, the size when taken), ``xmp`` (all XMP values, text) and from
        DJI's XMP ``relative_altitude``, ``absolute_altitude``, ``gimbal_yaw``,
        ``gimbal_pitch``, ``gimbal_roll``, ``flight_yaw``, ``rtk_flag``,
        ``rtk_sigma_height``; a missing value is None.

    Raises
    ------
    InputFileError
        When GDAL cannot open the file.
    """
    import rasterio
    from rasterio.errors import NotGeoreferencedWarning, RasterioIOError

    path = Path(path)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", NotGeoreferencedWarning)
            with rasterio.open(path) as ds:
                tags = ds.tags()
                xmp = ds.tags(ns="xml:XMP") if "xml:XMP" in ds.tag_namespaces() else {}
                width, height = ds.width, ds.height
    except RasterioIOError as exc:
        raise InputFileError(f"image {path} cannot be read ({exc})",
                             "Check that it is a JPEG or TIFF image and readable",
                             path=str(path)) from None
    info = _exif_values(tags)
    info.update(path=str(path), width=int(width), height=int(height))
    values = _xmp(" ".join(str(v) for v in xmp.values()))
    info["xmp"] = values
    for name, key in _XMP_FLOATS.items():
        nums = _numbers(values.get(name, ""))
        info[key] = nums[0] if nums else None
    return info


def _exif_values(tags: dict) -> dict:
    """The EXIF items of GDAL's default metadata domain, parsed."""
    alt = _first(tags, "EXIF_GPSAltitude")
    ref = str(tags.get("EXIF_GPSAltitudeRef", "0")).strip().lower()  # "0x01", "1", "(1)"
    hexa = re.fullmatch(r"0x([0-9a-f]+)", ref)
    if alt is not None and (int(hexa[1], 16) if hexa else (_numbers(ref) or [0])[0]) == 1:
        alt = -alt  # below the reference (sea level / ellipsoid)
    when = str(tags.get("EXIF_DateTimeOriginal") or tags.get("EXIF_DateTime") or "").strip()
    m = re.match(r"(\d{4}):(\d{2}):(\d{2})[ T](\d{2}:\d{2}:\d{2})", when)
    size = (_first(tags, "EXIF_PixelXDimension"), _first(tags, "EXIF_PixelYDimension"))
    return {
        "make": str(tags.get("EXIF_Make", "")).strip() or None,
        "model": str(tags.get("EXIF_Model", "")).strip() or None,
        "focal_length": _first(tags, "EXIF_FocalLength"),
        "focal_length_35mm": _first(tags, "EXIF_FocalLengthIn35mmFilm"),
        "latitude": _degrees(tags, "EXIF_GPSLatitude"),
        "longitude": _degrees(tags, "EXIF_GPSLongitude"),
        "altitude": alt,
        "datetime": f"{m[1]}-{m[2]}-{m[3]}T{m[4]}" if m else None,
        "exif_size": tuple(int(v) for v in size) if None not in size else None,
    }


# ------------------------------------------------------------------------- the camera
def camera_from_exif(info: dict, sensor_width: Optional[float] = None) -> dict:
    """The camera table of an image's EXIF (:func:`read_image_exif`).

    Parameters
    ----------
    info : dict
        :func:`read_image_exif` of one image.
    sensor_width : float, optional
        Sensor width (mm) when neither the 35 mm equivalent focal length nor
        :data:`SENSOR_WIDTHS` gives it (it overrides both when given).

    Returns
    -------
    dict
        ``name``, ``focal_length`` (mm), ``principal_point`` ``[0, 0]``, ``pixel_size``
        (mm), ``image_size`` ``[columns, rows]`` of the file, ``pixel_origin``
        ``"center"``.

    Raises
    ------
    CameraError
        No focal length in EXIF, or no way to the sensor size.
    """
    path, f = info.get("path"), info.get("focal_length")
    if not f or f <= 0:
        raise CameraError(f"image {path}: EXIF has no focal length (FocalLength)",
                          "Give the camera with --camera-json (an OpenSfM/OpenDroneMap camera), "
                          "or write [camera] in the project by hand", path=path)
    cols, rows = int(info["width"]), int(info["height"])
    model = str(info.get("model") or "").upper().replace(" ", "")
    f35 = info.get("focal_length_35mm")
    if sensor_width is not None:
        width, source = float(sensor_width), f"sensor width {float(sensor_width):g} mm given"
    elif f35 and f35 > 0:
        diagonal = FULL_FRAME_DIAGONAL * f / f35
        width = diagonal * cols / math.hypot(cols, rows)
        source = f"sensor from the 35 mm equivalent {f35:g} mm"
    elif model in SENSOR_WIDTHS:
        width, source = SENSOR_WIDTHS[model], f"sensor width of the {model} (table)"
    else:
        raise CameraError(
            f"image {path}: EXIF has no 35 mm equivalent focal length and the camera "
            f"model {info.get('model')!r} is not in the table of sensor sizes",
            "Give the sensor width (sensor_width=..., mm) or the camera with --camera-json",
            path=path)
    label = " ".join(str(v) for v in (info.get("make"), info.get("model")) if v) or "camera"
    return {"name": f"{label} (EXIF: {source})", "focal_length": float(f),
            "principal_point": [0.0, 0.0], "pixel_size": width / cols,
            "image_size": [cols, rows], "pixel_origin": "center"}


def read_opensfm_camera(path: PathLike, pixel_size: Optional[float] = None,
                        image_size: Optional[Sequence[int]] = None,
                        camera_id: Optional[str] = None) -> dict:
    """A Brown (or perspective) camera of OpenSfM / OpenDroneMap as a camera table.

    OpenSfM normalises by the larger image dimension ``s``: pixel
    ``= s * normalised + (w - 1) / 2`` (rows down), focal ``focal_x``, ``focal_y``,
    principal point offset ``c_x``, ``c_y``. With pixel size ``sx`` (mm):
    ``focal_length = focal_x s sx``, ``pixel_size = [sx, sx focal_x / focal_y]``,
    ``principal_point = [c_x s sx, -c_y s sy]`` (photo ``y`` up); ``k1 k2 k3 p1 p2``
    are copied (the camera model handles OpenCV's ``y`` down).

    Parameters
    ----------
    path : str or Path
        ``reconstruction.json`` (a list of reconstructions with ``cameras``) or
        ``cameras.json`` (``{camera id: parameters}``).
    pixel_size : float, optional
        Pixel width (mm) at ``image_size``; without it a nominal 0.001 mm (the geometry
        is the same, only the millimetres are nominal; said in ``name``).
    image_size : (int, int), optional
        ``[columns, rows]`` of the images the project measures on (default the JSON's
        ``width``, ``height``); the normalised camera is resolution independent, but the
        aspect ratio must be the JSON's.
    camera_id : str, optional
        Which camera when the file holds several.

    Returns
    -------
    dict
        A camera table with ``[distortion] model = "brown"``.

    Raises
    ------
    CameraError
        An unreadable file, no or several cameras (without ``camera_id``), another
        projection type, another aspect ratio.
    """
    path = Path(path)
    cams = _opensfm_cameras(path)
    if camera_id is None and len(cams) != 1:
        raise CameraError(f"{path} holds {len(cams)} cameras ({', '.join(cams) or 'none'})",
                          "Name one (camera_id=...), or give a file with one camera",
                          path=str(path))
    key = camera_id if camera_id is not None else next(iter(cams))
    if key not in cams:
        raise CameraError(f"{path} has no camera {key!r}", f"Use one of {', '.join(cams)}",
                          path=str(path))
    c = cams[key]
    kind = str(c.get("projection_type", "brown"))
    if kind not in ("brown", "perspective"):
        raise CameraError(f"{path}: camera {key!r} is a {kind!r} camera",
                          "Only brown and perspective (pinhole) cameras are read; re-run "
                          "OpenSfM/ODM with camera_projection_type brown", path=str(path))
    try:
        w, h = int(c["width"]), int(c["height"])
        fx = float(c.get("focal_x", c.get("focal")))
        fy = float(c.get("focal_y", c.get("focal")))
        cx, cy = float(c.get("c_x", 0.0)), float(c.get("c_y", 0.0))
        dist = {k: float(c.get(k, 0.0)) for k in ("k1", "k2", "k3", "p1", "p2")}
    except (KeyError, TypeError, ValueError) as exc:
        raise CameraError(f"{path}: camera {key!r} lacks or garbles {exc}",
                          "Give OpenSfM's reconstruction.json or cameras.json as written",
                          path=str(path)) from None
    cols, rows = (w, h) if image_size is None else (int(image_size[0]), int(image_size[1]))
    if abs(cols * h - rows * w) > max(w, h):
        raise CameraError(f"{path}: camera {key!r} is {w} x {h} px but the images are "
                          f"{cols} x {rows} px (another aspect ratio)",
                          "Give the camera of these images (cropped or rotated images need "
                          "their own calibration)", path=str(path))
    size = max(cols, rows)
    sx = float(pixel_size) if pixel_size else 0.001
    sy = sx * fx / fy
    note = "" if pixel_size else ", nominal pixel 0.001 mm"
    return {"name": f"OpenSfM {key}{note}", "focal_length": fx * size * sx,
            "principal_point": [cx * size * sx, -cy * size * sy],
            "pixel_size": [sx, sy], "image_size": [cols, rows], "pixel_origin": "center",
            "distortion": {"model": "brown", **dist}}


def _opensfm_cameras(path: Path) -> dict:
    """``{camera id: parameters}`` of a reconstruction.json or cameras.json."""
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise CameraError(f"{path} cannot be read as JSON ({exc})",
                          "Give OpenSfM's reconstruction.json or ODM's cameras.json",
                          path=str(path)) from None
    cams: dict = {}
    if isinstance(doc, list):  # reconstruction.json: one entry per reconstruction
        for rec in doc:
            if isinstance(rec, dict):
                cams.update(rec.get("cameras") or {})
    elif isinstance(doc, dict):
        cams = doc.get("cameras", doc)
    if not isinstance(cams, dict) or not all(isinstance(v, dict) for v in cams.values()):
        raise CameraError(f"{path} holds no OpenSfM cameras",
                          "Give OpenSfM's reconstruction.json or ODM's cameras.json",
                          path=str(path))
    return cams


# ------------------------------------------------------------------------- the import
def utm_crs(longitude: float, latitude: float) -> str:
    """The WGS84 UTM zone of a place, ``"EPSG:326zz"`` (north) or ``"EPSG:327zz"``."""
    zone = int(math.floor((longitude + 180.0) / 6.0)) % 60 + 1
    return f"EPSG:{32600 + zone if latitude >= 0 else 32700 + zone}"


def _image_files(folder: Path) -> list:
    if not folder.is_dir():
        raise InputFileError(f"{folder} is not a folder",
                             "Give the folder that holds the drone images", path=str(folder))
    files = sorted(p for p in folder.iterdir()
                   if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES)
    if not files:
        raise InputFileError(f"folder {folder} holds no images "
                             f"({', '.join(IMAGE_SUFFIXES)})",
                             "Give the folder of the drone's JPEG or TIFF images",
                             path=str(folder))
    return files


def _check_gps_and_camera(infos: list, folder: Path) -> None:
    """Every image has GPS, and all share one camera; else an error naming them."""
    missing = [Path(i["path"]).name for i in infos
               if None in (i["latitude"], i["longitude"], i["altitude"])]
    if missing:
        shown = ", ".join(missing[:10]) + (f" and {len(missing) - 10} more"
                                           if len(missing) > 10 else "")
        raise InputFileError(
            f"{len(missing)} of the {len(infos)} images in {folder} have no GPS position "
            f"in EXIF (latitude, longitude and altitude): {shown}",
            "Move them out of the folder and import again, then add them to the project "
            "by hand with an approximate position if they are needed",
            path=str(folder), details={"files": missing})
    groups: dict = {}
    for i in infos:
        key = (i["make"], i["model"], i["focal_length"], i["width"], i["height"])
        groups.setdefault(key, []).append(Path(i["path"]).name)
    if len(groups) > 1:
        said = "; ".join(f"{k[0]} {k[1]} f = {k[2]} mm, {k[3]} x {k[4]} px: "
                         f"{', '.join(v[:3])}{' ...' if len(v) > 3 else ''}"
                         for k, v in groups.items())
        raise CameraError(
            f"the images in {folder} were taken with {len(groups)} cameras ({said})",
            "A project has one camera: put each camera's images in a folder of its own "
            "and import each as a project", path=str(folder))


def _to_crs(infos: list, crs: Optional[str]) -> tuple:
    """Positions ``(n, 3)`` in ``crs`` (default the UTM zone of the mean position), the
    CRS, and per image the grid azimuth of true north (degrees)."""
    from pyproj import CRS, Transformer
    from pyproj.exceptions import CRSError as ProjCRSError

    lon = np.array([i["longitude"] for i in infos], float)
    lat = np.array([i["latitude"] for i in infos], float)
    name = crs or utm_crs(float(lon.mean()), float(lat.mean()))
    try:
        target = CRS.from_user_input(name)
    except ProjCRSError as exc:
        raise CRSError(f"--crs {name!r} is not a CRS PROJ knows ({exc})",
                       'Give e.g. "EPSG:32651"') from None
    if not target.is_projected:
        raise CRSError(f"--crs {name!r} is not a projected CRS in metres",
                       "Give a projected CRS, e.g. the UTM zone (EPSG:326zz), or leave it "
                       "out for the UTM zone of the images")
    tr = Transformer.from_crs("EPSG:4326", target, always_xy=True)
    e, n = tr.transform(lon, lat)
    e2, n2 = tr.transform(lon, lat + 1e-4)
    north = np.degrees(np.arctan2(np.asarray(e2) - e, np.asarray(n2) - n))
    z = np.array([i["altitude"] for i in infos], float)
    return np.column_stack([e, n, z]), name, north


def _gimbal_attitude(yaw: float, pitch: float) -> np.ndarray:
    """Omega, phi, kappa (degrees) of a camera looking along grid azimuth ``yaw`` and
    ``pitch`` below the horizon (-90 = nadir) with the image's top forward, roll 0."""
    a, t = math.radians(yaw), math.radians(pitch)
    look = np.array([math.sin(a) * math.cos(t), math.cos(a) * math.cos(t), math.sin(t)])
    x = np.array([math.cos(a), -math.sin(a), 0.0])  # image right
    z = -look  # the camera looks along -z
    m = np.vstack([x, np.cross(z, x), z])  # ground -> image axes
    return np.degrees(rotation_to_angles(m))


def _attitudes(infos: list, xyz: np.ndarray, north: np.ndarray) -> tuple:
    """Approximate attitudes (degrees) and their source per image (see module doc)."""
    n = len(infos)
    order = sorted(range(n), key=lambda i: (infos[i]["datetime"] or "", infos[i]["path"]))
    att, source = np.zeros((n, 3)), [""] * n
    for k, i in enumerate(order):
        yaw, pitch = infos[i]["gimbal_yaw"], infos[i]["gimbal_pitch"]
        if yaw is not None and pitch is not None:
            att[i] = _gimbal_attitude(yaw + north[i], pitch)
            source[i] = "gimbal yaw and pitch (XMP), roll 0"
            continue
        nxt = order[k + 1] if k + 1 < n else None
        prv = order[k - 1] if k > 0 else None
        step = None
        for a, b in ((i, nxt), (prv, i)):
            if a is not None and b is not None and np.hypot(*(xyz[b, :2] - xyz[a, :2])) > 1.0:
                step = xyz[b, :2] - xyz[a, :2]
                break
        if step is None:
            source[i] = "nadir, kappa 0 (no flight direction)"
            continue
        azimuth = math.degrees(math.atan2(step[0], step[1]))
        att[i, 2] = (-azimuth + 180.0) % 360.0 - 180.0  # image top along the flight
        source[i] = "nadir, kappa from the flight direction"
    return att, source


def import_images(folder: PathLike, crs: Optional[str] = None, height: str = "unknown",
                  gnss_sigma: Sequence[float] = (3.0, 5.0),
                  camera_json: Optional[PathLike] = None,
                  sensor_width: Optional[float] = None) -> DroneImport:
    """Read a folder of drone images into ``[[images]]`` entries and a camera.

    Parameters
    ----------
    folder : str or Path
        The images (``.jpg``, ``.jpeg``, ``.tif``, ``.tiff``; other files are ignored).
    crs : str, optional
        Projected CRS of the project; default the UTM zone of the mean position.
    height : {"ellipsoidal", "geoid", "unknown"}
        What EXIF GPSAltitude is (see the module docstring).
    gnss_sigma : (float, float)
        Horizontal and vertical sigma of the GNSS positions (m).
    camera_json : str or Path, optional
        OpenSfM's ``reconstruction.json`` or ODM's ``cameras.json``: the Brown camera
        (:func:`read_opensfm_camera`) replaces the EXIF one, in millimetres with the EXIF
        pixel size when EXIF gives one (else nominal), at the images' size.
    sensor_width : float, optional
        Sensor width (mm) for :func:`camera_from_exif`.

    Returns
    -------
    DroneImport

    Raises
    ------
    InputFileError
        Not a folder, no images, images without GPS (named).
    CameraError
        Several cameras, no focal length or sensor size.
    CRSError
        ``crs`` unknown or not projected.
    ProjectError
        ``height`` or ``gnss_sigma`` not understood.
    """
    from vectoradjust.errors import ProjectError

    if height not in HEIGHT_KINDS:
        raise ProjectError(f"height = {height!r} is unknown",
                           f"Use one of {', '.join(HEIGHT_KINDS)}")
    sig = [float(v) for v in gnss_sigma]
    if len(sig) != 2 or not all(math.isfinite(v) and v > 0 for v in sig):
        raise ProjectError(f"GNSS sigma {list(gnss_sigma)!r} is not two positive numbers",
                           "Give the horizontal and the vertical sigma in metres, e.g. 3 5")
    folder = Path(folder)
    infos = [read_image_exif(p) for p in _image_files(folder)]
    _check_gps_and_camera(infos, folder)
    xyz, crs_name, north = _to_crs(infos, crs)
    att, source = _attitudes(infos, xyz, north)
    cam = _camera(infos[0], camera_json, sensor_width)
    images = [{"id": Path(i["path"]).stem, "path": i["path"],
               "position": [round(float(v), 3) for v in xyz[k]],
               "attitude": [round(float(v), 4) for v in att[k]],
               "sigma_position": [float(sig[0]), float(sig[0]), float(sig[1])],
               "date": i["datetime"]}
              for k, i in enumerate(infos)]
    notes = [f"positions from EXIF GPS in {crs_name}; heights: EXIF GPSAltitude, "
             f"{_HEIGHT_SAID[height]}",
             f"GNSS sigma {sig[0]:g} m horizontal, {sig[1]:g} m vertical (sigma_position "
             "per axis)",
             "attitudes approximate, sigma_attitude left free: " + "; ".join(
                 f"{s} ({source.count(s)})" for s in dict.fromkeys(source)),
             f"camera: {cam.get('name', 'given')}"]
    return DroneImport(crs=crs_name, height=height, images=images, camera=cam,
                       attitude_source={im["id"]: s for im, s in zip(images, source)},
                       gnss_sigma=(sig[0], sig[1]), exif=infos, notes=notes)


def _camera(info: dict, camera_json: Optional[PathLike],
            sensor_width: Optional[float]) -> dict:
    """The EXIF camera, or the OpenSfM one in the EXIF pixel size."""
    if camera_json is None:
        return camera_from_exif(info, sensor_width)
    try:
        pixel = camera_from_exif(info, sensor_width)["pixel_size"]
    except CameraError:
        pixel = None
    return read_opensfm_camera(camera_json, pixel_size=pixel,
                               image_size=(info["width"], info["height"]))


_HEIGHT_SAID = {
    "ellipsoidal": "stated as heights above the WGS84 ellipsoid",
    "geoid": "stated as heights above the geoid (mean sea level)",
    "unknown": "NOT known whether above the ellipsoid or the geoid (check the drone's "
               "documentation; the two differ by the geoid undulation, tens of metres)",
}


# ------------------------------------------------------------------------- writing
def _toml(value: Any) -> str:
    """A TOML value of a str, number, bool or list of them."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, float, np.integer, np.floating)):
        return repr(float(value)) if isinstance(value, (float, np.floating)) else str(value)
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_toml(v) for v in value) + "]"
    return json.dumps(str(value), ensure_ascii=False)


def _relative(path: str, base: Path) -> str:
    try:
        return Path(path).resolve().relative_to(base.resolve()).as_posix()
    except ValueError:
        import os

        try:
            return Path(os.path.relpath(Path(path).resolve(), base.resolve())).as_posix()
        except ValueError:  # another drive (Windows)
            return str(Path(path).resolve())


def _camera_lines(cam: dict) -> list:
    lines = [f"{k} = {_toml(v)}" for k, v in cam.items() if k != "distortion"]
    if cam.get("distortion"):
        lines += ["", "[distortion]"]
        lines += [f"{k} = {_toml(v)}" for k, v in cam["distortion"].items()]
    return lines


def write_drone_project(result: DroneImport, out: PathLike,
                        measurements: str = "image_points.csv",
                        measurement_sigma: float = 0.5) -> Path:
    """Write the project TOML of an import, and its camera file beside it.

    The camera goes to ``<project stem>_camera.toml`` (``[camera] path = ...``); image
    paths are relative to the project file. ``[measurements]`` names ``measurements``
    in pixels (to be made with ``vectoradjust measure``); control and ``[[vectors]]``
    are added by the user.

    Parameters
    ----------
    result : DroneImport
    out : str or Path
        The project file to write (its folder is created).
    measurements : str
        ``[measurements] path`` (relative to the project).
    measurement_sigma : float
        ``[measurements] sigma`` (pixels).

    Returns
    -------
    Path
        The project file.
    """
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    cam_path = out.with_name(out.stem + "_camera.toml")
    cam_path.write_text("# camera of the drone images (vectoradjust import-images)\n"
                        + "\n".join(_camera_lines(result.camera)) + "\n", encoding="utf-8")
    lines = ["# drone images imported by vectoradjust import-images"]
    lines += [f"# {n}" for n in result.notes]
    lines += [f'name = {_toml(out.stem)}', f"crs = {_toml(result.crs)}"]
    if result.height == "ellipsoidal":
        lines.append('heights = "ellipsoidal"   # the EXIF GPS heights (stated on import)')
    else:
        lines.append(f"# heights of the images: {_HEIGHT_SAID[result.height]}")
    lines += ["", "[camera]", f"path = {_toml(cam_path.name)}", "",
              "[measurements]", f"path = {_toml(measurements)}", 'unit = "pixel"',
              f"sigma = {_toml(float(measurement_sigma))}"]
    for im in result.images:
        lines += ["", "[[images]]", f"id = {_toml(im['id'])}",
                  f"path = {_toml(_relative(im['path'], out.parent))}",
                  f"position = {_toml(im['position'])}",
                  f"attitude = {_toml(im['attitude'])}   # "
                  f"{result.attitude_source.get(im['id'], '')}",
                  f"sigma_position = {_toml(im['sigma_position'])}"]
        if im.get("date"):
            lines.append(f"date = {_toml(im['date'])}")
    lines += ["", "# add [control] and/or [[vectors]] (the road databases), then measure:",
              "# vectoradjust measure predict ... ; vectoradjust adjust ..."]
    out.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return out
