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


def test_adjust_into_a_folder_that_cannot_be_made_is_said_before_the_work(tmp_path, capsys):
    from vectoradjust.cli import main

    blocker = tmp_path / "a_file"
    blocker.write_text("not a folder")
    project = Path(__file__).resolve().parents[1] / "resources" / "sample" / "project.toml"
    assert main(["adjust", str(project), "--out", str(blocker / "out"), "-q"]) == 1
    err = capsys.readouterr().err
    assert "Cannot write into the output directory" in err and "--out" in err
    assert "Traceback" not in err
