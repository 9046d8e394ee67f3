"""Small runs (issue 32): the fixed costs a user waits for on small projects.

Run on demand (not part of the test suite), from the repository root:

    python benchmarks/small_runs.py                    # every row, 3 times each
    python benchmarks/small_runs.py --repeat 5 --rows pipeline,demo
    python benchmarks/small_runs.py --core OTHER/core  # another checkout (before/after)
    python benchmarks/small_runs.py --no-first         # skip the first-run rows
    python benchmarks/small_runs.py --first-only       # only the first-run rows

Rows (each measurement in its own child process; wall time, and the CPU time of the
child and everything it forked, user + system, from ``RUSAGE_CHILDREN`` of a one-child
wrapper; on a machine shared with other jobs the CPU time depends less on the load):

* ``pipeline.run sample``: :func:`vectoradjust.pipeline.run` on
  ``resources/sample/project.toml`` read once, timed in-process after one warm-up run
  (the median of five runs; the child's own CPU time of those runs). Target 0.3 s.
* ``study gcp sample``: ``vectoradjust study gcp`` with its defaults on the sample.
  Target 5 s.
* ``demo``: ``vectoradjust demo`` (the sample project written and adjusted). Target 6 s.
  The peak is the largest resident set of one process (the parent or a forked one).
* ``adjust pair 10^4``: ``vectoradjust adjust`` with its default outputs on the simulated
  project ``make_scenario(1, n_shape_points=10_000, databases=("OSM", "TNM"))`` (made
  once, in the work directory). Target 1.5 s.
* ``... first run``: the same command as if vectoradjust were just installed: a fresh
  copy of the core directory without bytecode or numba cache, and an empty
  ``NUMBA_CACHE_DIR`` (nothing in the checkout is deleted; the dependencies keep their
  bytecode, as pip compiles it when it installs them). Target: at most 2 s slower than
  warm.

Targets that are missed are marked ``MISSED`` in the last column; ``--check`` exits 1
then.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
CORE = HERE.parent / "core"
SAMPLE = HERE.parent / "resources" / "sample" / "project.toml"

#: one-child wrapper: runs the command, prints wall, CPU (child + descendants) and peak
_WRAP = r"""
import json, resource, subprocess, sys, time
t = time.perf_counter()
rc = subprocess.call(sys.argv[1:], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
wall = time.perf_counter() - t
ru = resource.getrusage(resource.RUSAGE_CHILDREN)
print(json.dumps({"rc": rc, "wall": wall, "cpu": ru.ru_utime + ru.ru_stime,
                  "mb": ru.ru_maxrss / 1024}))
"""

#: in-process pipeline timing on the sample
_PIPELINE = r"""
import json, sys, time
from vectoradjust import pipeline
from vectoradjust.files.readers import load_project_data
data = load_project_data(sys.argv[1])
pipeline.run(data)
walls, cpus = [], []
for _ in range(int(sys.argv[2])):
    t, c = time.perf_counter(), time.process_time()
    pipeline.run(data)
    walls.append(time.perf_counter() - t)
    cpus.append(time.process_time() - c)
print(json.dumps({"walls": walls, "cpus": cpus}))
"""

TARGETS = {"pipeline": 0.3, "gcp": 5.0, "demo": 6.0, "pair": 1.5}
ROWS = ("pipeline", "gcp", "demo", "pair")


def _env(core: Path, first: bool = False, tmp: Path = None) -> dict:
    """The child's environment: ``core`` first on the path; for a first run, a fresh
    copy of ``core`` in ``tmp`` without any ``__pycache__`` (no bytecode, no numba
    cache beside the kernels) and an empty ``NUMBA_CACHE_DIR``: vectoradjust as just
    installed from source (its dependencies keep their compiled bytecode, as pip
    installs them)."""
    env = dict(os.environ)
    if first:
        fresh = Path(tempfile.mkdtemp(prefix="fresh-", dir=tmp)) / "core"
        shutil.copytree(core, fresh, ignore=shutil.ignore_patterns("__pycache__", "*.egg-info"))
        core = fresh
        env["NUMBA_CACHE_DIR"] = tempfile.mkdtemp(prefix="numba-", dir=tmp)
    env["PYTHONPATH"] = str(core) + os.pathsep + env.get("PYTHONPATH", "")
    return env


def _timed(cmd: list, env: dict) -> dict:
    """Wall, CPU and peak of one command (in a one-child wrapper)."""
    out = subprocess.run([sys.executable, "-c", _WRAP, *cmd], env=env, capture_output=True,
                         text=True, check=True)
    rec = json.loads(out.stdout.strip().splitlines()[-1])
    if rec["rc"] != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed (exit {rec['rc']}): {out.stderr[-2000:]}")
    return rec


def _command(row: str, work: Path) -> list:
    """The command line of a row."""
    cli = [sys.executable, "-m", "vectoradjust.cli"]
    if row == "gcp":
        return cli + ["study", "gcp", str(SAMPLE), "-o", str(work / "gcp"), "-q"]
    if row == "demo":
        return cli + ["demo", "-o", str(work / "demo"), "-q"]
    return cli + ["adjust", str(work / "pair_1e4" / "project.toml"), "--out",
                  str(work / "out_pair"), "-q"]


def _pair_project(work: Path, core: Path) -> None:
    """The simulated 10^4 pair, written once (by ``core``)."""
    if (work / "pair_1e4" / "project.toml").exists():
        return
    code = ("import sys; from pathlib import Path; "
            "from vectoradjust.simulate import make_scenario, write_project; "
            "write_project(make_scenario(1, n_shape_points=10000, databases=('OSM', 'TNM')),"
            " Path(sys.argv[1]))")
    subprocess.run([sys.executable, "-c", code, str(work / "pair_1e4")], env=_env(core),
                   check=True)


def _row(row: str, work: Path, core: Path, repeat: int, first: bool) -> dict:
    """Median wall and CPU of ``repeat`` runs of a row (warm, or as a first run)."""
    if row == "pipeline":
        out = subprocess.run([sys.executable, "-c", _PIPELINE, str(SAMPLE), str(max(repeat, 5))],
                             env=_env(core), capture_output=True, text=True, check=True)
        rec = json.loads(out.stdout.strip().splitlines()[-1])
        return {"wall": statistics.median(rec["walls"]), "min": min(rec["walls"]),
                "max": max(rec["walls"]), "cpu": statistics.median(rec["cpus"])}
    if row == "pair":
        _pair_project(work, core)
    if not first:  # one warm-up run: caches filled as after any earlier run
        _timed(_command(row, work), _env(core))
    recs = [_timed(_command(row, work), _env(core, first, work)) for _ in range(repeat)]
    walls = [r["wall"] for r in recs]
    return {"wall": statistics.median(walls), "min": min(walls), "max": max(walls),
            "cpu": statistics.median(r["cpu"] for r in recs), "mb": max(r["mb"] for r in recs)}


def _table(results: dict) -> str:
    """The printed table: one line per row and kind (warm, first run)."""
    lines = ["| row | run | wall s (median) | range s | CPU s | peak MB | target | |",
             "|---|---|---:|---:|---:|---:|---|---|"]
    names = {"pipeline": "pipeline.run sample", "gcp": "study gcp sample", "demo": "demo",
             "pair": "adjust pair 10^4"}
    for (row, kind), r in results.items():
        if kind == "warm":
            target = f"<= {TARGETS[row]:g} s"
            ok = r["wall"] <= TARGETS[row]
        else:
            warm = results.get((row, "warm"))
            target = "<= warm + 2 s"
            ok = warm is not None and r["wall"] <= warm["wall"] + 2.0
        peak = f"{r['mb']:.0f}" if r.get("mb") is not None else "-"
        lines.append(f"| {names[row]} | {kind} | {r['wall']:.2f} | {r['min']:.2f}-{r['max']:.2f} "
                     f"| {r['cpu']:.2f} | {peak} | {target} | {'ok' if ok else 'MISSED'} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    """Time the rows and print the table; exit 1 with ``--check`` when a target is missed."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--core", type=Path, default=CORE, help="core directory to time")
    ap.add_argument("--repeat", type=int, default=3, help="runs per row (median)")
    ap.add_argument("--rows", default=",".join(ROWS), help="comma-separated subset of "
                    + ", ".join(ROWS))
    ap.add_argument("--no-first", action="store_true", help="skip the first-run rows")
    ap.add_argument("--first-only", action="store_true", help="only the first-run rows")
    ap.add_argument("--work", type=Path, default=None, help="work directory (default: temp)")
    ap.add_argument("--json", type=Path, default=None, help="also write the results here")
    ap.add_argument("--check", action="store_true", help="exit 1 when a target is missed")
    a = ap.parse_args(argv)
    work = a.work or Path(tempfile.mkdtemp(prefix="small-runs-"))
    work.mkdir(parents=True, exist_ok=True)
    results = {}
    load = os.getloadavg()  # (the machine's other work: say it with the times)
    for row in [r.strip() for r in a.rows.split(",") if r.strip()]:
        if row not in ROWS:
            ap.error(f"unknown row {row!r}: use {', '.join(ROWS)}")
        kinds = ([] if a.first_only else ["warm"]) + (
            [] if a.no_first or row == "pipeline" else ["first run"])
        for kind in kinds:
            t = time.perf_counter()
            results[(row, kind)] = _row(row, work, a.core.resolve(), a.repeat,
                                        kind == "first run")
            print(f"  {row} ({kind}): {results[(row, kind)]['wall']:.2f} s "
                  f"[{time.perf_counter() - t:.0f} s]", file=sys.stderr, flush=True)
    text = _table(results)
    print(f"core: {a.core.resolve()}\n{text}\nload average (1, 5, 15 min) before: "
          + ", ".join(f"{x:.2f}" for x in load) + "; after: "
          + ", ".join(f"{x:.2f}" for x in os.getloadavg()))
    if a.json:
        a.json.write_text(json.dumps({f"{r}|{k}": v for (r, k), v in results.items()}, indent=1))
    return 1 if a.check and "MISSED" in text else 0


if __name__ == "__main__":
    sys.exit(main())
