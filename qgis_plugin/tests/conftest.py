"""Fixtures of the QGIS plugin tests: one offscreen QGIS per session, the provider,
the sample project and the headless reference results.

Run under Debian's QGIS Python (``/usr/bin/python3``) with ``QT_QPA_PLATFORM=offscreen``
and ``PYTHONPATH=<repo>/core:<repo>``. Without ``qgis`` the tests are skipped.
"""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
SAMPLE = REPO / "resources" / "sample"
if str(REPO / "core") not in sys.path:  # the core, when PYTHONPATH does not give it
    try:
        import vectoradjust  # noqa: F401
    except ImportError:
        sys.path.insert(0, str(REPO / "core"))

try:  # collectable without QGIS: every fixture below skips then
    import qgis.core  # noqa: F401

    HAVE_QGIS = True
except ImportError:  # pragma: no cover - depends on the machine
    HAVE_QGIS = False

_APP = {}


def _processing_plugins_dir():
    from qgis.core import QgsApplication

    for d in (os.path.join(QgsApplication.pkgDataPath(), "python", "plugins"),
              "/usr/share/qgis/python/plugins"):
        if os.path.isdir(os.path.join(d, "processing")):
            return d
    return None


@pytest.fixture(scope="session")
def qgis_app():
    """An initialised QgsApplication with Processing and the vectoradjust provider."""
    if not HAVE_QGIS:
        pytest.skip("qgis is not importable (run under Debian's /usr/bin/python3 with QGIS)")
    os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")
    # no dem.tif.aux.xml statistics files written next to the sample data
    os.environ["GDAL_PAM_ENABLED"] = "NO"
    from qgis.core import QgsApplication

    if "app" not in _APP:
        app = QgsApplication([], False)
        app.initQgis()
        d = _processing_plugins_dir()
        if d and d not in sys.path:
            sys.path.append(d)
        from processing.core.Processing import Processing

        Processing.initialize()
        _APP["app"] = app
    registry = QgsApplication.processingRegistry()
    if registry.providerById("vectoradjust") is None:
        from qgis_plugin.provider import VectorAdjustProvider

        provider = VectorAdjustProvider()
        assert registry.addProvider(provider)
        _APP["provider"] = provider
    return _APP["app"]


@pytest.fixture(scope="session")
def sample():
    """The sample project directory (resources/sample)."""
    if not (SAMPLE / "project.toml").is_file():
        pytest.skip(f"the sample project is missing ({SAMPLE}); generate it with "
                    "python -m vectoradjust.simulate")
    return SAMPLE


def venv_python():
    """The Python of the test venv with the headless dependencies, or None."""
    p = os.environ.get("VECTORADJUST_VENV_PYTHON") or str(REPO / ".venv-test" / "bin" / "python")
    return p if os.path.isfile(p) and os.access(p, os.X_OK) else None


def run_headless(args, timeout=600):
    """Run ``python -m ...`` in the headless venv (skips when it is absent)."""
    py = venv_python()
    if py is None:
        pytest.skip("the headless test venv is missing (set VECTORADJUST_VENV_PYTHON or create "
                    "<repo>/.venv-test with pip install -e .): no headless reference")
    env = dict(os.environ)
    env["PYTHONPATH"] = str(REPO / "core")
    env.pop("QT_QPA_PLATFORM", None)
    proc = subprocess.run([py, *args], capture_output=True, text=True, env=env, timeout=timeout,
                          cwd=str(REPO))
    if proc.returncode != 0:
        raise AssertionError(f"headless run failed ({' '.join(args)}):\n{proc.stdout}\n"
                             f"{proc.stderr}")
    return proc


@pytest.fixture(scope="session")
def headless_adjust(sample, tmp_path_factory):
    """``vectoradjust adjust project.toml --vectors OSM`` in the headless venv."""
    out = tmp_path_factory.mktemp("headless_adjust")
    run_headless(["-m", "vectoradjust.cli", "adjust", str(sample / "project.toml"), "--out",
                  str(out), "--format", "gpkg", "--vectors", "OSM", "-q"])
    with open(out / "summary.json", encoding="utf-8") as fh:
        summary = json.load(fh)
    return {"dir": out, "gpkg": out / "adjusted.gpkg", "summary": summary}


@pytest.fixture(scope="session")
def headless_compare(sample, tmp_path_factory):
    """``vectoradjust compare project.toml`` in the headless venv."""
    out = tmp_path_factory.mktemp("headless_compare")
    run_headless(["-m", "vectoradjust.cli", "compare", str(sample / "project.toml"), "--out",
                  str(out), "--format", "gpkg", "-q"])
    return out


@pytest.fixture(scope="session")
def headless_reference(tmp_path_factory):
    """Run ``headless_reference.py MODE ARGS`` in the venv and return its JSON."""
    script = Path(__file__).with_name("headless_reference.py")

    def call(mode, *args):
        out = tmp_path_factory.mktemp(f"ref_{mode}") / "ref.json"
        run_headless([str(script), mode, str(out), *map(str, args)])
        with open(out, encoding="utf-8") as fh:
            return json.load(fh)

    return call
