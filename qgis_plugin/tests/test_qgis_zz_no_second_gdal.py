"""The plugin never loads a second GDAL, PROJ or GEOS into QGIS, even where one is installed.

geopandas, rasterio, fiona and pyogrio bring a second GDAL into the QGIS process (a
crash waiting to happen); shapely and pyproj a second GEOS/PROJ. The plugin reads
everything through the QGIS API. Debian's QGIS Python has none of the first five, so
checking ``sys.modules`` there proves nothing: an optional ``import pyogrio`` would
fail quietly. Here a venv over QGIS's Python (``--system-site-packages``, so ``qgis``
and Debian's numpy 1.24 stay) gets the pip wheels of all of them, each with its own
GDAL/PROJ, and ``second_gdal_probe.py`` runs in it: it starts an offscreen QGIS,
imports the plugin as QGIS does, runs every algorithm on the sample project and the
RPC satellite project, and reports what was loaded.

The venv is made once and kept in ``<repo>/.venv-qgis-gdal`` (ignored by git; another
folder with ``VECTORADJUST_QGIS_GDAL_VENV``); it is rebuilt when the pins below or
Debian's numpy change. Without the network pip fails: the test then fails when
``VECTORADJUST_REQUIRE_QGIS`` is set (or ``CI=true``), and skips with pip's message
otherwise. (Named ``zz`` as it was when it ran in the pytest process after the other
plugin tests.)
"""

import fcntl
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("qgis.core")

pytestmark = pytest.mark.qgis

REPO = Path(__file__).resolve().parents[2]
PROBE = Path(__file__).with_name("second_gdal_probe.py")
SECOND_GDAL = ("geopandas", "rasterio", "fiona", "pyogrio")
BANNED = SECOND_GDAL + ("shapely", "pyproj")
# wheels that bundle GDAL/PROJ/GEOS and run with numpy 1.24 (built against numpy 2, which
# keeps the 1.x ABI); their pure dependencies come from PyPI, numpy stays Debian's
PINS = ("rasterio==1.4.4", "pyogrio==0.13.0", "fiona==1.10.1", "pyproj==3.7.2",
        "geopandas==1.1.4", "shapely==2.1.2", "pandas==2.3.3")
READY = "vectoradjust-ready.json"
_CHECK = ("import json, numpy, rasterio, pyogrio, fiona, pyproj, geopandas, shapely; "
          "print(json.dumps({'numpy': [numpy.__version__, numpy.__file__], "
          "'rasterio': rasterio.__gdal_version__, 'pyogrio': pyogrio.__gdal_version_string__, "
          "'fiona': fiona.__gdal_version__, 'pyproj': pyproj.proj_version_str, "
          "'geopandas': geopandas.__version__, 'shapely': shapely.geos_version_string}))")


def _required():
    # as qgis_plugin/tests/conftest.py reads it (tests/run_all.sh sets it for its QGIS leg)
    flag = os.environ.get("VECTORADJUST_REQUIRE_QGIS", "").strip()
    return flag not in ("", "0") or os.environ.get("CI") == "true"


def _give_up(what, proc):
    tail = "\n".join(((proc.stdout or "") + (proc.stderr or "")).strip().splitlines()[-15:])
    msg = (f"{what} failed (exit {proc.returncode}), so the second-GDAL packages cannot be "
           f"made importable beside QGIS:\n{tail}\nThe venv is {_venv_dir()}; needs PyPI.")
    if _required():
        pytest.fail(msg + "\n(VECTORADJUST_REQUIRE_QGIS or CI is set: a failure, not a skip)")
    pytest.skip(msg)


def _venv_dir():
    return Path(os.environ.get("VECTORADJUST_QGIS_GDAL_VENV") or REPO / ".venv-qgis-gdal")


def _run(cmd, timeout=900, **kw):
    return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, **kw)


def _spec():
    """What the venv is made of: when it changes, the venv is made again."""
    import numpy

    return {"base": os.path.realpath(sys.executable), "numpy": numpy.__version__,
            "pins": list(PINS)}


def _build(venv, spec):
    proc = _run([sys.executable, "-m", "venv", "--clear", "--system-site-packages", str(venv)])
    if proc.returncode != 0:
        _give_up(f"{sys.executable} -m venv --system-site-packages", proc)
    py = venv / "bin" / "python"
    constraints = venv / "constraints.txt"
    constraints.write_text(f"numpy=={spec['numpy']}\n", encoding="utf-8")
    proc = _run([str(py), "-m", "pip", "install", "-q", "--disable-pip-version-check",
                 "--no-input", "-c", str(constraints), *PINS])
    if proc.returncode != 0:
        _give_up("pip install " + " ".join(PINS), proc)
    proc = _run([str(py), "-c", _CHECK], timeout=300)
    assert proc.returncode == 0, f"the installed wheels do not import:\n{proc.stderr}"
    (venv / READY).write_text(json.dumps(spec), encoding="utf-8")


@pytest.fixture(scope="module")
def gdal_venv():
    """The Python of the venv over QGIS's Python with the second-GDAL packages."""
    venv, spec = _venv_dir(), _spec()
    venv.mkdir(parents=True, exist_ok=True)
    fd = os.open(venv, os.O_RDONLY)  # one builder at a time (parallel runs)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        ready = venv / READY
        if not (ready.is_file() and json.loads(ready.read_text(encoding="utf-8")) == spec
                and (venv / "bin" / "python").is_file()):
            _build(venv, spec)
    finally:
        os.close(fd)
    return str(venv / "bin" / "python")


def test_the_second_gdal_imports_beside_qgis_with_debians_numpy(gdal_venv):
    import numpy

    proc = _run([gdal_venv, "-c", _CHECK], timeout=300)
    assert proc.returncode == 0, proc.stderr
    got = json.loads(proc.stdout)
    # Debian's numpy (QGIS's), not a wheel's: the probe runs the plugin as QGIS would
    assert got["numpy"] == [numpy.__version__, numpy.__file__]
    assert all(got[k] for k in BANNED), got  # their own GDAL, PROJ and GEOS


def _probe(python, sample, work):
    out = work / "probe.json"
    env = dict(os.environ, QT_QPA_PLATFORM="offscreen", GDAL_PAM_ENABLED="NO",
               PYTHONPATH=os.pathsep.join([str(REPO / "core"), str(REPO)]))
    proc = _run([python, str(PROBE), str(out), str(sample), str(work)], timeout=900,
                env=env, cwd=str(work))
    assert proc.returncode == 0, (
        f"the QGIS process with the second GDAL importable failed (exit {proc.returncode}; "
        f"negative: killed by that signal):\n{proc.stdout[-3000:]}\n{proc.stderr[-6000:]}")
    return json.loads(out.read_text(encoding="utf-8"))


def test_no_second_gdal_after_every_algorithm(gdal_venv, sample, tmp_path):
    import numpy

    work = tmp_path / "work"
    work.mkdir()
    rep = _probe(gdal_venv, sample, work)
    # the check is not vacuous: in that very process each banned package would import
    venv = str(Path(gdal_venv).parents[1])
    assert all((rep["findable"][n] or "").startswith(venv) for n in BANNED), rep["findable"]
    assert rep["numpy"] == [numpy.__version__, numpy.__file__]  # QGIS's numpy
    assert len(rep["algorithms"]) == 11 and {a for a, _ in rep["seconds"]} == set(
        rep["algorithms"]), "every algorithm of the provider runs once"
    for f in ("report.html", "ee.tif", "qa.json", "compare.html", "study/gcp_study.csv",
              "rpc/S1_rpc.txt"):
        assert f in rep["outputs"], f"{f} not written: {rep['outputs']}"
    # the report's figures: matplotlib's Agg canvas, never pyplot (no GUI backend in QGIS)
    assert not rep["pyplot"], "matplotlib.pyplot was loaded in the QGIS process"
    assert not rep["baseline"], f"QGIS itself loaded {rep['baseline']} before the plugin"
    tops = sorted({m.split(".")[0] for m in rep["loaded"]})
    where = "\n".join(f"{n} first imported from:\n{rep['stacks'].get(n, '?')}" for n in tops)
    assert not tops, (f"loaded in the QGIS process: {', '.join(tops)} "
                      f"({len(rep['loaded'])} modules)\n{where}")
