"""RPC images in QGIS: their RPCs and the ground frame, without a second GDAL or PROJ.

The command line reads an image's RPCs with rasterio and builds the ground frame (the
project CRS to WGS84 longitude, latitude and ellipsoidal height) with pyproj
(:func:`vectoradjust.files.rpc.read_rpc`, :func:`vectoradjust.files.rpc.crs_frame`,
:func:`vectoradjust.files.readers.read_rpc_images`). Neither may be loaded into QGIS, so:

* :func:`read_rpc` - side files (``*_rpc.txt``, ``*.RPB``) are parsed by the core as on
  the command line; an image's own RPC metadata (GeoTIFF tags, NITF RPC00B, or the side
  file GDAL finds next to it) is read with QGIS's own GDAL (``gdal.Open(path)
  .GetMetadata("RPC")``, :func:`gdal_rpc_metadata`) and turned into the model by the
  core (:meth:`vectoradjust.sensor.rpc.RpcModel.from_gdal`), with the core's messages.
* :func:`ground_frame` - a :class:`vectoradjust.sensor.ground.CallableFrame` whose
  functions are QGIS coordinate transformations (``QgsCoordinateTransform`` from the
  project CRS to EPSG:4979, honouring the project's datum transformations): a batch of
  points goes through one ``QgsGeometry.transform`` of a LineString Z (one PROJ call in
  C++; PyQGIS 3.22 has no usable array overload of ``transformCoords`` /
  ``transformInPlace``). Measured for 10^4 points: 3.3 ms, where a Python loop over
  ``QgsVector3D`` points takes 26 ms; the frame's ``to_geodetic`` (7 x 10^4 points with
  the central differences) 23 ms, pyproj's 17 ms. Ellipsoidal heights pass through.
  Orthometric heights need the geoid:
  QGIS 3.22 drops the vertical part of a compound CRS, so they go through QGIS's own
  GDAL/PROJ (``osgeo.osr``, the project CRS compounded with ``vertical_crs``; PROJ
  chooses the operation, the project's datum transformations do not apply), and a
  geoid PROJ does not have (a ballpark transformation that leaves the heights unchanged)
  is an error saying which grid to install (``to_geodetic`` of 10^4 points: 77 ms,
  pyproj's 28 ms).
* :func:`read_rpc_images` - the twin of :func:`vectoradjust.files.readers.read_rpc_images`.

Numbers (``qgis_plugin/tests/test_qgis_rpc.py``): in EPSG:32616 the frame's longitudes,
latitudes, heights and Jacobian are pyproj's (:func:`vectoradjust.files.rpc.crs_frame`)
to the last bit, ellipsoidal and orthometric (EGM96); the satellite sample adjusts to the
command line's numbers (1e-9).
"""

import struct

import numpy as np
from qgis.core import (
    QgsCoordinateReferenceSystem,
    QgsCoordinateTransform,
    QgsCoordinateTransformContext,
    QgsCsException,
    QgsGeometry,
    QgsVector3D,
)

from vectoradjust.errors import CRSError

__all__ = ["gdal_rpc_metadata", "read_rpc", "transform_points", "ground_frame",
           "read_rpc_images", "write_corrected_rpcs", "TRANSFORMATION_ACCURACY_LIMIT"]

_WGS84_3D = "EPSG:4979"
#: a transformation less accurate than this (m), or of unknown accuracy, is a warning
#: (as :data:`vectoradjust.files.rpc.TRANSFORMATION_ACCURACY_LIMIT`)
TRANSFORMATION_ACCURACY_LIMIT = 1.0
#: ISO WKB: little endian, LineString Z, the number of points
_WKB_HEAD = struct.Struct("<BII")
_LINESTRING_Z = 1002
_GEOIDS = {"EGM96": "EPSG:5773", "EGM2008": "EPSG:3855", "EGM08": "EPSG:3855",
           "EGM84": "EPSG:5798"}


# ---------------------------------------------------------------------- RPCs
def gdal_rpc_metadata(path):
    """``(RPC metadata, files)`` of an image through QGIS's GDAL (the ``opener`` of
    :func:`vectoradjust.files.rpc.read_rpc`).

    Raises
    ------
    OSError
        GDAL cannot open the file (its message).
    """
    from osgeo import gdal

    gdal.PushErrorHandler("CPLQuietErrorHandler")
    try:
        try:
            ds = gdal.Open(str(path))
        except RuntimeError as exc:  # with gdal.UseExceptions() set by another plugin
            raise OSError(str(exc)) from exc
        if ds is None:
            raise OSError(gdal.GetLastErrorMsg() or "GDAL cannot open it")
        tags = dict(ds.GetMetadata("RPC") or {})
        files = list(ds.GetFileList() or [str(path)])
        ds = None
    finally:
        gdal.PopErrorHandler()
    return tags, files


def read_rpc(path):
    """The RPC model of an image or side file, read in QGIS
    (:func:`vectoradjust.files.rpc.read_rpc` with :func:`gdal_rpc_metadata`).

    Returns
    -------
    vectoradjust.sensor.rpc.RpcModel

    Raises
    ------
    vectoradjust.errors.InputFileError
        Missing or unreadable file, no RPCs, a malformed value (naming file and key).
    """
    from vectoradjust.files.rpc import read_rpc as core_read_rpc

    return core_read_rpc(path, opener=gdal_rpc_metadata)


# ---------------------------------------------------------------------- batches
def _to_wkb(x, y, z):
    """A LineString Z of the points as ISO WKB."""
    pts = np.column_stack([np.ravel(x), np.ravel(y), np.ravel(z)]).astype("<f8")
    return _WKB_HEAD.pack(1, _LINESTRING_Z, len(pts)) + pts.tobytes()


def _from_wkb(wkb, n):
    """The (n, 3) points of a LineString Z's WKB."""
    head = _WKB_HEAD.size
    return np.frombuffer(bytes(wkb), "<f8", count=3 * n, offset=head).reshape(n, 3).copy()


def transform_points(ct, x, y, z, inverse=False):
    """``(x, y, z)`` through ``ct`` (a QgsCoordinateTransform, Z included) in one batch.

    Returns three float arrays; raises :class:`QgsCsException` when a point fails.
    """
    n = int(np.size(x))
    if n == 0:
        return np.zeros(0), np.zeros(0), np.zeros(0)
    direction = (QgsCoordinateTransform.ReverseTransform if inverse else
                 QgsCoordinateTransform.ForwardTransform)
    if n == 1:  # a LineString needs two points
        v = ct.transform(QgsVector3D(float(np.ravel(x)[0]), float(np.ravel(y)[0]),
                                     float(np.ravel(z)[0])), direction)
        return np.array([v.x()]), np.array([v.y()]), np.array([v.z()])
    geom = QgsGeometry()
    geom.fromWkb(_to_wkb(x, y, z))
    geom.transform(ct, direction, True)
    out = _from_wkb(geom.asWkb(), n)
    return out[:, 0], out[:, 1], out[:, 2]


def _failed_points(fn, x, y, z):
    """Indexes of the points ``fn`` cannot transform (one at a time: the error path)."""
    bad = []
    for i, p in enumerate(zip(np.ravel(x), np.ravel(y), np.ravel(z))):
        try:
            out = fn(*(np.array([v], float) for v in p))
        except (QgsCsException, RuntimeError):
            bad.append(i)
            continue
        if not all(np.isfinite(v).all() for v in out):
            bad.append(i)
    return bad


def _cannot_transform(crs_name, bad, x, y, z):
    i = bad[0]
    return CRSError(f"{len(bad)} point(s) cannot be transformed from {crs_name} to WGS 84 "
                    f"(the first: X={np.ravel(x)[i]:.3f}, Y={np.ravel(y)[i]:.3f}, "
                    f"Z={np.ravel(z)[i]:.3f})",
                    "Check that the points lie in the CRS's area (and in the geoid grid's) "
                    "and that their coordinates are in that CRS")


def _checked(fn, crs_name):
    """``fn(x, y, z)`` that raises a :class:`CRSError` naming the points it cannot
    transform (as :func:`vectoradjust.files.rpc.crs_frame`'s)."""

    def forward(x, y, z):
        try:
            out = fn(x, y, z)
        except (QgsCsException, RuntimeError):
            out = None
        if out is None or not all(np.isfinite(v).all() for v in out):
            raise _cannot_transform(crs_name, _failed_points(fn, x, y, z) or [0], x, y, z)
        return out

    return forward


# ---------------------------------------------------------------------- frames
def _crs_name(crs):
    return crs.authid() or crs.description() or "the project CRS"


def _qgis_functions(crs, transform_context):
    """forward/inverse through QgsCoordinateTransform, and the operation's details."""
    dst = QgsCoordinateReferenceSystem(_WGS84_3D)
    ct = QgsCoordinateTransform(crs, dst, transform_context or QgsCoordinateTransformContext())
    if not ct.isValid():
        raise CRSError(f"QGIS has no transformation from {_crs_name(crs)} to WGS 84 "
                       "(EPSG:4979)", "Choose a projected CRS in metres that PROJ knows")

    def forward(x, y, z):
        return transform_points(ct, x, y, z)

    def inverse(lon, lat, h):
        return transform_points(ct, lon, lat, h, inverse=True)

    return forward, inverse, ct


def _operation(ct):
    """(description, accuracy in m or -1) of the operation QGIS instantiated."""
    try:
        d = ct.instantiatedCoordinateOperationDetails()
    except AttributeError:  # pragma: no cover - QGIS < 3.14
        return "", -1.0
    acc = d.accuracy if d.accuracy is not None else -1.0
    return str(d.name or d.proj), float(acc)


def _osr(text):
    from osgeo import osr

    sr = osr.SpatialReference()
    sr.SetAxisMappingStrategy(osr.OAMS_TRADITIONAL_GIS_ORDER)
    if sr.SetFromUserInput(str(text)) != 0:
        raise CRSError(f"the CRS {str(text)[:80]!r} is not understood by GDAL",
                       'Give an EPSG code such as "EPSG:5773"')
    return sr


def _vertical_osr(vertical):
    """The vertical CRS of heights above ``vertical`` (a geoid name or a CRS)."""
    key = "".join(ch for ch in str(vertical) if ch not in " _-").upper()
    sr = _osr(_GEOIDS.get(key, vertical))
    if not sr.IsVertical() or sr.IsCompound():
        raise CRSError(f"vertical_crs {str(vertical)!r} ({sr.GetName()}) is not a vertical "
                       "CRS", 'Give vertical_crs = "EPSG:5773" (EGM96 height), "EPSG:3855" '
                       "(EGM2008) or your datum's code")
    return sr


def _osr_functions(crs, vertical):
    """forward/inverse through QGIS's GDAL/PROJ (osr) from the compound of the project
    CRS and ``vertical`` (orthometric heights) to EPSG:4979."""
    from osgeo import osr

    horizontal = _osr(crs.toWkt(QgsCoordinateReferenceSystem.WKT2_2019))
    vert = _vertical_osr(vertical)
    compound = osr.SpatialReference()
    compound.SetAxisMappingStrategy(osr.OAMS_TRADITIONAL_GIS_ORDER)
    if compound.SetCompoundCS(f"{horizontal.GetName()} + {vert.GetName()}", horizontal,
                              vert) != 0:
        raise CRSError(f"{_crs_name(crs)} cannot be compounded with {vert.GetName()}",
                       "Give the project crs as a projected 2D CRS in metres")
    dst = _osr(_WGS84_3D)
    fwd = osr.CoordinateTransformation(compound, dst)
    inv = osr.CoordinateTransformation(dst, compound)

    def run(ct, x, y, z):
        pts = np.column_stack([np.ravel(x), np.ravel(y), np.ravel(z)]).astype(float)
        if not len(pts):
            return np.zeros(0), np.zeros(0), np.zeros(0)
        out = np.asarray(ct.TransformPoints(pts), float).reshape(-1, 3)
        return out[:, 0], out[:, 1], out[:, 2]

    return (lambda x, y, z: run(fwd, x, y, z)), (lambda a, b, c: run(inv, a, b, c)), \
        vert.GetName()


def _probe_point(near):
    return (float(near[0]), float(near[1])) if near is not None else None


def _check_geoid(forward_2d, forward, lonlat, vertical_name, vertical):
    """Raise when the orthometric transformation leaves the heights as they are (PROJ's
    ballpark vertical transformation: the geoid grid is missing)."""
    if lonlat is None:
        return
    # a point of the data in the project CRS, then both transformations at Z = 0
    x, y, _ = forward_2d.inverse(np.array([lonlat[0]]), np.array([lonlat[1]]), np.zeros(1))
    _, _, h_ellipsoidal = forward_2d.forward(x, y, np.zeros(1))
    try:
        _, _, h = forward(x, y, np.zeros(1))
    except (RuntimeError, CRSError):
        h = np.array([np.nan])
    n = float(np.ravel(h)[0] - np.ravel(h_ellipsoidal)[0])
    if not np.isfinite(n) or abs(n) < 1e-6:
        raise CRSError(
            f"the heights cannot be converted from {vertical_name} to ellipsoidal heights: "
            f"QGIS's PROJ has no geoid grid for {vertical!r} here (at {lonlat[0]:.4f}, "
            f"{lonlat[1]:.4f} it gives a geoid height of {n if np.isfinite(n) else 'nothing'})",
            "Install the geoid grid into the PROJ data folder QGIS uses (projsync --file "
            "<grid>: us_nga_egm96_15.tif for EGM96, us_nga_egm08_25.tif for EGM2008; or set "
            "PROJ_NETWORK=ON), or give the heights as ellipsoidal (heights = \"ellipsoidal\")")


class _Pair:
    def __init__(self, forward, inverse):
        self.forward, self.inverse = forward, inverse


def ground_frame(crs, heights="ellipsoidal", vertical_crs=None, near=None,
                 transform_context=None, warn=None):
    """The ground frame of the project CRS in QGIS: ``X, Y, Z`` to WGS84 ``lon, lat, h``.

    Parameters
    ----------
    crs : QgsCoordinateReferenceSystem
        The project CRS (projected, metres; checked by :func:`qgis_io.check_ground_crs`).
    heights : {"ellipsoidal", "orthometric"}
        What ``Z`` is (the project's top-level ``heights``).
    vertical_crs : str, optional
        For orthometric heights: their vertical CRS (``"EPSG:5773"``) or a geoid name
        (``"EGM96"``, ``"EGM2008"``).
    near : tuple of 2 floats, optional
        ``lon, lat`` of the data (where the geoid is checked).
    transform_context : QgsCoordinateTransformContext, optional
        The project's datum transformations (default: PROJ's choice).
    warn : callable, optional
        ``warn(text)`` for a ballpark or inaccurate datum transformation.

    Returns
    -------
    vectoradjust.sensor.ground.CallableFrame

    Raises
    ------
    CRSError
        Unknown heights, no transformation, orthometric heights without a vertical CRS
        or without the geoid grid PROJ needs, points that cannot be transformed.
    """
    from vectoradjust.sensor.ground import CallableFrame

    if heights not in ("ellipsoidal", "orthometric"):
        raise CRSError(f"heights = {heights!r} is not known",
                       'Write heights = "ellipsoidal" or heights = "orthometric"')
    name = _crs_name(crs)
    forward, inverse, ct = _qgis_functions(crs, transform_context)
    lonlat = _probe_point(near)
    if lonlat is not None:  # the operation PROJ instantiates for the data's area
        forward(*inverse(np.array([lonlat[0]]), np.array([lonlat[1]]), np.zeros(1)))
    desc, accuracy = _operation(ct)
    if warn is not None and ("ballpark" in desc.lower() or accuracy < 0
                             or accuracy > TRANSFORMATION_ACCURACY_LIMIT):
        why = ("a ballpark one" if "ballpark" in desc.lower() else "of unknown accuracy"
               if accuracy < 0 else f"accurate to {accuracy:g} m only")
        warn(f"the transformation from {name} to WGS 84 is {why} ({desc}): positions may be "
             "off by that much; choose the datum transformation in the project's properties "
             "or use a CRS on WGS 84")
    what = "ellipsoidal heights"
    if heights == "orthometric":
        if not vertical_crs:
            raise CRSError('heights = "orthometric" needs the vertical datum of the heights',
                           'Add vertical_crs = "EPSG:5773" (EGM96 height), "EPSG:3855" '
                           "(EGM2008) or your datum's code to the project file")
        plain = _Pair(forward, inverse)
        forward, inverse, vname = _osr_functions(crs, vertical_crs)
        _check_geoid(plain, forward, lonlat, vname, vertical_crs)
        what = f"orthometric heights in {vname}"
        desc = f"QGIS's GDAL/PROJ from {name} + {vname}"
    return CallableFrame(_checked(forward, name), inverse,
                         f"{crs.description() or name}, {what} -> WGS 84 (EPSG:4979) in "
                         f"QGIS: {desc}")


def read_rpc_images(data, spec, crs, transform_context=None, warn=None):
    """Read the RPCs of the project's RPC images into their ``ImageSpec.rpc`` and give
    ``data`` the ground frame (the twin of
    :func:`vectoradjust.files.readers.read_rpc_images`).

    Parameters
    ----------
    data : vectoradjust.model.ProjectData
    spec : vectoradjust.files.project.ProjectSpec
    crs : QgsCoordinateReferenceSystem
        The project (ground) CRS.
    transform_context, warn
        As for :func:`ground_frame`.
    """
    from vectoradjust.files.assemble import read_image_rpcs

    near = read_image_rpcs(data.images, read_rpc)
    if near is None:
        return
    data.ground_frame = ground_frame(
        crs, heights=spec.heights or "ellipsoidal",
        vertical_crs=spec.vertical_crs if spec.heights == "orthometric" else None, near=near,
        transform_context=transform_context, warn=warn)


# ---------------------------------------------------------------------- outputs
def _shadowed(images, folder, names):
    """The files among ``folder/names`` that are (or GDAL would read as) an input image's
    own RPCs: writing them would change the project's inputs."""
    from pathlib import Path

    from vectoradjust.files.rpc import rpc_side_file

    inputs = set()
    for im in images:
        if im.model != "rpc":
            continue
        for p in (im.rpc.path, getattr(im.rpc.rpc, "source", None)):
            if p:
                inputs.update({Path(p).resolve(), rpc_side_file(p).resolve()})
    return [n for n in names.values() if (Path(folder) / n).resolve() in inputs]


def write_corrected_rpcs(run, folder, warn=None):
    """Each RPC image's RPCs with the estimated bias folded in, as ``<name>_rpc.txt`` in
    ``folder`` (:func:`vectoradjust.files.rpc.write_corrected_rpcs`, what ``vectoradjust
    adjust`` writes into its output folder).

    Nothing is written when a file would replace or shadow an input image's own RPCs
    (``folder`` holds the images): ``warn`` says so and the summary's
    ``images[].corrected_rpc`` entries are removed.

    Returns
    -------
    list of str
        The paths written.
    """
    import os

    from vectoradjust.files.rpc import write_corrected_rpcs as core_write
    from vectoradjust.sensor.models import corrected_rpc_names

    names = corrected_rpc_names(run.data.images)
    if not names:
        return []
    clash = _shadowed(run.data.images, folder, names)
    if clash:
        for entry in run.summary.get("images", []):
            entry.pop("corrected_rpc", None)
        if warn is not None:
            warn(f"the corrected RPCs are not written: {', '.join(clash)} in {folder} would "
                 "replace the RPCs the project reads (its images' own); write the summary "
                 "into another folder to have them")
        return []
    os.makedirs(folder, exist_ok=True)
    return [os.path.join(str(folder), n) for n in core_write(run, folder)]
