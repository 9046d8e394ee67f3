"""A run's second process (runner/background.py): the same result as in the
parent, progress forwarded, a failing child falls back to the parent (which raises as
it would have without the child)."""

from __future__ import annotations

import os
import re
import sys

import pytest

from vectoradjust.errors import VectorAdjustError
from vectoradjust.runner.background import Background, gather, workers

fork_only = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="forks on Linux only")


def _work(n, progress=None, parent=None):
    progress(0.5, "half way")
    return {"pid": os.getpid(), "values": list(range(n)), "parent": parent}


def _fails_in_child(parent, progress=None):
    if os.getpid() != parent:
        raise RuntimeError("only in the child")
    return "made in the parent"


def _user_error(progress=None):
    raise VectorAdjustError("a user's mistake", "mend it")


@fork_only
def test_result_and_progress_come_from_the_child(monkeypatch):
    monkeypatch.setenv("VECTORADJUST_WORKERS", "2")
    seen = []
    bg = Background(_work, 5, parent=os.getpid())
    assert bg.forked
    out = bg.result(lambda f, m: seen.append((f, m)))
    assert out["values"] == [0, 1, 2, 3, 4] and out["pid"] != os.getpid()
    assert seen == [(0.5, "half way")] and bg.proc is None


@pytest.mark.parametrize("bad", ["0", "two", "-1", "1.5"])
def test_a_wrong_worker_count_is_a_clear_error(monkeypatch, bad):
    monkeypatch.setenv("VECTORADJUST_WORKERS", bad)
    with pytest.raises(VectorAdjustError, match="VECTORADJUST_WORKERS") as err:
        workers()
    assert "unset it" in err.value.mend


def test_one_worker_runs_in_the_parent(monkeypatch):
    monkeypatch.setenv("VECTORADJUST_WORKERS", "1")
    assert workers() == 1
    bg = Background(_work, 3)
    assert not bg.forked
    assert bg.result()["pid"] == os.getpid()


@fork_only
def test_a_failing_child_is_run_again_in_the_parent(monkeypatch):
    monkeypatch.setenv("VECTORADJUST_WORKERS", "2")
    bg = Background(_fails_in_child, os.getpid())
    assert bg.result() == "made in the parent"
    assert "only in the child" in bg.failure
    bg = Background(_user_error)
    with pytest.raises(VectorAdjustError, match="a user's mistake"):
        bg.result()


@fork_only
@pytest.mark.io
@pytest.mark.slow
def test_adjust_writes_the_same_bands_with_and_without_the_child(sample_dir, tmp_path,
                                                                 monkeypatch):
    pytest.importorskip("geopandas")
    import pyogrio

    from vectoradjust.cli import main

    layers = {}
    for n in ("1", "2", "3"):
        monkeypatch.setenv("VECTORADJUST_WORKERS", n)
        assert main(["adjust", str(sample_dir / "project.toml"), "--out",
                     str(tmp_path / n), "-q"]) == 0
        layers[n] = pyogrio.read_dataframe(tmp_path / n / "adjusted.gpkg",
                                           layer="uncertainty_bands")
        info = pyogrio.read_info(tmp_path / n / "adjusted.gpkg", layer="uncertainty_bands")
        layers[n + "info"] = (info["geometry_type"], list(info["fields"]),
                              list(info["dtypes"]), info["crs"])
    assert layers["1info"] == layers["2info"] == layers["3info"]  # the same layer schema
    assert layers["1info"][0] == "MultiPolygon" and layers["1info"][3] == "EPSG:32616"
    a = layers["1"]
    assert len(a) > 10
    for b in (layers["2"], layers["3"]):  # shares of the features, put back in order
        assert list(a.columns) == list(b.columns) and len(a) == len(b)
        assert a.geometry.geom_equals_exact(b.geometry, 0.0).all()
        assert (a.drop(columns="geometry") == b.drop(columns="geometry")).all().all()
    for name in ("summary.json", "report.html"):  # the report too, written by a child
        assert (_unstamped((tmp_path / "1" / name).read_text(encoding="utf-8"))
                == _unstamped((tmp_path / "2" / name).read_text(encoding="utf-8")))


@fork_only
@pytest.mark.io
def test_bands_of_a_failed_process_are_built_in_the_parent_without_the_factorisation(
        sample_dir, tmp_path, monkeypatch):
    """The parent lets the factorisation go before it writes the layers; a band process
    that fails is run again in the parent from the covariances kept for the bands."""
    pytest.importorskip("geopandas")
    import pyogrio

    from vectoradjust.cli import main
    from vectoradjust.files import derived_outputs as do

    parent, real, calls = os.getpid(), do.uncertainty_bands_file, []

    def flaky(run, *args, **kwargs):
        if os.getpid() != parent:
            raise RuntimeError("a band process failed")
        calls.append(run.result.nep_obs is None)  # let go before the bands are asked for
        return real(run, *args, **kwargs)

    monkeypatch.setenv("VECTORADJUST_WORKERS", "2")
    assert main(["adjust", str(sample_dir / "project.toml"), "--out", str(tmp_path / "a"),
                 "-q"]) == 0
    monkeypatch.setattr(do, "uncertainty_bands_file", flaky)
    assert main(["adjust", str(sample_dir / "project.toml"), "--out", str(tmp_path / "b"),
                 "-q"]) == 0
    assert calls == [True, True]  # both shares, in the parent, after the release
    a, b = (pyogrio.read_dataframe(tmp_path / x / "adjusted.gpkg", layer="uncertainty_bands")
            for x in "ab")
    assert len(a) == len(b) > 10
    assert a.geometry.geom_equals_exact(b.geometry, 0.0).all()
    assert (a.drop(columns="geometry") == b.drop(columns="geometry")).all().all()


def _unstamped(text: str) -> str:
    """A report without the minute it was written in (the runs may be a minute apart)."""
    return re.sub(r"\d{4}-\d\d-\d\d \d\d:\d\d</p>", "</p>", text)


@fork_only
@pytest.mark.slow
def test_report_written_alongside_shows_the_warnings_of_writing(sample_dir, tmp_path,
                                                              monkeypatch):
    """The report's process starts before the layers are written; a warning GDAL gives
    while writing them still reaches the report (the parent writes it again)."""
    pytest.importorskip("geopandas")
    from vectoradjust.cli import main
    from vectoradjust.files import outputs
    from vectoradjust.runner import alongside

    original = outputs._write_layer
    monkeypatch.setattr(outputs.writing, "_write_layer", lambda gdf, path, layer, fmt: original(
        gdf, path, layer, fmt) + [f"a writer's note on {layer}"])
    forked = []
    real = alongside.ReportAlongside.result

    def result(self, progress=None):
        forked.append(self.forked)
        return real(self, progress)

    monkeypatch.setattr(alongside.ReportAlongside, "result", result)
    reports = {}
    for n in ("1", "2"):
        monkeypatch.setenv("VECTORADJUST_WORKERS", n)
        assert main(["adjust", str(sample_dir / "project.toml"), "--out", str(tmp_path / n),
                     "-q", "--no-bands"]) == 0
        reports[n] = _unstamped((tmp_path / n / "report.html").read_text(encoding="utf-8"))
    assert forked == [False, True]  # in the parent with one worker, else in a child
    assert "a writer&#x27;s note on features" in reports["2"]
    assert reports["1"] == reports["2"]


def _many_messages(i, progress=None):
    for k in range(20000):  # far more than a pipe holds if nobody reads
        progress(k / 20000, f"job {i}")
    return i * 10


@fork_only
def test_gather_reads_every_child_as_it_talks(monkeypatch):
    monkeypatch.setenv("VECTORADJUST_WORKERS", "3")
    jobs = [Background(_many_messages, i) for i in range(3)]
    seen = []
    assert gather(jobs, lambda f, m: seen.append(f)) == [0, 10, 20]
    assert all(j.proc is None for j in jobs)
    assert seen == sorted(seen)  # the mean of fractions that only grow


def test_preload_imports_in_a_thread_and_leaves_failures_for_later():
    import sys

    from vectoradjust.runner.background import Preload

    name = "wave"  # a standard module nothing here imports
    sys.modules.pop(name, None)
    p = Preload(["vectoradjust_no_such_module_xyz", name])
    p.wait()  # the failing import ends the thread quietly ...
    assert "vectoradjust_no_such_module_xyz" not in sys.modules
    p = Preload([name])
    p.wait()
    assert name in sys.modules and not p.thread.is_alive()


@pytest.mark.io
def test_band_file_written_chunk_by_chunk_equals_the_frame(tmp_path, monkeypatch):
    """The band file of a share is written as the features are united, a few at a time:
    the same rows, order, attributes and polygons as the frame of the same share."""
    pytest.importorskip("pyarrow")
    import functools

    import numpy as np
    import pyarrow as pa
    import shapely

    from vectoradjust.files import derived_outputs as do
    from vectoradjust.pipeline import run
    from vectoradjust.simulate import make_scenario

    r = run(make_scenario(3).to_project_data())
    monkeypatch.setattr(do, "_union_chunks", functools.partial(do._union_chunks, chunk=7))
    frame = do.uncertainty_bands_frame(r, part=(1, 2))
    path = do.uncertainty_bands_file(r, tmp_path, part=(1, 2))
    table = pa.ipc.open_file(pa.memory_map(path)).read_all()
    assert table.num_rows == len(frame) > 5
    assert len(pa.ipc.open_file(pa.memory_map(path)).get_batch(0)) < len(frame)  # chunks
    for c in ("database", "feature_id", "confidence", "NSeg", "_feature"):
        assert table.column(c).to_pylist() == frame[c].tolist()
    back = shapely.from_wkb(table.column("geometry").to_numpy(zero_copy_only=False))
    assert shapely.equals_exact(back, np.asarray(frame.geometry.values), 0.0).all()


@pytest.mark.io
@pytest.mark.parametrize("n", [2, 3])
def test_band_files_merged_batch_by_batch_equal_the_whole_layer(tmp_path, monkeypatch, n):
    """The parts' files, put in order a few rows at a time (batches that straddle the
    files' own record batches), give the rows, attributes and polygons of the whole layer
    built in one process."""
    pytest.importorskip("pyarrow")
    import functools

    import numpy as np
    import pyarrow as pa
    import shapely

    from vectoradjust.files import derived_outputs as do
    from vectoradjust.pipeline import run
    from vectoradjust.simulate import make_scenario

    r = run(make_scenario(3).to_project_data())
    whole = do.uncertainty_bands_frame(r)
    monkeypatch.setattr(do, "_union_chunks", functools.partial(do._union_chunks, chunk=5))
    paths = [do.uncertainty_bands_file(r, tmp_path, part=(i, n)) for i in range(n)]
    assert all(pa.ipc.open_file(pa.memory_map(p)).num_record_batches > 1 for p in paths)
    monkeypatch.setattr(do, "BAND_BATCH", 4)
    layer = do.merge_band_files(r, [*paths, None])
    assert len(layer) == len(whole) > 8
    for _ in range(2):  # the batches can be asked for again (a second writer)
        got = layer.batches().read_all()
        assert got.column_names == [*do.BAND_FIELDS, "geometry"]
        for c in do.BAND_FIELDS:
            assert got.column(c).to_pylist() == whole[c].tolist()
        back = shapely.from_wkb(got.column("geometry").to_numpy(zero_copy_only=False))
        assert shapely.equals_exact(back, np.asarray(whole.geometry.values), 0.0).all()


def _quick_steps(progress=None):
    for k in range(5):
        progress(k / 5, f"step {k}")
    progress(1.0, "finished")
    return 7


@fork_only
def test_the_last_progress_message_of_a_child_is_not_dropped(monkeypatch):
    """Messages within a second of each other are thinned out, but not the final one."""
    monkeypatch.setenv("VECTORADJUST_WORKERS", "2")
    seen = []
    job = Background(_quick_steps)
    assert job.forked
    assert job.result(lambda f, m="": seen.append((f, m))) == 7
    assert seen[-1] == (1.0, "finished") and len(seen) < 6


def _sample_run(sample_dir):
    from vectoradjust.files.project import load_project
    from vectoradjust.files.readers import load_project_data
    from vectoradjust.pipeline import run

    return run(load_project_data(load_project(sample_dir / "project.toml")))


def _arrow_rows(path):
    import pyarrow as pa

    with pa.OSFile(str(path), "rb") as f:
        return pa.ipc.open_file(f).read_all()


@fork_only
@pytest.mark.io
@pytest.mark.parametrize("saved", [True, False])
def test_the_parent_keeps_the_covariances_the_band_processes_saved(sample_dir, tmp_path,
                                                                  monkeypatch, saved):
    """Each band process saves its share's covariances; the parent then computes none
    (it reads a file only for a process that failed) and builds that share from the file
    after the factorisation is gone: the same bands as the process's. A process that
    could not save them leaves the parent to compute its share's covariances."""
    pytest.importorskip("pyarrow")
    import time

    from vectoradjust.accuracy import derived
    from vectoradjust.files import derived_outputs as do
    from vectoradjust.runner import alongside

    monkeypatch.setenv("VECTORADJUST_WORKERS", "2")
    if not do.arrow_layers():
        pytest.skip("the band processes write Arrow files only with pyarrow and GDAL >= 3.8")
    if not saved:
        def cannot(path, kept):
            raise OSError("disk full")
        monkeypatch.setattr(alongside, "save_covariances", cannot)
    result = _sample_run(sample_dir)
    bands = alongside.BandsAlongside(result, tmp_path / "out")
    assert all(j.forked for j in bands.jobs) and bands.parts == [(0, 2), (1, 2)]
    files = [alongside.covariance_file(bands.folder, p) for p in bands.parts]
    if saved:  # the processes save them first thing: wait for both files
        deadline = time.monotonic() + 120
        while not all(f.is_file() for f in files) and time.monotonic() < deadline:
            time.sleep(0.05)
    made, real = [], derived.segment_covariances
    monkeypatch.setattr(derived, "segment_covariances",
                        lambda run, d, part=(0, 1): made.append(part) or real(run, d, part))
    children = [j.result() for j in bands.jobs]  # the processes' own files
    said = []
    bands.keep(lambda f, m: said.append((f, m)))
    result.result.release_factorisation()
    names = [d.name for d in result.databases]
    if saved:
        assert made == [] and bands.kept == dict(zip(bands.parts, files)) and said == []
    else:
        assert made == [(0, 2)] * len(names) + [(1, 2)] * len(names)
        assert [m for _, m in said] == [  # the time it takes is not silent
            f"uncertainty bands: covariances of the segments (share {i} of 2)" for i in (1, 2)]
        assert not any(f.exists() for f in files)
    for part, child in zip(bands.parts, children):  # as if the process had failed
        here = alongside.band_share(do.uncertainty_bands_file, result, os.getpid(),
                                    bands.kept, part=part, folder=tmp_path)
        a, b = _arrow_rows(child), _arrow_rows(here)
        assert a.num_rows == b.num_rows > 0 and a.equals(b)
    bands.close()
