"""Speed of automatic transfer (``measure transfer``) from a JPEG of 10^8 pixels (issue 28).

Run:  python benchmarks/bench_transfer.py [--size 10000] [--points 1000] [--quality 30]
      [--repeat 3] [--profile] [--save FILE] [--compare FILE] [--dir /tmp/...]
      [--core OTHER/core] [--set FIELD=VALUE]

A stereo pair of 1500 x 1500 px is rendered (``simulate.measure_scene.stereo_pair``,
hopper texture, seed 1, orientation errors 0.5 m / 0.02 degrees), and each image is
tiled to ``size`` x ``size`` px (the tiles fall on other phases of the 8 x 8 JPEG
grid) and written once as an 8-bit JPEG of ``quality`` into ``--dir``
(default a temporary folder, removed afterwards; never the repository). Both JPEGs are
read with :class:`vectoradjust.files.images.RasterioImage` - what ``measure transfer``
uses: decoded once into a cache at the first read, then every window is a slice. The
``points`` random ground points are transferred L -> R with
:func:`vectoradjust.files.measuring.transfer` (the command's function, with its default
:class:`~vectoradjust.measure.transfer.MatchSettings`: NCC pyramid, LSM, back-matching);
point ``k`` is read from whole tile ``k mod 36`` (6 x 6 for 10^4 px) of the large
images (a reader that offsets the windows by whole tiles), so that the windows come
from all over the 10^8 pixels.

Printed: the decoding (once per image) and, over ``--repeat`` runs after it, the median
wall and CPU (process) time per transfer in milliseconds, the range of the wall time,
the load average (the machine may be shared: the CPU time is the comparable figure),
and a Markdown row for the benchmark table. ``--save FILE`` stores the accepted flags
and positions; ``--compare FILE`` checks that a run gives the same accepted set and
positions (before/after a change). ``--profile`` prints the cProfile of one run.
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np


def _core_dir(argv: list) -> str:
    """The ``core/`` to time: ``--core DIR`` (another checkout, before/after) or this one."""
    if "--core" in argv[:-1]:
        return argv[argv.index("--core") + 1]
    return str(Path(__file__).resolve().parents[1] / "core")


sys.path.insert(0, _core_dir(sys.argv))

from vectoradjust.files.images import RasterioImage  # noqa: E402
from vectoradjust.files.measuring import transfer  # noqa: E402
from vectoradjust.simulate.measure_scene import stereo_pair  # noqa: E402

TILE = 1500


class TileReader:
    """A window reader offset by a whole tile of a large tiled image (``size`` of one
    tile: the transfer's off-image test is the rendered image's)."""

    def __init__(self, reader: RasterioImage, tile: int) -> None:
        self.reader = reader
        self.size = (TILE, TILE)
        self.per_row = reader.size[0] // TILE
        self.set_tile(tile)

    def set_tile(self, tile: int) -> None:
        """Read from tile ``tile`` (row-major over the whole tiles of the large image)."""
        self.dc, self.dr = (tile % self.per_row) * TILE, (tile // self.per_row) * TILE

    def read(self, col0: int, row0: int, width: int, height: int) -> np.ndarray:
        """The window of the current tile."""
        return self.reader.read(col0 + self.dc, row0 + self.dr, width, height)


def write_jpeg(path: Path, img: np.ndarray, size: int, quality: int) -> None:
    """The rendered image tiled to ``size`` x ``size`` px as an 8-bit JPEG."""
    import rasterio

    a = np.clip(np.round(img), 0, 255).astype(np.uint8)
    reps = (size // a.shape[0] + 1, size // a.shape[1] + 1)
    big = np.tile(a, reps)[:size, :size]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # no georeferencing
        with rasterio.open(path, "w", driver="JPEG", width=size, height=size, count=1,
                           dtype="uint8", QUALITY=int(quality)) as ds:
            ds.write(big, 1)


def points(pair, n: int, seed: int = 1, margin: int = 40) -> np.ndarray:
    """Reference pixels on L of ``n`` random ground points seen on both images."""
    rng = np.random.default_rng(seed)
    c = pair.scene.origin + [250.0, -250.0]
    xy = np.c_[rng.uniform(c[0] - 100, c[0] + 100, 4 * n),
               rng.uniform(c[1] - 170, c[1] + 170, 4 * n)]
    xyz = np.c_[xy, pair.scene.height(xy)]
    pl, pr = pair.true["L"].to_pixel(xyz), pair.true["R"].to_pixel(xyz)
    size = pair.images["L"].shape[0]
    ok = (np.minimum(pl.min(1), pr.min(1)) > margin) & \
        (np.maximum(pl.max(1), pr.max(1)) < size - margin)
    return pl[ok][:n]


def run_once(pair, readers: dict, pl: np.ndarray, settings=None) -> tuple:
    """Transfer every point from its tile; (wall s, CPU s, merged result)."""
    tiled = {k: TileReader(r, 0) for k, r in readers.items()}
    n_tiles = min(r.per_row for r in tiled.values()) ** 2
    tiles = np.arange(len(pl)) % n_tiles
    parts = []
    w0, c0 = time.perf_counter(), time.process_time()
    for t in range(n_tiles):
        sel = np.flatnonzero(tiles == t)
        for r in tiled.values():
            r.set_tile(t)
        meas = {"point_id": sel.astype(str), "image_id": np.full(len(sel), "L"),
                "col": pl[sel, 0], "row": pl[sel, 1]}
        parts.append(transfer(pair.approx, tiled, meas, pair.scene.height, settings,
                              sigma_height=2.0))
    wall, cpu = time.perf_counter() - w0, time.process_time() - c0
    keys = ("point_id", "col", "row", "accepted", "flags")
    out = {k: np.concatenate([p[k] for p in parts]) for k in keys}
    order = np.argsort(out["point_id"].astype(int))
    return wall, cpu, {k: v[order] for k, v in out.items()}


def compare(out: dict, path: str) -> bool:
    """Whether ``out`` has the saved accepted set and positions (within 1e-6 px)."""
    ref = np.load(path)
    same = np.array_equal(ref["accepted"], out["accepted"])
    both = ref["accepted"] & out["accepted"]
    d = np.hypot(ref["col"] - out["col"], ref["row"] - out["row"])[both]
    worst = float(d.max()) if d.size else 0.0
    print(f"compared with {path}: accepted {int(ref['accepted'].sum())} -> "
          f"{int(out['accepted'].sum())}, same set: {same}, largest position change of "
          f"the accepted {worst:.2e} px")
    return same and worst < 1e-6


def main(argv=None) -> int:
    """Write the JPEGs, decode them once, time the transfers, print the table row."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, default=10000, help="side of the JPEGs (px)")
    ap.add_argument("--points", type=int, default=1000)
    ap.add_argument("--quality", type=int, default=30, help="JPEG quality")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--profile", action="store_true", help="cProfile of one more run")
    ap.add_argument("--save", help="store accepted flags and positions (.npz)")
    ap.add_argument("--compare", help="check the same accepted set and positions")
    ap.add_argument("--dir", help="folder for the JPEGs (default: a temporary one)")
    ap.add_argument("--core", help="time another checkout's core/ (read before the imports)")
    ap.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE",
                    help="a MatchSettings field other than its default (repeat), e.g. "
                    "retry_template=1 to time the matching without the retry")
    args = ap.parse_args(argv)
    if args.size < TILE:
        ap.error(f"--size must be at least {TILE} (tiles of {TILE} px)")
    pair = stereo_pair(TILE, seed=1, texture="hopper", sigma_position=0.5, sigma_attitude=0.02)
    pl = points(pair, args.points)
    tmp = Path(args.dir) if args.dir else Path(tempfile.mkdtemp(prefix="bench_transfer_"))
    tmp.mkdir(parents=True, exist_ok=True)
    readers = {}
    try:
        decode = {}
        for k, img in pair.images.items():
            path = tmp / f"{k}_{args.size}_q{args.quality}.jpg"
            if not path.is_file():
                write_jpeg(path, img, args.size, args.quality)
            readers[k] = RasterioImage(path, k)
            t0 = time.perf_counter()
            readers[k].read(0, 0, 1, 1)  # the one decoding
            decode[k] = time.perf_counter() - t0
        return _time_runs(args, pair, readers, pl, decode)
    finally:
        for r in readers.values():
            r.close()
        if not args.dir:
            shutil.rmtree(tmp, ignore_errors=True)


def _time_runs(args, pair, readers: dict, pl: np.ndarray, decode: dict) -> int:
    """The timed runs, the comparison and the printed table row."""
    from vectoradjust.measure.transfer import MatchSettings

    kw = {k: float(v) for k, v in (a.split("=", 1) for a in args.set)}
    st = MatchSettings(**{k: type(getattr(MatchSettings(), k))(v) for k, v in kw.items()})
    walls, cpus, loads = [], [], [os.getloadavg()[0]]
    out = None
    for _ in range(max(args.repeat, 1)):
        wall, cpu, out = run_once(pair, readers, pl, st)
        walls.append(wall)
        cpus.append(cpu)
        loads.append(os.getloadavg()[0])
    n = len(pl)
    ms_w = 1000.0 * np.median(walls) / n
    ms_c = 1000.0 * np.median(cpus) / n
    lo, hi = 1000.0 * min(walls) / n, 1000.0 * max(walls) / n
    dec = " + ".join(f"{v:.1f}" for v in decode.values())
    print(f"{args.size} x {args.size} px JPEG (quality {args.quality}), decoded once in "
          f"{dec} s (L + R); {n} transfers L -> R, accepted {int(out['accepted'].sum())}")
    print(f"per transfer: wall {ms_w:.1f} ms (range {lo:.1f}-{hi:.1f}, {len(walls)} runs), "
          f"CPU {ms_c:.1f} ms; load average {min(loads):.1f}-{max(loads):.1f} "
          f"on {os.cpu_count()} cores")
    print(f"| `measure transfer`, JPEG of {args.size * args.size / 1e8:g} x 10^8 px "
          f"(q{args.quality}), per transfer after the one decoding | {ms_w:.1f} ms wall "
          f"({lo:.1f}-{hi:.1f}), {ms_c:.1f} ms CPU, load {min(loads):.1f}-{max(loads):.1f} "
          f"| <= 20 ms: {'met' if ms_w <= 20.0 else 'missed'} |")
    if args.save:
        np.savez(args.save, **{k: out[k] for k in ("accepted", "col", "row", "flags")})
    ok = True
    if args.compare:
        ok = compare(out, args.compare)
    if args.profile:
        import cProfile
        import pstats

        prof = cProfile.Profile()
        prof.runcall(run_once, pair, readers, pl, st)
        pstats.Stats(prof).sort_stats("tottime").print_stats(20)
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
