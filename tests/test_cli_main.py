"""``python -m vectoradjust`` runs the command line (as the ``vectoradjust`` script does)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from vectoradjust import __version__

CORE = Path(__file__).resolve().parents[1] / "core"


def test_python_m_vectoradjust_is_the_cli():
    env = dict(os.environ, PYTHONPATH=str(CORE) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    out = subprocess.run([sys.executable, "-m", "vectoradjust", "--version"], env=env,
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == f"vectoradjust {__version__}"
    bad = subprocess.run([sys.executable, "-m", "vectoradjust", "adjust", "no_such.toml",
                          "--out", "x"], env=env, capture_output=True, text=True, timeout=120)
    assert bad.returncode != 0 and "Traceback" not in bad.stderr
    assert "no_such.toml" in bad.stderr + bad.stdout
