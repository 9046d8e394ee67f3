"""Benchmark: every stage of `vectoradjust adjust` around the solve, per stage.

Run on demand (not part of the test suite):

    python benchmarks/bench_stages.py --shape-points 100000 [--keep DIR] [--project P.toml]

Simulates a stereo pair with N shape points (OSM- and TNM-like databases and the true
centrelines, so the ``[truth]`` buffer test runs; or takes ``--project``), then times in
one process: reading, the pipeline (solve + statistics, reported apart: the solver is
benchmarked by benchmarks/run.py), the ``[truth]`` buffer test, the uncertainty bands,
the other outputs (GeoPackage, summary.json, feature_accuracy.csv), the report. Then
the CLI whole-process with default outputs, its wall time and peak memory (RSS), and
the sizes of summary.json and report.html.
"""

from __future__ import annotations

import argparse
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def _project(args, work: Path) -> Path:
    if args.project:
        return Path(args.project)
    from vectoradjust.simulate import make_scenario, write_project

    sc = make_scenario(args.seed, n_shape_points=args.shape_points, databases=("OSM", "TNM"))
    write_project(sc, work / "project")
    return work / "project" / "project.toml"


class _Clock:
    """Wall and CPU seconds of a stage (CPU time is the fairer figure on a loaded machine)."""

    def __init__(self, times: dict, name: str) -> None:
        self.times, self.name = times, name

    def __enter__(self):
        self.wall, self.cpu = time.perf_counter(), time.process_time()

    def __exit__(self, *exc) -> None:
        self.times[self.name] = (time.perf_counter() - self.wall, time.process_time() - self.cpu)


def _stages(project: Path, out: Path) -> dict:
    from vectoradjust.files.derived_outputs import uncertainty_bands_frame
    from vectoradjust.files.outputs import write_outputs
    from vectoradjust.files.project import load_project
    from vectoradjust.files.readers import load_project_data
    from vectoradjust.files.report import write_report
    from vectoradjust.files.truth import project_truth, truth_buffer
    from vectoradjust.pipeline import run

    t: dict = {}
    with _Clock(t, "read inputs"):
        spec = load_project(project)
        data = load_project_data(spec)
    with _Clock(t, "pipeline: solve + statistics (other branch)"):
        r = run(data)
    truth = project_truth(spec)
    if truth is not None:
        with _Clock(t, "[truth] buffer test"):
            truth_buffer(r, *truth)
    with _Clock(t, "uncertainty bands (built)"):
        uncertainty_bands_frame(r)
    with _Clock(t, "outputs without bands (gpkg, json, csv)"):
        write_outputs(r, out, bands=False)
    with _Clock(t, "report.html"):
        write_report(r, out / "report.html", reliability=r.reliability)
    n = sum(int((d.vertices["Adjusted"] == 1).sum()) for d in r.databases)
    print(f"shape points adjusted: {n}, sigma0^2 {r.summary['sigma0_squared']:.4f}")
    return t


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--shape-points", type=int, default=100_000)
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--project", help="an existing project instead of a simulated one")
    p.add_argument("--keep", help="directory to keep the project and outputs in")
    p.add_argument("--no-stages", action="store_true", help="only the CLI whole-process run")
    args = p.parse_args(argv)
    work = Path(args.keep or tempfile.mkdtemp(prefix="vastages-"))
    work.mkdir(parents=True, exist_ok=True)
    project = _project(args, work)
    times = {} if args.no_stages else _stages(project, work / "out_stages")
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-m", "vectoradjust.cli", "adjust", str(project),
                    "--out", str(work / "out_cli"), "-q"], check=True)
    child = resource.getrusage(resource.RUSAGE_CHILDREN)
    times["CLI whole process (default outputs)"] = (time.perf_counter() - t0,
                                                    child.ru_utime + child.ru_stime)
    rss = child.ru_maxrss / 1024
    print(f"  {'stage':44s} {'wall s':>8s} {'CPU s':>8s}")
    for k, (wall, cpu) in times.items():
        print(f"  {k:44s} {wall:8.2f} {cpu:8.2f}")
    print(f"  CLI peak RSS {rss:.0f} MB")
    for name in ("summary.json", "report.html", "feature_accuracy.csv", "adjusted.gpkg"):
        f = work / "out_cli" / name
        if f.exists():
            print(f"  {name:22s} {os.path.getsize(f) / 1e6:8.2f} MB")
    print(f"  files in {work}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
