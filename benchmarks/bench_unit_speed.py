"""Benchmark: the speed targets that unit tests used to assert with wall-clock times.

Run on demand (not part of the test suite), from the repository root:

    PYTHONPATH=core python benchmarks/bench_unit_speed.py [--repeat 3] [--check]

Rows (median wall time of ``--repeat`` runs, and the range):

* ``ce90 10^6``: :func:`vectoradjust.accuracy.stats.ce90` of 10^6 random 2 x 2
  covariances (the exact CE90's table built before the timing); target < 2 s, about
  0.25 s on the 2-core reference machine. Was ``tests/test_stats.py::
  test_ce90_million_points_fast``.
* ``make_scenario 10^5``: :func:`vectoradjust.simulate.make_scenario` with 100 000 shape
  points (dense mode, seed 1); target < 10 s. Was ``tests/test_simulate.py::
  test_dense_mode_size_and_speed``.

The unit tests keep what is deterministic (shapes, finiteness, sizes, RMSE); only the
times live here. ``--check`` makes the exit status 1 when a median misses its target
(times on a machine shared with other jobs depend on its load: quote them with it).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path
from typing import Callable

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "core"))

from vectoradjust.accuracy import stats as S  # noqa: E402
from vectoradjust.simulate import make_scenario  # noqa: E402

__all__ = ["bench_ce90", "bench_make_scenario", "main"]


def _times(f: Callable[[], object], repeat: int) -> list[float]:
    out = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        f()
        out.append(time.perf_counter() - t0)
    return out


def bench_ce90(repeat: int, n: int = 1_000_000) -> list[float]:
    """Wall times of ``ce90`` on ``n`` random covariances (table built beforehand).

    Parameters
    ----------
    repeat : int
        Number of timed runs.
    n : int, optional
        Number of 2 x 2 covariances.

    Returns
    -------
    list of float
        The wall time of each run, in seconds.
    """
    rng = np.random.default_rng(0)
    a = rng.standard_normal((n, 2, 2))
    cov = a @ a.transpose(0, 2, 1)
    S.ce90(cov[:10])  # build the table outside the timing
    return _times(lambda: S.ce90(cov), repeat)


def bench_make_scenario(repeat: int, n: int = 100_000) -> list[float]:
    """Wall times of ``make_scenario(1, n_shape_points=n)``.

    Parameters
    ----------
    repeat : int
        Number of timed runs.
    n : int, optional
        Number of shape points.

    Returns
    -------
    list of float
        The wall time of each run, in seconds.
    """
    return _times(lambda: make_scenario(1, n_shape_points=n), repeat)


def main(argv=None) -> int:
    """Print the table; with ``--check`` return 1 when a target is missed."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--check", action="store_true", help="exit 1 when a target is missed")
    args = ap.parse_args(argv)

    rows: list[tuple[str, list[float], float]] = [
        ("ce90 10^6", bench_ce90(args.repeat), 2.0),
        ("make_scenario 10^5", bench_make_scenario(args.repeat), 10.0),
    ]
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(f"load average {load:.1f}, median of {args.repeat}")
    print(f"{'row':<20s} {'median s':>9s} {'range s':>14s} {'target s':>9s}  met")
    missed = 0
    for name, times, target in rows:
        med = float(np.median(times))
        ok = med < target
        missed += not ok
        print(f"{name:<20s} {med:9.3f} {min(times):6.3f}-{max(times):<7.3f} {target:9.1f}  "
              f"{'yes' if ok else 'NO'}")
    return 1 if (args.check and missed) else 0


if __name__ == "__main__":
    sys.exit(main())
