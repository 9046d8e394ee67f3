"""Measurement on the images from a project: prediction, transfer, road junctions.

The steps the ``vectoradjust measure`` command and the QGIS algorithm share. Images are
read through *readers*: objects with ``size`` (columns, rows) and ``read(col0, row0,
width, height) -> array`` (NaN outside the image) - :class:`files.images.RasterioImage`
on the command line, a GDAL reader of QGIS's own in the plugin - so this module imports
no raster library.

* :func:`image_geometries` - one :class:`measure.geometry.ImageGeometry` per
  ``[[images]]`` entry (approximate or adjusted orientation and its sigmas);
* :func:`project_points` - control/check points and shape points with their
  covariances and, for shape points, the road arms;
* :func:`predict` - pixel and mm position and search ellipse of every point on every
  image it falls on (the measurement template);
* :func:`transfer` - points measured on one image found on the others (NCC + LSM),
  matched back onto the reference image and, on three or more frame images, checked
  against the forward intersection of all their rays;
* :func:`transfer_window` - a transfer's prediction and search covariance;
* :func:`measure_roads` - junctions and corners located on every image;
* :func:`image_points` - the accepted measurements in the contract format.

Satellite images with RPCs (``model = "rpc"``) get a :class:`measure.geometry.RpcGeometry`:
their pixels are GDAL's (``(0, 0)`` the upper-left corner of the first pixel, the first
pixel's centre at ``(0.5, 0.5)``), in the template, in the measured and transferred
tables and in ``image_points.csv`` (``x, y`` = column, row and sigmas in pixels, as the
adjustment reads rows on RPC images); windows of the image files are read at the array
indices ``pixel - 0.5`` (``index_offset``). Their search windows hold the ground point's
uncertainty and the bias's: the bias a previous adjustment estimated (``summary.json``
given as ``orientation``) or, before one, the a-priori sigmas
(:func:`measure.geometry.rpc_bias_prior`: ``bias_sigma``, else the RPC's ``ERR_BIAS``,
else 10 px).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Callable, Optional

import numpy as np

from vectoradjust.errors import CancelledError, MeasurementError
from vectoradjust.measure.geometry import (
    WINDOW_K,
    ImageGeometry,
    RpcGeometry,
    local_affine,
    pixel_covariance,
    rpc_bias_prior,
    transfer_covariance,
    window_axes,
)
from vectoradjust.measure.matching import FLAGS, flag_names
from vectoradjust.measure.roads import ROAD_FLAGS, RoadSettings, centreline_crossing, measurable
from vectoradjust.measure.roads import vertex_arms as _vertex_arms
from vectoradjust.measure.transfer import MatchSettings, match_batch
from vectoradjust.sensor.interior import parse_corrections, terrain_height_for
from vectoradjust.sensor.models import EO_PARAMETERS
from vectoradjust.sensor.refine import fit_fiducial_affine

__all__ = ["PointSet", "image_geometries", "project_points", "predict", "transfer",
           "transfer_window", "height_parallax", "measure_roads", "image_points",
           "read_chips", "back_tolerance", "BATCH"]

#: points matched at once (memory: a few MB per point)
BATCH = 100
Progress = Optional[Callable[[float, str], None]]


@dataclass
class PointSet:
    """Object points to measure.

    Attributes
    ----------
    ids : numpy.ndarray of str, shape (n,)
    xyz : numpy.ndarray, shape (n, 3)
    sigma : numpy.ndarray, shape (n, 3)
        Standard deviations (m) of the database/survey position (shape points: the
        database sigma and the identification sigma in quadrature).
    kind : numpy.ndarray of str, shape (n,)
        ``control``, ``check`` or ``shape``.
    arms : numpy.ndarray, shape (n, 4, 3)
        Neighbouring vertices along each road arm (NaN for control points).
    degree : numpy.ndarray of int, shape (n,)
    """

    ids: np.ndarray
    xyz: np.ndarray
    sigma: np.ndarray
    kind: np.ndarray
    arms: np.ndarray = field(default_factory=lambda: np.zeros((0, 4, 3)))
    degree: np.ndarray = field(default_factory=lambda: np.zeros(0, int))


def image_geometries(spec, orientation: Optional[Mapping] = None,
                     default_sigma: tuple[float, float] = (5.0, 0.5),
                     image_sizes: Optional[Mapping] = None, control=None,
                     fiducials=None, ground_frame=None) -> dict:
    """One :class:`ImageGeometry` (:class:`RpcGeometry` for RPC images) per ``[[images]]``
    entry.

    Parameters
    ----------
    spec : ProjectSpec
    orientation : mapping, optional
        A ``summary.json`` of an adjustment: its ``images`` (adjusted position,
        attitude in degrees and their sigmas) replace the approximations.
    default_sigma : (float, float)
        Sigma of position (m) and attitude (degrees) of an image whose orientation is
        free (no ``sigma_position`` / ``sigma_attitude``).
    image_sizes : mapping, optional
        Image id -> (columns, rows) of its file, used when the camera has no
        ``image_size`` (a scan treated as a digital frame of the camera's pixel size,
        centred on the fiducial centre). Without it such a camera's image size is the
        fiducials' extent.
    control : ControlPoints, optional
        Their mean height is the terrain height of refraction and earth curvature when
        ``[corrections]`` gives none.
    fiducials : FiducialMeasurements, optional
        Fiducials measured in pixels (scanned film, ``[measurements] fiducials`` with
        ``unit = "pixel"``): each image with fiducials gets its fiducial affine, which
        then maps between its pixels and photo mm.
    ground_frame : GroundFrame, optional
        Object coordinates to WGS84 (:func:`vectoradjust.files.rpc.crs_frame`); needed,
        with the RPCs read into the images' ``rpc.rpc``, when the project has RPC
        images. Their bias is the one ``orientation`` estimated (with its covariance),
        else zero with the a-priori sigmas of :func:`measure.geometry.rpc_bias_prior`.

    Raises
    ------
    MeasurementError
        An RPC image without its RPCs or without the ground frame.
    """
    switches, terrain = parse_corrections(spec.corrections)
    terrain, _ = terrain_height_for(control, terrain)
    cal = spec.camera.calibration if spec.camera is not None else None
    adjusted = {}
    for im in (orientation or {}).get("images", []) or []:
        adjusted[str(im.get("id"))] = im
    out = {}
    for im in spec.images:
        if getattr(im, "model", "frame") == "rpc":
            out[im.id] = _rpc_geometry(im, adjusted.get(im.id), ground_frame,
                                       (image_sizes or {}).get(im.id), terrain)
            continue
        pos, att = np.asarray(im.position, float), np.asarray(im.attitude, float)
        sp, sa = im.sigma_position, im.sigma_attitude
        if im.id in adjusted:
            a = adjusted[im.id]
            pos, att = np.asarray(a["position"], float), np.asarray(a["attitude"], float)
            sp, sa = a.get("sigma_position"), a.get("sigma_attitude")
        sp = _sigma3(sp, default_sigma[0])
        sa = _sigma3(sa, default_sigma[1])
        eo = np.r_[pos, np.radians(att)]
        sig = np.r_[sp, np.radians(sa)]
        cov_eo = _eo_covariance(adjusted.get(im.id), sig)
        fit = None
        measured = fiducials.of_image(im.id) if fiducials is not None else {}
        if measured:
            fit = fit_fiducial_affine(measured, cal, unit="pixel", image_id=im.id)
        size = (image_sizes or {}).get(im.id)
        cam = _sized(cal, size) if fit is None else (
            cal if size is None else dataclasses.replace(cal, image_size=tuple(size)))
        out[im.id] = ImageGeometry(im.id, eo, cam, switches, terrain, fit, sig, cov_eo)
    return out




def _eo_covariance(entry: Optional[Mapping], sig: np.ndarray) -> Optional[np.ndarray]:
    """The joint ``(6, 6)`` covariance (m, radians) of a frame image's orientation from a
    ``summary.json`` entry's ``correlation`` (``parameters`` named as
    :data:`EO_PARAMETERS`, ``matrix``) and the sigmas ``sig``; None without one."""
    c = (entry or {}).get("correlation")
    if not c or not c.get("parameters"):
        return None
    names = [str(n) for n in c["parameters"]]
    unknown = sorted(set(names) - set(EO_PARAMETERS))
    if unknown:
        raise MeasurementError(
            f"image {entry.get('id')!r}: the orientation's correlation names "
            f"{', '.join(unknown)}", f"Name its parameters among {', '.join(EO_PARAMETERS)}",
            details={"image_id": entry.get("id")})
    idx = [EO_PARAMETERS.index(n) for n in names]
    corr = np.eye(6)
    corr[np.ix_(idx, idx)] = np.nan_to_num(np.asarray(c["matrix"], float))
    return corr * np.outer(sig, sig)


def _rpc_geometry(im, entry: Optional[Mapping], frame, size, terrain) -> RpcGeometry:
    """The :class:`RpcGeometry` of an RPC image (bias from a summary entry, else prior)."""
    if im.rpc is None or im.rpc.rpc is None or frame is None:
        raise MeasurementError(
            f"image {im.id!r} is an RPC image: measuring on it needs its RPCs and the "
            "ground frame of the project CRS",
            "Read the RPCs (vectoradjust.files.rpc.read_rpc) into the image's rpc.rpc and "
            "pass ground_frame (vectoradjust.files.rpc.crs_frame), as vectoradjust "
            "measure does", details={"image_id": im.id})
    if entry is not None and entry.get("model") == "rpc":
        bias, cov = _summary_bias(entry)
        source = "the adjustment's estimate"
    else:
        bias = np.zeros(6)
        cov, source = rpc_bias_prior(im.rpc.rpc, frame, im.rpc.bias, im.rpc.bias_sigma)
    return RpcGeometry(im.id, im.rpc.rpc, frame, bias, cov,
                       None if size is None else tuple(size), terrain, source)


def _summary_bias(entry: Mapping) -> tuple[np.ndarray, np.ndarray]:
    """Bias ``(6,)`` and its covariance ``(6, 6)`` from a ``summary.json`` image entry."""
    from vectoradjust.sensor.models import BIAS_PARAMETERS

    values, sigmas = entry.get("bias") or {}, entry.get("sigma_bias") or {}
    b = np.array([float(values.get(n, 0.0)) for n in BIAS_PARAMETERS])
    sd = np.array([float(sigmas.get(n, 0.0) or 0.0) for n in BIAS_PARAMETERS])
    corr = np.eye(6)
    c = entry.get("correlation")
    if c and c.get("parameters"):
        idx = [BIAS_PARAMETERS.index(str(p)) for p in c["parameters"]]
        corr[np.ix_(idx, idx)] = np.nan_to_num(np.asarray(c["matrix"], float))
    return b, corr * np.outer(sd, sd)


def _sized(cal, size):
    """The calibration with an image size (from the file, else the fiducials' extent)."""
    if cal.image_size is not None or cal.pixel_size is None:
        return cal
    if size is None and cal.fiducials:
        ext = 2.0 * np.abs(np.array(list(cal.fiducials.values()))).max(axis=0) + 2.0
        size = tuple(int(np.ceil(e / p)) for e, p in zip(ext, cal.pixel_size))
    return cal if size is None else dataclasses.replace(cal, image_size=tuple(size))


def _sigma3(v, default: float) -> np.ndarray:
    if v is None:
        return np.full(3, float(default))
    return np.broadcast_to(np.asarray(v, float), (3,)).copy()


def project_points(control=None, layers: Optional[list] = None,
                   merge_tolerance: float = 0.001) -> PointSet:
    """Control/check points and the shape points of ``layers`` ((VectorSpec, LineLayer)).

    Shape points get the database sigma and the identification sigma in quadrature and
    their road arms (:func:`measure.roads.vertex_arms`).
    """
    from vectoradjust.adjust.shapepoints import extract_shape_points

    ids, xyz, sig, kind, arms, deg = [], [], [], [], [], []
    if control is not None and len(control.point_id):
        ids.append(np.asarray(control.point_id).astype(str))
        xyz.append(np.asarray(control.xyz, float))
        sig.append(np.asarray(control.sigma, float))
        kind.append(np.asarray(control.role).astype(str))
        arms.append(np.full((len(control.point_id), 4, 3), np.nan))
        deg.append(np.zeros(len(control.point_id), int))
    for spec, layer in layers or []:
        sp = extract_shape_points(layer, merge_tolerance)
        a, d = _vertex_arms(layer.coords, layer.vertex_feature, layer.vertex_part,
                            sp.vertex_object, sp.n_objects)
        s = np.asarray(spec.sigma, float)
        ident = spec.identification_sigma or (0.0, 0.0)
        s = np.sqrt(s**2 + np.array([ident[0], ident[0], ident[1]]) ** 2)
        ids.append(sp.object_ids.astype(str))
        xyz.append(sp.object_xyz)
        sig.append(np.broadcast_to(s, (sp.n_objects, 3)))
        kind.append(np.full(sp.n_objects, "shape"))
        arms.append(a)
        deg.append(d)
    if not ids:
        return PointSet(np.zeros(0, str), np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0, str))
    return PointSet(np.concatenate(ids), np.concatenate(xyz), np.concatenate(sig),
                    np.concatenate(kind), np.concatenate(arms), np.concatenate(deg))


def _tick(progress: Progress, is_cancelled, frac: float, msg: str) -> None:
    if is_cancelled is not None and is_cancelled():
        raise CancelledError("The measurement was cancelled", "Run it again when ready")
    if progress is not None:
        progress(frac, msg)


def predict(geoms: Mapping[str, ImageGeometry], points: PointSet, k: float = WINDOW_K,
            progress: Progress = None, is_cancelled=None) -> dict:
    """Predicted position and search window of every point on every image it falls on.

    The window is the ellipse ``k`` wide of :func:`measure.geometry.pixel_covariance`:
    the point's database/survey covariance and the image's orientation (a frame camera)
    or bias (an RPC image) uncertainty.

    Returns
    -------
    dict of numpy.ndarray
        Columns ``point_id, image_id, kind, col, row, x, y`` (x, y: photo mm as measured,
        the contract's unit; on RPC images the pixels), ``win_major, win_minor,
        win_angle`` (search ellipse, pixels, degrees), ``sigma_col, sigma_row``
        (pixels), ``source`` = predicted and
        the empty ``measured_col, measured_row`` for the analyst's measurements.
    """
    cols: dict = {k_: [] for k_ in ("point_id", "image_id", "kind", "col", "row", "x", "y",
                                     "win_major", "win_minor", "win_angle", "sigma_col",
                                     "sigma_row")}
    for i, (iid, g) in enumerate(geoms.items()):
        _tick(progress, is_cancelled, i / max(len(geoms), 1), f"predicting on {iid}")
        px = g.to_pixel(points.xyz)
        cov = pixel_covariance(g, points.xyz, points.sigma)
        if isinstance(g, RpcGeometry):  # GDAL's pixels: the image spans 0 .. size
            w, h = g.image_size if g.image_size is not None else (np.inf, np.inf)
            inside = (px[:, 0] >= 0.0) & (px[:, 1] >= 0.0) & (px[:, 0] <= w) & \
                     (px[:, 1] <= h)
        else:
            w, h = g.camera.image_size if g.camera.image_size is not None else (np.inf,
                                                                                 np.inf)
            e = g.index_offset - 0.5  # the image's outer edge: -0.5 (centre), 0 (corner)
            inside = (px[:, 0] >= e) & (px[:, 1] >= e) & (px[:, 0] <= w + e) & \
                     (px[:, 1] <= h + e)
        ax = window_axes(cov[inside], k)
        mm = g.pixel_to_measured_mm(px[inside])
        cols["point_id"].append(points.ids[inside])
        cols["image_id"].append(np.full(inside.sum(), iid))
        cols["kind"].append(points.kind[inside])
        cols["col"].append(px[inside, 0])
        cols["row"].append(px[inside, 1])
        cols["x"].append(mm[:, 0])
        cols["y"].append(mm[:, 1])
        cols["win_major"].append(ax[:, 0])
        cols["win_minor"].append(ax[:, 1])
        cols["win_angle"].append(ax[:, 2])
        cols["sigma_col"].append(np.sqrt(cov[inside, 0, 0]))
        cols["sigma_row"].append(np.sqrt(cov[inside, 1, 1]))
    out = {k_: np.concatenate(v) if v else np.zeros(0) for k_, v in cols.items()}
    out["source"] = np.full(len(out["col"]), "predicted")
    out["measured_col"] = np.full(len(out["col"]), np.nan)  # filled in by the analyst
    out["measured_row"] = np.full(len(out["col"]), np.nan)
    _tick(progress, is_cancelled, 1.0, "predicted")
    return out


def read_chips(reader, centres: np.ndarray, half: int) -> tuple[np.ndarray, np.ndarray]:
    """Chips ``(n, 2 half + 1, 2 half + 1)`` around rounded centres, and their origins."""
    c = np.round(np.asarray(centres, float)).astype(int) - half
    size = 2 * half + 1
    chips = np.full((len(c), size, size), np.nan)
    for j, (c0, r0) in enumerate(c):  # I/O: one window per point
        chips[j] = reader.read(int(c0), int(r0), size, size)
    return chips, c.astype(float)


def _heights(height, g_src: ImageGeometry):
    """The terrain height function; the mean terrain height when there is no DEM."""
    if height is not None:
        return height
    if g_src.terrain_height is None:
        raise MeasurementError(
            "the transfer needs the terrain height: the project has no DEM, no control "
            "points and no [corrections] terrain_height",
            "Give a dem = in a [[vectors]] entry, control points, or [corrections] "
            "terrain_height = <metres above sea level>")
    return float(g_src.terrain_height)


def _transfer_pair(src, dst, rd_src, rd_dst, ref_px, height, sigma_height: float,
                   sigma_ref_px: float, st: MatchSettings) -> dict:
    """:func:`_matched_pair`, and again with a larger template
    (``st.retry_template``) where it was rejected only for precision, texture or
    ambiguity: the retry's rows replace those it accepts."""
    out = _matched_pair(src, dst, rd_src, rd_dst, ref_px, height, sigma_height,
                        sigma_ref_px, st)
    soft = FLAGS["poor_precision"] | FLAGS["no_texture"] | FLAGS["ambiguous"]
    h2 = int(round(st.retry_template * st.half_template))
    redo = np.flatnonzero((out["flags"] != 0) & (out["flags"] & ~soft == 0)
                          & ~out["off_image"])
    if h2 <= st.half_template or redo.size == 0:
        return out
    again = _matched_pair(src, dst, rd_src, rd_dst, np.asarray(ref_px, float)[redo], height,
                          sigma_height, sigma_ref_px, dataclasses.replace(st, half_template=h2))
    take = again["flags"] == 0
    for key, val in out.items():
        if key == "texture":
            for k in val:
                val[k][redo[take]] = again[key][k][take]
        else:
            val[redo[take]] = again[key][take]
    return out


def _matched_pair(src, dst, rd_src, rd_dst, ref_px, height, sigma_height: float,
                  sigma_ref_px: float, st: MatchSettings) -> dict:
    """Match the reference pixels of ``src`` on ``dst`` and, where that is accepted, the
    matches back on ``src`` (:func:`_one_way`): a back-match whose least-squares matching
    fails, or lands farther than its tolerance (:func:`back_tolerance`) from the
    reference pixel, flags ``back_mismatch`` (the back-match's own quality flags do not
    count: the distance is the test).
    ``back_error`` (px) is NaN where no back-match was tried."""
    fwd = _one_way(src, dst, rd_src, rd_dst, ref_px, height, sigma_height, sigma_ref_px, st)
    err = np.full(len(ref_px), np.nan)
    ok = np.flatnonzero((fwd["flags"] == 0) & ~fwd["off_image"])
    if np.isfinite(st.back_tolerance) and ok.size:
        back = _one_way(dst, src, rd_dst, rd_src, fwd["px"][ok], height, sigma_height,
                        sigma_ref_px, st)
        err[ok] = np.hypot(*(back["px"] - np.asarray(ref_px, float)[ok]).T)
        tol = back_tolerance(fwd["sigma"][ok], back["sigma"], fwd["inflation"][ok],
                             back["inflation"], st)
        fwd["flags"][ok[~(err[ok] <= tol)]] |= FLAGS["back_mismatch"]
    fwd["back_error"] = err
    return fwd


def back_tolerance(sigma_fwd: np.ndarray, sigma_back: np.ndarray, inflation_fwd: np.ndarray,
                   inflation_back: np.ndarray, st: MatchSettings) -> np.ndarray:
    """How far a back-match may land from the reference pixel (px), from the noise.

    The back-match's distance from the reference is the sum of the two matches' errors:
    its standard deviation is about ``hypot(s_f i_f, s_b i_b)`` with ``s`` the larger
    LSM sigma of each match and ``i`` its residual inflation
    (:func:`vectoradjust.measure.matching.residual_inflation`: the LSM sigma assumes
    independent residuals, which compressed images do not have). The tolerance is
    ``st.back_k`` times that, at least ``st.back_tolerance`` and at most twice that
    (``st.back_tolerance`` alone where a sigma is undefined or ``st.back_k`` is 0).

    Parameters
    ----------
    sigma_fwd, sigma_back : numpy.ndarray, shape (n, 2)
        LSM standard deviations of the forward and the back match (px).
    inflation_fwd, inflation_back : numpy.ndarray, shape (n,)
    st : MatchSettings

    Returns
    -------
    numpy.ndarray, shape (n,)
    """
    sf = np.max(np.asarray(sigma_fwd, float), axis=1) * np.asarray(inflation_fwd, float)
    sb = np.max(np.asarray(sigma_back, float), axis=1) * np.asarray(inflation_back, float)
    tol = np.clip(st.back_k * np.hypot(sf, sb), st.back_tolerance, 2.0 * st.back_tolerance)
    return np.where(np.isfinite(tol), tol, st.back_tolerance)


def _one_way(src, dst, rd_src, rd_dst, ref_px, height, sigma_height: float,
             sigma_ref_px: float, st: MatchSettings) -> dict:
    """Match the reference pixels of ``src`` on ``dst`` (batched, no back-matching).

    Pixels are the images' own (``px``, ``pred``); chips are read and matched at array
    indices (``pixel - index_offset``: 0.5 for GDAL's pixels of an RPC image).
    """
    pred, a, cov, cov_rays = transfer_window(src, dst, ref_px, height, sigma_height,
                                             sigma_ref_px)
    o_src, o_dst = src.index_offset, dst.index_offset
    ref_i = ref_px - o_src if o_src else ref_px
    pred_i = pred - o_dst if o_dst else pred
    h = st.half_template
    scale = float(np.nanmax(np.abs(a))) if len(a) else 1.0
    half_t = int(np.ceil(scale * (h + st.max_radius) * 1.5)) + 4
    rc, ro = read_chips(rd_src, ref_i, h + 3)
    tc, to = read_chips(rd_dst, np.nan_to_num(pred_i), half_t)
    res = match_batch(rc, ro, ref_i, tc, to, pred_i, a, cov, st)
    w, hh = rd_dst.size
    off = ~np.all(np.isfinite(pred_i), axis=1) | (pred_i[:, 0] < 0) | (pred_i[:, 1] < 0) | \
        (pred_i[:, 0] > w - 1) | (pred_i[:, 1] > hh - 1)
    px = res.px + o_dst if o_dst else res.px
    return {"pred": pred, "px": px, "ncc": res.ncc, "rho": res.rho, "sigma": res.sigma,
            "flags": res.flags, "off_image": off, "texture": res.texture,
            "cov_rays": cov_rays, "inflation": res.inflation}


def transfer_window(src, dst, ref_px: np.ndarray, height, sigma_height: float = 1.0,
                    sigma_ref_px: float = 0.5) -> tuple:
    """Where a transfer of ``ref_px`` from ``src`` to ``dst`` searches.

    Parameters
    ----------
    src, dst : ImageGeometry or RpcGeometry
    ref_px : numpy.ndarray, shape (n, 2)
        Reference pixels on ``src`` (the image's own pixels).
    height : callable or float
        Terrain height (:func:`transfer`).
    sigma_height, sigma_ref_px : float
        Uncertainty of the terrain height (m) and of the reference pointing (px).

    Returns
    -------
    pred : numpy.ndarray, shape (n, 2)
        Predicted target pixels.
    affine : numpy.ndarray, shape (n, 2, 2)
        ``d target / d reference`` over the terrain.
    cov : numpy.ndarray, shape (n, 2, 2)
        Covariance of the prediction (target px^2): the search window is the ellipse
        ``MatchSettings.k`` wide of ``cov + (0.5 / k)^2 I``, clipped to
        ``MatchSettings.max_radius`` in the reference geometry
        (:func:`measure.transfer.match_batch`).
    cov_rays : numpy.ndarray, shape (n, 2, 2)
        ``cov`` without the terrain height's part between frame images (the
        consistency check of :func:`transfer`).
    """
    pred, a = local_affine(src, dst, ref_px, height)
    ground = src.to_ground(ref_px, height)
    if isinstance(src, ImageGeometry) and isinstance(dst, ImageGeometry):
        cov_rays = _frame_transfer_cov(src, dst, ground, a, sigma_ref_px)
        g = height_parallax(src, dst, ref_px, height)
        cov = cov_rays + sigma_height**2 * g[:, :, None] * g[:, None, :]
    else:
        cov = transfer_covariance(src, dst, ref_px, ground, a, sigma_height, sigma_ref_px)
        cov_rays = cov
    return pred, a, cov, cov_rays


def _frame_transfer_cov(src: ImageGeometry, dst: ImageGeometry, ground, a,
                        sigma_ref_px) -> np.ndarray:
    """The search covariance of a transfer between two frame images from their
    orientations and the reference pointing (without the terrain height's part)."""
    src_only = ImageGeometry(src.image_id, src.eo, src.camera, src.corrections,
                             src.terrain_height, src.affine, src.sigma_eo, src.cov_eo)
    c_src = pixel_covariance(src_only, ground, np.zeros((len(ground), 3)))
    c_src += sigma_ref_px**2 * np.eye(2)
    cov = a @ c_src @ np.swapaxes(a, 1, 2)
    dst_only = ImageGeometry(dst.image_id, dst.eo, dst.camera, dst.corrections,
                             dst.terrain_height, dst.affine, dst.sigma_eo, dst.cov_eo)
    return cov + pixel_covariance(dst_only, ground, np.zeros((len(ground), 3)))


def height_parallax(src, dst, ref_px: np.ndarray, height) -> np.ndarray:
    """``d target / d h`` (px per m, shape (n, 2)): how the prediction of ``ref_px`` of
    ``src`` on ``dst`` moves when the terrain is 1 m higher - the ground point sliding
    along the reference pixel's ray, i.e. along the epipolar line (central difference
    of +-1 m). A height error moves the target this way, not as the point moved
    vertically would (that is zero at the target's nadir and twice too large at a
    wide-angle image's edge)."""
    def shifted(dz):
        if callable(height):
            return lambda xy: np.asarray(height(xy), float) + dz
        return float(height) + dz

    p = np.asarray(ref_px, float).reshape(-1, 2)
    up = dst.to_pixel(src.to_ground(p, shifted(1.0)))
    down = dst.to_pixel(src.to_ground(p, shifted(-1.0)))
    return 0.5 * (up - down)


def transfer(geoms: Mapping[str, ImageGeometry], readers: Mapping, measured: Mapping,
             height=None, settings: Optional[MatchSettings] = None,
             sigma_height: float = 1.0, sigma_ref_px: float = 0.5,
             progress: Progress = None, is_cancelled=None) -> dict:
    """Find points measured on one image on every other image (NCC, then LSM).

    Parameters
    ----------
    geoms : mapping of image id to ImageGeometry or RpcGeometry
        Any pair of frame and RPC images (the search window:
        :func:`measure.geometry.transfer_covariance`; between two frame images
        :func:`transfer_window`: the terrain height's uncertainty along the epipolar
        line, :func:`height_parallax`).
    readers : mapping of image id to reader
    measured : mapping
        Columns ``point_id, image_id, col, row`` (pixels; GDAL's on RPC images); the
        first image of a point is its reference, images already measured are not
        transferred to.
    height : callable or float, optional
        Terrain height ``(n, 2) -> (n,)`` (a DEM), default the mean terrain height.
    settings : MatchSettings, optional
        Thresholds; ``back_tolerance`` (default 0.5 px) and ``back_k`` set the
        back-matching (:func:`back_tolerance`).
    sigma_height : float
        Uncertainty of the terrain height (m) for the search window.
    sigma_ref_px : float
        Pointing precision of the reference measurement (pixels).

    Returns
    -------
    dict of numpy.ndarray
        One row per point and target image: ``point_id, image_id, ref_image, col, row``
        (NaN when failed), ``pred_col, pred_row, ncc, rho, sigma_col, sigma_row``,
        ``back_error`` (px, the match matched back to the reference image; NaN where
        not tried), the reference template's ``entropy, blockiness, roundness``
        (:func:`measure.matching.texture_measures`), ``flags`` (int bits), ``flag_text``
        and ``accepted``.
    """
    st = settings or MatchSettings()
    pid = np.asarray(measured["point_id"]).astype(str)
    iid = np.asarray(measured["image_id"]).astype(str)
    for bad in sorted(set(iid.tolist()) - set(geoms)):
        raise MeasurementError(f"measured image {bad!r} is not in [[images]]",
                               f"Use one of {', '.join(geoms)}", details={"image_id": bad})
    px = np.column_stack([measured["col"], measured["row"]]).astype(float)
    _, first = np.unique(pid, return_index=True)
    ref_rows = np.sort(first)
    have = np.char.add(np.char.add(pid, "\x1f"), iid)
    rows: dict = {k: [] for k in ("point_id", "image_id", "ref_image", "col", "row", "pred_col",
                                  "pred_row", "ncc", "rho", "sigma_col", "sigma_row",
                                  "back_error", "entropy", "blockiness", "roundness",
                                  "flags", "_cov")}
    pairs = [(s, d) for s in geoms for d in geoms if s != d]
    for n_pair, (s_id, d_id) in enumerate(pairs):
        sel = ref_rows[(iid[ref_rows] == s_id)]
        sel = sel[~np.isin(np.char.add(pid[sel], "\x1f" + d_id), have)]
        for b0 in range(0, len(sel), BATCH):
            _tick(progress, is_cancelled, (n_pair + b0 / max(len(sel), 1)) / len(pairs),
                  f"transferring {s_id} -> {d_id}")
            b = sel[b0:b0 + BATCH]
            r = _transfer_pair(geoms[s_id], geoms[d_id], readers[s_id], readers[d_id], px[b],
                               _heights(height, geoms[s_id]), sigma_height, sigma_ref_px, st)
            _append_rows(rows, r, pid[b], s_id, d_id)
    out = {k: np.concatenate(v) if v else np.zeros(0) for k, v in rows.items()}
    out["flags"] = out["flags"].astype(np.int64)
    cov = out.pop("_cov").reshape(-1, 2, 2)
    if np.isfinite(st.max_ray_misfit):
        bad = _inconsistent(geoms, out, pid, iid, px, cov, sigma_ref_px, st)
        out["flags"][bad] |= FLAGS["inconsistent"]
    out["flag_text"] = np.array([flag_names(f) for f in out["flags"]], dtype=object)
    out["accepted"] = out["flags"] == 0
    _tick(progress, is_cancelled, 1.0, "transferred")
    return out


def _append_rows(rows: dict, r: dict, pid: np.ndarray, s_id: str, d_id: str) -> None:
    """Add the on-image transfers of one batch (:func:`_transfer_pair`) to ``rows``."""
    keep = ~r["off_image"]
    n = len(pid)
    for key, val in (("point_id", pid), ("image_id", np.full(n, d_id)),
                     ("ref_image", np.full(n, s_id)), ("col", r["px"][:, 0]),
                     ("row", r["px"][:, 1]), ("pred_col", r["pred"][:, 0]),
                     ("pred_row", r["pred"][:, 1]), ("ncc", r["ncc"]), ("rho", r["rho"]),
                     ("sigma_col", r["sigma"][:, 0]), ("sigma_row", r["sigma"][:, 1]),
                     ("back_error", r["back_error"]), ("entropy", r["texture"]["entropy"]),
                     ("blockiness", r["texture"]["blockiness"]),
                     ("roundness", r["texture"]["roundness"]), ("flags", r["flags"]),
                     ("_cov", r["cov_rays"])):
        rows[key].append(np.asarray(val)[keep])


def _inconsistent(geoms, out: dict, pid, iid, px, cov, sigma_ref_px: float,
                  st: MatchSettings) -> np.ndarray:
    """Accepted transfers of points seen on three or more frame images (the reference and
    at least two accepted matches) whose forward intersection misses them.

    All rays of a point are intersected (least squares); a match is inconsistent when its
    misfit ``r`` (px) fails ``r' (C + (t / k)^2 I)^-1 r <= k^2`` (``k`` = WINDOW_K,
    ``t`` = ``st.max_ray_misfit`` px): ``C`` is the transfer's covariance without the
    terrain height's part (the orientations' uncertainty moves the rays; the height is
    what the intersection determines), so with a good orientation a match more than
    about ``t`` px off its intersection - e.g. one at the wrong place along the
    epipolar line - is refused. RPC images are left out.
    """
    bad = np.zeros(len(out["flags"]), bool)
    acc = np.flatnonzero(out["flags"] == 0)
    frame = {k for k, g in geoms.items() if isinstance(g, ImageGeometry)}
    acc = acc[np.isin(out["image_id"][acc], list(frame))]
    ids, counts = np.unique(out["point_id"][acc], return_counts=True)
    ref_of = {p: k for k, p in reversed(list(enumerate(pid)))}
    for p in ids[counts >= 2]:  # loop over the few points seen on 3+ images
        k = ref_of[p]
        if iid[k] not in frame:
            continue
        rows = acc[out["point_id"][acc] == p]
        imgs = [iid[k]] + list(out["image_id"][rows])
        obs = np.vstack([px[k][None], np.column_stack([out["col"][rows], out["row"][rows]])])
        x = _intersect([geoms[i] for i in imgs], obs)
        for j, r in enumerate(rows, start=1):
            d = geoms[imgs[j]].to_pixel(x[None])[0] - obs[j]
            c = cov[r] + (st.max_ray_misfit / WINDOW_K) ** 2 * np.eye(2)
            bad[r] = not float(d @ np.linalg.solve(c, d)) <= WINDOW_K**2
    return bad


def _intersect(geoms: list, obs: np.ndarray) -> np.ndarray:
    """Least-squares intersection ``(3,)`` of the rays of pixels ``obs`` of frame images."""
    m, b = np.zeros((3, 3)), np.zeros(3)
    for g, o in zip(geoms, obs):
        d = g.ray(o[None])[0]
        p = np.eye(3) - np.outer(d, d)
        m += p
        b += p @ g.eo[:3]
    return np.linalg.solve(m, b)


def measure_roads(geoms: Mapping[str, ImageGeometry], readers: Mapping, points: PointSet,
                  road_width: float = 6.0, settings: Optional[RoadSettings] = None,
                  min_turn: float = 30.0, progress: Progress = None,
                  is_cancelled=None) -> dict:
    """Locate junction and corner shape points on every image (centreline crossing).

    Parameters
    ----------
    geoms, readers : mappings of image id
    points : PointSet
        Its shape points with ``degree >= 3`` or a corner of at least ``min_turn``
        degrees are measured (:func:`measure.roads.measurable`).
    road_width : float
        Width of the roads' surface (m).
    settings : RoadSettings, optional

    Returns
    -------
    dict of numpy.ndarray
        ``point_id, image_id, col, row`` (NaN when failed), ``pred_col, pred_row``,
        ``arms, rms`` (pixels), ``flags``, ``flag_text``, ``accepted``.
    """
    st = settings or RoadSettings()
    sel = np.flatnonzero((points.kind == "shape") & measurable(points.xyz, points.arms,
                                                                 points.degree, min_turn))
    rows: dict = {k: [] for k in ("point_id", "image_id", "col", "row", "pred_col", "pred_row",
                                  "arms", "rms", "flags")}
    for n_img, (iid, g) in enumerate(geoms.items()):
        xyz = points.xyz[sel]
        pred = g.to_pixel(xyz)
        o = g.index_offset  # chips are read and searched at array indices
        if o:
            pred = pred - o
        w, h = readers[iid].size
        ins = sel[(pred[:, 0] >= 0) & (pred[:, 1] >= 0) & (pred[:, 0] < w) & (pred[:, 1] < h)]
        for b0 in range(0, len(ins), BATCH):
            _tick(progress, is_cancelled, (n_img + b0 / max(len(ins), 1)) / len(geoms),
                  f"road junctions on {iid}")
            b = ins[b0:b0 + BATCH]
            p0 = g.to_pixel(points.xyz[b])
            arm_px = g.to_pixel(points.arms[b].reshape(-1, 3)).reshape(len(b), -1, 2)
            dirs = arm_px - p0[:, None, :]
            east = g.to_pixel(points.xyz[b] + [road_width, 0.0, 0.0])
            width_px = np.hypot(*(east - p0).T)
            wmax = float(width_px.max())
            half = int(np.ceil(wmax * (st.start + st.arm_length) + st.search + 2 * wmax)) + 3
            p0_i = p0 - o if o else p0
            chips, org = read_chips(readers[iid], p0_i, half)
            r = centreline_crossing(chips, org, p0_i, dirs, width_px, st)
            found = r.px + o if o else r.px
            for key, val in (("point_id", points.ids[b]), ("image_id", np.full(len(b), iid)),
                             ("col", found[:, 0]), ("row", found[:, 1]), ("pred_col", p0[:, 0]),
                             ("pred_row", p0[:, 1]), ("arms", r.arms_used), ("rms", r.rms),
                             ("flags", r.flags)):
                rows[key].append(np.asarray(val))
    out = {k: np.concatenate(v) if v else np.zeros(0) for k, v in rows.items()}
    out["flags"] = out["flags"].astype(np.int64)
    names = {v: k for k, v in ROAD_FLAGS.items()}
    out["flag_text"] = np.array(["|".join(names[b] for b in names if f & b)
                                 for f in out["flags"]], dtype=object)
    out["accepted"] = out["flags"] == 0
    _tick(progress, is_cancelled, 1.0, "road junctions measured")
    return out


def image_points(geoms: Mapping[str, ImageGeometry], manual: Optional[Mapping] = None,
                 transferred: Optional[Mapping] = None, automatic: Optional[Mapping] = None,
                 sigma_manual_px: float = 0.5, sigma_floor_px: float = 0.3,
                 sigma_road_px: float = 0.75, unit: str = "mm") -> dict:
    """The accepted measurements as ``image_points.csv`` columns (photo mm as measured).

    With ``unit = "pixel"`` (``[measurements] unit`` of a scanned-film project with
    measured fiducials) ``x, y`` are the column and row and the sigmas are in pixels;
    so are they, whatever the unit, on RPC images (the adjustment reads their rows as
    pixels).

    Columns: ``point_id, image_id, x, y, sigma_x, sigma_y`` (mm; the contract) and
    ``source`` (manual, transferred, automatic), ``ncc``, ``lsm_sigma`` (pixels),
    ``col, row`` (pixels). The sigma of a transferred measurement is the LSM sigma with
    ``sigma_floor_px`` in quadrature (LSM's own precision is optimistic); that of a road
    junction the RMS of its profile peaks with ``sigma_road_px`` in quadrature (the
    centreline found on rendered pairs is within 0.2-0.3 px in the median but up to
    1.7 px off where the verges differ in brightness).
    """
    parts = []
    if manual is not None and len(manual["point_id"]):
        n = len(manual["point_id"])
        parts.append((manual, np.full(n, "manual"), np.full(n, np.nan),
                      np.full(n, sigma_manual_px), np.full(n, np.nan)))
    for tab, name in ((transferred, "transferred"), (automatic, "automatic")):
        if tab is None or not len(tab["point_id"]):
            continue
        ok = np.asarray(tab["accepted"], bool)
        t = {k: np.asarray(v)[ok] for k, v in tab.items()}
        lsm_s = (np.fmax(t["sigma_col"], t["sigma_row"]) if "sigma_col" in t
                 else np.asarray(t["rms"], float))
        parts.append((t, np.full(ok.sum(), name), np.asarray(t["ncc"], float)
                      if "ncc" in t else np.full(ok.sum(), np.nan),
                      np.hypot(np.nan_to_num(lsm_s),
                               sigma_floor_px if name == "transferred" else sigma_road_px),
                      lsm_s))
    cols: dict = {k: [] for k in ("point_id", "image_id", "x", "y", "sigma_x", "sigma_y",
                                  "source", "ncc", "lsm_sigma", "col", "row")}
    for t, src, ncc, sig_px, lsm_s in parts:
        iid = np.asarray(t["image_id"]).astype(str)
        px = np.column_stack([t["col"], t["row"]]).astype(float)
        mm = np.zeros_like(px)
        smm = np.zeros_like(px)
        for g_id in np.unique(iid) if unit != "pixel" else ():
            m = iid == g_id
            g = geoms[g_id]
            mm[m] = g.pixel_to_measured_mm(px[m])
            jac = np.abs(g.pixel_to_measured_mm(px[m] + [1.0, 0.0]) - mm[m])[:, 0], \
                np.abs(g.pixel_to_measured_mm(px[m] + [0.0, 1.0]) - mm[m])[:, 1]
            smm[m] = np.column_stack(jac) * sig_px[m, None]
        if unit == "pixel":
            mm, smm = px.copy(), np.column_stack([sig_px, sig_px])
        for key, val in (("point_id", t["point_id"]), ("image_id", iid), ("x", mm[:, 0]),
                         ("y", mm[:, 1]), ("sigma_x", smm[:, 0]), ("sigma_y", smm[:, 1]),
                         ("source", src), ("ncc", ncc), ("lsm_sigma", lsm_s),
                         ("col", px[:, 0]), ("row", px[:, 1])):
            cols[key].append(np.asarray(val))
    return {k: np.concatenate(v) if v else np.zeros(0) for k, v in cols.items()}
