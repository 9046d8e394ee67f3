"""Shared fixtures: paths of the shared worked examples and the sample project."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT / "core") not in sys.path:  # run from a source checkout without installing
    sys.path.insert(0, str(ROOT / "core"))

SHARED = ROOT.parent / "shared" / "data" / "dewitt"


def _dewitt_dir() -> Path:
    for cand in (ROOT / "tests" / "data" / "dewitt", SHARED):
        if (cand / "resect.dat").is_file():
            return cand
    pytest.skip("Dewitt sample data not found")


@pytest.fixture(scope="session")
def dewitt_dir() -> Path:
    """Directory with resect.dat, relor.dat, 3dconf.dat."""
    return _dewitt_dir()


@pytest.fixture(scope="session")
def sample_dir() -> Path:
    """The committed sample project."""
    return ROOT / "resources" / "sample"
