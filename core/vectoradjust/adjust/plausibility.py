"""Plausibility checks of a project before the adjustment: the gross mistake, not its symptom.

A unit, an axis order, a CRS or a copied line that is wrong makes the adjustment fail
far from the cause ("N object point(s) cannot be determined", "diverged", "singular").
These checks compare the inputs with each other before the solve and name the likely
mistake and its fix:

* :func:`check_inputs` (before the measurements are classified): image coordinates
  outside the camera format (micrometres or pixels where millimetres are expected),
  every measurement on one image, an image under the ground, control points, road
  layers or image positions far from the others (X and Y swapped, degrees, another UTM
  zone or CRS), an attitude given in radians, mirrored image coordinates;
* :func:`check_classified` (after it): two images at the same approximate position
  sharing tie points (zero base), a DEM that does not cover the measured roads.

A certain mistake raises a :class:`~vectoradjust.errors.VectorAdjustError` subclass
naming the file, point or image, the likely cause and the fix; a suspicious input is a
warning of the run. Frame images only where the check is frame geometry (RPC images:
:func:`vectoradjust.adjust.intersection.check_rpc_domain`). Numpy only, no file I/O.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import TYPE_CHECKING, Optional

import numpy as np

from vectoradjust.adjust.shapepoints import lookup
from vectoradjust.errors import (
    ControlError,
    DEMError,
    LayerError,
    MeasurementError,
    ProjectError,
    VectorAdjustError,
)
from vectoradjust.model import ProjectData
from vectoradjust.sensor.collinearity import project
from vectoradjust.sensor.refine import DEFAULT_CORRECTIONS, refine

if TYPE_CHECKING:  # pragma: no cover - annotations only
    from vectoradjust.adjust.classify import Classification

__all__ = ["check_inputs", "check_classified", "format_half_size", "OUTSIDE_FORMAT",
           "FAR_FACTOR", "FAR_MIN", "GEOID_MARGIN", "DEM_MISSING"]

#: a photo coordinate beyond this many half format sizes is outside the camera format
OUTSIDE_FORMAT = 1.25
#: points farther from the images' footprint than this many footprint diagonals ...
FAR_FACTOR = 2.0
#: ... and than this many metres are far outside it
FAR_MIN = 2000.0
#: a DEM that gives no height to this share of a database's measured shape points misses
#: the roads (fewer: the first point without a height is named)
DEM_MISSING = 0.9
#: an image this far (m) below the ground is under it (more than any geoid undulation:
#: the heights of the positions and of the control may be in different datums)
GEOID_MARGIN = 120.0

_SHAPE_ID = re.compile(r"^(?:[^:]+:)?.+_\d+$")


@dataclass
class _Facts:
    """What the checks share: images, rows and the terrain height."""

    image_ids: np.ndarray
    img_of_row: np.ndarray  # image index of each measurement (-1: unknown id)
    is_frame: np.ndarray  # per image: a frame camera
    ctrl_of_row: np.ndarray  # control row of each measurement (-1: none)
    terrain: Optional[float] = None
    terrain_source: str = ""

    @property
    def on_frame(self) -> np.ndarray:
        """Measurements on frame images."""
        return (self.img_of_row >= 0) & self.is_frame[np.maximum(self.img_of_row, 0)]


def _facts(data: ProjectData, selected: set) -> _Facts:
    meas = data.measurements
    image_ids = np.array([str(im.id) for im in data.images], dtype=object).astype(str)
    facts = _Facts(image_ids, lookup(image_ids, meas.image_id),
                   np.array([im.model != "rpc" for im in data.images], bool),
                   lookup(data.control.point_id, meas.point_id))
    facts.terrain, facts.terrain_source = _terrain(data, facts, selected)
    return facts


def _terrain(data: ProjectData, facts: _Facts, selected: set) -> tuple[Optional[float], str]:
    """The ground height: measured control points, else road vertices, else the
    refinement's terrain height."""
    rows = facts.on_frame & (facts.ctrl_of_row >= 0)
    z = data.control.xyz[np.unique(facts.ctrl_of_row[rows]), 2]
    z = z[np.isfinite(z)]
    if z.size:
        return float(np.median(z)), f"the median height of the {z.size} measured control points"
    zs = [layer.coords[:, 2] for spec, layer in data.vectors if spec.name in selected]
    z = np.concatenate(zs) if zs else np.zeros(0)
    z = z[np.isfinite(z)]
    if z.size:
        return float(np.median(z)), "the median height of the road vertices"
    th = (data.interior or {}).get("terrain_height") or {}
    if th.get("value") is not None and np.isfinite(th["value"]):
        return float(th["value"]), str(th.get("source", "the terrain height"))
    return None, ""


def format_half_size(camera) -> tuple[float, float, str]:
    """Half the camera format (mm) and where it comes from.

    Parameters
    ----------
    camera : vectoradjust.model.Camera
        Its ``calibration``'s ``image_size`` times ``pixel_size``, else its calibrated
        fiducials, else 1.5 times the focal length (wider than any aerial camera).

    Returns
    -------
    (float, float, str)
        Half width, half height (mm) and a description of the source.
    """
    cal = getattr(camera, "calibration", None)
    size, pixel = getattr(cal, "image_size", None), getattr(cal, "pixel_size", None)
    if size is not None and pixel is not None:
        return (size[0] * pixel[0] / 2, size[1] * pixel[1] / 2,
                "[camera] image_size x pixel_size")
    fid = getattr(cal, "fiducials", None)
    if fid:
        xy = np.abs(np.array(list(fid.values()), float))
        return float(xy[:, 0].max()), float(xy[:, 1].max()), "the calibrated fiducials"
    f = 1.5 * float(camera.focal_length)
    return f, f, "1.5 x the focal length: [camera] gives no format"


# =========================================================================== the entries
def check_inputs(data: ProjectData, selected: set, warnings: list) -> None:
    """The checks before the measurements are classified (:func:`vectoradjust.pipeline.run`).

    Parameters
    ----------
    data : ProjectData
    selected : set of str
        The databases in the run.
    warnings : list of str
        Suspicious inputs are appended.

    Raises
    ------
    MeasurementError
        Image coordinates outside the format (the unit named), every measurement on
        one image, mirrored image coordinates.
    ProjectError
        An image under the ground, image positions far from control and roads, an
        attitude in radians.
    ControlError, LayerError
        Control points or a road layer far outside the images' footprint (swapped
        axes, degrees, another UTM zone or CRS).
    """
    facts = _facts(data, selected)
    # the frame images with measurements (none in a block of RPC images only)
    frames = np.flatnonzero(facts.is_frame & np.isin(np.arange(len(data.images)),
                                                     facts.img_of_row))
    if not np.isfinite(data.camera.focal_length):
        frames = frames[:0]
    if frames.size:
        _check_image_coordinates(data, facts, frames, warnings)
    _check_one_image(data, facts, warnings)
    if not frames.size:
        return
    if facts.terrain is not None:
        _check_under_ground(data, facts, frames, warnings)
        _check_ground(data, facts, frames, selected, warnings)
    _check_attitude(data, facts, frames, warnings)


def check_classified(data: ProjectData, cls: Classification, selected: set,
                     warnings: list) -> None:
    """The checks that need the classification (before the bundle problem is built).

    Parameters
    ----------
    data : ProjectData
    cls : vectoradjust.adjust.classify.Classification
    selected : set of str
    warnings : list of str

    Raises
    ------
    MeasurementError
        Two images at the same approximate position share tie points (zero base).
    DEMError
        The DEM gives no height to (nearly) all of a database's measured shape points.
    """
    facts = _facts(data, selected)
    _check_zero_base(data, facts, cls, warnings)
    _check_dem(data, cls, selected)


# =========================================================================== image coordinates
def _check_image_coordinates(data: ProjectData, facts: _Facts, frames: np.ndarray,
                             warnings: list) -> None:
    """Most of an image's coordinates outside the format: the unit (error); a few: warning."""
    meas = data.measurements
    hx, hy, src = format_half_size(data.camera)
    bad = []
    for j in frames.tolist():
        rows = np.flatnonzero(facts.img_of_row == j)
        xy = meas.xy[rows]
        inside = (np.abs(xy[:, 0]) <= OUTSIDE_FORMAT * hx) & \
            (np.abs(xy[:, 1]) <= OUTSIDE_FORMAT * hy)
        out = rows[~inside]
        if 2 * out.size > rows.size:
            bad.append((j, rows, out))
        elif out.size:
            lines = ", ".join(str(int(meas.rows[i])) for i in out[:5])
            warnings.append(
                f"image {str(facts.image_ids[j])!r}: {out.size} of {rows.size} measurement(s) lie "
                f"outside the camera format (+-{hx:.1f} x {hy:.1f} mm, {src}): {meas.source}, "
                f"line(s) {lines}{' ...' if out.size > 5 else ''}; a typo, or a point of "
                "another image?")
    if bad:
        raise _unit_error(data, facts, bad, (hx, hy, src))


def _interior_image(data: ProjectData, image_id: str) -> dict:
    for rec in (data.interior or {}).get("images") or []:
        if str(rec.get("id")) == image_id:
            return rec
    return {}


def _raw_radius(data: ProjectData, j: int, applied: list, radius: float) -> float:
    """The largest distance from the centre as measured (before the refinement) that the
    refinement of image ``j`` turns into ``radius`` (mm); NaN when not found.

    The corrections are radial, so one ray of the chain suffices; their polynomials grow
    so fast far outside the format that the largest such distance is the one measured.
    """
    radial = [s for s in ("distortion", "refraction", "earth_curvature") if s in applied]
    if not radial:
        return radius
    t = np.geomspace(1e-2, 1e13, 4000)
    switches = {s: s in applied for s in DEFAULT_CORRECTIONS}
    heights = {"flying_height": float(data.images[j].position[2]),
               "terrain_height": ((data.interior or {}).get("terrain_height") or {}).get("value")}
    try:
        with np.errstate(all="ignore"):
            xy = refine(np.column_stack([t, np.zeros_like(t)]), data.camera, unit="mm",
                        corrections=switches, **heights).xy
    except (VectorAdjustError, TypeError, ValueError):
        return float("nan")
    g = np.hypot(xy[:, 0], xy[:, 1])
    ok = np.isfinite(g) & (g <= radius)
    return float(t[ok].max()) if ok.any() else float("nan")


def _unit_cause(data: ProjectData, raw: float, half: float) -> tuple[str, str]:
    """The likely unit of coordinates reaching ``raw`` (unit of the file) in a format of
    half diagonal ``half`` (mm), and the fix."""
    pixel = getattr(getattr(data.camera, "calibration", None), "pixel_size", None)
    ps = float(np.mean(pixel)) if pixel is not None else None
    if np.isfinite(raw) and 0.3 * half <= raw / 1000.0 <= OUTSIDE_FORMAT * half:
        return (f"they are about 1000 times too large: micrometres where millimetres are "
                f"expected ({raw:.4g} um = {raw / 1000:.4g} mm fits the format)",
                "Divide x and y (and sigma_x, sigma_y if they are micrometres too) by 1000, "
                "or export the measurements in millimetres")
    if ps and np.isfinite(raw) and 0.3 * half <= raw * ps <= 2 * OUTSIDE_FORMAT * half:
        return (f"they are pixels (column, row), not millimetres: {raw:.4g} px x {ps:g} mm "
                f"= {raw * ps:.4g} mm spans the format",
                'Write [measurements] unit = "pixel" (with the fiducials measured in pixels, '
                "[measurements] fiducials, or [camera] pixel_size and image_size for a digital "
                "frame), or convert them to millimetres in the fiducial frame")
    size = f"{raw:.4g} (in the unit of the file)" if np.isfinite(raw) else "far beyond it"
    return (f"they reach {size}: they are not photo millimetres (micrometres, pixels, "
            "another image's coordinates?)",
            'Give photo coordinates in millimetres in the fiducial frame, or pixels with '
            '[measurements] unit = "pixel"')


def _unit_error(data: ProjectData, facts: _Facts, bad: list, fmt: tuple) -> MeasurementError:
    meas = data.measurements
    hx, hy, src = fmt
    j, rows, out = bad[0]
    image_id = str(facts.image_ids[j])
    rec = _interior_image(data, image_id)
    applied = list(rec.get("applied") or [])
    unit = (data.interior or {}).get("input_unit", "mm")
    r = np.hypot(meas.xy[rows, 0], meas.xy[rows, 1])
    radius = float(r[np.isfinite(r)].max()) if np.isfinite(r).any() else float("inf")
    if unit != "mm" or {"affine", "pixel_to_photo"} & set(applied):
        cause, mend = ("the fiducial affine or the pixel size does not map them into the format",
                       "Check [camera] pixel_size and image_size, the fiducial measurements and "
                       "the image ids of the rows")
    else:
        raw = _raw_radius(data, j, applied, radius)
        cause, mend = _unit_cause(data, raw, float(np.hypot(hx, hy)))
    images = ", ".join(repr(str(facts.image_ids[b[0]])) for b in bad)
    return MeasurementError(
        f"{meas.source}: the image coordinates of image(s) {images} lie outside the camera "
        f"format of +-{hx:.1f} x {hy:.1f} mm ({src}): {out.size} of {rows.size} rows of "
        f"image {image_id!r} (e.g. line {int(meas.rows[out[0]])}); likely cause: {cause}",
        mend, path=meas.source, details={"image_id": image_id, "line": int(meas.rows[out[0]])})


# =========================================================================== one image
def _shape_like(ids: np.ndarray) -> np.ndarray:
    return np.array([bool(_SHAPE_ID.match(str(i))) for i in ids], bool)


def _check_one_image(data: ProjectData, facts: _Facts, warnings: list) -> None:
    """Every measurement on one image of several (error when a point needs a second ray),
    or most points measured on one image only (warning)."""
    meas = data.measurements
    if len(data.images) < 2 or not len(meas.point_id) or (facts.img_of_row < 0).any():
        return  # an unknown image id: the classification names it
    used = np.unique(facts.img_of_row)
    free = facts.ctrl_of_row < 0
    if used.size == 1:
        only = str(facts.image_ids[used[0]])
        others = ", ".join(repr(str(i)) for k, i in enumerate(facts.image_ids) if k != used[0])
        ids = np.unique(meas.point_id[free])
        ties = ids[~_shape_like(ids)]
        what = (f"{meas.source}: all {len(meas.point_id)} measurements are on image {only!r}; "
                f"image(s) {others} of [[images]] have none")
        if ties.size:
            raise MeasurementError(
                what + f", so no point is measured on two images and the tie points (e.g. "
                f"{str(ties[0])!r}) cannot be intersected; likely cause: the measurements of "
                "the other image(s) are missing (an export of one image only) or carry the "
                f"image id {only!r}",
                f"Add the measurements of image(s) {others} to {meas.source} (one row per point "
                "and image), or correct their image_id",
                path=meas.source, details={"image_id": only})
        warnings.append(what + ": every point is fixed by one ray and its prior (check that "
                        "the other images' measurements are not missing)")
        return
    ids, inv = np.unique(meas.point_id[free], return_inverse=True)
    n_img = len(facts.image_ids)
    pairs = np.unique(inv.reshape(-1).astype(np.int64) * n_img + facts.img_of_row[free])
    single = int((np.bincount(pairs // n_img, minlength=ids.size) == 1).sum())
    if ids.size >= 10 and 2 * single > ids.size:
        warnings.append(f"{meas.source}: {single} of {ids.size} points (other than control) are "
                        "measured on one image only: each is fixed by one ray and its prior "
                        "(measure them on every image that shows them)")


# =========================================================================== orientation
def _check_under_ground(data: ProjectData, facts: _Facts, frames: np.ndarray,
                        warnings: list) -> None:
    """An approximate projection centre below the ground: error; just above it: warning."""
    h = float(facts.terrain)
    zl = np.array([float(data.images[j].position[2]) for j in frames])
    under = frames[~(zl > h - GEOID_MARGIN)]
    if under.size:
        j = int(under[0])
        z = float(data.images[j].position[2])
        names = ", ".join(repr(str(facts.image_ids[k])) for k in under)
        raise ProjectError(
            f"{data.source}: [[images]] {names}: the approximate position ZL = {z:g} m puts the "
            f"camera under the ground ({h:.1f} m, {facts.terrain_source}); likely cause: ZL is "
            "0 or left out, has the wrong sign, or is in another unit or height datum",
            "Give ZL as the height of the projection centre in metres in the datum of the "
            "control heights: the ground height plus the flying height above ground",
            path=data.source, details={"image_id": str(facts.image_ids[j]), "ZL": z})
    low = frames[~(zl > h)]
    for j in low.tolist():
        warnings.append(f"image {str(facts.image_ids[j])!r}: the approximate ZL = "
                        f"{float(data.images[j].position[2]):g} m is not above the ground "
                        f"({h:.1f} m, {facts.terrain_source}): a mix of height datums?")


def _rotation(measured: np.ndarray, projected: np.ndarray) -> tuple[float, float, float]:
    """Angle (degrees) turning ``measured`` onto ``projected`` about their centroids, and
    how well a rotation and a mirrored rotation fit (1: exactly up to scale)."""
    a = measured - measured.mean(axis=0)
    b = projected - projected.mean(axis=0)
    a = a[:, 0] + 1j * a[:, 1]
    b = b[:, 0] + 1j * b[:, 1]
    norm = float(np.sqrt(np.sum(np.abs(a) ** 2) * np.sum(np.abs(b) ** 2)))
    if not np.isfinite(norm) or norm <= 0:
        return 0.0, 0.0, 0.0
    c = np.sum(np.conj(a) * b)
    return float(np.degrees(np.angle(c))), float(abs(c)) / norm, \
        float(abs(np.sum(a * b))) / norm


def _turn(data: ProjectData, j: int, xy: np.ndarray, xyz: np.ndarray,
          attitude_rad: np.ndarray) -> tuple[float, float, float]:
    eo = np.r_[np.asarray(data.images[j].position, float), attitude_rad]
    with np.errstate(all="ignore"):
        proj = project(eo, xyz, data.camera.focal_length, data.camera.principal_point)
    ok = np.isfinite(proj).all(axis=1) & np.isfinite(xy).all(axis=1)
    if ok.sum() < 3:
        return 0.0, 0.0, 0.0
    return _rotation(xy[ok], proj[ok])


def _check_attitude(data: ProjectData, facts: _Facts, frames: np.ndarray,
                    warnings: list) -> None:
    """The measured control points against their projection with the approximate
    orientation: mirrored coordinates, an attitude in radians, a kappa far off."""
    meas, ctrl = data.measurements, data.control
    for j in frames.tolist():
        rows = np.flatnonzero((facts.img_of_row == j) & (facts.ctrl_of_row >= 0))
        if rows.size < 3:
            continue
        im = data.images[j]
        att = np.asarray(im.attitude, float)
        xy, xyz = meas.xy[rows], ctrl.xyz[facts.ctrl_of_row[rows]]
        angle, fit, mirror = _turn(data, j, xy, xyz, np.radians(att))
        name = str(facts.image_ids[j])
        many = rows.size >= 5  # with fewer, two swapped point ids can look like a mirror
        if many and mirror > 0.95 and fit < 0.8:
            raise MeasurementError(
                f"{meas.source}: the image coordinates of image {name!r} are mirrored: its "
                f"{rows.size} measured control points match their projection with the "
                "approximate orientation only with one axis reversed; likely cause: y points "
                "down (pixel rows, a scanner's or a viewer's frame)",
                "Give photo coordinates with x to the right and y up (negate y), or pixels with "
                '[measurements] unit = "pixel"', path=meas.source, details={"image_id": name})
        if fit < 0.9 or abs(angle) <= 30.0:
            continue
        if np.abs(att).max() > 1e-3:
            angle_r, fit_r, _ = _turn(data, j, xy, xyz, att)
            if fit_r > 0.9 and abs(angle_r) < 10.0:
                raise _radians_error(data, name, att, angle, angle_r)
        if not many:
            continue
        kappa = round((att[2] + angle + 180.0) % 360.0 - 180.0) + 0.0  # no "-0"
        text = (f"image {name!r}: its measured control points are turned by {angle:.0f} deg "
                f"against their projection with the approximate attitude (kappa = "
                f"{att[2]:g} deg); likely cause: kappa is off by about {abs(angle):.0f} deg (its "
                "sign or convention, the flight direction, a camera turned in the mount): "
                f"the points fit kappa = {kappa:.0f} deg")
        sig = im.sigma_attitude
        if sig is not None and abs(angle) > max(5 * float(sig), 45.0):
            raise ProjectError(f"{data.source}: {text}, and sigma_attitude = {sig:g} deg holds "
                               "kappa where it is", f"Give kappa of image {name!r} in degrees "
                               f"as it is (about {kappa:.0f} deg), or a larger sigma_attitude",
                               path=data.source, details={"image_id": name})
        warnings.append(text)


def _radians_error(data: ProjectData, name: str, att: np.ndarray, angle: float,
                   angle_r: float) -> ProjectError:
    given = ", ".join(f"{a:g}" for a in att)
    deg = ", ".join(f"{a:.4g}" for a in np.degrees(att))
    return ProjectError(
        f"{data.source}: [[images]] {name!r}: attitude = [{given}] looks like radians: the "
        f"measured control points are turned by {angle:.0f} deg against their projection "
        f"with these angles as degrees, and by {angle_r:.1f} deg with them as radians",
        f"Give omega, phi, kappa in degrees: attitude = [{deg}] (degrees = radians x 180/pi) "
        "in every [[images]] entry", path=data.source, details={"image_id": name})


# =========================================================================== ground
def _box(xy: np.ndarray) -> np.ndarray:
    xy = xy[np.isfinite(xy).all(axis=1)]
    return np.r_[xy.min(axis=0), xy.max(axis=0)]


def _distance(xy: np.ndarray, box: np.ndarray) -> np.ndarray:
    """Plan distance of each point to a box ``xmin, ymin, xmax, ymax`` (0 inside)."""
    dx = np.maximum(np.maximum(box[0] - xy[:, 0], xy[:, 0] - box[2]), 0.0)
    dy = np.maximum(np.maximum(box[1] - xy[:, 1], xy[:, 1] - box[3]), 0.0)
    return np.hypot(dx, dy)


def _footprint(data: ProjectData, facts: _Facts, frames: np.ndarray) -> tuple[np.ndarray, float]:
    """The box the frame images cover on the ground (from the approximate positions, the
    height above the ground, the format and the tilt, as a square about the nadir) and the
    distance beyond which a point is far outside it."""
    hx, hy, _ = format_half_size(data.camera)
    half_angle = np.arctan(float(np.hypot(hx, hy)) / float(data.camera.focal_length))
    pos = np.array([np.asarray(data.images[j].position, float) for j in frames])
    att = np.radians([np.asarray(data.images[j].attitude, float) for j in frames])
    tilt = np.arccos(np.clip(np.abs(np.cos(att[:, 0]) * np.cos(att[:, 1])), 0.0, 1.0))
    w = np.maximum(pos[:, 2] - float(facts.terrain), 1.0) * \
        np.tan(np.minimum(tilt + half_angle, np.radians(80.0)))
    box = np.r_[(pos[:, :2] - w[:, None]).min(axis=0), (pos[:, :2] + w[:, None]).max(axis=0)]
    return box, max(FAR_FACTOR * float(np.hypot(*(box[2:] - box[:2]))), FAR_MIN)


def _utm(crs: str) -> Optional[tuple[int, bool]]:
    """UTM zone and hemisphere (north: True) of a CRS name, code or WKT; None otherwise."""
    text = str(crs)
    m = re.search(r"UTM[ _]zone[ _](\d{1,2})\s*([NS])", text, re.I)
    if m:
        return int(m.group(1)), m.group(2).upper() == "N"
    m = re.search(r"EPSG\W+(32[67])(\d\d)\b", text)
    if m:
        return int(m.group(2)), m.group(1) == "326"
    return None


def _compass(dx: float, dy: float) -> str:
    names = ["east", "north-east", "north", "north-west", "west", "south-west", "south",
             "south-east"]
    return names[int(np.round(np.degrees(np.arctan2(dy, dx)) / 45.0)) % 8]


def _where(xy: np.ndarray, box: np.ndarray) -> str:
    """How far and where points lie from a box."""
    c = np.median(xy[np.isfinite(xy).all(axis=1)], axis=0)
    d = float(np.median(_distance(xy, box)))
    size = f"{d / 1000:.0f} km" if d >= 10e3 else f"{d / 1000:.1f} km" if d >= 1e3 else \
        f"{d:.0f} m"
    return f"{size} {_compass(*(c - (box[:2] + box[2:]) / 2))}"


def _why_far(xy: np.ndarray, box: np.ndarray, tol: float, crs: str) -> tuple[str, str]:
    """The likely cause of points ``xy`` far from the reference ``box``: its kind
    (``degrees``, ``latlon``, ``swap``, ``zone``, ``far``) and a text."""
    xy = xy[np.isfinite(xy).all(axis=1)]
    ref_far = float(np.abs(box).max()) > 1000.0
    ax, ay = np.abs(xy[:, 0]), np.abs(xy[:, 1])
    utm = _utm(crs)
    if ref_far and (ax <= 180).all() and (ay <= 180).all() and \
            ((ax <= 90).all() or (ay <= 90).all()):
        order = _degree_order(xy, utm)
        names = "longitude, latitude" if order == "lonlat" else "latitude, longitude"
        return order, f"they look like degrees ({names}), not metres"
    if np.median(_distance(xy[:, ::-1], box)) <= tol:
        return "swap", "X and Y are swapped (X holds the northing, Y the easting)"
    dx, dy = np.median(xy, axis=0) - (box[:2] + box[2:]) / 2
    if abs(dy) < 100e3 and 250e3 < abs(dx) < 1500e3:
        if utm is None:
            return "zone", "they look like coordinates of another zone or CRS"
        zone = (utm[0] % 60) + 1 if dx < 0 else (utm[0] - 2) % 60 + 1
        code = f"EPSG:{326 if utm[1] else 327}{zone:02d}"
        return "zone:" + code, (f"they look like coordinates of the neighbouring UTM zone "
                                f"{zone} ({code}), not of zone {utm[0]} of the project CRS")
    return "far", "another CRS, or a wrong false easting or northing?"


def _degree_order(xy: np.ndarray, utm: Optional[tuple[int, bool]]) -> str:
    """``lonlat`` or ``latlon``: which column of coordinates in degrees is the longitude
    (the one near the UTM zone's central meridian; else the one beyond 90)."""
    x, y = np.median(xy[:, 0]), np.median(xy[:, 1])
    if utm is not None:
        meridian = 6.0 * utm[0] - 183.0
        if abs(y - meridian) <= 4.0 < abs(x - meridian):
            return "latlon"
        return "lonlat"
    return "latlon" if (np.abs(xy[:, 1]) > 90).any() else "lonlat"


def _measured_control(data: ProjectData, facts: _Facts) -> np.ndarray:
    rows = facts.on_frame & (facts.ctrl_of_row >= 0)
    idx = np.unique(facts.ctrl_of_row[rows])
    return idx[np.isfinite(data.control.xyz[idx, :2]).all(axis=1)]


def _layers(data: ProjectData, selected: set, box: np.ndarray) -> list:
    """(spec, layer, finite XY, nearest distance to ``box``) of each selected database."""
    out = []
    for spec, layer in data.vectors:
        xy = layer.coords[:, :2]
        xy = xy[np.isfinite(xy).all(axis=1)]
        if spec.name in selected and len(xy):
            out.append((spec, layer, xy, float(_distance(xy, box).min())))
    return out


def _check_ground(data: ProjectData, facts: _Facts, frames: np.ndarray, selected: set,
                  warnings: list) -> None:
    """Control points, road layers and image positions far from each other (error for the
    odd one out; single control points far outside the footprint: warning)."""
    box, tol = _footprint(data, facts, frames)
    cidx = _measured_control(data, facts)
    cxy = data.control.xyz[cidx, :2]
    dist = _distance(cxy, box)
    control_far = bool(cidx.size) and float(np.median(dist)) > tol
    layers = [] if data.has_rpc else _layers(data, selected, box)
    far = [entry for entry in layers if entry[3] > tol]
    refs = len(layers) + (1 if cidx.size else 0)
    if (control_far or not cidx.size) and refs >= 2 and len(far) == len(layers):
        ref = np.concatenate(([cxy] if cidx.size else []) + [e[2] for e in layers])
        ref_box = _box(ref)
        if all(float(_distance(e[2], ref_box).min()) <= tol for e in layers):
            raise _images_error(data, facts, frames, ref, ref_box, tol)
    if control_far:
        raise _control_error(data, cidx, box, tol)
    if far:
        raise _layer_error(data, far[0], box, tol)
    for k in np.flatnonzero(dist > tol)[:5].tolist():
        i = int(cidx[k])
        warnings.append(f"control point {str(data.control.point_id[i])!r} "
                        f"({data.control.source}, line {int(data.control.rows[i])}) lies "
                        f"{dist[k] / 1000:.1f} km outside the images' footprint: a typo in its "
                        "coordinates or its id?")


def _box_text(box: np.ndarray) -> str:
    return f"E {box[0]:.0f} to {box[2]:.0f}, N {box[1]:.0f} to {box[3]:.0f}"


def _control_error(data: ProjectData, cidx: np.ndarray, box: np.ndarray,
                   tol: float) -> ControlError:
    ctrl = data.control
    xy = ctrl.xyz[cidx, :2]
    kind, cause = _why_far(xy, box, tol, data.crs)
    i = int(cidx[0])
    mends = {
        "lonlat": 'Give [control] crs = "EPSG:4326" in the project (X = longitude, Y = '
                   "latitude) so that they are transformed into the project CRS",
        "latlon": f"Swap the columns X and Y of {ctrl.source} (X = longitude) and give "
                  '[control] crs = "EPSG:4326" so that they are transformed',
        "swap": f"Swap the columns X and Y of {ctrl.source} (X = easting, Y = northing)",
        "far": f"Give [control] crs = \"<their CRS>\" so that they are transformed into "
               f"{_crs_name(data.crs)}, or check the images' approximate positions",
    }
    mend = (f'Give [control] crs = "{kind[5:]}" (the CRS they are in) so that they are '
            f"transformed into {_crs_name(data.crs)}" if kind.startswith("zone:")
            else mends.get(kind, mends["far"]))
    return ControlError(
        f"{ctrl.source}: the {cidx.size} control points measured on the images lie "
        f"{_where(xy, box)} of the images' footprint ({_box_text(box)} in "
        f"{_crs_name(data.crs)}; e.g. {str(ctrl.point_id[i])!r} at X = {xy[0, 0]:.3f}, "
        f"Y = {xy[0, 1]:.3f}, line {int(ctrl.rows[i])}); likely cause: {cause}",
        mend, path=ctrl.source, details={"point_id": str(ctrl.point_id[i]), "cause": kind})


def _layer_error(data: ProjectData, entry: tuple, box: np.ndarray, tol: float) -> LayerError:
    spec, layer, xy, _ = entry
    kind, cause = _why_far(xy, box, tol, data.crs)
    info = (layer.reading or {}).get("crs") or {}
    read = ""
    if info.get("source_crs"):
        read = (f"its vertices were transformed from {info['source_crs']!r}, the CRS its file "
                "states, into the project CRS; ")
        if kind.startswith("zone") or kind == "far":
            cause = (f"the CRS its file states ({info['source_crs']}) is not the one its "
                     "coordinates are in (a .prj of another UTM zone or CRS)")
    mend = (f"Swap X and Y of the layer {layer.source}" if kind == "swap" else
            f"Give {layer.source} the CRS its coordinates are in (a GIS's 'set CRS' or "
            "'define projection', not 'reproject'; for a shapefile its .prj)")
    return LayerError(
        f"{spec.name} ({layer.source}): the road vertices lie {_where(xy, box)} of the images' "
        f"footprint ({_box_text(box)} in {_crs_name(data.crs)}); {read}likely cause: {cause}",
        mend, path=layer.source, details={"database": spec.name, "cause": kind})


def _images_error(data: ProjectData, facts: _Facts, frames: np.ndarray, ref: np.ndarray,
                  ref_box: np.ndarray, tol: float) -> ProjectError:
    pos = np.array([np.asarray(data.images[j].position, float)[:2] for j in frames])
    kind, cause = _why_far(pos, ref_box, tol, data.crs)
    name = str(facts.image_ids[frames[0]])
    return ProjectError(
        f"{data.source}: the approximate positions of the images ([[images]] position) lie "
        f"{_where(pos, ref_box)} of the control points and the roads ({_box_text(ref_box)}; "
        f"e.g. image {name!r} at X = {pos[0, 0]:.1f}, Y = {pos[0, 1]:.1f}); likely cause: "
        f"{cause}",
        f"Give each image's approximate projection centre in the project CRS "
        f"({_crs_name(data.crs)}): position = [easting, northing, height in metres]",
        path=data.source, details={"image_id": name, "cause": kind})


def _crs_name(crs: str) -> str:
    text = str(crs)
    m = re.match(r'\s*\w+\["([^"]+)"', text)
    return m.group(1) if m else text


# =========================================================================== classified
def _check_zero_base(data: ProjectData, facts: _Facts, cls: Classification,
                     warnings: list) -> None:
    """Two frame images at (nearly) the same approximate position: error when they share
    tie points (their rays are parallel), else a warning."""
    frames = np.flatnonzero(facts.is_frame)
    if frames.size < 2:
        return
    pos = np.array([np.asarray(data.images[j].position, float) for j in frames])
    height = pos[:, 2] - (facts.terrain if facts.terrain is not None else 0.0)
    limit = 0.01 * np.maximum(np.abs(height), 1.0)
    from scipy.spatial import cKDTree

    tie = np.flatnonzero(cls.is_tie)
    pairs = np.unique(np.asarray(cls.tie_inv).reshape(-1).astype(np.int64) * len(data.images)
                      + cls.img_of_obs[tie])
    two = set(cls.tie_ids[np.bincount(pairs // len(data.images), minlength=len(cls.tie_ids))
                          == 2].tolist())  # tie points on two images only
    for a, b in sorted(cKDTree(pos).query_pairs(float(limit.max()))):
        gap = float(np.linalg.norm(pos[a] - pos[b]))
        if gap > min(limit[a], limit[b]):
            continue
        ja, jb = int(frames[a]), int(frames[b])
        names = f"{str(facts.image_ids[ja])!r} and {str(facts.image_ids[jb])!r}"
        on_a, on_b = (set(data.measurements.point_id[cls.img_of_obs == j].tolist())
                      for j in (ja, jb))
        ties = sorted(on_a & on_b & two)
        what = (f"{data.source}: images {names} have the same approximate position "
                f"({', '.join(f'{v:.1f}' for v in pos[a])}; {gap:.2f} m apart)")
        if ties:
            raise MeasurementError(
                what + f", so the rays of the {len(ties)} tie point(s) measured on both (e.g. "
                f"{ties[0]!r}) are parallel and cannot be intersected; likely cause: the "
                "position of one image was copied to the other",
                "Give each image its own approximate position ([[images]] position: the "
                "projection centre, e.g. from the flight plan or GNSS)",
                path=data.source, details={"images": [names]})
        if on_a & on_b:
            warnings.append(what + ": the points they share are fixed by their priors only "
                            "until the adjustment separates them")


def _check_dem(data: ProjectData, cls: Classification, selected: set) -> None:
    """A DEM that gives no height to (nearly) all the measured shape points of the databases
    that take their heights from it: error naming its extent and the roads'. (A DEM that
    misses a few of them: :func:`vectoradjust.adjust.classify.build_problem` names the
    first point.)"""
    missing: dict = {}
    for (spec, sp), vi in zip(cls.shapes, cls.db_vertex_of_obs):
        if spec.name not in selected or not spec.dem:
            continue
        obj = np.unique(sp.vertex_object[vi[vi >= 0]])
        xyz = sp.object_xyz[obj]
        no_z = ~np.isfinite(xyz[:, 2])
        if obj.size and int(no_z.sum()) >= DEM_MISSING * obj.size:
            missing.setdefault(str(spec.dem), []).append((spec, sp.layer, xyz, no_z))
    for dem, entries in missing.items():
        names = ", ".join(e[0].name for e in entries)
        n_no = sum(int(e[3].sum()) for e in entries)
        n = sum(len(e[2]) for e in entries)
        roads = np.concatenate([e[2][e[3], :2] for e in entries])
        where, cause = _dem_extent(next((e[1].dem for e in entries if e[1].dem is not None),
                                        None), roads)
        raise DEMError(
            f"{dem}: the DEM gives no height to {n_no} of the {n} measured shape points of "
            f"{names}: it {'covers none' if n_no == n else 'covers almost none'} of them; "
            f"{where}likely cause: {cause}",
            f"Give in the [[vectors]] entry of {names} a DEM (dem = ...) that covers the roads "
            "on the images, in the CRS its file states",
            path=dem, details={"databases": [e[0].name for e in entries]})


def _dem_extent(grid, roads: np.ndarray) -> tuple[str, str]:
    """Where a DEM (a :class:`~vectoradjust.model.DemGrid`, None when not known) lies
    against the road points it gives no height to, and the likely cause."""
    another = "a DEM of another area (a neighbouring tile, a crop), or a DEM whose CRS is wrong"
    if grid is None:
        return "", another
    x0, dx, _, y0, _, dy = grid.transform
    rows, cols = grid.grid.shape
    xs, ys = sorted([x0, x0 + cols * dx]), sorted([y0, y0 + rows * dy])
    dbox = np.array([xs[0], ys[0], xs[1], ys[1]])
    text = f"the DEM covers {_box_text(dbox)}, the roads without a height {_box_text(_box(roads))}"
    if float(np.median(_distance(roads, dbox))) > 0:
        return f"{text}, which lie {_where(roads, dbox)} of it; ", another
    return (f"{text}, inside its extent; ", "the DEM has no data (nodata cells) where the roads "
            "are: holes, or a mask of another area")
