"""The command line keeps freed memory for reuse (glibc's mallopt): fewer page faults."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

CORE = str(Path(__file__).resolve().parents[1] / "core")

_PROBE = """
import resource, sys
sys.path.insert(0, {core!r})
import numpy as np
from vectoradjust.cli.memory import keep_freed_memory
ok = keep_freed_memory() if sys.argv[1] == "tuned" else None
a = np.ones(2_500_000); del a          # 20 MB, once: the heap grows
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
for _ in range(20):                    # the same size again and again
    a = np.ones(2_500_000); del a
print(ok, resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
"""


def _faults(mode: str) -> tuple:
    # 4 KiB pages counted (numpy's transparent huge pages would fault 512 at once)
    env = {**os.environ, "NUMPY_MADVISE_HUGEPAGE": "0"}
    env.pop("VECTORADJUST_MALLOC", None)
    out = subprocess.run([sys.executable, "-c", _PROBE.format(core=CORE), mode],
                         capture_output=True, text=True, check=True, env=env).stdout.split()
    return out[0], int(out[1])


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's mallopt: Linux")
def test_freed_arrays_are_reused_without_page_faults():
    ok, tuned = _faults("tuned")
    if ok != "True":
        pytest.skip("this C library has no mallopt (not glibc)")
    _, plain = _faults("plain")
    # 20 x 20 MB: glibc's default gives each back to the kernel and faults it in again
    assert plain > 2000 and tuned < plain / 20, (plain, tuned)


def test_default_leaves_the_c_library_alone(monkeypatch):
    from vectoradjust.cli.memory import keep_freed_memory

    monkeypatch.setenv("VECTORADJUST_MALLOC", "default")
    assert keep_freed_memory() is False
