"""Simulated roads: true centrelines and the road databases that sample them.

The true scene is a street grid split at intersections, a curved residential street
and a two-part feature (:func:`_grid_roads`), or, in dense mode, a street grid filling
the stereo overlap (:func:`_dense_roads`, sized by :func:`_dense_scene`); real road
geometry comes from :mod:`~vectoradjust.simulate.real_roads`. Each road
database (:class:`DatabaseModel`, :data:`DATABASES`: OSM, TNM, TIGER) samples the same
roads with its own vertices and positional errors (:func:`_make_database`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from vectoradjust.errors import ProjectError
from vectoradjust.model import LineLayer
from vectoradjust.simulate.geometry import _rng, terrain_height


@dataclass(frozen=True)
class DatabaseModel:
    """Vertex sampling and positional error model of one road database.

    A database vertex is a point of the true centreline; its stored XY is the true XY
    plus ``bias`` (common to the database) plus a systematic shift of its feature
    (magnitude ``N(shift_mean, shift_sd)``, uniformly random direction) plus per-vertex
    noise ``N(0, noise)`` on each axis. A vertex shared by several features (an
    intersection) gets the shift of the first of them and one noise draw, so its
    stored XY is the same in every feature.

    Attributes
    ----------
    name : str
        ``[[vectors]] name``.
    id_field : str
        Name of the feature id field (at most 10 characters, shapefile-safe).
    stem : str
        File name stem: ``<stem>_roads.shp``, ``truth_<stem>.csv``.
    spacing : float
        Nominal vertex spacing along straight roads (m).
    curve_factor : float
        Spacing on curved roads is ``spacing * curve_factor``.
    bias : tuple of float
        Common horizontal offset ``(dx, dy)`` of the database (m).
    shift_mean, shift_sd : float
        Magnitude of the per-feature systematic shift (m).
    noise : float
        Per-vertex noise, standard deviation per axis (m).
    """

    name: str
    id_field: str
    stem: str
    spacing: float
    curve_factor: float
    bias: tuple[float, float]
    shift_mean: float
    shift_sd: float
    noise: float

    @property
    def expected_rmse(self) -> float:
        """Expected horizontal RMSE of the stored vertices against the truth (m)."""
        return math.sqrt(
            self.bias[0] ** 2
            + self.bias[1] ** 2
            + self.shift_mean**2
            + self.shift_sd**2
            + 2.0 * self.noise**2
        )


_TIGER_BIAS = 17.5  # m towards the south-east
DATABASES: dict[str, DatabaseModel] = {
    # dissertation head-to-head RMSE: TNM 2.89 m, OSM 4.35 m, TIGER 19.17 m
    "OSM": DatabaseModel("OSM", "osm_id", "osm", 20.0, 0.4, (0.0, 0.0), 3.0, 0.5, 2.2),
    "TNM": DatabaseModel("TNM", "permanent_", "tnm", 15.0, 0.4, (0.0, 0.0), 1.5, 0.3, 1.75),
    "TIGER": DatabaseModel(
        "TIGER",
        "tlid",
        "tiger",
        30.0,
        0.4,
        (_TIGER_BIAS / math.sqrt(2.0), -_TIGER_BIAS / math.sqrt(2.0)),
        4.0,
        1.0,
        4.5,
    ),
}


def _database_models(databases: Sequence[str | DatabaseModel]) -> list:
    """The error models of ``databases`` (names from :data:`DATABASES` or models)."""
    models = []
    for d in databases:
        if isinstance(d, DatabaseModel):
            models.append(d)
        elif str(d) in DATABASES:
            models.append(DATABASES[str(d)])
        else:
            raise ProjectError(f"unknown simulated database {d!r}",
                               f"Use {', '.join(DATABASES)} or a DatabaseModel")
    if len({m.name for m in models}) != len(models):
        raise ProjectError("a simulated database is named twice", "Give every database once")
    return models


# --- true roads ----------------------------------------------------------------------
@dataclass
class _TrueRoads:
    """True road features as flat arrays: parts are polylines, grouped by feature."""

    coords: np.ndarray  # (m, 2) vertices of all parts
    part_ptr: np.ndarray  # (n_parts + 1,) offsets into coords
    part_feature: np.ndarray  # (n_parts,) feature of each part (non-decreasing)
    part_curved: np.ndarray  # (n_parts,) bool
    name: list  # per feature, str or None
    highway: list  # per feature


def _grid_roads(cx, cy, grid, block, x_west_limit) -> _TrueRoads:
    """The default scene: street grid split at intersections, a curve, a two-part road."""
    n_ew, n_ns = int(grid[0]), int(grid[1])
    ext = 0.4 * block
    ys = cy + (np.arange(n_ew) - (n_ew - 1) / 2.0) * block
    xs = cx + (np.arange(n_ns) - (n_ns - 1) / 2.0) * block
    ew_names = [f"{_ordinal(i + 1)} Street" for i in range(n_ew)]
    ns_names = [f"{t} Avenue" for t in _tree_names(n_ns)]
    parts: list[np.ndarray] = []
    curved: list[bool] = []
    feat_of_part: list[int] = []
    names: list = []
    highways: list = []

    def add(pieces, name, highway, is_curved=False):
        f = len(names)
        names.append(name)
        highways.append(highway)
        for p in pieces:
            parts.append(np.asarray(p, float))
            curved.append(is_curved)
            feat_of_part.append(f)

    mid_ew, mid_ns = n_ew // 2, n_ns // 2
    for i, y in enumerate(ys):
        west = x_west_limit if (i == mid_ew and n_ew > 0) else xs[0] - ext
        stops = np.concatenate([[west], xs, [xs[-1] + ext]])
        hw = "tertiary" if i == mid_ew else "residential"
        for a, b in zip(stops[:-1], stops[1:]):
            add([[[a, y], [b, y]]], ew_names[i], hw)
    for j, x in enumerate(xs):
        stops = np.concatenate([[ys[0] - ext], ys, [ys[-1] + ext]])
        hw = "tertiary" if j == mid_ns else "residential"
        for a, b in zip(stops[:-1], stops[1:]):
            add([[[x, a], [x, b]]], ns_names[j], hw)
    # curved residential street: an S-curve from the east end of the southern street
    # to beyond the east edge of the stereo overlap (its far vertices are not measured)
    t = np.linspace(0.0, 1.0, 461)
    x0, y0 = xs[-1] + ext, ys[0]
    curve = np.column_stack([x0 + 230.0 * t, y0 - 120.0 * t + 35.0 * np.sin(2.0 * np.pi * t)])
    curve[0] = (x0, y0)
    add([curve], "Crescent Drive", "residential", True)
    # a two-part feature (MultiLineString): two parallel parking aisles, unnamed (null)
    ya = ys[0] - ext - 90.0
    xa, xb = cx - 120.0, cx + 60.0
    add([[[xa, ya], [xb, ya]], [[xb, ya - 12.0], [xa, ya - 12.0]]], None, "service")
    return _flatten(parts, feat_of_part, curved, names, highways)


def _dense_roads(x_lo, x_hi, y_lo, y_hi, b) -> _TrueRoads:
    """A street grid with spacing ``b`` filling a rectangle, split at intersections."""
    ys = y_lo + b / 2.0 + b * np.arange(max(1, int((y_hi - y_lo) // b)))
    xs = x_lo + b / 2.0 + b * np.arange(max(1, int((x_hi - x_lo) // b)))
    xstops = np.concatenate([[x_lo], xs, [x_hi]])
    ystops = np.concatenate([[y_lo], ys, [y_hi]])
    ne, nn = len(ys), len(xs)
    # E-W segments: street i, segment k
    ew_a = np.column_stack([np.tile(xstops[:-1], ne), np.repeat(ys, nn + 1)])
    ew_b = np.column_stack([np.tile(xstops[1:], ne), np.repeat(ys, nn + 1)])
    ns_a = np.column_stack([np.repeat(xs, ne + 1), np.tile(ystops[:-1], nn)])
    ns_b = np.column_stack([np.repeat(xs, ne + 1), np.tile(ystops[1:], nn)])
    a = np.concatenate([ew_a, ns_a])
    bb = np.concatenate([ew_b, ns_b])
    nseg = len(a)
    coords = np.empty((2 * nseg, 2))
    coords[0::2] = a
    coords[1::2] = bb
    ew_names = [f"Street {i + 1:03d}" for i in range(ne)]
    ns_names = [f"Avenue {j + 1:03d}" for j in range(nn)]
    names = list(np.repeat(ew_names, nn + 1)) + list(np.repeat(ns_names, ne + 1))
    names = [str(s) for s in names]
    return _TrueRoads(
        coords=coords,
        part_ptr=np.arange(0, 2 * nseg + 1, 2),
        part_feature=np.arange(nseg),
        part_curved=np.zeros(nseg, bool),
        name=names,
        highway=["residential"] * nseg,
    )


def _flatten(parts, feat_of_part, curved, names, highways) -> _TrueRoads:
    sizes = np.array([len(p) for p in parts])
    return _TrueRoads(
        coords=np.concatenate(parts),
        part_ptr=np.concatenate([[0], np.cumsum(sizes)]),
        part_feature=np.asarray(feat_of_part, np.int64),
        part_curved=np.asarray(curved, bool),
        name=names,
        highway=highways,
    )


def _ordinal(n: int) -> str:
    words = ["First", "Second", "Third", "Fourth", "Fifth", "Sixth", "Seventh", "Eighth",
             "Ninth", "Tenth"]
    return words[n - 1] if n <= len(words) else f"{n}th"


def _tree_names(n: int) -> list:
    trees = ["Oak", "Elm", "Maple", "Cedar", "Ash", "Birch", "Walnut", "Cherry", "Pine"]
    return [trees[i] if i < len(trees) else f"Tree {i + 1}" for i in range(n)]


def _part_lengths(roads: _TrueRoads):
    seg = np.hypot(*np.diff(roads.coords, axis=0).T)
    # cumulative arc with a gap of 1 m at every part start keeps parts apart
    d = np.concatenate([[0.0], seg])
    starts = roads.part_ptr[:-1]
    d[starts] = 1.0
    g = np.cumsum(d)
    ends = roads.part_ptr[1:] - 1
    lengths = g[ends] - g[starts]
    return g, lengths


def _sample_roads(roads: _TrueRoads, spacing: float, curve_factor: float,
                  rng: np.random.Generator, jitter: float = 0.3, nseg=None):
    """Vertices of one database: points along every true part.

    ``nseg`` (per part, optional) overrides the number of intervals that ``spacing``
    gives.

    Returns
    -------
    xy : (n, 2) true positions of the sampled vertices
    part : (n,) part index of each vertex
    """
    g, lengths = _part_lengths(roads)
    starts = roads.part_ptr[:-1]
    ends = roads.part_ptr[1:] - 1
    step = spacing * np.where(roads.part_curved, curve_factor, 1.0)
    if nseg is None:
        nseg = np.maximum(1, np.rint(lengths / step)).astype(np.int64)
    nsamp = nseg + 1
    part = np.repeat(np.arange(len(lengths)), nsamp)
    first = np.repeat(np.cumsum(nsamp) - nsamp, nsamp)
    k = np.arange(len(part)) - first
    n_of = nseg[part]
    t = k / n_of
    interior = (k > 0) & (k < n_of)
    t = t + np.where(interior, rng.uniform(-jitter, jitter, len(t)) / n_of, 0.0)
    query = g[starts[part]] + t * lengths[part]
    idx = np.searchsorted(g, query, side="right") - 1
    idx = np.clip(idx, starts[part], np.maximum(ends[part] - 1, starts[part]))
    den = g[idx + 1] - g[idx]
    frac = np.where(den > 0, (query - g[idx]) / np.where(den > 0, den, 1.0), 0.0)
    xy = roads.coords[idx] + frac[:, None] * (roads.coords[idx + 1] - roads.coords[idx])
    # exact end points, so that vertices shared by features have identical coordinates
    xy[k == 0] = roads.coords[starts[part[k == 0]]]
    xy[k == n_of] = roads.coords[ends[part[k == n_of]]]
    return xy, part


def _truth_lines(roads: _TrueRoads, center) -> tuple[list, dict]:
    lines = []
    g, lengths = _part_lengths(roads)
    for p in range(len(lengths)):
        c = roads.coords[roads.part_ptr[p]:roads.part_ptr[p + 1]]
        if len(c) == 2 and lengths[p] > 5.0:
            n = int(math.ceil(lengths[p] / 5.0))
            t = np.linspace(0.0, 1.0, n + 1)[:, None]
            c = c[0] + t * (c[1] - c[0])
            c[-1] = roads.coords[roads.part_ptr[p + 1] - 1]
        z = terrain_height(c[:, 0], c[:, 1], center)
        lines.append(np.column_stack([c, z]))
    part_index = np.arange(len(lengths)) - np.searchsorted(roads.part_feature,
                                                           roads.part_feature, side="left")
    attrs = {
        "road_id": [int(f) + 1 for f in roads.part_feature],
        "part": [int(p) for p in part_index],
        "name": [roads.name[f] for f in roads.part_feature],
        "highway": [roads.highway[f] for f in roads.part_feature],
    }
    return lines, attrs


def _dense_scene(in_x, in_y, n_models: int, n_shape_points: int, block_size: float):
    """Dense mode: a street grid filling the inset overlap with ``n_shape_points`` in all.

    Returns the true roads, the number of vertex intervals of every part and the mean
    vertex spacing (m) they give.
    """
    w, h = in_x[1] - in_x[0], in_y[1] - in_y[0]
    per_block = 8.0  # vertices per block edge
    b = math.sqrt(n_models * 2.0 * w * h * per_block / float(n_shape_points))
    b = float(min(max(b, 2.0), block_size, w, h))
    roads = _dense_roads(in_x[0], in_x[1], in_y[0], in_y[1], b)
    dense_nseg, spacing = _spread_intervals(roads, n_models, n_shape_points)
    return roads, dense_nseg, spacing


def _spread_intervals(roads: _TrueRoads, n_models: int, n_shape_points: int):
    """Vertex intervals of every part for about ``n_shape_points`` object points in all.

    Object points per database = part end points (nodes) + interior vertices; the
    intervals are spread over the parts in proportion to their length, rounding
    cumulatively (at least one per part). Returns the intervals and the mean spacing (m).
    """
    _, lengths = _part_lengths(roads)
    ptr = roads.part_ptr
    ends = np.concatenate([roads.coords[ptr[:-1]], roads.coords[ptr[1:] - 1]])
    n_nodes = len(np.unique(ends, axis=0))
    intervals = max(float(n_shape_points) / n_models - n_nodes, 0.0) + len(lengths)
    ideal = np.cumsum(lengths) * intervals / lengths.sum()
    nseg = np.maximum(1, np.diff(np.concatenate([[0], np.rint(ideal)]))).astype(np.int64)
    return nseg, float(lengths.sum() / nseg.sum())


# --- databases -----------------------------------------------------------------------
_MTFCC = {"tertiary": "S1400", "residential": "S1400", "service": "S1640"}
_ABBREV = (("Street", "St"), ("Avenue", "Ave"), ("Drive", "Dr"))


def _feature_ids(model: DatabaseModel, n: int, rng: np.random.Generator):
    """Feature id values (typed as in the source database) in distinct ranges."""
    steps = rng.integers(1, 90, n)
    if model.stem == "osm":
        return (40_000_000 + int(rng.integers(0, 5_000_000)) + np.cumsum(steps)).astype(np.int64)
    if model.stem == "tiger":
        return (610_000_000 + int(rng.integers(0, 5_000_000)) + np.cumsum(steps)).astype(np.int64)
    if model.stem == "tnm":
        nums = int(rng.integers(0, 10_000)) + np.cumsum(steps)
        return np.char.add("TNM-", np.char.zfill(nums.astype(str), 6)).astype(object)
    nums = np.cumsum(steps)
    return np.char.add(f"{model.stem.upper()}-", nums.astype(str)).astype(object)


def _attributes(model: DatabaseModel, ids, roads: _TrueRoads) -> dict:
    if model.stem == "osm":
        return {"osm_id": [int(v) for v in ids], "name": list(roads.name),
                "highway": list(roads.highway)}
    full = []
    for nm in roads.name:
        if nm is not None and model.stem == "tiger":
            for long, short in _ABBREV:
                nm = nm.replace(long, short)
        full.append(nm)
    mtfcc = [_MTFCC.get(h, "S1400") for h in roads.highway]
    id_values = [int(v) for v in ids] if model.stem == "tiger" else [str(v) for v in ids]
    return {model.id_field: id_values, "fullname": full, "mtfcc": mtfcc}


def _make_database(model: DatabaseModel, roads: _TrueRoads, seed: int, spacing, crs,
                   nseg=None):
    rng = _rng(seed, f"database:{model.name}")
    sp = model.spacing if spacing is None else float(spacing)
    true_xy, part = _sample_roads(roads, sp, model.curve_factor, rng, nseg=nseg)
    feat = roads.part_feature[part]
    n_feat = len(roads.name)
    ids = _feature_ids(model, n_feat, rng)
    # vertex index along the feature (continuing across parts) and part within feature
    feat_first_vertex = np.searchsorted(feat, feat, side="left")
    vertex_index = np.arange(len(feat)) - feat_first_vertex
    first_part_of_feat = np.searchsorted(roads.part_feature, roads.part_feature, side="left")
    vertex_part = part - first_part_of_feat[part]
    # object points: vertices at the same true XY (shared ends) are one point
    _, group_first, group = np.unique(true_xy, axis=0, return_index=True, return_inverse=True)
    group = np.asarray(group).reshape(-1)
    # number the object points in the order of their first vertex
    order = np.argsort(group_first, kind="stable")
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    group = rank[group]
    group_first = group_first[order]
    n_group = len(group_first)
    mag = np.abs(rng.normal(model.shift_mean, model.shift_sd, n_feat))
    ang = rng.uniform(0.0, 2.0 * np.pi, n_feat)
    shift = np.column_stack([mag * np.cos(ang), mag * np.sin(ang)])
    noise = rng.normal(0.0, model.noise, (n_group, 2))
    disp = np.asarray(model.bias, float) + shift[feat[group_first[group]]] + noise[group]
    db_xy = np.round(true_xy + disp, 3)
    fid = np.asarray([str(v) for v in ids], dtype=str)
    point_ids = np.char.add(np.char.add(fid[feat], "_"), vertex_index.astype(str))
    layer = LineLayer(
        name=model.name,
        feature_ids=fid,
        attributes=_attributes(model, ids, roads),
        coords=np.column_stack([db_xy, np.full(len(db_xy), np.nan)]),
        vertex_feature=feat,
        vertex_index=vertex_index,
        vertex_part=vertex_part,
        crs=crs,
        source=f"{model.stem}_roads.shp",
        geometry_type="LineString",
    )
    return layer, point_ids.astype(object).astype(str), true_xy, group, group_first
