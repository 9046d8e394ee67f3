"""Shared fixtures: paths of the shared worked examples and the sample project."""

from __future__ import annotations

import os
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


# ------------------------------------------------------------- full validation tier
def pytest_addoption(parser):
    """``--validation``: run the full tier of the validation/ scripts (tests marked
    ``validation``; hours). ``--validation-out DIR`` keeps their output and JSON."""
    group = parser.getgroup("vectoradjust")
    group.addoption("--validation", action="store_true", default=False,
                    help="run the full validation tier (tests marked 'validation'); also "
                         "VECTORADJUST_VALIDATION=1")
    group.addoption("--validation-out", default=None, metavar="DIR",
                    help="write each full validation run's output and JSON into DIR")


def _validation_enabled(config) -> bool:
    return bool(config.getoption("--validation")) or \
        os.environ.get("VECTORADJUST_VALIDATION", "") not in ("", "0")


def pytest_collection_modifyitems(config, items):
    """Skip the full validation tier unless it was asked for."""
    if _validation_enabled(config):
        return
    skip = pytest.mark.skip(reason="full validation tier: run with --validation "
                                   "(or VECTORADJUST_VALIDATION=1)")
    for item in items:
        if item.get_closest_marker("validation") is not None:
            item.add_marker(skip)

