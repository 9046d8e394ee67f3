"""Helpers of the QGIS plugin tests: layers as columns, tolerant comparisons."""

import math

import numpy as np

ATOL = 1e-9  # "the same numbers": every compared value agrees to 1e-9


def is_null(v):
    if v is None:
        return True
    try:
        from qgis.PyQt.QtCore import QVariant

        if isinstance(v, QVariant):
            return v.isNull()
    except ImportError:  # pragma: no cover
        pass
    return False


def plain(v):
    """An attribute value as plain Python (None for NULL)."""
    return None if is_null(v) else v


def columns(layer):
    """dict field -> list of values (NULL -> None), in feature order; plus '_geom'."""
    names = layer.fields().names()
    out = {n: [] for n in names}
    out["_geom"] = []
    for f in layer.getFeatures():
        for n, v in zip(names, f.attributes()):
            out[n].append(plain(v))
        out["_geom"].append(f.geometry())
    return out


def reorder(cols, key, order):
    """Columns re-ordered so that ``cols[key]`` follows ``order``."""
    index = {k: i for i, k in enumerate(cols[key])}
    assert len(index) == len(cols[key]), f"{key} is not unique"
    missing = [k for k in order if k not in index]
    assert not missing, f"{key} values missing: {missing[:5]}"
    idx = [index[k] for k in order]
    return {n: [vals[i] for i in idx] for n, vals in cols.items()}


def as_float(values):
    return np.array([np.nan if v is None else float(v) for v in values], float)


def assert_same_values(a, b, name, atol=ATOL):
    """Equal text/ints, floats within ``atol``, NULL/NaN where the other is NULL/NaN."""
    assert len(a) == len(b), f"{name}: {len(a)} values vs {len(b)}"
    numeric = any(isinstance(v, float) for v in list(a) + list(b) if v is not None)
    if numeric:
        x, y = as_float(a), as_float(b)
        nx, ny = np.isnan(x), np.isnan(y)
        assert np.array_equal(nx, ny), f"{name}: nulls differ at {np.flatnonzero(nx != ny)[:5]}"
        if (~nx).any():
            d = np.abs(x[~nx] - y[~nx])
            assert d.max() <= atol, f"{name}: max difference {d.max():.3g} > {atol}"
    else:
        aa = [None if v is None else str(v) for v in a]
        bb = [None if v is None else str(v) for v in b]
        bad = [i for i, (u, v) in enumerate(zip(aa, bb)) if u != v]
        assert not bad, f"{name}: differs at rows {bad[:5]}: {aa[bad[0]]!r} vs {bb[bad[0]]!r}"


def vertices(geom):
    """(n, 3) array of a geometry's vertices (Z NaN for 2D)."""
    pts = [(v.x(), v.y(), v.z()) for v in geom.vertices()]
    return np.array(pts, float).reshape(-1, 3)


def close(a, b, atol=ATOL):
    if a is None or b is None:
        return a is None and b is None
    if isinstance(a, float) and math.isnan(a):
        return isinstance(b, float) and math.isnan(b)
    return abs(float(a) - float(b)) <= atol
