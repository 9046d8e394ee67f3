"""Quantities between object ids: distance, length and mean height between points
(:class:`DerivedValue`) and the height profile of a feature (:class:`FeatureProfile`).

Heart module: numpy and scipy only.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Optional

import numpy as np

from vectoradjust.accuracy import propagate as prop
from vectoradjust.accuracy.derived.bands import vertex_covariance
from vectoradjust.accuracy.derived.covariance import _adjusted_coords, _identification_variance
from vectoradjust.errors import LayerError, MeasurementError, ProjectError

if TYPE_CHECKING:  # pragma: no cover
    from vectoradjust.results import AdjustmentRun

__all__ = ["DerivedValue", "resolve_points", "distance_between", "length_between",
           "mean_height_between", "FeatureProfile", "profile"]


# --------------------------------------------------------------- quantities between ids
@dataclass
class DerivedValue:
    """A derived quantity with its sigma with and without covariances between points.

    Attributes
    ----------
    quantity : str
        What it is (``"distance 2D"``, ``"length"``, ``"mean height"``).
    value : float
    sigma : float
        With the full covariance of the points.
    sigma_no_cov : float
        With each point's own covariance block only.
    point_ids : list of str
        The ids as given.
    points : numpy.ndarray of int
        Bundle point indices.
    """

    quantity: str
    value: float
    sigma: float
    sigma_no_cov: float
    point_ids: list
    points: np.ndarray

    def to_dict(self) -> dict:
        """JSON-ready dict."""
        return {"quantity": self.quantity, "value": float(self.value),
                "sigma": float(self.sigma), "sigma_no_cov": float(self.sigma_no_cov),
                "ratio": (float(self.sigma / self.sigma_no_cov)
                          if self.sigma_no_cov > 0 else None),
                "point_ids": [str(p) for p in self.point_ids],
                "points": [int(p) for p in self.points]}


def resolve_points(run: AdjustmentRun, ids: Sequence[str]) -> np.ndarray:
    """Bundle point index of each given point id.

    An id may be a control or tie point id, the canonical id of a shape point or the
    id ``<feature id>_<vertex index>`` of any vertex of an object point, optionally
    qualified by its database (``OSM:123_4``).

    Raises
    ------
    MeasurementError
        For an id that is not an adjusted point, or a shape point id that several
        databases share.
    """
    ids = np.asarray([str(i) for i in ids], dtype=object).astype(str)
    from vectoradjust.adjust.shapepoints import lookup

    out = lookup(run.point_ids, ids)
    for i in np.flatnonzero(out < 0):
        pid = str(ids[i])
        found = []
        for d in run.databases:
            q = pid
            if ":" in pid:
                name, _, rest = pid.partition(":")
                if name != d.name:
                    continue
                q = rest
            v = lookup(d.shape.vertex_ids, np.array([q]))[0]
            if v >= 0:
                found.append((d.name, int(d.vertex_point[v])))
        if len(found) > 1:
            raise MeasurementError(
                f"Point id {pid!r} is a shape point id of several road databases "
                f"({', '.join(n for n, _ in found)})",
                f"Qualify it with the database name, e.g. '{found[0][0]}:{pid}'",
            )
        if not found:
            raise MeasurementError(
                f"Point id {pid!r} is not a point of the adjustment (not a control, tie or "
                "shape point id of this project)",
                "Give the id of a measured point: a control or tie point id, or a shape point "
                "id '<feature id>_<vertex index>' (qualified 'NAME:...' if ambiguous)",
            )
        name, p = found[0]
        if p < 0:
            raise MeasurementError(
                f"Shape point {pid!r} of {name} was not measured on the images, so it was not "
                "adjusted and has no covariance",
                "Choose a shape point that was measured (Adjusted = 1 in shape_points)",
            )
        out[i] = p
    return out


def _point_identification(run: AdjustmentRun, points: np.ndarray) -> np.ndarray:
    """Identification variance (p, 3) of bundle points: their database's for shape
    points (the real road vertex, as their CE90), zero for control and tie points."""
    out = np.zeros((len(points), 3))
    kind = np.asarray(getattr(run, "point_kind", []))
    dbname = np.asarray(getattr(run, "point_database", []))
    if len(kind) == 0 or len(points) == 0:
        return out
    for d in run.databases:
        m = (kind[points] == "shape") & (dbname[points].astype(str) == d.name)
        out[m] = _identification_variance(d)
    return out


def _joint(run: AdjustmentRun, points: np.ndarray) -> np.ndarray:
    """Joint covariance ``(3p, 3p)`` of ``points``; a point may be repeated.

    The adjustment's covariance plus the identification error of each shape point
    (independent from point to point, the same for a repeated point): that of the
    points' CE90/LE90.
    """
    pts = np.asarray(points, np.int64).reshape(-1)
    upts, inv = np.unique(pts, return_inverse=True)
    c = run.result.joint_covariance(upts).reshape(len(upts), 3, len(upts), 3)
    idv = _point_identification(run, upts)
    c[np.arange(len(upts)), :, np.arange(len(upts)), :] += idv[:, :, None] * np.eye(3)
    inv = np.asarray(inv).reshape(-1)
    return c[np.ix_(inv, [0, 1, 2], inv, [0, 1, 2])].reshape(3 * len(pts), 3 * len(pts))


def distance_between(run: AdjustmentRun, id_a: str, id_b: str, dims: int = 2) -> DerivedValue:
    """Distance between two adjusted points (2D or 3D) with its sigma.

    ``F = [dx/D, dy/D, (dz/D), -dx/D, ...]`` applied to the joint 6x6 covariance
    (:func:`vectoradjust.accuracy.propagate.distance`).

    Parameters
    ----------
    run : AdjustmentRun
    id_a, id_b : str
        Point ids (see :func:`resolve_points`).
    dims : {2, 3}
    """
    pts = resolve_points(run, [id_a, id_b])
    xyz = run.result.xyz[pts]
    r = prop.distance(xyz[0], xyz[1], _joint(run, pts), dims=dims)
    return DerivedValue(f"distance {dims}D", float(r.value), float(r.sigma),
                        float(r.sigma_no_cov), [id_a, id_b], pts)


def length_between(run: AdjustmentRun, ids: Sequence[str], dims: int = 2) -> DerivedValue:
    """Length of the polyline through the given adjusted points, with its sigma.

    Parameters
    ----------
    run : AdjustmentRun
    ids : sequence of str
        At least two point ids, in order along the line.
    dims : {2, 3}
        Horizontal (default) or 3D length.
    """
    if len(ids) < 2:
        raise MeasurementError("A length needs at least two point ids",
                               "Give the ids of the points in order along the line")
    pts = resolve_points(run, ids)
    r = prop.polyline_length(run.result.xyz[pts], _joint(run, pts), dims=dims)
    return DerivedValue("length" if dims == 2 else "length 3D", float(r.value), float(r.sigma),
                        float(r.sigma_no_cov), list(ids), pts)


def mean_height_between(run: AdjustmentRun, ids: Sequence[str]) -> DerivedValue:
    """Average height of a set of adjusted points, with its sigma."""
    if len(ids) < 1:
        raise MeasurementError("A mean height needs at least one point id",
                               "Give the ids of the points")
    pts = resolve_points(run, ids)
    c = _joint(run, pts)
    iz = 3 * np.arange(len(pts)) + 2
    r = prop.mean_height(run.result.xyz[pts, 2], c[np.ix_(iz, iz)])
    return DerivedValue("mean height", float(r.value), float(r.sigma), float(r.sigma_no_cov),
                        list(ids), pts)


@dataclass
class FeatureProfile:
    """Height profile along one feature of the adjusted geometry (:func:`profile`).

    Per vertex (all vertices of the feature, in order): ``part``, ``chainage``
    (horizontal distance from the start of its part), ``z``, ``sigma_z``,
    ``sigma_chainage`` and ``sigma_chainage_no_cov``, ``adjusted`` (measured or not;
    conflated vertices have their own sigma, vertices without a value are fixed).
    Plus the mean height of the adjusted vertices and the rise (last minus first
    adjusted vertex) with their sigmas with and without covariances.
    """

    database: str
    feature_id: str
    feature: int
    vertex_ids: np.ndarray
    part: np.ndarray
    chainage: np.ndarray
    z: np.ndarray
    sigma_z: np.ndarray
    sigma_chainage: np.ndarray
    sigma_chainage_no_cov: np.ndarray
    adjusted: np.ndarray
    mean_height: Optional[DerivedValue] = None
    rise: Optional[DerivedValue] = None
    extra: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        """JSON-ready dict (NaN as None)."""
        def col(a):
            return [None if (isinstance(v, float) and not np.isfinite(v)) else v
                    for v in np.asarray(a).tolist()]
        return {
            "database": self.database, "feature_id": self.feature_id,
            "vertices": [
                {"point_id": str(i), "part": int(p), "chainage": c, "z": z,
                 "sigma_z": s, "sigma_chainage": sc, "sigma_chainage_no_cov": sn,
                 "adjusted": bool(a)}
                for i, p, c, z, s, sc, sn, a in zip(
                    self.vertex_ids, self.part, col(self.chainage), col(self.z),
                    col(self.sigma_z), col(self.sigma_chainage),
                    col(self.sigma_chainage_no_cov), self.adjusted)],
            "mean_height": self.mean_height.to_dict() if self.mean_height else None,
            "rise": self.rise.to_dict() if self.rise else None,
        }


def _find_feature(run: AdjustmentRun, feature_id: str, database: Optional[str]):
    dbs = run.databases
    if database is not None:
        dbs = [d for d in dbs if d.name == database]
        if not dbs:
            raise ProjectError(
                f"There is no road database named {database!r} in this run",
                f"Use one of: {', '.join(d.name for d in run.databases) or '(none)'}",
            )
    hits = []
    for d in dbs:
        f = np.flatnonzero(d.shape.layer.feature_ids == str(feature_id))
        if f.size:
            hits.append((d, int(f[0])))
    if not hits:
        raise LayerError(
            f"No feature with id {feature_id!r} in "
            + (f"database {database!r}" if database else "the road databases of this run"),
            "Give a feature id of the id field (id_field of the [[vectors]] entry) or a "
            "0-based feature index when the layer has no id field",
        )
    if len(hits) > 1:
        raise LayerError(
            f"Feature id {feature_id!r} exists in several road databases "
            f"({', '.join(d.name for d, _ in hits)})",
            "Name the database (--database NAME)",
        )
    return hits[0]


def profile(run: AdjustmentRun, feature_id: str,
            database: Optional[str] = None) -> FeatureProfile:
    """Height profile along a feature with the sigma of every vertex.

    Each part of the feature is profiled with
    :func:`vectoradjust.accuracy.propagate.height_profile` on the covariance of its
    vertices' CE90/LE90: the joint covariance of the measured ones with their
    identification error (:func:`_joint`), each conflated vertex's own covariance
    (:func:`vertex_covariance`; no covariance between them or with the measured ones),
    vertices without a value fixed. Also the mean height of the measured vertices and
    the rise between the first and last measured vertex.

    Parameters
    ----------
    run : AdjustmentRun
    feature_id : str
        Feature id (the id field's value).
    database : str, optional
        Road database; needed only when the id exists in several.

    Returns
    -------
    FeatureProfile
    """
    db, f = _find_feature(run, feature_id, database)
    layer = db.shape.layer
    verts = np.flatnonzero(layer.vertex_feature == f)
    if verts.size == 0:
        raise LayerError(f"Feature {feature_id!r} of {db.name} has no vertices "
                         f"({layer.problems.get(f, 'empty geometry')})",
                         "Choose a feature with a line geometry")
    adj = _adjusted_coords(run, db)[verts]
    vp = np.asarray(db.vertex_point, np.int64)[verts]
    meas = vp >= 0
    nv = verts.size
    full = np.zeros((nv, 3, nv, 3))
    if meas.any():
        mi = np.flatnonzero(meas)
        full[np.ix_(mi, [0, 1, 2], mi, [0, 1, 2])] = \
            _joint(run, vp[mi]).reshape(mi.size, 3, mi.size, 3)
    vc = vertex_covariance(db)
    conf = np.zeros(nv, bool) if vc is None else (~meas & np.isfinite(vc[verts, 0, 0]))
    if conf.any():  # conflated vertices: their own covariance (as their CE90 / LE90)
        ci = np.flatnonzero(conf)
        full[ci, :, ci, :] = vc[verts[ci]]
    cov = full.reshape(3 * nv, 3 * nv)
    part = layer.vertex_part[verts]
    chain = np.zeros(nv)
    sz = np.zeros(nv)
    sc = np.zeros(nv)
    scn = np.zeros(nv)
    for p in np.unique(part):  # parts of one feature (usually one)
        sel = np.flatnonzero(part == p)
        ci = (3 * sel[:, None] + np.arange(3)).ravel()
        pr = prop.height_profile(adj[sel], cov[np.ix_(ci, ci)])
        chain[sel], sz[sel] = pr.chainage, pr.sigma_z
        sc[sel], scn[sel] = pr.sigma_chainage, pr.sigma_chainage_no_cov
    sz = np.where(meas | conf, sz, np.nan)
    out = FeatureProfile(db.name, str(feature_id), f, db.shape.vertex_ids[verts], part, chain,
                         adj[:, 2].copy(), sz, sc, scn, meas)
    if meas.any():
        mi = np.flatnonzero(meas)
        iz = 3 * mi + 2
        mh = prop.mean_height(adj[mi, 2], cov[np.ix_(iz, iz)])
        ids = list(db.shape.vertex_ids[verts][mi])
        out.mean_height = DerivedValue("mean height", mh.value, mh.sigma, mh.sigma_no_cov,
                                       ids, vp[mi])
        if mi.size >= 2:
            i0, i1 = iz[0], iz[-1]
            c2 = cov[np.ix_([i0, i1], [i0, i1])]
            g = np.array([-1.0, 1.0])
            out.rise = DerivedValue(
                "rise", float(adj[mi[-1], 2] - adj[mi[0], 2]),
                float(np.sqrt(max(g @ c2 @ g, 0.0))),
                float(np.sqrt(max(c2[0, 0] + c2[1, 1], 0.0))),
                [ids[0], ids[-1]], vp[[mi[0], mi[-1]]])
    return out
