"""Tie-point zone coverage and inter-strip ties of a block (``docs/method.md`` section 7.4).

The PHOTOMOD production manual asks, before the block adjustment is accepted, that every
stereo pair carries tie (pass) points in the standard zones of its overlap and that
neighbouring strips are tied to each other with points whose vertical parallax meets the
relative orientation tolerance. This module measures both on an adjusted block.

Zones
-----
* The **frame** of an image is the rectangle ``|x| <= w/2, |y| <= h/2`` about the fiducial
  centre (photo coordinates, mm; :func:`frame_size`).
* The **overlap** of a stereo pair is the left image's frame clipped by the right image's
  frame mapped into the left image through the ground: the right frame's corners are
  intersected with the plane ``Z = Z_ref`` (the mean adjusted height of the pair's
  common points) and projected into the left image with the adjusted exterior
  orientation (collinearity), giving a convex quadrilateral (:func:`overlap_polygon`).
* The zones are laid out in the **base frame** of the left image: ``u`` along the air
  base as seen in the left image (``M_left (C_right - C_left)``, its x and y), ``v``
  across it. The overlap's extent in ``u`` is cut into 2 columns, its extent in ``v``
  into 3 rows (top / centre / bottom): the 6 von Gruber positions, the standard points
  of a relative orientation. Choice: 3 x 2, not 3 x 3, for every overlap - the third
  column of a 3 x 3 layout at 60 % forward overlap is the triple overlap, which the
  triplet zones check on their own (``columns=3`` gives the 3 x 3 layout).
* **Triplet zones** are the 3 rows of the triple overlap of three consecutive images
  (the first image's frame clipped by the two others), in the frame of the middle
  image, counting the points seen on all three.
* **Counted points**: tie (pass) points, i.e. points that are neither control/check
  points nor road vertices, when the block has any; else every measured point (a block
  tied by road vertices only). Road vertices and control points are reported per zone
  separately.
* **Verdict per zone**: at least 3 points pass, 2 is a warning, fewer fail.

Strips
------
From ``strip`` labels when the project gives them, else from the flight (:func:`image_strips`):
consecutive images (``[[images]]`` order) stay in one strip while the step between
their stations keeps within 45 degrees of the strip's first step and under 2.5 times the
median step. Strips are ordered across track (perpendicular to the mean flight axis);
neighbours in that order are adjacent strips. **Inter-strip points** are points measured
on images of two adjacent strips; their vertical parallax is computed for every pair of
their rays from images of different strips with
:func:`vectoradjust.qa.tolerances.vertical_parallax` (observed photo coordinates,
adjusted EO) and judged with the relative orientation tolerance.

A "heart" module: numpy and other vectoradjust heart modules only; no file I/O.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Optional

import numpy as np

from vectoradjust.qa.tolerances import vertical_parallax
from vectoradjust.sensor.collinearity import rotation_matrix

__all__ = [
    "ZONE_PASS",
    "ZONE_WARN",
    "BlockView",
    "ZoneGrid",
    "frame_size",
    "photo_to_ground",
    "ground_to_photo",
    "clip_polygon",
    "overlap_polygon",
    "zone_grid",
    "counted_kinds",
    "zone_status",
    "pair_zones",
    "triplet_zones",
    "image_strips",
    "adjacent_strips",
    "inter_strip_ties",
]

#: points per zone for a pass / for a warning (fewer fail)
ZONE_PASS = 3
ZONE_WARN = 2
ROW_NAMES = ("top", "centre", "bottom")
COLUMN_NAMES = {1: ("",), 2: ("left", "right"), 3: ("left", "centre", "right")}
_ROAD_KINDS = ("shape", "road")
_CONTROL_KINDS = ("control", "check", "gcp")


@dataclass
class BlockView:
    """The arrays of an adjusted frame-camera block that the zone checks need.

    Attributes
    ----------
    image_ids : list of str
        In flight order (``[[images]]``).
    eo : numpy.ndarray, shape (n, 6)
        Adjusted exterior orientation (m, rad).
    xyz : numpy.ndarray, shape (m, 3)
        Adjusted object points.
    point_ids : numpy.ndarray of str, shape (m,)
    point_kind : numpy.ndarray of str, shape (m,)
        ``"tie"``, ``"shape"`` (road vertex), ``"control"`` ...
    obs_point, obs_image : numpy.ndarray of int, shape (k,)
    obs_xy : numpy.ndarray, shape (k, 2)
        Observed photo coordinates (mm).
    focal_length : float
        mm.
    principal_point : numpy.ndarray, shape (2,)
        mm.
    frame : (float, float)
        Frame width and height (mm).
    """

    image_ids: list
    eo: np.ndarray
    xyz: np.ndarray
    point_ids: np.ndarray
    point_kind: np.ndarray
    obs_point: np.ndarray
    obs_image: np.ndarray
    obs_xy: np.ndarray
    focal_length: float
    principal_point: np.ndarray
    frame: tuple

    def on_images(self, images) -> tuple:
        """Points measured on every image of ``images`` and their observation on each.

        Returns
        -------
        (points, obs) : numpy.ndarray of int, shapes (p,) and (len(images), p)
        """
        k = len(images)
        n_pt = len(self.point_ids)
        table = np.full((k, n_pt), -1, np.int64)
        for r, img in enumerate(images):
            sel = np.flatnonzero(self.obs_image == img)
            table[r, self.obs_point[sel]] = sel
        points = np.flatnonzero((table >= 0).all(axis=0))
        return points, table[:, points]


# ------------------------------------------------------------------------- geometry
def frame_size(camera: Any = None, obs_xy=None, principal_point=(0.0, 0.0),
               size: Optional[tuple] = None) -> tuple:
    """The frame's width and height (mm) and where they came from.

    Parameters
    ----------
    camera : vectoradjust.model.Camera, optional
        Its calibration's ``image_size`` (pixels) times ``pixel_size`` (mm), else twice
        the largest fiducial coordinate (fiducials sit at the frame's edge).
    obs_xy : array_like, shape (k, 2), optional
        Last resort: twice the largest distance of a measured point from the principal
        point, per axis.
    principal_point : (float, float)
    size : (float, float), optional
        Explicit (wins).

    Returns
    -------
    (width, height, source) : (float, float, str)
    """
    if size is not None:
        w, h = (float(v) for v in np.broadcast_to(np.asarray(size, float), (2,)))
        return w, h, "argument"
    cal = getattr(camera, "calibration", None)
    get = cal.get if isinstance(cal, dict) else (lambda k: getattr(cal, k, None))
    if cal is not None and get("image_size") is not None and get("pixel_size") is not None:
        px = np.broadcast_to(np.asarray(get("pixel_size"), float).ravel()[:2], (2,))
        wh = np.asarray(get("image_size"), float).ravel()[:2] * px
        return float(wh[0]), float(wh[1]), "camera image_size x pixel_size"
    fid = get("fiducials") if cal is not None else None
    if isinstance(fid, dict) and fid:
        a = np.abs(np.array([np.asarray(v, float).ravel()[:2] for v in fid.values()]))
        return float(2 * a[:, 0].max()), float(2 * a[:, 1].max()), "camera fiducials"
    if obs_xy is not None and len(obs_xy):
        d = np.abs(np.asarray(obs_xy, float) - np.asarray(principal_point, float))
        return float(2 * d[:, 0].max()), float(2 * d[:, 1].max()), "extent of the measurements"
    raise ValueError("no frame size: give the camera's image_size and pixel_size")


def photo_to_ground(xy, eo, f: float, pp, z: float) -> np.ndarray:
    """Intersect the rays of photo points with the plane ``Z = z``.

    Parameters
    ----------
    xy : array_like, shape (k, 2)
        Photo coordinates (mm).
    eo : array_like, shape (6,)
    f : float
    pp : (float, float)
    z : float

    Returns
    -------
    numpy.ndarray, shape (k, 3)
    """
    xy = np.asarray(xy, float).reshape(-1, 2)
    eo = np.asarray(eo, float)
    m = rotation_matrix(eo[3], eo[4], eo[5])
    v = np.column_stack([xy[:, 0] - pp[0], xy[:, 1] - pp[1], np.full(len(xy), -float(f))])
    d = v @ m  # M^T v per row
    t = (z - eo[2]) / d[:, 2]
    return eo[:3] + t[:, None] * d


def ground_to_photo(xyz, eo, f: float, pp) -> np.ndarray:
    """Collinearity: photo coordinates (mm) of object points.

    Parameters
    ----------
    xyz : array_like, shape (k, 3)
    eo : array_like, shape (6,)
    f : float
    pp : (float, float)

    Returns
    -------
    numpy.ndarray, shape (k, 2)
    """
    eo = np.asarray(eo, float)
    m = rotation_matrix(eo[3], eo[4], eo[5])
    v = (np.asarray(xyz, float).reshape(-1, 3) - eo[:3]) @ m.T
    return np.column_stack([pp[0] - f * v[:, 0] / v[:, 2], pp[1] - f * v[:, 1] / v[:, 2]])


def _rectangle(frame: tuple) -> np.ndarray:
    w, h = 0.5 * float(frame[0]), 0.5 * float(frame[1])
    return np.array([[-w, -h], [w, -h], [w, h], [-w, h]])


def _ccw(poly: np.ndarray) -> np.ndarray:
    x, y = poly[:, 0], poly[:, 1]
    area2 = float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))
    return poly if area2 >= 0 else poly[::-1]


def clip_polygon(subject, clip) -> np.ndarray:
    """Sutherland-Hodgman: the part of polygon ``subject`` inside the convex ``clip``.

    Parameters
    ----------
    subject, clip : array_like, shape (k, 2)
        Vertices in order (either orientation); ``clip`` convex.

    Returns
    -------
    numpy.ndarray, shape (j, 2)
        Counter-clockwise; empty (0, 2) when they do not overlap.
    """
    out = [tuple(p) for p in _ccw(np.asarray(subject, float))]
    c = _ccw(np.asarray(clip, float))
    for a, b in zip(c, np.roll(c, -1, axis=0)):
        if not out:
            break
        edge = b - a

        def inside(p, a=a, edge=edge):
            return edge[0] * (p[1] - a[1]) - edge[1] * (p[0] - a[0]) >= -1e-12

        def cut(p, q, a=a, edge=edge):
            dp = np.subtract(q, p)
            den = edge[0] * dp[1] - edge[1] * dp[0]
            t = (edge[1] * (p[0] - a[0]) - edge[0] * (p[1] - a[1])) / den
            return (p[0] + t * dp[0], p[1] + t * dp[1])

        src, out = out, []
        for p, q in zip(src, src[1:] + src[:1]):
            if inside(q):
                if not inside(p):
                    out.append(cut(p, q))
                out.append(q)
            elif inside(p):
                out.append(cut(p, q))
    return np.array(out, float).reshape(-1, 2)


def overlap_polygon(view: BlockView, ref: int, others, z: float) -> np.ndarray:
    """The common area of image ``ref`` and ``others`` in the photo frame of ``ref``.

    Every other image's frame is mapped through the plane ``Z = z`` into ``ref``
    (adjusted EO) and clips ``ref``'s frame.

    Returns
    -------
    numpy.ndarray, shape (j, 2)
        Photo coordinates (mm); empty when the frames do not overlap.
    """
    f, pp = float(view.focal_length), tuple(view.principal_point)
    rect = _rectangle(view.frame)
    poly = rect
    for o in others:
        ground = photo_to_ground(rect, view.eo[o], f, pp, z)
        poly = clip_polygon(poly, ground_to_photo(ground, view.eo[ref], f, pp))
    return poly


@dataclass
class ZoneGrid:
    """Zones of an overlap: rows across the base, columns along it.

    Attributes
    ----------
    origin : numpy.ndarray, shape (2,)
        Photo coordinates (mm) of the base frame's origin.
    e_u, e_v : numpy.ndarray, shape (2,)
        Unit vectors along and across the base (photo frame).
    u_edges : numpy.ndarray, shape (cols + 1,)
    v_edges : numpy.ndarray, shape (rows + 1,)
        Descending: the first row is the top (largest ``v``).
    names : list of str
        Row-major: ``"top-left"``, ``"top-right"``, ...
    """

    origin: np.ndarray
    e_u: np.ndarray
    e_v: np.ndarray
    u_edges: np.ndarray
    v_edges: np.ndarray
    names: list

    @property
    def shape(self) -> tuple:
        """(rows, columns)."""
        return len(self.v_edges) - 1, len(self.u_edges) - 1

    def assign(self, xy) -> np.ndarray:
        """Zone index (row-major) of photo points; points outside go to the nearest zone."""
        d = np.asarray(xy, float).reshape(-1, 2) - self.origin
        u, v = d @ self.e_u, d @ self.e_v
        rows, cols = self.shape
        cu = np.clip(np.searchsorted(self.u_edges, u, side="right") - 1, 0, cols - 1)
        rv = np.clip(np.searchsorted(-self.v_edges, -v, side="right") - 1, 0, rows - 1)
        return rv * cols + cu

    def corners(self) -> list:
        """Per zone the photo coordinates (mm) of its lower-left and upper-right corners in
        the base frame, as ``[[x, y], [x, y]]`` (for drawing)."""
        rows, cols = self.shape
        out = []
        for r in range(rows):
            for c in range(cols):
                a = self.origin + self.u_edges[c] * self.e_u + self.v_edges[r + 1] * self.e_v
                b = self.origin + self.u_edges[c + 1] * self.e_u + self.v_edges[r] * self.e_v
                out.append([a.tolist(), b.tolist()])
        return out


def zone_grid(polygon, direction, rows: int = 3, columns: int = 2) -> ZoneGrid:
    """Zones over an overlap polygon: ``rows`` across ``direction``, ``columns`` along it.

    Parameters
    ----------
    polygon : array_like, shape (j, 2)
        The overlap (photo coordinates, mm).
    direction : array_like, shape (2,)
        The base as seen in the photo (any length).
    rows, columns : int
        3 x 2: the von Gruber zones; 3 x 1: triplet zones.

    Returns
    -------
    ZoneGrid
    """
    if columns not in COLUMN_NAMES:
        raise ValueError(f"columns must be 1, 2 or 3, got {columns!r}")
    p = np.asarray(polygon, float).reshape(-1, 2)
    e_u = np.asarray(direction, float)[:2]
    e_u = e_u / np.linalg.norm(e_u)
    e_v = np.array([-e_u[1], e_u[0]])
    origin = np.zeros(2)
    u, v = p @ e_u, p @ e_v
    u_edges = np.linspace(u.min(), u.max(), columns + 1)
    v_edges = np.linspace(v.max(), v.min(), rows + 1)
    row_names = ROW_NAMES if rows == 3 else tuple(f"row {i + 1}" for i in range(rows))
    names = [f"{r}-{c}" if c else r for r in row_names for c in COLUMN_NAMES[columns]]
    return ZoneGrid(origin, e_u, e_v, u_edges, v_edges, names)


# -------------------------------------------------------------------------- counting
def counted_kinds(point_kind) -> tuple:
    """Which points the zone verdict counts: ``("tie",)``-like kinds, or all.

    Returns
    -------
    (mask, label) : (numpy.ndarray of bool, str)
        Per point whether it is counted; ``"tie points"`` when the block has points that
        are neither road vertices nor control/check points, else ``"all points"``.
    """
    kind = np.char.lower(np.asarray(point_kind).astype(str))
    tie = ~np.isin(kind, _ROAD_KINDS + _CONTROL_KINDS)
    if tie.any():
        return tie, "tie points"
    return np.ones(kind.shape, bool), "all points"


def zone_status(count: int) -> str:
    """``"pass"`` (>= 3), ``"warn"`` (2) or ``"fail"`` (< 2)."""
    return "pass" if count >= ZONE_PASS else ("warn" if count >= ZONE_WARN else "fail")


def _zone_rows(view: BlockView, grid: ZoneGrid, points, xy_ref, counted) -> list:
    """Per zone: counted points, tie, road and control points, status, counted ids."""
    zone = grid.assign(xy_ref) if len(points) else np.zeros(0, np.int64)
    kind = np.char.lower(view.point_kind[points].astype(str))
    road = np.isin(kind, _ROAD_KINDS)
    ctrl = np.isin(kind, _CONTROL_KINDS)
    cnt = counted[points]
    out = []
    for z, name in enumerate(grid.names):
        here = zone == z
        n = int((here & cnt).sum())
        out.append({"zone": name, "count": n, "tie": int((here & ~road & ~ctrl).sum()),
                    "road": int((here & road).sum()), "control": int((here & ctrl).sum()),
                    "status": zone_status(n),
                    "ids": view.point_ids[points[here & cnt]].astype(str).tolist()})
    return out


def _reference_height(view: BlockView, points) -> float:
    z = view.xyz[points, 2] if len(points) else view.xyz[:, 2]
    z = z[np.isfinite(z)]
    return float(np.mean(z)) if z.size else 0.0


def _base_in_photo(view: BlockView, ref: int, a: int, b: int) -> np.ndarray:
    """The object-space base ``C_b - C_a`` as a direction in the photo frame of ``ref``."""
    e = view.eo[ref]
    m = rotation_matrix(e[3], e[4], e[5])
    d = m @ (view.eo[b, :3] - view.eo[a, :3])
    # photo x ~ -f v_x / v_z with v_z < 0 for a downward view: same sign as v_x
    return d[:2] if np.linalg.norm(d[:2]) > 0 else np.array([1.0, 0.0])


def _zones_entry(view: BlockView, images: list, ref_row: int, columns: int,
                 counted: np.ndarray) -> dict:
    """Zones of the overlap of ``images`` in the frame of ``images[ref_row]``."""
    points, obs = view.on_images(images)
    ref = images[ref_row]
    z = _reference_height(view, points)
    others = [i for i in images if i != ref]
    poly = overlap_polygon(view, ref, others, z)
    entry = {"images": [view.image_ids[i] for i in images],
             "reference_image": view.image_ids[ref], "reference_height_m": z,
             "points": int(len(points)), "counted": int(counted[points].sum()),
             "overlap_mm": poly.tolist()}
    if len(poly) < 3:
        entry.update({"zones": [], "status": "fail", "min_count": 0,
                      "note": "the frames do not overlap"})
        return entry
    grid = zone_grid(poly, _base_in_photo(view, ref, images[0], images[-1]),
                     3, columns)
    rows = _zone_rows(view, grid, points, view.obs_xy[obs[ref_row]], counted)
    counts = [r["count"] for r in rows]
    worst = min(counts)
    entry.update({"zones": rows, "min_count": int(worst), "status": zone_status(worst),
                  "zone_corners_mm": grid.corners(),
                  "overlap_area_mm2": float(_area(poly))})
    return entry


def _area(poly: np.ndarray) -> float:
    x, y = poly[:, 0], poly[:, 1]
    return 0.5 * abs(float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y)))


def pair_zones(view: BlockView, left: int, right: int, columns: int = 2,
               counted: Optional[np.ndarray] = None) -> dict:
    """Zone coverage of the stereo pair ``(left, right)`` (image indices).

    Parameters
    ----------
    view : BlockView
    left, right : int
    columns : {2, 3}
        Columns along the base (2: the 6 von Gruber zones).
    counted : numpy.ndarray of bool, optional
        Points counted (default :func:`counted_kinds`).

    Returns
    -------
    dict
        ``images``, ``reference_image`` (the left), ``reference_height_m``, ``points``
        (measured on both), ``counted``, ``overlap_mm`` (polygon), ``zones`` (per zone
        ``zone``, ``count``, ``tie``, ``road``, ``control``, ``status``, ``ids``),
        ``min_count``, ``status`` (of the worst zone), ``zone_corners_mm``,
        ``overlap_area_mm2``.
    """
    if counted is None:
        counted = counted_kinds(view.point_kind)[0]
    return _zones_entry(view, [left, right], 0, columns, counted)


def triplet_zones(view: BlockView, first: int, counted: Optional[np.ndarray] = None) -> dict:
    """Zone coverage (3 rows) of the triple overlap of images ``first .. first + 2``.

    Returns
    -------
    dict
        As :func:`pair_zones`, in the frame of the middle image, counting the points
        measured on all three images.
    """
    if counted is None:
        counted = counted_kinds(view.point_kind)[0]
    return _zones_entry(view, [first, first + 1, first + 2], 1, 1, counted)


# ---------------------------------------------------------------------------- strips
def _angle(a, b) -> float:
    c = float(np.dot(a, b) / (np.linalg.norm(a) * np.linalg.norm(b)))
    return math.degrees(math.acos(max(-1.0, min(1.0, c))))


def image_strips(eo, strip=None, max_turn: float = 45.0, max_jump: float = 2.5) -> np.ndarray:
    """Strip number of every image (0, 1, ... in flight order).

    Parameters
    ----------
    eo : array_like, shape (n, 6)
        Exterior orientation in flight order.
    strip : sequence, optional
        Given labels (e.g. ``[[images]] strip``); renumbered in order of appearance.
    max_turn : float
        Degrees the step between consecutive stations may turn from the strip's first
        step.
    max_jump : float
        A step longer than this times the median step starts a new strip.

    Returns
    -------
    numpy.ndarray of int, shape (n,)
    """
    eo = np.asarray(eo, float).reshape(-1, 6)
    n = len(eo)
    if strip is not None:
        labels = [str(s) for s in strip]
        first = {s: None for s in labels}
        order = {s: k for k, s in enumerate(first)}
        return np.array([order[s] for s in labels], np.int64)
    out = np.zeros(n, np.int64)
    if n < 2:
        return out
    steps = np.diff(eo[:, :2], axis=0)
    length = np.hypot(steps[:, 0], steps[:, 1])
    med = float(np.median(length)) if len(length) else 0.0
    direction = None
    for j, (d, ln) in enumerate(zip(steps, length)):
        same = ln > 0 and ln <= max_jump * med and (direction is None
                                                    or _angle(d, direction) <= max_turn)
        out[j + 1] = out[j] if same else out[j] + 1
        direction = (d if direction is None else direction) if same else None
    return out


def _flight_axis(eo: np.ndarray, strips: np.ndarray) -> np.ndarray:
    """Mean flight axis (unit XY vector, sign-free) of the within-strip steps."""
    steps = np.diff(eo[:, :2], axis=0)[np.diff(strips) == 0]
    if not len(steps):
        return np.array([1.0, 0.0])
    ang = 2.0 * np.arctan2(steps[:, 1], steps[:, 0])  # doubled: direction-free
    a = 0.5 * math.atan2(float(np.sin(ang).sum()), float(np.cos(ang).sum()))
    return np.array([math.cos(a), math.sin(a)])


def adjacent_strips(eo, strips) -> list:
    """Pairs of strip numbers next to each other across track.

    Returns
    -------
    list of (int, int)
        Strips sorted by their mean station across the flight axis; consecutive ones, each
        pair as (lower number, higher number).
    """
    eo = np.asarray(eo, float).reshape(-1, 6)
    strips = np.asarray(strips, np.int64)
    axis = _flight_axis(eo, strips)
    across = np.array([-axis[1], axis[0]])
    labels = np.unique(strips)
    pos = [float(np.mean(eo[strips == s, :2] @ across)) for s in labels]
    order = labels[np.argsort(pos, kind="stable")]
    return [(int(min(a, b)), int(max(a, b))) for a, b in zip(order[:-1], order[1:])]


def inter_strip_ties(view: BlockView, strips, counted: Optional[np.ndarray] = None) -> list:
    """Points tying adjacent strips and their vertical parallax.

    Parameters
    ----------
    view : BlockView
    strips : array_like of int, shape (n,)
        Strip of every image (:func:`image_strips`).
    counted : numpy.ndarray of bool, optional
        Points counted for the per-image numbers (default :func:`counted_kinds`).

    Returns
    -------
    list of dict
        Per adjacent strip pair ``strips`` (a, b), ``images`` (ids per strip),
        ``point_ids`` (every point measured in both strips), ``n_points``,
        ``n_counted``, ``per_image`` (image id -> counted linking points on it),
        ``min_per_image``; ``ray_pairs``: ``point_ids`` / ``left`` / ``right`` /
        ``py_mm`` of every pair of rays of those points from images of the two strips.
    """
    strips = np.asarray(strips, np.int64)
    if counted is None:
        counted = counted_kinds(view.point_kind)[0]
    n_pt = len(view.point_ids)
    out = []
    for a, b in adjacent_strips(view.eo, strips):
        in_a = strips[view.obs_image] == a
        in_b = strips[view.obs_image] == b
        on_a = np.bincount(view.obs_point[in_a], minlength=n_pt) > 0
        on_b = np.bincount(view.obs_point[in_b], minlength=n_pt) > 0
        link = on_a & on_b
        per_image = {}
        for img in np.flatnonzero((strips == a) | (strips == b)):
            pts = view.obs_point[view.obs_image == img]
            per_image[view.image_ids[img]] = int((link[pts] & counted[pts]).sum())
        out.append({
            "strips": (int(a), int(b)),
            "images": [[view.image_ids[i] for i in np.flatnonzero(strips == s)] for s in (a, b)],
            "point_ids": view.point_ids[link].astype(str).tolist(),
            "n_points": int(link.sum()), "n_counted": int((link & counted).sum()),
            "per_image": per_image,
            "min_per_image": int(min(per_image.values())) if per_image else 0,
            "ray_pairs": _cross_rays(view, link, in_a, in_b),
        })
    return out


def _cross_rays(view: BlockView, link: np.ndarray, in_a: np.ndarray, in_b: np.ndarray) -> dict:
    """Every (strip a ray, strip b ray) pair of the linking points and its parallax."""
    ia = np.flatnonzero(in_a & link[view.obs_point])
    ib = np.flatnonzero(in_b & link[view.obs_point])
    pa, pb = view.obs_point[ia], view.obs_point[ib]
    order = np.argsort(pb, kind="stable")
    ib, pb = ib[order], pb[order]
    lo = np.searchsorted(pb, pa, side="left")
    hi = np.searchsorted(pb, pa, side="right")
    first = np.repeat(ia, hi - lo)
    idx = (np.concatenate([np.arange(s, e) for s, e in zip(lo, hi)]) if len(lo)
           else np.zeros(0, np.int64))
    second = ib[idx.astype(np.int64)]
    if not len(first):
        return {"point_ids": [], "left": [], "right": [], "py_mm": np.zeros(0)}
    py = vertical_parallax(view.obs_xy[first], view.obs_xy[second],
                           view.eo[view.obs_image[first]], view.eo[view.obs_image[second]],
                           view.focal_length, tuple(view.principal_point))
    ids = [view.image_ids[i] for i in range(len(view.image_ids))]
    return {"point_ids": view.point_ids[view.obs_point[first]].astype(str).tolist(),
            "left": [ids[i] for i in view.obs_image[first]],
            "right": [ids[i] for i in view.obs_image[second]], "py_mm": py}
