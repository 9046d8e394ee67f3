"""The compiled G-band ring kernel (numba, issue 13) against the numpy code.

Truth here is the vectorised numpy construction of :func:`band_kernels.g_band_rings`, which
``tests/test_gband_envelope.py`` checks against the definition of the band (sampled
ellipses, dense envelopes, ``union_all``). The kernel repeats its floating-point
expressions in the same order, so the rings must come out the same point for point.
The kernel is only used where numba is installed: without it (QGIS's Python) the module
is skipped and the numpy code is what runs.
"""

from __future__ import annotations

import sys

import numpy as np
import pytest

from vectoradjust.accuracy.derived import band_kernels

pytest.importorskip("numba")


@pytest.fixture
def kernel(monkeypatch):
    """The compiled kernel for any number of segments."""
    monkeypatch.delenv("VECTORADJUST_NUMBA", raising=False)
    monkeypatch.setattr(band_kernels, "_KERNEL_MIN", 0)
    k = band_kernels._ring_kernel()
    assert k is not None
    return k


def _numpy_rings(monkeypatch, *args, **kwargs):
    with monkeypatch.context() as mp:
        mp.setenv("VECTORADJUST_NUMBA", "0")
        assert band_kernels._ring_kernel() is None
        return band_kernels.g_band_rings(*args, **kwargs)


def _segments(m, seed, scale=0.06, length=(0.8, 2.5)):
    """Segments of random direction with correlated end-point covariances."""
    rng = np.random.default_rng(seed)
    p1 = rng.normal(size=(m, 2)) * 50
    ang = rng.uniform(0, 2 * np.pi, m)
    p2 = p1 + rng.uniform(*length, (m, 1)) * np.column_stack([np.cos(ang), np.sin(ang)])
    a = rng.normal(size=(m, 4, 4)) * scale
    return p1, p2, a @ np.swapaxes(a, 1, 2) + np.eye(4) * scale**2


def _helsinki_segments():
    """Consecutive vertices of the real Helsinki OSM centrelines (tests/data/helsinki,
    ODbL, (c) OpenStreetMap contributors), with covariances like an adjustment's: the
    two end points share most of their error (correlation 0.6 .. 0.95)."""
    from pathlib import Path

    from vectoradjust.simulate import read_road_lines

    lines = read_road_lines(Path(__file__).parent / "data" / "helsinki"
                            / "helsinki_roads.geojson")
    p1 = np.concatenate([np.asarray(c, float)[:-1, :2] for c in lines.lines])
    p2 = np.concatenate([np.asarray(c, float)[1:, :2] for c in lines.lines])
    m = len(p1)
    rng = np.random.default_rng(5)
    own = rng.normal(size=(m, 2, 2)) * 0.3
    own = own @ np.swapaxes(own, 1, 2) + np.eye(2) * 0.01
    rho = rng.uniform(0.6, 0.95, m)[:, None, None]
    c = np.zeros((m, 4, 4))
    c[:, :2, :2] = own
    c[:, 2:, 2:] = own * rng.uniform(0.7, 1.4, (m, 1, 1))
    c[:, :2, 2:] = rho * own
    c[:, 2:, :2] = rho * np.swapaxes(own, 1, 2)
    return p1, p2, c


@pytest.mark.parametrize("n_pairs,n_directions", [(6, 24), (3, 8), (8, 32), (1, 12)])
def test_kernel_rings_equal_the_numpy_rings(kernel, monkeypatch, n_pairs, n_directions):
    p1, p2, c = _segments(3000, n_pairs)
    ref = _numpy_rings(monkeypatch, p1, p2, c, 0.9, n_pairs, n_directions)
    got = band_kernels.g_band_rings(p1, p2, c, 0.9, n_pairs, n_directions)
    assert np.array_equal(got[1], ref[1])
    assert np.array_equal(got[0], ref[0])


def test_kernel_rings_equal_the_numpy_rings_on_real_roads(kernel, monkeypatch):
    p1, p2, c = _helsinki_segments()
    assert len(p1) > 700
    for conf, scale in ((0.9, 1.0), (0.5, 1.0), (0.9, 0.01), (0.9, 100.0)):
        ref = _numpy_rings(monkeypatch, p1, p2, c * scale, conf)
        got = band_kernels.g_band_rings(p1, p2, c * scale, conf)
        assert np.array_equal(got[1], ref[1]) and np.array_equal(got[0], ref[0])


def test_kernel_on_degenerate_segments(kernel, monkeypatch):
    """Zero length, no uncertainty, singular, long and short segments, and inputs that
    are not finite (left to the numpy code, spliced in at their place)."""
    p1, p2, c = _segments(400, 9)
    p2[:20] = p1[:20]  # zero length
    c[20:40] = 0.0  # no uncertainty: the segment itself
    v = np.random.default_rng(2).normal(size=(20, 4, 1))
    c[40:60] = v @ np.swapaxes(v, 1, 2) * 0.01  # rank one
    p2[60:80] = p1[60:80] + 1e-4  # much shorter than the ellipses
    p2[80:100] = p1[80:100] + 5e3  # much longer
    c[100:120] *= 1e6
    c[120:125] = np.nan  # not finite: empty rings
    p1[125:130, 0] = np.inf
    c[130, 1, 1] = -1.0  # not positive (clipped like the numpy code)
    ref = _numpy_rings(monkeypatch, p1, p2, c)
    got = band_kernels.g_band_rings(p1, p2, c)
    assert np.array_equal(got[1], ref[1]) and np.array_equal(got[0], ref[0])
    assert np.all(np.diff(got[1])[120:130] == 0)  # the rows the numpy code took
    c[:] = np.nan  # no row for the kernel: every one from the numpy code
    got = band_kernels.g_band_rings(p1, p2, c)
    assert got[0].shape == (0, 2) and np.array_equal(got[1], np.zeros(401, np.int64))


def test_splice_puts_rings_back_in_row_order():
    xy = np.arange(10.0).reshape(5, 2)  # rows 0 (2 points) and 2 (3 points)
    xy_b = -np.arange(8.0).reshape(4, 2)  # rows 1 (0 points), 3 (4 points)
    ok = np.array([True, False, True, False])
    out, cnt = band_kernels._splice(xy, np.array([2, 0, 3, 0]), ok, xy_b, np.array([0, 0, 4]))
    assert list(cnt) == [2, 0, 3, 4]
    assert np.array_equal(out, np.concatenate([xy[:2], xy[2:], xy_b]))
    none = np.zeros(2, bool)  # every row from the second set
    out, cnt = band_kernels._splice(xy[:0], np.zeros(2, np.int64), none, xy_b, np.array([0, 1, 4]))
    assert list(cnt) == [1, 3] and np.array_equal(out, xy_b[:4])


def test_kernel_reports_progress_per_chunk(kernel, monkeypatch):
    monkeypatch.setattr(band_kernels, "_KERNEL_CHUNK", 64)
    p1, p2, c = _segments(300, 4)
    seen = []
    xy, off = band_kernels.g_band_rings(p1, p2, c, progress=seen.append)
    assert seen == [64 / 300, 128 / 300, 192 / 300, 256 / 300, 1.0]
    ref = _numpy_rings(monkeypatch, p1, p2, c)
    assert np.array_equal(off, ref[1]) and np.array_equal(xy, ref[0])
    xy0, off0 = band_kernels.g_band_rings(p1[:0], p2[:0], c[:0])
    assert xy0.shape == (0, 2) and list(off0) == [0]


def test_kernel_only_for_many_segments_and_loaded_once(monkeypatch):
    monkeypatch.delenv("VECTORADJUST_NUMBA", raising=False)
    monkeypatch.setattr(band_kernels, "_KERNEL", [])  # not looked for yet in this process
    used = []
    real = band_kernels._compiled_rings
    monkeypatch.setattr(band_kernels, "_compiled_rings",
                        lambda *a: used.append(len(a[1])) or real(*a))
    p1, p2, c = _segments(50, 1)
    band_kernels.g_band_rings(p1, p2, c)
    assert used == [] and band_kernels._KERNEL == []  # fewer than _KERNEL_MIN: numpy only
    said = []
    assert not band_kernels.warm_ring_kernel(band_kernels._KERNEL_MIN - 1, said.append)
    assert used == [] and said == []
    assert band_kernels.warm_ring_kernel(band_kernels._KERNEL_MIN, said.append)
    assert used == [1] and len(said) == 1 and "loading" in said[0]  # loaded now, said so
    assert band_kernels.warm_ring_kernel(band_kernels._KERNEL_MIN, said.append)
    assert used == [1] and len(said) == 1  # once
    monkeypatch.setattr(band_kernels, "_KERNEL_MIN", 50)
    band_kernels.g_band_rings(p1, p2, c)
    assert used == [1, 50]


def test_a_kernel_that_fails_leaves_the_numpy_code_with_a_warning(monkeypatch):
    from vectoradjust.accuracy import _bandkernel

    def broken(*args):
        raise RuntimeError("cannot cache function 'rings': no locator available")

    monkeypatch.delenv("VECTORADJUST_NUMBA", raising=False)
    monkeypatch.setattr(band_kernels, "_KERNEL", [])
    monkeypatch.setattr(_bandkernel, "rings", broken)
    with pytest.warns(RuntimeWarning, match="no locator available.*numpy code"):
        assert band_kernels._ring_kernel() is None
    assert band_kernels._KERNEL == [None]
    monkeypatch.setattr(band_kernels, "_KERNEL_MIN", 0)
    p1, p2, c = _segments(40, 3)
    got = band_kernels.g_band_rings(p1, p2, c)
    ref = _numpy_rings(monkeypatch, p1, p2, c)
    assert np.array_equal(got[0], ref[0]) and np.array_equal(got[1], ref[1])


def test_without_numba_the_numpy_code_runs(monkeypatch):
    import sys

    import vectoradjust.accuracy as package

    monkeypatch.setattr(band_kernels, "_KERNEL", [])
    monkeypatch.setitem(sys.modules, "vectoradjust.accuracy._bandkernel", None)
    monkeypatch.delattr(package, "_bandkernel", raising=False)
    assert band_kernels._ring_kernel() is None  # the import failed: numpy, and remembered
    assert band_kernels._KERNEL == [None]
    assert not band_kernels.warm_ring_kernel(10**6)
    monkeypatch.setattr(band_kernels, "_KERNEL", [])
    monkeypatch.delitem(sys.modules, "vectoradjust.accuracy._bandkernel")
    monkeypatch.setenv("VECTORADJUST_NUMBA", "0")
    assert band_kernels._ring_kernel() is None and band_kernels._KERNEL == []
    monkeypatch.delenv("VECTORADJUST_NUMBA")
    assert band_kernels._ring_kernel() is not None


@pytest.mark.io
@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="forks on Linux only")
def test_the_command_line_builds_the_same_bands_with_the_kernel(sample_dir, tmp_path,
                                                                monkeypatch):
    """The kernels (rings and their union) loaded in the parent, then used in the
    forked band processes: the same uncertainty_bands layer as the numpy code and GEOS
    (the same polygons; the union's rings may start at another vertex)."""
    pytest.importorskip("geopandas")
    import os

    import pyogrio
    import shapely

    from vectoradjust.cli import main
    from vectoradjust.files import derived_outputs

    real, real_union = band_kernels._compiled_rings, derived_outputs._kernel_union

    def counted(*args):  # a file per process that used the kernel
        (tmp_path / f"used-{os.getpid()}").touch()
        return real(*args)

    def counted_union(*args):
        (tmp_path / f"union-{os.getpid()}").touch()
        return real_union(*args)

    monkeypatch.setenv("VECTORADJUST_WORKERS", "2")
    monkeypatch.setattr(band_kernels, "_KERNEL_MIN", 0)
    monkeypatch.setattr(band_kernels, "_KERNEL", [])  # to be loaded by the command's parent
    monkeypatch.setattr(band_kernels, "_UNION", [])
    monkeypatch.setattr(band_kernels, "_compiled_rings", counted)
    monkeypatch.setattr(derived_outputs, "_kernel_union", counted_union)
    layers = {}
    for numba in ("1", "0"):
        monkeypatch.setenv("VECTORADJUST_NUMBA", numba)
        out = tmp_path / f"numba{numba}"
        assert main(["adjust", str(sample_dir / "project.toml"), "--out", str(out), "-q"]) == 0
        layers[numba] = pyogrio.read_dataframe(out / "adjusted.gpkg", layer="uncertainty_bands")
        if numba == "1":  # the parent (loading it), the child that looked for it first
            # (KernelsAlongside) and both band processes used it
            assert len(list(tmp_path.glob("used-*"))) == 4
            assert (tmp_path / f"used-{os.getpid()}").exists()
            # in both band processes, and in the parent for the conflated segments (their
            # covariance exists only after the conflation, when the processes have begun)
            unions = list(tmp_path.glob("union-*"))
            assert len(unions) == 3 and (tmp_path / f"union-{os.getpid()}").exists()
    a, b = layers["1"], layers["0"]
    assert len(a) == len(b) > 10
    assert shapely.equals_exact(shapely.normalize(a.geometry.values),
                                shapely.normalize(b.geometry.values), 1e-9).all()
    assert (a.drop(columns="geometry") == b.drop(columns="geometry")).all().all()


@pytest.mark.io
@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="forks on Linux only")
@pytest.mark.slow
def test_the_command_line_compiles_the_kernels_in_a_child_while_it_adjusts(
        sample_dir, tmp_path, monkeypatch):
    """A forked child looks for (the first time: compiles) the band kernels while the
    parent adjusts; only when the bands will use them."""
    pytest.importorskip("geopandas")
    import os

    from vectoradjust.cli import main
    from vectoradjust.runner import alongside

    real = alongside.compile_kernels

    def counted(n, progress=None):  # a file per process that looked for them
        (tmp_path / f"compile-{os.getpid()}").touch()
        return real(n, progress)

    monkeypatch.setattr(alongside, "compile_kernels", counted)
    monkeypatch.setenv("VECTORADJUST_WORKERS", "2")
    monkeypatch.delenv("VECTORADJUST_NUMBA", raising=False)
    project = str(sample_dir / "project.toml")
    # the sample has far fewer segments than _KERNEL_MIN: nothing started
    assert main(["adjust", project, "--out", str(tmp_path / "a"), "-q"]) == 0
    assert not list(tmp_path.glob("compile-*"))
    monkeypatch.setattr(band_kernels, "_KERNEL_MIN", 0)
    monkeypatch.setattr(band_kernels, "_KERNEL", [])
    monkeypatch.setattr(band_kernels, "_UNION", [])
    assert main(["adjust", project, "--out", str(tmp_path / "b"), "-q"]) == 0
    done = list(tmp_path.glob("compile-*"))
    assert len(done) == 1 and done[0].name != f"compile-{os.getpid()}"  # in a child
    assert band_kernels._KERNEL[0] is not None and band_kernels._UNION[0] is not None  # then loaded
    done[0].unlink()
    monkeypatch.setenv("VECTORADJUST_NUMBA", "0")  # switched off: nothing started
    assert main(["adjust", project, "--out", str(tmp_path / "c"), "-q"]) == 0
    assert not list(tmp_path.glob("compile-*"))
