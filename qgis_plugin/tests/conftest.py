"""Fixtures of the QGIS plugin tests: one offscreen QGIS per session, the provider,
the sample project and the headless reference results.

Run under Debian's QGIS Python (``/usr/bin/python3``) with ``QT_QPA_PLATFORM=offscreen``
and ``PYTHONPATH=<repo>/core:<repo>``. Without ``qgis`` the tests are skipped - unless
``VECTORADJUST_REQUIRE_QGIS=1`` (set by ``tests/run_all.sh`` for its QGIS leg, i.e. by
CI): then a ``qgis.core`` that does not import stops the run at once (a conftest error,
pytest exit status 4), and at the end the session fails (exit status 1) when a plugin test
module was skipped as a whole or a plugin test was skipped for a reason the QGIS leg
provides (QGIS, ``qgis_process``, the headless venv, the sample projects). Skips for
absent optional data (the real RPC images, a PROJ grid) stay skips. The plugin tests'
count is printed: selected, run, skipped.
"""

import json
import os
import re
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

#: the QGIS leg of tests/run_all.sh: QGIS must import and the plugin tests must run
REQUIRE_QGIS = os.environ.get("VECTORADJUST_REQUIRE_QGIS", "").strip() not in ("", "0")

try:  # collectable without QGIS: every fixture below skips then
    import qgis.core  # noqa: F401

    HAVE_QGIS = True
except ImportError as _exc:  # pragma: no cover - depends on the machine
    HAVE_QGIS = False
    if REQUIRE_QGIS:
        raise ImportError(
            f"VECTORADJUST_REQUIRE_QGIS is set (the QGIS leg of tests/run_all.sh) but qgis.core "
            f"does not import under {sys.executable}: {_exc!r}. The plugin tests would all be "
            "skipped; install Debian's python3-qgis and qgis, run under /usr/bin/python3, or "
            "unset VECTORADJUST_REQUIRE_QGIS to let them skip") from _exc

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


# ---------------------------------------------------------------------------
# VECTORADJUST_REQUIRE_QGIS: no plugin test may vanish in the QGIS leg
# ---------------------------------------------------------------------------

#: skip reasons that mean the QGIS leg itself is broken (what run_all.sh installs and sets)
_LEG_SKIP = re.compile(
    r"qgis\.core|no module named 'qgis|qgis is not importable|qgis_process is not installed"
    r"|headless test venv|sample project is missing|satellite sample is missing", re.I)

_LEG = {"module_skips": [], "skips": [], "ran": set()}


def _reason(report) -> str:
    lr = report.longrepr
    return str(lr[2]) if isinstance(lr, tuple) and len(lr) == 3 else str(lr)


def _plugin_prefix(config) -> str:
    """This directory as the node ids spell it (relative to the rootdir)."""
    return os.path.relpath(Path(__file__).resolve().parent, config.rootpath).replace(os.sep, "/")


def _in(nodeid: str, prefix: str) -> bool:
    return nodeid.split("::")[0].replace("\\", "/").startswith(prefix + "/")


def pytest_collectreport(report):
    """A plugin test module skipped as a whole (``importorskip`` at its top)."""
    if REQUIRE_QGIS and report.skipped:
        _LEG["module_skips"].append((report.nodeid, _reason(report)))


def pytest_runtest_logreport(report):
    """Plugin tests that ran (passed, failed, errored, xfailed) and those skipped, and why."""
    if not REQUIRE_QGIS:
        return
    if report.skipped and not hasattr(report, "wasxfail"):
        _LEG["skips"].append((report.nodeid, _reason(report)))
    elif report.when == "call" or report.failed:
        _LEG["ran"].add(report.nodeid)


def pytest_sessionfinish(session, exitstatus):
    """Fail the session when the QGIS leg ran fewer plugin tests than it selected for
    reasons of the leg itself; print the count."""
    if not REQUIRE_QGIS:
        return
    prefix = _plugin_prefix(session.config)
    selected = [i.nodeid for i in session.items if _in(i.nodeid, prefix)]
    ran = {n for n in _LEG["ran"] if _in(n, prefix)}
    skips = [(n, r) for n, r in _LEG["skips"] if _in(n, prefix)]
    leg_skips = [(n, r) for n, r in skips if _LEG_SKIP.search(r)]
    module_skips = [(n, r) for n, r in _LEG["module_skips"] if _in(n, prefix)]
    problems = [f"plugin test module skipped: {n}: {r}" for n, r in module_skips]
    problems += [f"plugin test skipped: {n}: {r}" for n, r in leg_skips]
    if selected and not ran:
        problems.append(f"none of the {len(selected)} selected plugin tests ran")
    # every selected test either ran or was skipped (for a reason checked above)
    accounted = len(ran | {n for n, _ in skips})
    if len(selected) > accounted and exitstatus == 0:
        problems.append(f"only {accounted} of {len(selected)} selected plugin tests reported")
    _LEG["summary"] = [
        f"{len(selected)} plugin tests selected, {len(ran)} ran, "
        f"{len(skips) - len(leg_skips)} skipped for other reasons (optional data), "
        f"{len(leg_skips)} skipped because of the leg, {len(module_skips)} modules skipped",
        *(f"FAILED: {p}" for p in problems)]
    if problems and session.exitstatus == 0:
        session.exitstatus = pytest.ExitCode.TESTS_FAILED


def pytest_terminal_summary(terminalreporter):
    """The QGIS leg's count and what made it fail."""
    if REQUIRE_QGIS and _LEG.get("summary"):
        terminalreporter.write_sep("-", "QGIS leg (VECTORADJUST_REQUIRE_QGIS=1)")
        for line in _LEG["summary"]:
            terminalreporter.write_line(line)
