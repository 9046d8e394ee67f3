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


#: buffer-test shares (``in_1m_before``...): the command line measures them with exact round
#: buffers (accuracy/buffer.py, shapely), the plugin with QGIS's polygon buffers, which
#: are narrower on round caps and joins by at most 0.03 % of the width
BUFFER_ATOL = 1e-6


def assert_same_values(a, b, name, atol=ATOL):
    """Equal text/ints, floats within ``atol``, NULL/NaN where the other is NULL/NaN."""
    if name.rsplit(".", 1)[-1].startswith("in_"):
        atol = max(atol, BUFFER_ATOL)
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


def compare_summaries(a, b, path="summary"):
    """Recursive comparison of two summary dicts: numbers to 1e-9, relative for large ones
    (derived quantities such as a suspected blunder of -5814.8 divide by tiny
    redundancy numbers and carry the last digits of the adjustment further)."""
    if isinstance(a, dict):
        assert isinstance(b, dict), path
        keys = set(a) | set(b)
        keys.discard("project")
        # how a layer was read (file, filter, CRS transformation) is the headless
        # reader's; the plugin reads through QGIS
        keys.discard("input")
        keys.discard("control_input")
        for k in keys:
            assert k in a and k in b, f"{path}.{k} missing on one side"
            compare_summaries(a[k], b[k], f"{path}.{k}")
    elif isinstance(a, list):
        assert isinstance(b, list) and len(a) == len(b), path
        for i, (u, v) in enumerate(zip(a, b)):
            compare_summaries(u, v, f"{path}[{i}]")
    elif isinstance(a, bool) or a is None or isinstance(a, str):
        assert a == b, f"{path}: {a!r} vs {b!r}"
    else:
        last = path.rsplit(".", 1)[-1]
        atol = BUFFER_ATOL if (".buffer." in path or last.startswith("in_")) else ATOL
        assert close(a, b, atol * max(1.0, abs(float(b)))), f"{path}: {a!r} vs {b!r}"


def project_copy(sample, path, extra="", drop=()):
    """Write a copy of the sample project file to ``path`` (files named by absolute paths).

    ``extra`` is appended (e.g. a ``[qa]`` table); ``drop`` names ``[[vectors]]`` entries
    to leave out. The data files stay where they are (nothing is written to the repo).
    """
    import json
    import re

    text = (sample / "project.toml").read_text(encoding="utf-8")
    text = re.sub(r'^(\s*(?:path|dem|truth)\s*=\s*)"([^"]+)"',
                  lambda m: m.group(1) + json.dumps(str((sample / m.group(2)).resolve())),
                  text, flags=re.MULTILINE)
    sections, current = [], []
    for line in text.splitlines():
        if line.startswith("[") and current:
            sections.append(current)
            current = []
        current.append(line)
    sections.append(current)
    keep = []
    for sec in sections:
        if sec[0].strip() == "[[vectors]]" and any(
                re.match(rf'\s*name\s*=\s*"{re.escape(n)}"', ln) for ln in sec for n in drop):
            continue
        keep += sec
    path.write_text("\n".join(keep) + "\n" + extra, encoding="utf-8")
    return path
