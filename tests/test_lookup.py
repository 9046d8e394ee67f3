"""Measured ids matched to the database's vertex ids: the vectorised string lookup and
the ``NAME:`` qualifier, against plain Python definitions."""

from __future__ import annotations

import numpy as np
import pytest

from vectoradjust.adjust import shapepoints
from vectoradjust.adjust.classify import _bare_ids
from vectoradjust.adjust.shapepoints import lookup


def _by_dict(keys, ids):
    first = {}
    for i, k in enumerate(keys):
        first.setdefault(str(k), i)
    return np.array([first.get(str(x), -1) for x in ids], np.int64)


def _ids(rng, n):
    alphabet = list("abc_019:Äß")
    return np.array(["".join(rng.choice(alphabet, rng.integers(0, 9))) for _ in range(n)])


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_lookup_equals_a_dictionary(seed):
    rng = np.random.default_rng(seed)
    keys = np.unique(_ids(rng, 3000))
    rng.shuffle(keys)
    ids = np.concatenate([keys[rng.integers(0, len(keys), 2000)], _ids(rng, 500),
                          np.array(["a" * 30, ""])])  # wider than every key; empty
    assert np.array_equal(lookup(keys, ids), _by_dict(keys, ids))


def test_lookup_with_equal_hashes_falls_back_to_the_strings(monkeypatch):
    keys = np.array(["x_1", "x_2", "y_1"])
    ids = np.array(["y_1", "x_2", "z", "x_1"])
    monkeypatch.setattr(shapepoints, "string_hash", lambda a: np.zeros(len(a), np.uint64))
    assert lookup(keys, ids).tolist() == [2, 1, -1, 0]


def test_lookup_confirms_a_hash_match_on_the_strings(monkeypatch):
    """A measured id whose hash equals a key's but whose text differs is not found."""
    keys = np.array(["k1", "k2"])
    ids = np.array(["k2", "other"])
    monkeypatch.setattr(shapepoints, "string_hash", lambda a: np.array(
        [{"k1": 1, "k2": 2, "other": 2}[str(x)] for x in a], np.uint64))
    assert lookup(keys, ids).tolist() == [1, -1]


def test_bare_ids_cut_this_database_s_qualifier_only():
    ids = np.array(["OSM:12_3", "TNM:4_5", "12_3", "", "OSM:", "OS", "OSM:a:b", "x:y",
                    "OSM:OSM:1", "Ä:1"])
    for name in ("OSM", "TNM", "Ä", "a_very_long_name"):
        bare, other = _bare_ids(ids, name)
        pre = f"{name}:"
        want = [s[len(pre):] if s.startswith(pre) else s for s in ids.tolist()]
        assert bare.tolist() == want
        assert other.tolist() == [(":" in s) and not s.startswith(pre) for s in ids.tolist()]
    bare, other = _bare_ids(np.array([], dtype=str), "OSM")
    assert len(bare) == 0 and len(other) == 0


@pytest.mark.parametrize("chunk", [1, 3, 1 << 16])
def test_string_hash_is_horners_rule_modulo_2_64(chunk):
    """The product form gives the hash of the character loop, in any chunking, for
    empty strings, padding and characters beyond the basic plane."""
    words = ["", "a", "OSM:123:4", "tnm/\u00e9\u00df", "\U0001f600x", "z" * 40, "a\x00b"]
    arr = np.array(words)
    got = shapepoints.string_hash(arr, chunk=chunk)
    width = arr.dtype.itemsize // 4
    for word, h in zip(arr.tolist(), got.tolist()):
        ref = 0
        for ch in word.ljust(width, "\x00"):  # numpy pads with code point 0
            ref = (ref * 1099511628211 + ord(ch)) % (1 << 64)
        assert h == ref
    assert len(set(got.tolist())) == len(set(arr.tolist()))


def test_lookup_does_not_copy_text_ids_it_only_reads():
    """ids given as text of one width are searched as they are (no copy is made)."""
    keys = np.array(["b", "a", "c"])
    ids = np.array(["c", "x", "a"])
    assert shapepoints._as_text(keys) is keys
    assert shapepoints.lookup(keys, ids).tolist() == [2, -1, 1]
    assert shapepoints.lookup(np.array([1, 2, 3]), np.array(["3", "1"])).tolist() == [2, 0]
