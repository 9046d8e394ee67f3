"""Benchmark: the uncertainty bands stage alone (``uncertainty_bands_frame``).

Run on demand (not part of the test suite):

    python benchmarks/bench_bands.py --project P.toml [--core OTHER/core] [--profile out.prof]

Reads the project, runs ``pipeline.run`` (not timed), then times
``files.derived_outputs.uncertainty_bands_frame`` (wall and CPU seconds, peak RSS of the
process) and prints the number of features, segments and ring vertices. ``--core``
puts another checkout's ``core/`` first on ``sys.path`` (before/after on the same
project, back to back).
"""

from __future__ import annotations

import argparse
import resource
import sys
import time
from pathlib import Path


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--project", required=True)
    ap.add_argument("--core", default=str(Path(__file__).resolve().parents[1] / "core"),
                    help="the core/ directory of the checkout to time (default: this one)")
    ap.add_argument("--profile", help="write a cProfile of the stage to this file")
    ap.add_argument("--repeat", type=int, default=1)
    args = ap.parse_args(argv)
    sys.path.insert(0, args.core)
    import vectoradjust
    from vectoradjust.files.derived_outputs import uncertainty_bands_frame
    from vectoradjust.files.project import load_project
    from vectoradjust.files.readers import load_project_data
    from vectoradjust.pipeline import run

    print(f"vectoradjust from {vectoradjust.__file__}")
    r = run(load_project_data(load_project(args.project)))
    rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    for _ in range(args.repeat):
        prof = None
        if args.profile:
            import cProfile

            prof = cProfile.Profile()
            prof.enable()
        w, c = time.perf_counter(), time.process_time()
        frame = uncertainty_bands_frame(r)
        w, c = time.perf_counter() - w, time.process_time() - c
        if prof is not None:
            prof.disable()
            prof.dump_stats(args.profile)
        rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
        nv = int(sum(len(g.exterior.coords) for mp in frame.geometry for g in mp.geoms))
        print(f"bands: wall {w:.2f} s, CPU {c:.2f} s; features {len(frame)}, segments "
              f"{int(frame['NSeg'].sum())}, outer ring vertices {nv}, area "
              f"{frame.geometry.area.sum():.3f} m2; peak RSS {rss:.0f} MB "
              f"(after the pipeline {rss0:.0f} MB)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
