"""One OpenBLAS thread for the adjustment: the OpenBLAS thread controls numpy and scipy
link and :func:`_single_blas_thread`.
"""

from __future__ import annotations

import ctypes
import os
import sys
from contextlib import contextmanager

from vectoradjust.adjust.intersection import (  # noqa: F401 (inv3x3, ray_intersection: API)
    _block_sum,
    approximate_points,
    inv3x3,
    ray_intersection,
)

__all__ = []


#: (set, get) symbol pairs of the OpenBLAS builds numpy and scipy ship or link
_BLAS_THREAD_SYMBOLS = (
    ("openblas_set_num_threads", "openblas_get_num_threads"),
    ("scipy_openblas_set_num_threads", "scipy_openblas_get_num_threads"),
    ("scipy_openblas_set_num_threads64_", "scipy_openblas_get_num_threads64_"),
    ("openblas_set_num_threads64_", "openblas_get_num_threads64_"),
)


#: the controls found, by (process, number of imported modules): an OpenBLAS is loaded
#: only by importing a module, so the scan of /proc/self/maps (3 ms) runs again only then
_CONTROLS_CACHE: dict = {}


def _openblas_controls() -> list:
    """``(set, get)`` thread functions of every OpenBLAS loaded in this process (Linux)."""
    if not sys.platform.startswith("linux") or os.environ.get("VECTORADJUST_BLAS_THREADS"):
        return []
    key = (os.getpid(), len(sys.modules))
    if key not in _CONTROLS_CACHE:
        _CONTROLS_CACHE.clear()
        _CONTROLS_CACHE[key] = _scan_openblas()
    return _CONTROLS_CACHE[key]


def _scan_openblas() -> list:
    """The controls of the OpenBLAS libraries mapped into this process."""
    try:
        with open("/proc/self/maps", encoding="utf-8") as fh:
            paths = sorted({ln.split()[-1] for ln in fh if "openblas" in ln.lower()
                            and ln.split()[-1].startswith("/")})
    except OSError:
        return []
    controls = []
    for path in paths:
        try:
            lib = ctypes.CDLL(path)
        except OSError:
            continue
        for set_name, get_name in _BLAS_THREAD_SYMBOLS:
            if hasattr(lib, set_name) and hasattr(lib, get_name):
                controls.append((getattr(lib, set_name), getattr(lib, get_name)))
                break
    return controls


@contextmanager
def _single_blas_thread():
    """Run the adjustment with one OpenBLAS thread, then restore the previous setting.

    Its matrix products are small (a block's images) or many; a threaded BLAS splits
    them across cores that other work (or other processes on a shared machine) holds,
    and waits: on a loaded 2-core machine that made a 1200 x 1200 Cholesky take seconds.
    Set the environment variable ``VECTORADJUST_BLAS_THREADS`` (any value) to leave the
    BLAS threads alone. Without OpenBLAS (or off Linux) this does nothing.
    """
    controls = _openblas_controls()
    old = []
    try:
        for set_fn, get_fn in controls:
            old.append((set_fn, int(get_fn())))
            set_fn(1)
        yield
    finally:
        for set_fn, n in old:
            set_fn(n)

