"""Keep freed memory for reuse in the command-line process (Linux, glibc).

A large run allocates and frees tens of gigabytes of temporary arrays (a million shape
points: about 28 GB in the adjustment alone). glibc gives every block above its mmap
threshold back to the kernel when it is freed, so the next array of that size is
faulted in and zeroed page by page again: a third of the adjustment's time at 10^6
points went to the kernel. Raising the threshold to its maximum (32 MiB) and never
trimming the heap lets the blocks up to that size be reused as they are; larger
blocks still come from and go back to the kernel, so the peak memory stays about the
same (``benchmarks/README.md``).

Only the command line calls :func:`keep_freed_memory` (QGIS's process is not ours to
tune); ``VECTORADJUST_MALLOC=default`` leaves glibc's settings alone.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os
import sys

__all__ = ["keep_freed_memory"]

#: mallopt parameters of glibc's malloc.h
_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3
#: the largest mmap threshold glibc accepts on 64-bit systems (HEAP_MAX / 2)
MMAP_THRESHOLD = 32 * 1024 * 1024


def keep_freed_memory() -> bool:
    """Ask glibc to keep freed blocks of up to 32 MiB for reuse; True when it agreed.

    Does nothing (False) off Linux, without glibc, or with ``VECTORADJUST_MALLOC=default``.
    """
    if os.environ.get("VECTORADJUST_MALLOC", "").strip().lower() == "default":
        return False
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):  # musl and others: no mallopt
        return False
    mallopt.argtypes, mallopt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
    ok = mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD) == 1
    # the freed top of the heap is not given back (2 GiB: int range of mallopt)
    return ok and mallopt(_M_TRIM_THRESHOLD, 2 ** 31 - 1) == 1
