"""Benchmark: a county of stereo models through `adjust-many` on a 1- and a 2-worker LocalCluster.

Run on demand (not part of the test suite):

    python benchmarks/bench_county.py                  # scaled down: 20 models x 2x10^4
    python benchmarks/bench_county.py --models 200     # the county of issue 32

Writes N simulated stereo models (``make_scenario`` with seeds 1..N, ``--points`` shape
points each, OSM- and TNM-like databases as in bench_adjust.py; kept in ``--keep`` and
reused when there), then for each worker count (``--workers 1,2``) starts a
``distributed.LocalCluster`` (worker processes, one thread each, ``--memory-limit``
each), imports the package on every worker (the start-up is not the county's), and times
``adjust_many`` on it into a fresh folder with the merged output. Reports per run: wall
time, throughput (models/min), the peak resident memory of each worker process
(``getrusage``; the highest of the worker's life, the warm-up included), each worker's
CPU seconds over the wall time (1.0: a core of its own all along), the merged
files' rows against the sum of the models' (must be equal) and the load average before
and after; then the throughput ratio of the largest worker count to one worker.
``--json`` writes all of it. Bands and report.html are off unless ``--bands``/
``--report`` (the county's layers and summary are what is merged).

The issue's target: 2 workers >= 1.6 x one worker's throughput, <= 1 GB per worker, one
merged output. On a machine others are loading the ratio is meaningless; the load
average is printed so a reader can tell.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path


def _models(root: Path, n: int, points: int) -> list:
    """The project files of ``n`` simulated stereo models (written once, then reused)."""
    from vectoradjust.simulate import make_scenario, write_project

    out = []
    for seed in range(1, n + 1):
        d = root / f"model{seed:03d}_{points}"
        if not (d / "project.toml").is_file():
            write_project(make_scenario(seed, n_shape_points=points,
                                        databases=("OSM", "TNM")), d)
        out.append(d / "project.toml")
    return out


def _peak_rss_mb() -> float:
    """This process's peak resident memory (MB): getrusage, else /proc VmHWM."""
    try:
        import resource

        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    except (ImportError, OSError):
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024.0
    return float("nan")


def _cpu_s() -> float:
    """This process's CPU seconds (user + system)."""
    t = os.times()
    return t.user + t.system


def _warm() -> bool:
    """Import what a project run imports (on a worker: not timed as the county's)."""
    import vectoradjust.files.many  # noqa: F401
    import vectoradjust.files.many_merge  # noqa: F401
    import vectoradjust.runner.project_run  # noqa: F401

    return True


def _merged_rows(out: Path) -> int:
    from pyogrio import list_layers, read_info

    n = 0
    for path in sorted(out.glob("merged_*.gpkg")):
        if "shape_points" in list_layers(path)[:, 0]:
            n += int(read_info(path, layer="shape_points")["features"])
    return n


def run_once(projects: list, out: Path, workers: int, memory_limit: str, bands: bool,
             report: bool) -> dict:
    """``adjust_many`` on a LocalCluster of ``workers`` processes; what it measured."""
    import logging

    from distributed import Client, LocalCluster

    from vectoradjust.files.many import adjust_many

    if out.exists():
        shutil.rmtree(out)
    load0 = os.getloadavg()
    with LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                      memory_limit=memory_limit, dashboard_address=None,
                      silence_logs=logging.ERROR) as cluster, Client(cluster) as client:
        client.run(_warm)
        cpu0 = client.run(_cpu_s)
        t0 = time.perf_counter()
        rows = adjust_many(projects, out, scheduler=client, bands=bands, report=report)
        wall = time.perf_counter() - t0
        cpu = client.run(_cpu_s)
        peaks = sorted(client.run(_peak_rss_mb).values())
    busy = sorted(round((cpu[w] - cpu0[w]) / wall, 2) for w in cpu)
    ok = [r for r in rows if r["status"] == "ok"]
    expected = sum(int(r["shape_points_total"] or 0) for r in ok)
    merged = _merged_rows(out)
    return {"workers": workers, "models": len(projects), "ok": len(ok), "wall_s": round(wall, 1),
            "models_per_min": round(60.0 * len(projects) / wall, 2),
            "peak_worker_mb": [round(p) for p in peaks], "worker_cpu_share": busy,
            "merged_shape_points": merged, "sum_of_models": expected,
            "merged_equals_sum": merged == expected,
            "merged_files": sorted(p.name for p in out.glob("merged_*.gpkg")),
            "load_before": [round(x, 2) for x in load0],
            "load_after": [round(x, 2) for x in os.getloadavg()]}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--models", type=int, default=20, help="stereo models (default 20)")
    p.add_argument("--points", type=int, default=20_000, help="shape points per model")
    p.add_argument("--workers", default="1,2", help="worker counts to run (default 1,2)")
    p.add_argument("--memory-limit", default="2GB", help="Dask memory limit per worker")
    p.add_argument("--bands", action="store_true", help="write the bands layer")
    p.add_argument("--report", action="store_true", help="write report.html")
    p.add_argument("--keep", help="directory for the models and outputs (reused)")
    p.add_argument("--json", help="write the results here")
    args = p.parse_args(argv)

    root = Path(args.keep or tempfile.mkdtemp(prefix="vacounty-"))
    root.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    projects = _models(root / "models", args.models, args.points)
    print(f"{args.models} models x {args.points} shape points in {root / 'models'} "
          f"({time.perf_counter() - t0:.0f} s to write or find); load average "
          f"{os.getloadavg()[0]:.2f} on {os.cpu_count()} cores", flush=True)
    results = []
    for n in (int(w) for w in args.workers.split(",")):
        r = run_once(projects, root / f"out_{n}w", n, args.memory_limit, args.bands,
                     args.report)
        results.append(r)
        print(f"  {n} worker(s): {r['wall_s']:7.1f} s, {r['models_per_min']:6.2f} models/min, "
              f"peak per worker {r['peak_worker_mb']} MB, CPU share per worker "
              f"{r['worker_cpu_share']}, merged {r['merged_shape_points']} "
              f"shape points = sum {r['sum_of_models']}: {r['merged_equals_sum']}, "
              f"{r['ok']}/{r['models']} ok, load {r['load_before'][0]} -> "
              f"{r['load_after'][0]}", flush=True)
    if len(results) > 1 and results[0]["workers"] == 1:
        ratio = results[-1]["models_per_min"] / results[0]["models_per_min"]
        print(f"  throughput {results[-1]['workers']} workers / 1 worker: {ratio:.2f} "
              f"(target >= 1.6 on 2 workers; meaningless on a loaded machine)")
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=2), encoding="utf-8")
    if not args.keep:
        shutil.rmtree(root, ignore_errors=True)
    return 0 if all(r["merged_equals_sum"] and r["ok"] == r["models"] for r in results) else 1


if __name__ == "__main__":
    sys.exit(main())
