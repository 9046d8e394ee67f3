"""Real true roads: road centrelines from a file or arrays instead of the street grid.

``make_scenario(..., true_roads=...)`` takes the true roads from real road geometry
(:class:`RoadLines`, a sequence of ``(n, 2)`` XY arrays, or the path of a GeoJSON file
read by :func:`read_road_lines`). :func:`_real_roads` snaps vertices closer than 1 mm
into one, splits every line at the vertices it shares with another line (or with
itself), so that intersections are shared vertices of the features, as in the street
grid, and translates the roads so that the centre of their bounding box is the model
centre. Each piece between intersections is one true feature; the road databases are
then sampled from these features exactly as from the grid.

Only numpy, scipy and the standard library are used (the GeoJSON is read with
:mod:`json`), so that the simulator needs no geodata package.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from vectoradjust.errors import ProjectError
from vectoradjust.simulate.roads import _flatten, _TrueRoads

SNAP_TOLERANCE = 1e-3  # m: vertices closer than this are one vertex (an intersection)
CURVED_SINUOSITY = 1.01  # a piece longer than 1.01 x its chord counts as curved


@dataclass(frozen=True)
class RoadLines:
    """Real road centrelines in a projected CRS (metres).

    Attributes
    ----------
    lines : tuple of numpy.ndarray
        ``(n_i, 2)`` XY vertices of every line (a MultiLineString gives one line per part).
    name : tuple
        Street name of every line (str or None).
    highway : tuple
        Road class of every line (an OSM ``highway`` value; str or None).
    source : str or None
        Where the lines come from (recorded in the scenario's options).
    """

    lines: tuple
    name: tuple
    highway: tuple
    source: str | None = None

    @classmethod
    def of(cls, true_roads) -> RoadLines:
        """``true_roads`` as :class:`RoadLines` (a path is read with :func:`read_road_lines`).

        Parameters
        ----------
        true_roads : RoadLines, str, pathlib.Path or sequence of array_like
            The roads; arrays get no name and the highway ``"residential"``.

        Returns
        -------
        RoadLines
        """
        if isinstance(true_roads, RoadLines):
            return true_roads
        if isinstance(true_roads, (str, Path)):
            return read_road_lines(true_roads)
        lines = tuple(np.asarray(c, float).reshape(-1, 2) for c in true_roads)
        return cls(lines, (None,) * len(lines), ("residential",) * len(lines))


def read_road_lines(path: str | Path) -> RoadLines:
    """Read the LineString and MultiLineString features of a GeoJSON file.

    Coordinates are taken as they are (a projected CRS in metres is expected; the
    ``crs`` member is not interpreted); ``name`` and ``highway`` properties are kept.

    Parameters
    ----------
    path : str or pathlib.Path
        GeoJSON FeatureCollection.

    Returns
    -------
    RoadLines
    """
    doc = json.loads(Path(path).read_text(encoding="utf-8"))
    lines, names, highways = [], [], []
    for f in doc.get("features", []):
        geom = f.get("geometry") or {}
        props = f.get("properties") or {}
        if geom.get("type") == "LineString":
            parts = [geom["coordinates"]]
        elif geom.get("type") == "MultiLineString":
            parts = geom["coordinates"]
        else:
            continue
        for p in parts:
            lines.append(np.asarray(p, float)[:, :2])
            names.append(props.get("name"))
            highways.append(props.get("highway"))
    if not lines:
        raise ProjectError(f"{path} has no LineString features",
                           "Give a GeoJSON FeatureCollection of road centrelines")
    return RoadLines(tuple(lines), tuple(names), tuple(highways), source=Path(path).name)


def _snapped_nodes(lines: Sequence[np.ndarray]):
    """Node number of every vertex (vertices within 1 mm are one node) and node XY."""
    xy = np.concatenate(lines)
    pairs = cKDTree(xy).query_pairs(SNAP_TOLERANCE, output_type="ndarray")
    n = len(xy)
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    _, label = connected_components(graph, directed=False)
    # every vertex takes the XY of the first vertex of its cluster
    first = np.full(label.max() + 1, n, np.int64)
    np.minimum.at(first, label, np.arange(n))
    node_xy, node = np.unique(xy[first[label]], axis=0, return_inverse=True)
    return np.asarray(node).reshape(-1), node_xy


def _pieces(node_lines: list) -> list:
    """Split node sequences at their shared nodes: ``(line index, node sequence)`` pieces.

    A node is shared when it occurs more than once in all lines together (an
    intersection, a junction of two ways, a loop's closing node).
    """
    count = np.bincount(np.concatenate(node_lines))
    pieces = []
    for i, seq in enumerate(node_lines):
        cut = np.flatnonzero(count[seq[1:-1]] > 1) + 1
        bounds = np.concatenate([[0], cut, [len(seq) - 1]])
        for a, b in zip(bounds[:-1], bounds[1:]):
            pieces.append((i, seq[a:b + 1]))
    return pieces


def _real_roads(true_roads, center) -> tuple[_TrueRoads, tuple[float, float]]:
    """True roads from real centrelines, translated to ``center``.

    Parameters
    ----------
    true_roads : RoadLines, str, pathlib.Path or sequence of array_like
        See :meth:`RoadLines.of`.
    center : (float, float)
        Model centre the middle of the roads' bounding box is moved to.

    Returns
    -------
    roads : _TrueRoads
        One feature (and part) per piece between shared nodes.
    shift : (float, float)
        The translation added to the input coordinates (m).
    """
    rl = RoadLines.of(true_roads)
    keep = [i for i, c in enumerate(rl.lines) if len(c) >= 2 and np.isfinite(c).all()]
    if not keep:
        raise ProjectError("true_roads has no line with two vertices",
                           "Give road centrelines as (n, 2) XY arrays")
    node, node_xy = _snapped_nodes([rl.lines[i] for i in keep])
    sizes = np.array([len(rl.lines[i]) for i in keep])
    node_lines = []
    for seq in np.split(node, np.cumsum(sizes)[:-1]):
        seq = seq[np.concatenate([[True], np.diff(seq) != 0])]  # drop repeated vertices
        node_lines.append(seq)
    line_of = [k for k, s in zip(keep, node_lines) if len(s) >= 2]
    node_lines = [s for s in node_lines if len(s) >= 2]
    lo, hi = node_xy.min(axis=0), node_xy.max(axis=0)
    shift = np.asarray(center, float) - 0.5 * (lo + hi)
    xy = node_xy + shift
    parts, curved, names, highways = [], [], [], []
    for i, seq in _pieces(node_lines):
        c = xy[seq]
        length = float(np.hypot(*np.diff(c, axis=0).T).sum())
        chord = math.hypot(*(c[-1] - c[0]))
        parts.append(c)
        curved.append(bool(length > CURVED_SINUOSITY * chord))
        names.append(rl.name[line_of[i]])
        highways.append(rl.highway[line_of[i]])
    roads = _flatten(parts, np.arange(len(parts)), curved, names, highways)
    return roads, (float(shift[0]), float(shift[1]))
