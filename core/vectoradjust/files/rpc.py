"""RPC files: reading and writing RPC00B models, and the ground frame of a project CRS.

- :func:`read_rpc` - the RPCs of an image (GeoTIFF RPC tags, NITF RPC00B, or a side file
  next to the image: ``<name>_rpc.txt`` / ``<name>_RPC.TXT`` / ``<name>.RPB``, as GDAL
  finds them), or of a side file given directly (parsed here, in GDAL's formats).
- :func:`write_rpc` - ``<name>_rpc.txt`` in GDAL's format (``KEY: value`` lines), which
  GDAL reads back for the image ``<name>.<ext>`` next to it.
- :func:`write_rpc_geotiff` - a copy of an image with (corrected) RPCs in its GeoTIFF tags.
- :func:`crs_frame` - a :class:`~vectoradjust.sensor.ground.CallableFrame` from the
  project CRS (projected, metres) to WGS84 longitude, latitude and ellipsoidal height,
  with the geoid when the heights are orthometric.

GDAL's rules, checked with GDAL 3.10 (``tests/test_rpc_files.py``): the side file of
``dir/name.ext`` is ``dir/name_rpc.txt`` or ``dir/name_RPC.TXT`` (the name up to its last
dot) or ``dir/name.RPB`` / ``.rpb``; a side file takes precedence over RPC tags in the
image itself. GDAL reads RPC metadata values with up to 15 significant digits (GeoTIFF
tags), and NITF RPC00B holds offsets and scales as integers or 4 decimals, so only the
``_rpc.txt`` keeps every digit of a model. rasterio and pyproj are imported inside the
functions (docs/architecture.md).
"""

from __future__ import annotations

import re
import shutil
import warnings
from pathlib import Path
from typing import Callable, Optional, Union

import numpy as np

from vectoradjust.errors import CRSError, InputFileError
from vectoradjust.sensor.ground import CallableFrame
from vectoradjust.sensor.rpc import RpcModel

__all__ = [
    "read_rpc",
    "write_rpc",
    "write_rpc_geotiff",
    "rpc_side_file",
    "crs_frame",
    "utm_crs",
    "GEOIDS",
]

#: geoid names accepted by :func:`crs_frame` -> the vertical CRS of heights above it
GEOIDS = {"EGM96": "EPSG:5773", "EGM2008": "EPSG:3855", "EGM08": "EPSG:3855",
          "EGM84": "EPSG:5798"}
_SCALAR_KEYS = ("ERR_BIAS", "ERR_RAND", "LINE_OFF", "SAMP_OFF", "LAT_OFF", "LONG_OFF",
                "HEIGHT_OFF", "LINE_SCALE", "SAMP_SCALE", "LAT_SCALE", "LONG_SCALE",
                "HEIGHT_SCALE")
_COEFF_KEYS = ("LINE_NUM_COEFF", "LINE_DEN_COEFF", "SAMP_NUM_COEFF", "SAMP_DEN_COEFF")
#: DigitalGlobe .RPB keyword -> GDAL RPC key
_RPB_KEYS = {"errBias": "ERR_BIAS", "errRand": "ERR_RAND", "lineOffset": "LINE_OFF",
             "sampOffset": "SAMP_OFF", "latOffset": "LAT_OFF", "longOffset": "LONG_OFF",
             "heightOffset": "HEIGHT_OFF", "lineScale": "LINE_SCALE",
             "sampScale": "SAMP_SCALE", "latScale": "LAT_SCALE", "longScale": "LONG_SCALE",
             "heightScale": "HEIGHT_SCALE", "lineNumCoef": "LINE_NUM_COEFF",
             "lineDenCoef": "LINE_DEN_COEFF", "sampNumCoef": "SAMP_NUM_COEFF",
             "sampDenCoef": "SAMP_DEN_COEFF"}
_READ_MEND = ("Give the image with its RPCs (GeoTIFF RPC tags, NITF RPC00B, or the side "
              "file <name>_rpc.txt or <name>.RPB next to it), or the _rpc.txt / .RPB file")
_WGS84_3D = "EPSG:4979"
#: a datum transformation less accurate than this (m), or of unknown accuracy, is a
#: warning (as :data:`vectoradjust.files.readers.TRANSFORMATION_ACCURACY_LIMIT`, which
#: imports this module)
TRANSFORMATION_ACCURACY_LIMIT = 1.0

PathLike = Union[str, Path]


# ---------------------------------------------------------------------- reading
def read_rpc(path: PathLike, opener: Optional[Callable] = None) -> RpcModel:
    """The RPC model of an image or of an RPC side file.

    Parameters
    ----------
    path : str or os.PathLike
        An image GDAL reads (its RPCs from GeoTIFF tags, NITF RPC00B or the side file
        GDAL finds next to it), or a side file itself: ``*_rpc.txt`` (GDAL's and
        GeoEye's ``KEY: value`` format, units after the values allowed) or ``*.RPB``
        (DigitalGlobe).
    opener : callable, optional
        ``opener(path) -> (tags, files)`` reads an image's metadata: ``tags`` its
        ``RPC`` metadata domain as a dict (empty when it has none), ``files`` the files
        GDAL opened for it, the image first (a side file among them is named as the
        source). Any exception it raises means "not readable as an image". Default:
        rasterio. The QGIS plugin passes one on QGIS's own GDAL
        (``qgis_plugin/rpc_io.py``); side files are parsed here either way.

    Returns
    -------
    RpcModel
        ``source`` is the file the RPCs came from (the side file when GDAL used one).

    Raises
    ------
    InputFileError
        The file is missing or unreadable, holds no RPCs, or an RPC value is malformed
        (the message names the file and the key).
    """
    p = Path(path)
    if not p.is_file():
        raise InputFileError(f"RPC file {p}: " + ("is a directory" if p.is_dir()
                                                   else "does not exist"),
                             _READ_MEND, path=str(p))
    name = p.name.lower()
    if name.endswith("_rpc.txt"):
        return RpcModel.from_gdal(_parse_rpc_txt(_read_text(p), str(p)), source=str(p))
    if name.endswith(".rpb"):
        return RpcModel.from_gdal(_parse_rpb(_read_text(p), str(p)), source=str(p))
    return _read_image_rpc(p, opener or _rasterio_metadata)


def _read_text(p: Path) -> str:
    try:
        return p.read_text(encoding="utf-8", errors="replace")
    except OSError as exc:
        raise InputFileError(f"RPC file {p}: cannot be read ({exc})", _READ_MEND,
                             path=str(p)) from exc


def _rasterio_metadata(p: Path) -> tuple:
    """``(RPC tags, files)`` of an image through rasterio (GDAL)."""
    import rasterio
    import rasterio.errors

    with warnings.catch_warnings():  # RPC images are rarely georeferenced
        warnings.simplefilter("ignore", rasterio.errors.NotGeoreferencedWarning)
        with rasterio.open(p) as src:
            return dict(src.tags(ns="RPC")), [str(f) for f in src.files]


def _read_image_rpc(p: Path, opener: Callable) -> RpcModel:
    """RPCs of an image through GDAL (tags, RPC00B or side file)."""
    try:
        tags, files = opener(p)
    except ImportError:  # a missing reader is no fault of the file
        raise
    except Exception as exc:  # rasterio raises RasterioIOError, CPLE_* errors
        raise InputFileError(f"RPC file {p}: cannot be read as an image ({exc})",
                             _READ_MEND, path=str(p)) from exc
    tags, files = dict(tags or {}), [str(f) for f in files or []]
    if not tags:
        stem = _stem(p)
        raise InputFileError(
            f"RPC file {p}: the image has no RPCs (no RPC tags or RPC00B, and no "
            f"{stem}_rpc.txt or {stem}.RPB next to it)", _READ_MEND, path=str(p))
    side = [f for f in files[1:] if f.lower().endswith(("_rpc.txt", ".rpb"))]
    source = str(p.parent / Path(side[0]).name) if side else str(p)
    return RpcModel.from_gdal(_clean_values(tags), source=source)


def _clean_values(d: dict) -> dict:
    """Scalar values reduced to their number (GeoEye writes units: '+003360.00 pixels')."""
    out = {}
    for key, value in d.items():
        k = str(key).strip().upper()
        if k in _SCALAR_KEYS and isinstance(value, str) and value.split():
            value = value.split()[0]
        out[k] = value
    return out


def _parse_rpc_txt(text: str, source: str) -> dict:
    """GDAL's RPC dictionary from a ``_rpc.txt`` file (``KEY: value`` or ``KEY=value``)."""
    lines = {}
    for line in text.splitlines():
        m = re.match(r"\s*([A-Za-z_0-9]+)\s*[:=]\s*(.*?)\s*$", line)
        if m:
            lines[m.group(1).upper()] = m.group(2)
    d = {k: lines[k] for k in _SCALAR_KEYS if k in lines}
    for key in _COEFF_KEYS:
        values = []
        for j in range(1, 21):
            item = lines.get(f"{key}_{j}")
            if item is None:
                raise InputFileError(
                    f"{source}: the RPC file lacks {key}_{j}", "An _rpc.txt file has "
                    f"the lines {key}_1 to {key}_20 (GDAL's format: 'KEY: value')",
                    path=source, details={"key": f"{key}_{j}"})
            values.append(item.split()[0] if item.split() else item)
        d[key] = " ".join(values)
    return _clean_values(d)


def _parse_rpb(text: str, source: str) -> dict:
    """GDAL's RPC dictionary from a DigitalGlobe ``.RPB`` file (``name = value;``)."""
    found = {}
    for m in re.finditer(r"(\w+)\s*=\s*(\([^)]*\)|[^;\n]*)\s*;?", text):
        found[m.group(1)] = m.group(2).strip().strip("\"'")
    d = {}
    for rpb, key in _RPB_KEYS.items():
        if rpb not in found:
            if key.startswith("ERR_"):
                continue
            raise InputFileError(f"{source}: the RPB file lacks {rpb}",
                                 "An .RPB file has lineOffset ... sampDenCoef in its "
                                 "IMAGE group (DigitalGlobe's format)", path=source,
                                 details={"key": key})
        d[key] = found[rpb].strip("()").replace(",", " ")
    return _clean_values(d)


# ---------------------------------------------------------------------- writing
def _stem(p: Path) -> str:
    """The name up to its last dot (GDAL's rule for side files); the name if none."""
    return p.name.rsplit(".", 1)[0] if "." in p.name else p.name


def rpc_side_file(image: PathLike) -> Path:
    """The ``_rpc.txt`` side file GDAL reads for ``image``: ``dir/<name>_rpc.txt``.

    A path that already ends in ``_rpc.txt`` (any case) is returned unchanged.
    """
    p = Path(image)
    if p.name.lower().endswith("_rpc.txt"):
        return p
    return p.parent / f"{_stem(p)}_rpc.txt"


def _rpc_text(rpc: RpcModel) -> str:
    """The model in GDAL's ``_rpc.txt`` format, every number as its shortest exact repr."""
    lines = []
    for key in _SCALAR_KEYS:
        value = getattr(rpc, key.lower())
        if value is not None:
            lines.append(f"{key}: {float(value)!r}")
    for key in _COEFF_KEYS:
        coeffs = getattr(rpc, key[: -len("_COEFF")].lower())
        lines.extend(f"{key}_{j}: {float(c)!r}" for j, c in enumerate(coeffs, start=1))
    return "\n".join(lines) + "\n"


def write_rpc(rpc: RpcModel, path: PathLike) -> Path:
    """Write ``rpc`` as an ``_rpc.txt`` side file in GDAL's format.

    Parameters
    ----------
    rpc : RpcModel
    path : str or os.PathLike
        The image the RPCs belong to (the file written is ``<name>_rpc.txt`` beside it,
        which GDAL then uses in preference to RPC tags in the image), or the
        ``..._rpc.txt`` path itself.

    Returns
    -------
    pathlib.Path
        The file written. Numbers are written with every digit (``repr``), so
        :func:`read_rpc` gives back an equal model.

    Raises
    ------
    InputFileError
        The file cannot be written.
    """
    out = rpc_side_file(path)
    try:
        out.write_text(_rpc_text(rpc), encoding="ascii")
    except OSError as exc:
        raise InputFileError(f"Cannot write the RPC file {out} ({exc})",
                             "Choose a writable directory", path=str(out)) from exc
    return out


def _overriding_side_files(dst: Path) -> list:
    stem = _stem(dst)
    names = {f"{stem}_rpc.txt".lower(), f"{stem}.rpb".lower()}
    if not dst.parent.is_dir():
        return []
    return sorted(str(f) for f in dst.parent.iterdir() if f.name.lower() in names)


def write_rpc_geotiff(src_image: PathLike, rpc: RpcModel, dst: PathLike) -> Path:
    """A copy of ``src_image`` with ``rpc`` in its GeoTIFF RPC tags.

    A GeoTIFF is copied byte for byte and its RPC tags then replaced in place (the
    pixels are not decoded, so a JPEG-compressed image stays exactly as it was); any
    other format GDAL reads is converted to a tiled, deflate-compressed GeoTIFF first.

    Parameters
    ----------
    src_image : str or os.PathLike
        The image.
    rpc : RpcModel
        The RPCs to store (e.g. the corrected model of
        :func:`~vectoradjust.sensor.rpc.fold_bias`).
    dst : str or os.PathLike
        The GeoTIFF to write (not the source itself).

    Returns
    -------
    pathlib.Path
        ``dst``. Read back, it gives ``rpc`` to GDAL's precision (15 significant digits).

    Raises
    ------
    InputFileError
        The source is missing or unreadable, ``dst`` is the source, ``dst`` cannot be
        written, or an RPC side file next to ``dst`` would override its tags.
    """
    import rasterio
    import rasterio.errors
    import rasterio.shutil
    from rasterio.rpc import RPC

    src, out = Path(src_image), Path(dst)
    if not src.is_file():
        raise InputFileError(f"image {src}: does not exist", "Give the image to copy",
                             path=str(src))
    if out.resolve() == src.resolve():
        raise InputFileError(f"{out}: the copy would overwrite the source image",
                             "Give another name for the image with the corrected RPCs",
                             path=str(out))
    side = _overriding_side_files(out)
    if side:
        raise InputFileError(f"{out}: {side[0]} lies next to it, and GDAL would take the "
                             "RPCs from that side file instead of the new tags",
                             "Remove or rename the side file, or write the copy elsewhere",
                             path=side[0])
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", rasterio.errors.NotGeoreferencedWarning)
            with rasterio.open(src) as ds:
                driver = ds.driver
            if driver == "GTiff":
                shutil.copyfile(src, out)
            else:
                rasterio.shutil.copy(src, out, driver="GTiff", TILED="YES",
                                     COMPRESS="DEFLATE", BIGTIFF="IF_SAFER")
            with rasterio.open(out, "r+") as ds:
                ds.rpcs = RPC.from_gdal(rpc.to_gdal())
    except OSError as exc:
        raise InputFileError(f"Cannot write {out} ({exc})", "Choose a writable directory",
                             path=str(out)) from exc
    except rasterio.errors.RasterioError as exc:
        raise InputFileError(f"image {src}: cannot be copied to {out} ({exc})",
                             "Give an image GDAL reads", path=str(src)) from exc
    return out


# ---------------------------------------------------------------------- ground frame
def utm_crs(lon: float, lat: float) -> str:
    """The WGS84 UTM zone (or UPS beyond 84 N / 80 S) of a point, as ``"EPSG:xxxxx"``.

    Includes the zone exceptions of south-west Norway (32V) and Svalbard (31X-37X).
    """
    if lat >= 84.0:
        return "EPSG:5041"
    if lat < -80.0:
        return "EPSG:5042"
    zone = int((lon + 180.0) // 6.0) % 60 + 1
    if 56.0 <= lat < 64.0 and 3.0 <= lon < 12.0:
        zone = 32
    elif 72.0 <= lat < 84.0 and 0.0 <= lon < 42.0:
        zone = 31 if lon < 9.0 else 33 if lon < 21.0 else 35 if lon < 33.0 else 37
    return f"EPSG:{(32600 if lat >= 0 else 32700) + zone}"


def _parse_crs(value, what: str, example: str = "EPSG:32616"):
    """``value`` (an EPSG code, WKT ...) as a pyproj CRS; a :class:`CRSError` naming
    ``what`` if PROJ does not understand it."""
    from pyproj import CRS
    from pyproj.exceptions import CRSError as _PCRSError

    try:
        return CRS.from_user_input(value)
    except _PCRSError as exc:
        raise CRSError(f"{what} {str(value)[:80]!r} is not understood ({exc})",
                       f'Give an EPSG code such as "{example}"') from exc


def _horizontal(crs, near: Optional[tuple]):
    """The horizontal part of ``crs`` and its vertical part (None); refuses degrees."""
    subs = crs.sub_crs_list if crs.is_compound else [crs]
    horizontal = subs[0]
    vertical = subs[1] if len(subs) > 1 else None
    if horizontal.is_geographic:
        zone = (f"the UTM zone of the data is {utm_crs(*near)}" if near is not None else
                "e.g. the UTM zone of the data: EPSG:326zz north or EPSG:327zz south with "
                "zz = floor((lon + 180) / 6) + 1")
        raise CRSError(f"the project CRS {crs.name!r} is geographic (degrees); the "
                       "adjustment of RPC images needs object coordinates in metres",
                       f"Choose a projected CRS in metres: {zone}")
    if not horizontal.is_projected:
        raise CRSError(f"the project CRS {crs.name!r} is not a projected CRS",
                       "Choose a projected CRS in metres, such as the UTM zone of the data")
    unit = horizontal.axis_info[0].unit_name if horizontal.axis_info else "metre"
    if unit not in ("metre", "meter", "m"):
        raise CRSError(f"the project CRS {crs.name!r} has units of {unit!r}, not metres",
                       "Choose a projected CRS in metres")
    return horizontal, vertical


def _vertical_crs(geoid):
    """The vertical CRS of heights above ``geoid`` (a name of :data:`GEOIDS` or a CRS)."""
    key = re.sub(r"[\s_-]", "", str(geoid)).upper()
    v = _parse_crs(GEOIDS.get(key, geoid), "the geoid / vertical CRS")
    if not v.is_vertical or v.is_compound:
        raise CRSError(f"the geoid {str(geoid)!r} ({v.name}) is not a vertical CRS",
                       "Give geoid='EGM96', 'EGM2008' or a vertical CRS such as "
                       "'EPSG:5703' (NAVD88 height)")
    return v


def _source_crs(crs, heights: str, geoid, near):
    """The 3D source CRS of the frame, and the vertical CRS (None: ellipsoidal heights)."""
    from pyproj.crs import CompoundCRS

    if heights not in ("ellipsoidal", "orthometric"):
        raise CRSError(f"heights={heights!r} is not known",
                       "Give heights='ellipsoidal' (above WGS84, as RPCs use them) or "
                       "'orthometric' (above a geoid, with geoid=...)")
    c = _parse_crs(crs, "the project CRS")
    horizontal, vertical = _horizontal(c, near)
    if vertical is not None:
        if heights == "ellipsoidal":
            raise CRSError(f"the project CRS {c.name!r} has orthometric heights "
                           f"({vertical.name}) but heights='ellipsoidal' was given",
                           "Give heights='orthometric', or the 2D CRS for ellipsoidal "
                           "heights")
        if geoid is not None and not _vertical_crs(geoid).equals(vertical):
            raise CRSError(f"the project CRS {c.name!r} has heights in {vertical.name}, "
                           f"not in {_vertical_crs(geoid).name}",
                           "Give either a compound CRS or geoid=, not both")
        return c, vertical
    if heights == "ellipsoidal":
        if geoid is not None:
            raise CRSError(f"geoid={geoid!r} was given with heights='ellipsoidal'",
                           "Give heights='orthometric' to convert heights above the geoid")
        return (horizontal if len(horizontal.axis_info) == 3 else horizontal.to_3d()), None
    if geoid is None:
        raise CRSError("heights='orthometric' needs the geoid the heights refer to",
                       "Give geoid='EGM96', 'EGM2008' or a vertical CRS such as "
                       "'EPSG:5703', or heights='ellipsoidal'")
    if len(horizontal.axis_info) == 3:
        raise CRSError(f"the project CRS {c.name!r} already has ellipsoidal heights",
                       "Give its 2D CRS with heights='orthometric'")
    vertical = _vertical_crs(geoid)
    return CompoundCRS(f"{horizontal.name} + {vertical.name}", [horizontal, vertical]), vertical


def _probe_point(horizontal, near) -> tuple:
    """A lon, lat to test the transformation at: ``near`` or the CRS's area of use centre."""
    if near is not None:
        return float(near[0]), float(near[1])
    area = horizontal.area_of_use
    if area is None:
        return 0.0, 0.0
    west, east = area.west, area.east if area.east >= area.west else area.east + 360.0
    lon = (west + east) / 2.0
    return (lon - 360.0 if lon > 180.0 else lon), (area.south + area.north) / 2.0


def _missing_grids(source, aoi) -> list:
    """Names of the missing grids, in PROJ's order of preference of their operations."""
    from pyproj.transformer import TransformerGroup

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            group = TransformerGroup(source, _WGS84_3D, always_xy=True, area_of_interest=aoi)
        grids = [g for op in group.unavailable_operations for g in op.grids
                 if not g.available]
    except Exception:  # only for the message
        return []
    # the ones projsync can fetch (from PROJ's content server) first
    ordered = [g.short_name for g in grids if g.direct_download]
    ordered += [g.short_name for g in grids if not g.direct_download]
    return list(dict.fromkeys(ordered))


def _no_geoid_error(source, vertical, aoi, why: str) -> CRSError:
    from pyproj.datadir import get_user_data_dir

    grids = _missing_grids(source, aoi)
    name = grids[0] if grids else "<grid>"
    need = f" (it needs the grid {', '.join(grids[:4])})" if grids else ""
    return CRSError(
        f"the heights cannot be converted from {vertical.name} to ellipsoidal heights: PROJ "
        f"has no geoid grid for it here{need}; {why}",
        f"Install the grid: projsync --file {name} (into {get_user_data_dir()}), or set "
        "PROJ_NETWORK=ON to let PROJ download it, or give the heights as "
        "ellipsoidal (heights='ellipsoidal')")


def crs_frame(crs, heights: str = "ellipsoidal", geoid: Optional[str] = None,
              near: Optional[tuple] = None) -> CallableFrame:
    """The ground frame of a project CRS: its ``X, Y, Z`` to WGS84 ``lon, lat, h``.

    Parameters
    ----------
    crs : str, int or pyproj.CRS
        The project CRS: projected, in metres (e.g. ``"EPSG:32616"``), or a compound
        CRS of one and a vertical CRS (e.g. ``"EPSG:32616+5703"``: heights are then
        orthometric in that datum).
    heights : {"ellipsoidal", "orthometric"}
        What ``Z`` is: the height above the ellipsoid of ``crs``'s datum (as RPCs use
        it), or above the geoid given by ``geoid`` (or by the compound ``crs``).
    geoid : str, optional
        For orthometric heights: ``"EGM96"`` (EPSG:5773), ``"EGM2008"`` (EPSG:3855),
        ``"EGM84"`` or a vertical CRS (``"EPSG:5703"``).
    near : tuple of 2 floats, optional
        ``lon, lat`` (degrees) of the data: the area PROJ chooses the transformation
        for, the point where the geoid is checked, and the UTM zone suggested when
        ``crs`` is geographic.

    Returns
    -------
    CallableFrame
        ``forward`` / ``inverse`` are pyproj transformations to and from EPSG:4979;
        ``description`` names the CRS, the heights and PROJ's operation.

    Raises
    ------
    CRSError
        ``crs`` is unknown, geographic or not in metres; the heights options
        contradict; PROJ lacks the geoid grid the orthometric heights need (the message
        names the grid and how to install it).
    """
    from pyproj import Transformer
    from pyproj.aoi import AreaOfInterest

    source, vertical = _source_crs(crs, heights, geoid, near)
    horizontal = source.sub_crs_list[0] if source.is_compound else source
    lon, lat = _probe_point(horizontal, near)
    aoi = AreaOfInterest(lon - 0.01, lat - 0.01, lon + 0.01, lat + 0.01) if near else None
    with warnings.catch_warnings():  # pyproj warns of missing grids; checked below
        warnings.simplefilter("ignore")
        t = Transformer.from_crs(source, _WGS84_3D, always_xy=True, area_of_interest=aoi)
    desc, accuracy, z = _probe(t, lon, lat)
    if vertical is not None:
        if "ballpark vertical" in desc.lower():
            raise _no_geoid_error(source, vertical, aoi, "PROJ offers only a ballpark "
                                  "transformation that takes the geoid as 0 m")
        # the probe of a CRS's area of use may lie outside a regional grid: only a
        # point of the data (near) must transform; _checked guards the points later
        if abs(z) < 1e-6 or (near is not None and not np.isfinite(z)):
            raise _no_geoid_error(source, vertical, aoi, f"at {lon:.4f}, {lat:.4f} it gives "
                                  f"a geoid height of {-z} m")
    if "ballpark" in desc.lower() or accuracy < 0 or accuracy > TRANSFORMATION_ACCURACY_LIMIT:
        why = ("a ballpark one" if "ballpark" in desc.lower() else "of unknown accuracy"
               if accuracy < 0 else f"accurate to {accuracy:g} m only")
        warnings.warn(f"the transformation from {source.name} to WGS 84 is {why} ({desc}): "
                      "positions may be off by that much; install PROJ's grids (projsync) "
                      "if one applies, or use a CRS on WGS 84", UserWarning, stacklevel=2)
    what = (f"orthometric heights in {vertical.name}" if vertical is not None else
            "ellipsoidal heights")
    return CallableFrame(_checked(t, str(crs)), _inverse(t),
                         f"{horizontal.name}, {what} -> WGS 84 (EPSG:4979): {desc}")


def _probe(t, lon: float, lat: float) -> tuple:
    """(description, accuracy in m or -1, Z of (lon, lat, h=0)) of the operation PROJ
    uses at the probe point (it may choose per point: ask after one transformation)."""
    from pyproj.exceptions import ProjError

    _, _, z = t.transform(lon, lat, 0.0, direction="INVERSE", errcheck=False)
    op = t
    try:
        op = t.get_last_used_operation()
    except (ProjError, AttributeError):  # PROJ < 9.1: the transformer's own description
        pass
    accuracy = float(op.accuracy) if op.accuracy is not None else -1.0
    return str(op.description), accuracy, float(z)


def _checked(t, crs: str):
    """``t.transform`` that raises a :class:`CRSError` for points it cannot transform."""

    def forward(x, y, z):
        lon, lat, h = t.transform(x, y, z, errcheck=False)
        lon, lat, h = np.asarray(lon, float), np.asarray(lat, float), np.asarray(h, float)
        bad = ~(np.isfinite(lon) & np.isfinite(lat) & np.isfinite(h))
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise CRSError(f"{int(bad.sum())} point(s) cannot be transformed from {crs} to "
                           f"WGS 84 (the first: X={np.ravel(x)[i]:.3f}, "
                           f"Y={np.ravel(y)[i]:.3f}, Z={np.ravel(z)[i]:.3f})",
                           "Check that the points lie in the CRS's area (and in the geoid "
                           "grid's) and that their coordinates are in that CRS")
        return lon, lat, h

    return forward


def _inverse(t):
    def inverse(lon, lat, h):
        return t.transform(lon, lat, h, direction="INVERSE")

    return inverse


def write_corrected_rpcs(run, folder: PathLike, final: Optional[PathLike] = None) -> list:
    """Each RPC image's RPCs with its estimated bias folded in, as GDAL side files.

    For an image whose RPCs came from ``img_01.tif`` (or ``img_01_rpc.txt``) this writes
    ``img_01_rpc.txt`` into ``folder``
    (:func:`vectoradjust.sensor.models.corrected_rpc_names`): copied next to the image,
    GDAL uses it instead of the image's own RPC tags (``gdalwarp -rpc`` orthorectifies
    with the corrected model at once). A pure shift is folded exactly; drift and affine
    biases by refitting the numerators (:func:`vectoradjust.sensor.rpc.fold_bias`); the
    file name and the fold's largest misfit are in the run's summary
    (``images[].corrected_rpc``).

    Parameters
    ----------
    run : vectoradjust.results.AdjustmentRun
    folder : path
    final : path, optional
        The folder the files end up in when ``folder`` is a temporary one. A name that
        would replace one of the project's own RPC files there (an output folder that
        holds the inputs) becomes ``<name>_corrected_rpc.txt`` instead, and the summary
        says so.

    Returns
    -------
    list of str
        The file names written (in ``folder``).
    """
    from vectoradjust.sensor.models import corrected_rpc_names
    from vectoradjust.sensor.rpc import fold_bias

    folder = Path(folder)
    final = Path(final) if final is not None else folder
    names = corrected_rpc_names(run.data.images)
    inputs = {Path(im.rpc.path).resolve() for im in run.data.images
              if im.model == "rpc" and im.rpc.path}
    entries = {e["id"]: e for e in run.summary.get("images", []) if e.get("model") == "rpc"}
    written = []
    for j, iid in enumerate(run.image_ids):
        im = next((m for m in run.data.images if m.id == iid), None)
        if im is None or im.model != "rpc":
            continue
        name = names[str(iid)]
        if (final / name).resolve() in inputs:  # never over the project's own RPCs
            name = name[: -len("_rpc.txt")] + "_corrected_rpc.txt"
            if str(iid) in entries and "corrected_rpc" in entries[str(iid)]:
                entries[str(iid)]["corrected_rpc"]["file"] = name
                entries[str(iid)]["corrected_rpc"]["note"] = (
                    "renamed: the output folder holds the project's RPC file of this name; "
                    "rename it to <image>_rpc.txt next to the image for GDAL to use it")
        folded, _ = fold_bias(im.rpc.rpc, run.result.eo[j])
        write_rpc(folded, folder / name)
        written.append(name)
    return written
