"""Benchmark: `vectoradjust adjust` on a simulated stereo pair with N shape points.

Run on demand (not part of the test suite):

    python benchmarks/bench_adjust.py --shape-points 100000

Writes a simulated project (OSM- and TNM-like databases; TIGER's 17.5 m bias over
tens of thousands of 10 m priors would outweigh the control, see the simulator's
notes), then times each stage of the headless pipeline: reading, adjustment
(with covariances), statistics, writing. Prints a table and the peak memory.
"""

from __future__ import annotations

import argparse
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--shape-points", type=int, default=100_000)
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--keep", help="directory to keep the project and outputs in")
    args = p.parse_args(argv)

    from vectoradjust.adjust.bundle import adjust  # noqa: F401  (import cost outside the timings)
    from vectoradjust.files.outputs import write_outputs
    from vectoradjust.files.readers import load_project_data
    from vectoradjust.pipeline import run
    from vectoradjust.simulate import make_scenario, write_project

    work = Path(args.keep or tempfile.mkdtemp(prefix="vabench-"))
    t = {}
    t0 = time.perf_counter()
    sc = make_scenario(args.seed, n_shape_points=args.shape_points, databases=("OSM", "TNM"))
    t["simulate"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    write_project(sc, work / "project")
    t["write project"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    data = load_project_data(work / "project" / "project.toml")
    t["read inputs"] = time.perf_counter() - t0
    stages = {}

    def progress(frac, msg):
        stages.setdefault(msg.split(":")[0], time.perf_counter())

    t0 = time.perf_counter()
    r = run(data, progress=progress)
    t["adjust + statistics"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    write_outputs(r, work / "out")
    t["write outputs"] = time.perf_counter() - t0

    # the CLI end to end, as a user runs it
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-m", "vectoradjust.cli", "adjust",
                    str(work / "project" / "project.toml"), "--out", str(work / "out_cli"), "-q"],
                   check=True)
    t["CLI wall time (all stages)"] = time.perf_counter() - t0

    obs = r.summary["observations"]
    print(f"shape points measured: {obs['shape_points']}, image observations: "
          f"{obs['image_coordinates'] // 2}, iterations: {r.result.iterations}, "
          f"sigma0^2: {r.summary['sigma0_squared']:.4f}")
    for k, v in t.items():
        print(f"  {k:28s} {v:8.2f} s")
    first = min(stages.values()) if stages else 0
    for k, v in sorted(stages.items(), key=lambda kv: kv[1]):
        print(f"    stage '{k}' began at +{v - first:6.2f} s")
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"  peak RSS of this process: {rss:.0f} MB")
    print(f"  files in {work}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
