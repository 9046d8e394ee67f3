"""Faults (issue 31): an interrupted run never leaves a result that looks complete.

Every command writes its run into a hidden staging folder inside ``--out`` and moves the
files into place at the end, ``run_manifest.json`` (every file with its size and SHA-256)
last (:class:`vectoradjust.files.outputs.RunFolder`). Checked here:

- ``vectoradjust adjust`` on the sample killed (SIGKILL) at 20 random moments, half of
  them just after it starts writing a layer of the GeoPackage / a shapefile, the
  summary or the report, into a folder holding a previous complete result: the folder
  holds that previous result, the new complete one, or one that says it is incomplete
  (never files that differ from what its manifest lists); Ctrl-C (SIGINT) leaves the
  previous result and no temporaries; a re-run takes the killed run's lock over;
- a full disk (a small tmpfs; without root, a writer that raises ENOSPC) leaves the
  previous result, byte for byte, and says that the disk is full;
- a second run into a folder that a run is writing into gets a clear error;
- a kill in the middle of moving the files into place leaves a folder that says it is
  incomplete, and the next run cleans it up;
- a re-run in another format removes the previous run's files (files of an older run
  without a manifest are reported);
- ``compare`` with a DEM hole at a measured vertex of one database finishes the others;
- ``adjust-many`` over 50 small projects of which 3 are broken: 47 complete results and
  the 3 named with the reason, exit status 1;
- ``buffer-test`` on layers in a geographic CRS measures in the UTM zone of the data.
"""

from __future__ import annotations

import csv
import errno
import hashlib
import json
import os
import random
import re
import shutil
import signal
import subprocess
import sys
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest

pytest.importorskip("geopandas")
pytestmark = pytest.mark.io

from vectoradjust.cli.commands import main  # noqa: E402
from vectoradjust.errors import InputFileError  # noqa: E402
from vectoradjust.files import outputs  # noqa: E402
from vectoradjust.files.outputs import (  # noqa: E402
    LOCK_NAME,
    MANIFEST,
    DirLock,
    RunFolder,
    read_manifest,
    write_outputs,
)

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "resources" / "sample"
CORE = ROOT / "core"


# ------------------------------------------------------------------------- helpers
def _env() -> dict:
    return dict(os.environ, PYTHONPATH=str(CORE) + os.pathsep + os.environ.get("PYTHONPATH", ""))


def _cli(*args) -> list:
    return [sys.executable, "-m", "vectoradjust", *map(str, args)]


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _files(folder: Path) -> dict:
    """The visible files under ``folder`` (relative POSIX path -> path); hidden ones (the
    lock, a killed run's staging folder) are temporaries, not part of a result."""
    out = {}
    for root, dirs, files in os.walk(folder):
        dirs[:] = [d for d in dirs if not d.startswith(".")]
        for f in files:
            if not f.startswith("."):
                p = Path(root) / f
                out[p.relative_to(folder).as_posix()] = p
    return out


def _state(folder: Path) -> str:
    """``"complete"`` when the manifest says so and lists exactly the files present, with
    their sizes and hashes; ``"incomplete"`` when there is no manifest or it says it is
    incomplete. Anything else (a mix that looks complete) fails the test."""
    doc = read_manifest(folder)
    if doc is None or doc.get("complete") is not True:
        return "incomplete"
    present = _files(folder)
    # (files named like outputs that no manifest claimed are listed as not of the run)
    listed = set(doc["files"]) | {MANIFEST} | set(doc.get("not_of_this_run", []))
    assert set(present) == listed, (
        f"{folder}: files not as the manifest lists them: extra "
        f"{sorted(set(present) - listed)}, missing {sorted(listed - set(present))}")
    for rel, entry in doc["files"].items():
        p = present[rel]
        assert p.stat().st_size == entry["size"], f"{rel}: size differs from the manifest"
        assert _sha256(p) == entry["sha256"], f"{rel}: content differs from the manifest"
    return "complete"


def _hidden(folder: Path) -> list:
    return sorted(p.name for p in folder.iterdir() if p.name.startswith("."))


@pytest.fixture(scope="module")
def baseline(tmp_path_factory) -> Path:
    """A complete result of ``adjust`` on the sample (GeoPackage)."""
    out = tmp_path_factory.mktemp("faults") / "baseline"
    assert main(["adjust", str(SAMPLE / "project.toml"), "-o", str(out), "-q"]) == 0
    assert _state(out) == "complete" and not _hidden(out)
    return out


@pytest.fixture(scope="module")
def tiny(tmp_path_factory) -> Path:
    """A small simulated project (one stereo model, one road database): about a second."""
    from vectoradjust.simulate import make_scenario, write_project

    d = tmp_path_factory.mktemp("tiny")
    return write_project(make_scenario(5, grid=(1, 1), databases=("OSM",), n_control=8,
                                       n_check=2, n_tie=4), d / "project")


@pytest.fixture(scope="module")
def tiny_run(tiny):
    from vectoradjust.files.readers import load_project_data
    from vectoradjust.pipeline import run

    return run(load_project_data(tiny))


def _copy_result(src: Path, dst: Path) -> Path:
    shutil.copytree(src, dst)
    return dst


# ------------------------------------------------------------------ kill at random
class _Trial:
    """``vectoradjust adjust`` on the sample into ``folder``, killed ``delay`` seconds
    after its progress says ``trigger`` (or ``delay`` seconds after the start)."""

    def __init__(self, folder: Path, fmt: str, trigger, delay: float, sig=signal.SIGKILL):
        self.folder, self.fmt, self.trigger, self.delay, self.sig = (folder, fmt, trigger,
                                                                     delay, sig)
        self.log: list = []
        self.seen = threading.Event()
        self.killed = False

    def _read(self, proc) -> None:
        for raw in iter(proc.stdout.readline, b""):
            line = raw.decode("utf-8", "replace")
            self.log.append(line)
            if self.trigger is not None and self.trigger in line:
                self.seen.set()

    def __call__(self) -> _Trial:
        proc = subprocess.Popen(_cli("adjust", SAMPLE / "project.toml", "-o", self.folder,
                                     "--format", self.fmt), env=_env(),
                                stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                start_new_session=True)
        reader = threading.Thread(target=self._read, args=(proc,), daemon=True)
        reader.start()
        try:
            if self.trigger is not None:
                assert self.seen.wait(120), f"never saw {self.trigger!r}: {self.log[-5:]}"
            time.sleep(self.delay)
            if proc.poll() is None:
                if self.sig == signal.SIGINT:  # Ctrl-C: to the whole process group
                    os.killpg(proc.pid, signal.SIGINT)
                else:  # kill -9 PID: the run's own process only
                    proc.send_signal(self.sig)
                self.killed = True
            self.code = proc.wait(120)
            self.state = _state(self.folder)  # before any orphaned child could act
            # after Ctrl-C the run's children end with it (the pipe closes); a SIGKILL
            # leaves them running, holding the pipe
            reader.join(0 if self.sig == signal.SIGKILL else 30)
            self.orphans = reader.is_alive()
            if self.killed and self.sig == signal.SIGKILL:  # the lock died with the run,
                try:  # not held by its children still running
                    DirLock(self.folder, "test").acquire().release()
                    self.lock_free = True
                except InputFileError:
                    self.lock_free = False
        finally:
            try:  # the run's forked children (bands, report) outlive a SIGKILL
                os.killpg(proc.pid, signal.SIGKILL)
            except OSError:
                pass
            reader.join(30)
        return self


#: progress messages of a run's writing: a kill just after one of them must leave the
#: previous result (the new files move into place only after the report)
_WRITING = {"gpkg": ["writing the shape_points layer", "writing the features layer",
                     "writing the control_points layer", "writing the uncertainty_bands layer",
                     "writing truth_points.csv"],
            "shp": ["writing shape_points.shp", "writing features.shp",
                    "writing control_points.shp", "writing uncertainty_bands.shp",
                    "building the features table"]}


@pytest.mark.slow
def test_a_run_killed_at_random_moments_leaves_the_previous_or_an_incomplete_result(
        baseline, tmp_path):
    rng = random.Random(31)
    before = read_manifest(baseline)
    trials = []
    for i in range(20):
        fmt = "gpkg" if i % 2 == 0 else "shp"
        if i < 10:  # while each layer (and a truth table) is written, in both formats
            trigger, delay = _WRITING[fmt][i // 2], rng.uniform(0.0, 0.03)
        else:  # anywhere in the run (reading, adjusting, writing, or after the end)
            trigger, delay = None, rng.uniform(0.5, 8.0)
        trials.append(_Trial(_copy_result(baseline, tmp_path / f"t{i:02d}"), fmt, trigger,
                             delay))
    with ThreadPoolExecutor(2) as pool:  # two at a time: as random, and twice as fast
        done = list(pool.map(lambda t: t(), trials))
    outcomes = []
    for t in done:
        doc = read_manifest(t.folder)
        if t.state == "complete" and doc["started"] == before["started"]:
            assert doc["files"] == before["files"]
            outcome = "previous"
        else:
            outcome = "new" if t.state == "complete" else "incomplete"
        outcomes.append(outcome)
        print(f"{t.folder.name} {t.fmt:4s} {t.trigger or 'at'!s:36s} +{t.delay:.3f} s: "
              f"{outcome} (exit {t.code}, children left running {t.orphans})")
        if t.trigger is not None and outcome != "previous":  # killed late (a loaded machine)
            assert "outputs written" in "".join(t.log), (t.trigger, outcome, t.log[-3:])
        if outcome == "new":  # (finished before the kill, or killed after its commit)
            assert t.code == 0 or t.killed
            assert ("adjusted.gpkg" in doc["files"]) == (t.fmt == "gpkg")
    print("outcomes:", {k: outcomes.count(k) for k in ("previous", "new", "incomplete")})
    # killed while writing: the previous result survives
    assert sum(o == "previous" for o, t in zip(outcomes, done) if t.trigger) >= 8
    assert outcomes.count("previous") >= 10
    killed = [t for t in done if t.killed]
    assert all(t.lock_free for t in killed)
    print(f"killed {len(killed)}; lock free at once, while children of the run still ran: "
          f"{sum(t.orphans for t in killed)}")
    # a re-run into a killed run's folder: its leftovers are removed
    killed = next(t for t in killed if _hidden(t.folder))
    out = subprocess.run(_cli("adjust", SAMPLE / "project.toml", "-o", killed.folder, "-q",
                              "--no-bands", "--format", "shp"),
                         env=_env(), capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    assert _state(killed.folder) == "complete" and not _hidden(killed.folder)
    assert "adjusted.gpkg" not in _files(killed.folder)  # the gpkg run's file is gone


def test_ctrl_c_while_writing_leaves_the_previous_result_and_no_temporaries(baseline,
                                                                             tmp_path):
    # while the band processes build their shares and the main one writes the layers
    t = _Trial(_copy_result(baseline, tmp_path / "c"), "gpkg", "writing the features layer",
               0.02, sig=signal.SIGINT)()
    assert t.killed and t.code == 130, "".join(t.log[-5:])
    assert not t.orphans  # no process of the run left behind
    assert "interrupted" in "".join(t.log)
    assert t.state == "complete"
    assert read_manifest(t.folder) == read_manifest(baseline)
    assert not _hidden(t.folder)  # staging folder and lock removed on the way out


# ----------------------------------------------------------------------- full disk
def _mount_tmpfs(path: Path, kib: int) -> bool:
    if not hasattr(os, "geteuid") or os.geteuid() != 0 or shutil.which("mount") is None:
        return False
    path.mkdir()
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={kib}k", "tmpfs", str(path)],
                          capture_output=True)
    return done.returncode == 0


@pytest.mark.parametrize("free_kib", [60, 1000])  # full in the truth tables / the GeoPackage
def test_a_full_disk_leaves_the_previous_result(baseline, tmp_path, capsys, monkeypatch,
                                                free_kib):
    size = sum(p.stat().st_size for p in _files(baseline).values()) // 1024
    disk = tmp_path / "disk"
    mounted = _mount_tmpfs(disk, size + 8 + free_kib)
    if not mounted:  # no root: the GeoPackage writer finds the disk full
        def full(*args, **kwargs):
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

        monkeypatch.setattr(outputs, "_write_layer", full)
        disk.mkdir(exist_ok=True)
    try:
        out = _copy_result(baseline, disk / "out")
        before = {rel: _sha256(p) for rel, p in _files(out).items()}
        code = main(["adjust", str(SAMPLE / "project.toml"), "-o", str(out), "-q"])
        err = capsys.readouterr().err
        assert code == 1
        assert "The disk of the output directory" in err and "is full" in err, err
        assert "Traceback" not in err and "--out" in err
        assert {rel: _sha256(p) for rel, p in _files(out).items()} == before
        assert _state(out) == "complete" and not _hidden(out)
    finally:
        if mounted:
            subprocess.run(["umount", str(disk)], check=True)


# ---------------------------------------------------------------- two runs at once
_HOLD = """
import sys, time
from vectoradjust.files.outputs import RunFolder
f = RunFolder(sys.argv[1], command="adjust").__enter__()
(f.stage / "half.gpkg").write_bytes(b"half written")
print("locked", flush=True)
time.sleep(120)
"""


def test_a_second_run_into_a_busy_folder_is_refused_and_a_dead_runs_lock_taken_over(
        tiny, tmp_path, capsys):
    out = tmp_path / "out"
    holder = subprocess.Popen([sys.executable, "-c", _HOLD, str(out)], env=_env(),
                              stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "locked"
        assert main(["adjust", str(tiny), "-o", str(out), "-q"]) == 1
        err = capsys.readouterr().err
        assert f"Another vectoradjust run (pid {holder.pid}" in err
        assert repr(str(out)) in err and "--out" in err and "Traceback" not in err
        with pytest.raises(InputFileError, match=rf"pid {holder.pid}, adjust"):
            write_outputs(None, out)  # the API says the same (before touching the run)
    finally:
        holder.kill()
        holder.wait(30)
    # killed: its lock file (with its pid) and half-written staging folder are left ...
    assert LOCK_NAME in _hidden(out) and len(_hidden(out)) == 2
    assert json.loads((out / LOCK_NAME).read_text())["pid"] == holder.pid
    # ... and the next run takes them over
    assert main(["adjust", str(tiny), "-o", str(out), "--no-bands"]) == 0
    said = capsys.readouterr().out
    assert f"(pid {holder.pid}) did not finish" in said
    assert _state(out) == "complete" and not _hidden(out)


def test_two_adjust_runs_into_one_folder_at_once(tiny, tmp_path, capsys):
    out = tmp_path / "out"
    first = subprocess.Popen(_cli("adjust", tiny, "-o", out, "-q"), env=_env(),
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    lock = out / LOCK_NAME
    t0 = time.monotonic()
    while not (lock.is_file() and lock.read_text()) and time.monotonic() - t0 < 60:
        time.sleep(0.01)
    second = main(["adjust", str(tiny), "-o", str(out), "-q"])
    err = capsys.readouterr().err
    _, first_err = first.communicate(timeout=300)
    assert first.returncode == 0, first_err
    assert second == 1 and f"Another vectoradjust run (pid {first.pid}, adjust" in err
    assert _state(out) == "complete" and not _hidden(out)


# ---------------------------------------------------------- the commit interrupted
def test_a_kill_while_the_files_move_into_place_leaves_an_incomplete_folder(
        tiny_run, tmp_path, monkeypatch):
    out = tmp_path / "out"
    write_outputs(tiny_run, out, fmt="shp", bands=False)
    assert _state(out) == "complete"
    real = os.replace
    calls = []

    def killed_after_three(src, dst):
        calls.append(dst)
        if len(calls) > 3:  # the manifest (incomplete), two files: then the kill
            raise KeyboardInterrupt("killed")
        return real(src, dst)

    monkeypatch.setattr(outputs.run_folder.os, "replace", killed_after_three)
    with pytest.raises(KeyboardInterrupt, match="killed"):
        write_outputs(tiny_run, out, fmt="gpkg", bands=False)
    monkeypatch.setattr(outputs.run_folder.os, "replace", real)
    doc = read_manifest(out)
    assert doc["complete"] is False and _state(out) == "incomplete"
    assert "features.shp" in doc["earlier"]
    # the next run knows the files of both, and removes what it does not write
    write_outputs(tiny_run, out, fmt="gpkg", bands=False)
    assert _state(out) == "complete"
    assert not [n for n in _files(out) if n.endswith((".shp", ".dbf", ".shx"))]


# ------------------------------------------------------------- the previous run's files
def test_a_rerun_in_another_format_removes_or_reports_the_old_files(tiny, tiny_run,
                                                                     tmp_path, capsys):
    out = tmp_path / "out"
    write_outputs(tiny_run, out, fmt="shp", bands=False)
    shp = {n for n in _files(out) if n.startswith("features.")}
    assert len(shp) >= 4
    with RunFolder(out) as folder:
        write_outputs(tiny_run, out, fmt="gpkg", bands=False)
        notes = folder.commit()
    assert _state(out) == "complete" and not shp & set(_files(out))
    assert notes[0][0] == "info" and "removed 15 file(s) of the previous run" in notes[0][1]
    assert "control_points.shp" in notes[0][1]
    # an older version's run (no manifest): its files are reported, not removed
    (out / MANIFEST).unlink()
    assert main(["adjust", str(tiny), "-o", str(out), "-q", "--no-bands",
                 "--format", "shp"]) == 0
    err = capsys.readouterr().err
    assert "warning:" in err and "adjusted.gpkg" in err and MANIFEST in err
    assert (out / "adjusted.gpkg").is_file()
    assert _state(out) == "complete"
    doc = read_manifest(out)
    assert doc["not_of_this_run"] == ["adjusted.gpkg"]


def test_a_manifest_never_removes_files_outside_its_folder(tiny_run, tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    victim = tmp_path / "victim.txt"
    victim.write_text("keep me")
    (out / "keep.txt").write_text("also keep me")
    (out / MANIFEST).write_text(json.dumps({
        "written_by": "vectoradjust", "complete": True,
        "files": {"../victim.txt": {"size": 7}, str(victim): {"size": 7},
                  ".vectoradjust.lock": {}, MANIFEST: {}}}))
    write_outputs(tiny_run, out, bands=False)
    assert victim.read_text() == "keep me" and (out / "keep.txt").is_file()


def test_a_failed_run_leaves_no_folder_it_made(tmp_path, capsys):
    out = tmp_path / "new" / "out"
    assert main(["adjust", str(tmp_path / "missing.toml"), "-o", str(out), "-q"]) == 1
    assert "missing.toml" in capsys.readouterr().err
    assert not out.exists()


# ------------------------------------------------------------------------- compare
def _dem_hole(project: Path, database: str, dem_name: str) -> str:
    """A copy of the project's DEM with a hole at a measured vertex of ``database``,
    given to that database; returns the vertex's point id."""
    import numpy as np
    import rasterio

    from vectoradjust.files.readers import load_project_data
    from vectoradjust.pipeline import run

    r = run(load_project_data(project), vectors=[database])
    v = r.databases[0].vertices
    k = int(np.flatnonzero(np.asarray(v["Adjusted"]) == 1)[0])
    x, y = float(v["X"][k]), float(v["Y"][k])
    with rasterio.open(project.parent / "dem.tif") as src:
        profile, z = src.profile, src.read(1)
        row, col = src.index(x, y)
    z[max(row - 3, 0):row + 4, max(col - 3, 0):col + 4] = profile["nodata"]
    with rasterio.open(project.parent / dem_name, "w", **profile) as dst:
        dst.write(z, 1)
    text = project.read_text(encoding="utf-8")
    head, tail = text.split(f'name = "{database}"', 1)
    project.write_text(head + f'name = "{database}"' + tail.replace(
        'dem = "dem.tif"', f'dem = "{dem_name}"', 1), encoding="utf-8")
    return str(v["point_id"][k])


@pytest.mark.slow
def test_compare_finishes_the_other_databases_when_one_has_a_dem_hole(tmp_path, capsys):
    work = tmp_path / "p"
    work.mkdir()
    for p in SAMPLE.iterdir():
        if p.is_file():
            shutil.copy(p, work / p.name)
    _dem_hole(work / "project.toml", "TNM", "dem_tnm.tif")
    out = tmp_path / "out"
    assert main(["compare", str(work / "project.toml"), "-o", str(out), "-q"]) == 1
    captured = capsys.readouterr()
    rows = list(csv.DictReader(open(out / "compare.csv", encoding="utf-8")))
    assert [r["database"] for r in rows] == ["OSM", "TIGER", "TNM"]
    assert all(not r["error"] and int(r["adjusted"]) > 0 for r in rows[:2])
    assert "dem_tnm.tif" in rows[2]["error"] and "measured shape point" in rows[2]["error"]
    assert "1 of 3 databases failed: TNM" in captured.err
    assert "TNM: not adjusted" in captured.out
    assert _state(out) == "complete" and not _hidden(out)
    files = _files(out)
    assert {"OSM/adjusted.gpkg", "OSM/report.html", "TIGER/summary.json", "report.html"} <= \
        set(files)
    assert not [n for n in files if n.startswith("TNM/")]


# -------------------------------------------------------------------- adjust-many
def _many_projects(root: Path, n: int = 50, broken=(6, 22, 40)) -> tuple:
    """``n`` projects sharing one small simulated block's files; three broken: a TOML
    syntax error, a missing measurements file, a DEM hole at a measured vertex."""
    from vectoradjust.simulate import make_scenario, write_project

    base = write_project(make_scenario(7, grid=(1, 1), databases=("OSM",), n_control=8,
                                       n_check=2, n_tie=4), root / "base")
    hole = root / "hole"
    hole.mkdir()
    for p in base.parent.iterdir():
        os.symlink(p, hole / p.name)
    (hole / "project.toml").unlink()
    shutil.copy(base, hole / "project.toml")
    _dem_hole(hole / "project.toml", "OSM", "dem_hole.tif")
    # (no conflation, no truth lines: a third of a second a project)
    fast = "\n[conflation]\nenabled = false\n"
    text = re.sub(r"(?s)\n\[truth\].*$", "\n", base.read_text(encoding="utf-8")) + fast
    projects, why = [], {}
    for i in range(n):
        d = root / f"p{i:02d}"
        d.mkdir()
        src = hole if i == broken[2] else base.parent
        for p in src.iterdir():
            if p.name != "project.toml":
                os.symlink(p.resolve() if p.is_symlink() else p, d / p.name)
        body = text if i != broken[2] else re.sub(
            r"(?s)\n\[truth\].*$", "\n", (hole / "project.toml").read_text(encoding="utf-8")) + fast
        body = re.sub(r'(?m)^name = ".*"$', f'name = "p{i:02d}"', body, count=1)
        if i == broken[0]:
            body = body.replace("[camera]", "[camera", 1)
            why[f"p{i:02d}"] = "project.toml"
        elif i == broken[1]:
            (d / "image_points.csv").unlink()
            why[f"p{i:02d}"] = "image_points.csv"
        elif i == broken[2]:
            why[f"p{i:02d}"] = "dem_hole.tif"
        (d / "project.toml").write_text(body, encoding="utf-8")
        projects.append(d / "project.toml")
    return projects, why


@pytest.mark.slow
def test_adjust_many_finishes_47_of_50_projects_and_names_the_3_broken(tmp_path, capsys):
    pytest.importorskip("dask")
    projects, why = _many_projects(tmp_path / "in")
    out = tmp_path / "out"
    t0 = time.perf_counter()
    code = main(["adjust-many", *map(str, projects), "-o", str(out), "--workers", "2",
                 "--no-bands", "--no-report", "-q"])
    seconds = time.perf_counter() - t0
    err = capsys.readouterr().err
    assert code == 1
    doc = json.loads((out / "many_summary.json").read_text(encoding="utf-8"))
    assert doc["projects"] == 50 and sorted(doc["failed"]) == sorted(why)
    for f in doc["failures"]:
        assert why[f["name"]] in f["error"], f
        assert f["project"].endswith(f"{f['name']}/project.toml")
        assert f"{f['name']} (" in err and why[f["name"]] in err
    assert "3 of 50 projects failed" in err
    complete = [r["name"] for r in doc["rows"] if r["status"] == "ok"]
    assert len(complete) == 47
    for name in complete:
        assert _state(out / name) == "complete" and not _hidden(out / name)
        assert "adjusted.gpkg" in read_manifest(out / name)["files"]
    for name in why:  # nothing that looks like a result
        assert read_manifest(out / name) is None if (out / name).exists() else True
    assert not _hidden(out)  # the lock of DIR let go
    print(f"adjust-many: 50 projects (3 broken) in {seconds:.1f} s")


def test_a_project_that_fails_in_adjust_many_keeps_its_earlier_result(tiny, tmp_path):
    from vectoradjust.files.many import adjust_one

    out = tmp_path / "model"
    assert adjust_one(tiny, out, bands=False, report=False)["status"] == "ok"
    before = read_manifest(out)
    broken = tiny.parent / "broken.toml"  # (beside the project: its files found)
    broken.write_text(tiny.read_text(encoding="utf-8").replace(
        'path = "gcps.csv"', 'path = "no_gcps.csv"'), encoding="utf-8")
    row = adjust_one(broken, out, bands=False, report=False)
    assert row["status"] == "failed" and "no_gcps.csv" in row["error"]
    assert f"the result in {out} is an earlier run's, left as it was" in row["error"]
    assert read_manifest(out) == before and _state(out) == "complete" and not _hidden(out)


# ---------------------------------------------------------------------- buffer-test
def test_buffer_test_measures_geographic_layers_in_the_utm_zone_of_their_centre(tmp_path,
                                                                                capsys):
    import geopandas as gpd

    for name in ("osm_roads", "truth_roads"):
        gpd.read_file(SAMPLE / f"{name}.shp").to_crs(4326).to_file(tmp_path / f"{name}.gpkg")
    args = ["--widths", "1,2,500"]
    assert main(["buffer-test", str(SAMPLE / "osm_roads.shp"), str(SAMPLE / "truth_roads.shp"),
                 *args, "-o", str(tmp_path / "utm.csv")]) == 0
    capsys.readouterr()
    assert main(["buffer-test", str(tmp_path / "osm_roads.gpkg"),
                 str(tmp_path / "truth_roads.gpkg"), *args, "-o",
                 str(tmp_path / "deg.csv")]) == 0
    said = capsys.readouterr().out
    assert "geographic CRS (WGS 84)" in said and "UTM zone 16N (EPSG:32616)" in said
    assert "--crs" in said
    utm = list(csv.DictReader(open(tmp_path / "utm.csv", encoding="utf-8")))
    deg = list(csv.DictReader(open(tmp_path / "deg.csv", encoding="utf-8")))
    for a, b in zip(utm, deg):  # the same lines, there and back through degrees
        assert float(b["share"]) == pytest.approx(float(a["share"]), abs=1e-4)
        assert float(b["length_total"]) == pytest.approx(float(a["length_total"]), rel=1e-6)
    # a CRS given: used; a geographic one given: refused with what to give
    assert main(["buffer-test", str(tmp_path / "osm_roads.gpkg"),
                 str(tmp_path / "truth_roads.gpkg"), *args, "--crs", "EPSG:32616"]) == 0
    assert "note:" not in capsys.readouterr().out
    assert main(["buffer-test", str(tmp_path / "osm_roads.gpkg"),
                 str(tmp_path / "truth_roads.gpkg"), "--crs", "EPSG:4326"]) == 1
    err = capsys.readouterr().err
    assert "--crs 'EPSG:4326' is not a projected CRS in metres" in err and "EPSG:326" in err


def test_utm_zones():
    from vectoradjust.cli.buffer import utm_crs

    assert utm_crs(-86.9, 40.4).to_epsg() == 32616
    assert utm_crs(13.4, 52.5).to_epsg() == 32633
    assert utm_crs(151.2, -33.9).to_epsg() == 32756
    assert utm_crs(179.99, 10.0).to_epsg() == 32660 and utm_crs(-180.0, 10.0).to_epsg() == 32601
    assert utm_crs(0.0, 89.0).to_epsg() == 32661 and utm_crs(0.0, -85.0).to_epsg() == 32761
