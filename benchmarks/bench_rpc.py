"""Benchmark: the RPC sensor model's projection with analytic partials for 10^6 points.

Run on demand (not part of the test suite):

    PYTHONPATH=core python benchmarks/bench_rpc.py [--points 1000000] [--repeat 5]

Builds an RPC00B model with every one of the 20 terms of the four polynomials non-zero
(magnitudes like a real QuickBird-2 RPC's), draws ground points uniformly over its
normalised domain, and times :meth:`vectoradjust.sensor.rpc.RpcModel.project_partials`
(column, row and the 2 x 3 Jacobian of every point): the median of ``--repeat`` runs,
the target being 0.5 s for 10^6 points. Also prints ``project`` and ``localize`` (the
Newton inverse) for the same points, and the largest round-trip error.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "core"))

from vectoradjust.sensor.rpc import RpcModel  # noqa: E402


def _model(seed: int = 1) -> RpcModel:
    """Columns follow longitude, rows the negative latitude, with small terms everywhere."""
    rng = np.random.default_rng(seed)
    small = np.r_[0.0, [1e-2] * 3, [1e-3] * 6, [5e-5] * 10]
    samp = rng.normal(0, 1, 20) * small + np.eye(20)[1]
    line = rng.normal(0, 1, 20) * small - np.eye(20)[2]
    tiny = small * 0.1
    return RpcModel(line_off=5000.0, samp_off=5000.0, lat_off=-33.67, long_off=24.41,
                    height_off=700.0, line_scale=5000.0, samp_scale=5000.0, lat_scale=0.07,
                    long_scale=0.1, height_scale=500.0, line_num=line,
                    line_den=rng.normal(0, 1, 20) * tiny + np.eye(20)[0], samp_num=samp,
                    samp_den=rng.normal(0, 1, 20) * tiny + np.eye(20)[0], source="bench")


def _median_time(f, repeat: int) -> float:
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        f()
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, default=1_000_000)
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args(argv)

    m = _model()
    u = np.random.default_rng(2).uniform(-1, 1, (args.points, 3))
    lon = m.long_off + m.long_scale * u[:, 0]
    lat = m.lat_off + m.lat_scale * u[:, 1]
    h = m.height_off + m.height_scale * u[:, 2]
    m.project_partials(lon[:1000], lat[:1000], h[:1000])   # warm-up

    t_partials = _median_time(lambda: m.project_partials(lon, lat, h), args.repeat)
    t_project = _median_time(lambda: m.project(lon, lat, h), args.repeat)
    xy = m.project(lon, lat, h)
    t0 = time.perf_counter()
    ll = m.localize(xy[:, 0], xy[:, 1], h)
    t_localize = time.perf_counter() - t0
    err = np.abs(ll - np.column_stack([lon, lat])).max()

    print(f"project_partials, {args.points} points: {t_partials:.3f} s "
          f"(median of {args.repeat}; target 0.5 s for 10^6)")
    print(f"project:  {t_project:.3f} s (median of {args.repeat})")
    print(f"localize: {t_localize:.3f} s (once; {int(np.isnan(ll).any(axis=1).sum())} "
          f"not converged, round trip {err:.1e} deg)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
