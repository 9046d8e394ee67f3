"""Benchmark: `vectoradjust adjust` in this process, with the wall time and the peak memory
of every stage (as its progress messages name them).

Run on demand (not part of the test suite):

    python benchmarks/trace_stages.py PROJECT.toml --out DIR [other adjust options]

A thread samples every 0.2 s the proportional set size (PSS, /proc/PID/smaps_rollup) of
this process plus its forked children (the uncertainty bands' processes), and the last
progress message; the table gives each stage's start, duration and peak memory. Linux
only.
"""

from __future__ import annotations

import os
import sys
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "core"))

import vectoradjust.cli.progress as pg  # noqa: E402

_state = {"msg": "start"}
_orig = pg.ProgressBar.__call__


def _call(self, frac, msg="", *a, **k):
    _state["msg"] = f"{getattr(self, 'label', '')}: {msg}"[:60]
    return _orig(self, frac, msg, *a, **k)


def _pss(pid) -> float:
    try:
        with open(f"/proc/{pid}/smaps_rollup") as f:
            for line in f:
                if line.startswith("Pss:"):
                    return int(line.split()[1]) / 1024
    except OSError:
        pass
    return 0.0


def _memory() -> float:
    try:
        with open(f"/proc/self/task/{os.getpid()}/children") as f:
            kids = f.read().split()
    except OSError:
        kids = []
    return _pss("self") + sum(_pss(k) for k in kids)


def main(argv=None) -> int:
    from vectoradjust.cli import main as cli

    pg.ProgressBar.__call__ = _call
    peak: dict = {}
    first: dict = {}
    t0 = time.perf_counter()

    def sample():
        while True:
            key = _state["msg"][:45]
            peak[key] = max(peak.get(key, 0.0), _memory())
            first.setdefault(key, time.perf_counter() - t0)
            time.sleep(0.2)

    threading.Thread(target=sample, daemon=True).start()
    try:
        return cli(["adjust", *(sys.argv[1:] if argv is None else argv)])
    finally:
        total = time.perf_counter() - t0
        keys = list(first)
        print(f"{'start s':>8s} {'stage s':>8s} {'peak MB':>8s}  stage", file=sys.stderr)
        for i, k in enumerate(keys):
            end = first[keys[i + 1]] if i + 1 < len(keys) else total
            print(f"{first[k]:8.1f} {end - first[k]:8.1f} {peak[k]:8.0f}  {k}", file=sys.stderr)
        print(f"total {total:.1f} s, peak {max(peak.values(), default=0):.0f} MB (PSS)",
              file=sys.stderr)


if __name__ == "__main__":
    sys.exit(main())
