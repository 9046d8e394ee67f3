"""``qgis_process`` end to end: the plugin loads from a plugin folder in a fresh profile,
lists its algorithms and runs "Adjust road vectors" from the command line.

How ``qgis_process`` (QGIS 3.22) finds the provider: Python plugins in the folders of
``QGIS_PLUGINPATH`` (and the profile's ``python/plugins``) whose metadata.txt says
``hasProcessingProvider=yes`` are loaded if they are enabled in the profile
(``qgis_process plugins enable NAME``); loading calls the plugin's ``initProcessing``.
The test uses a temporary HOME / XDG profile, so the user's QGIS settings are never
touched. Debian's ``/usr/bin/qgis_process`` is a shell wrapper that adds
``--noversioncheck`` (from /etc/default/qgis), an option only the desktop understands;
``qgis_process.bin`` beside it is the real executable and is used when present.
"""

import json
import os
import shutil
import subprocess
from pathlib import Path

import pytest

pytest.importorskip("qgis.core")

from .util import assert_same_values, close, columns, reorder  # noqa: E402

pytestmark = pytest.mark.qgis

PLUGIN = Path(__file__).resolve().parents[1]
REPO = PLUGIN.parent
ALGORITHM_LINES = [
    "vectoradjust:accuracycontrol\tAccuracy control",
    "vectoradjust:adjustroadvectors\tAdjust road vectors",
    "vectoradjust:bufferaccuracytest\tBuffer accuracy test",
    "vectoradjust:compareroaddatabases\tCompare road databases",
    "vectoradjust:dtmaccuracy\tDTM accuracy",
    "vectoradjust:equalerrormap\tEqual-error map",
    "vectoradjust:extractshapepoints\tExtract shape points",
    "vectoradjust:gcpstudy\tGCP study (number and location of control points)",
    "vectoradjust:measureonimages\tMeasure on the images",
    "vectoradjust:smartconflation\tSmart conflation",
    "vectoradjust:uncertaintybands\tUncertainty bands",
]


def qgis_process_executable():
    exe = shutil.which("qgis_process")
    if exe is None:
        return None
    real = exe + ".bin"
    return real if os.path.isfile(real) and os.access(real, os.X_OK) else exe


@pytest.fixture(scope="module")
def qgis_process(tmp_path_factory):
    """A function running qgis_process with the plugin installed in a fresh profile."""
    exe = qgis_process_executable()
    if exe is None:
        pytest.skip("qgis_process is not installed")
    root = tmp_path_factory.mktemp("qgis_process")
    plugins = root / "plugins"
    plugins.mkdir()
    try:
        (plugins / "vectoradjust_qgis").symlink_to(PLUGIN, target_is_directory=True)
    except OSError:  # pragma: no cover - no symlinks
        shutil.copytree(PLUGIN, plugins / "vectoradjust_qgis")
    home = root / "home"
    runtime = root / "runtime"
    for d in (home, runtime):
        d.mkdir()
    runtime.chmod(0o700)
    env = dict(os.environ)
    env.update({
        "HOME": str(home), "XDG_DATA_HOME": str(home / ".local" / "share"),
        "XDG_CONFIG_HOME": str(home / ".config"), "XDG_CACHE_HOME": str(home / ".cache"),
        "XDG_RUNTIME_DIR": str(runtime), "QT_QPA_PLATFORM": "offscreen",
        "QGIS_PLUGINPATH": str(plugins), "GDAL_PAM_ENABLED": "NO",
        # the core for the plugin (the zip vendors it instead)
        "PYTHONPATH": os.pathsep.join([str(REPO / "core")]
                                      + [p for p in [env.get("PYTHONPATH")] if p]),
    })

    def call(*args, timeout=600):
        proc = subprocess.run([exe, *args], capture_output=True, text=True, env=env,
                              timeout=timeout, cwd=str(root))
        return proc

    proc = call("plugins", "enable", "vectoradjust_qgis")
    assert proc.returncode == 0, proc.stdout + proc.stderr
    return call


def test_qgis_process_lists_the_provider(qgis_process):
    proc = qgis_process("list")
    assert proc.returncode == 0, proc.stderr
    lines = proc.stdout.splitlines()
    start = lines.index("vectoradjust")
    section = []
    for line in lines[start + 1:]:
        if not line.strip():
            break
        section.append(line.strip())
    assert section == ALGORITHM_LINES


def test_qgis_process_runs_adjust(qgis_process, sample, headless_adjust, tmp_path, qgis_app):
    from qgis.core import QgsVectorLayer

    out = {k: tmp_path / f"{k.lower()}.gpkg"
           for k in ("SHAPE_POINTS", "FEATURES", "CONTROL_POINTS", "RESIDUALS")}
    args = ["--json", "run", "vectoradjust:adjustroadvectors", "--",
            f"INPUT={sample / 'osm_roads.shp'}", f"PROJECT={sample / 'project.toml'}",
            f"SUMMARY={tmp_path / 'summary.json'}", f"REPORT={tmp_path / 'report.html'}"]
    args += [f"{k}={v}" for k, v in out.items()]
    proc = qgis_process(*args)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    result = json.loads(proc.stdout[proc.stdout.index("{"):])["results"]
    s = headless_adjust["summary"]
    assert close(result["SIGMA0_SQUARED"], s["sigma0_squared"])
    assert result["CHI_SQUARE_PASSED"] == s["chi_square"]["passed"]
    assert close(result["RMSE"], s["shape_points"]["rmse_horizontal"])
    for path in out.values():
        assert path.is_file()
    with open(tmp_path / "summary.json", encoding="utf-8") as fh:
        assert close(json.load(fh)["sigma0_squared"], s["sigma0_squared"])
    report = (tmp_path / "report.html").read_text(encoding="utf-8")  # matplotlib, headless
    assert report.count("data:image/png;base64,") >= 3 and "</html>" in report
    mine = columns(QgsVectorLayer(str(out["SHAPE_POINTS"]), "sp", "ogr"))
    ref = columns(QgsVectorLayer(f"{headless_adjust['gpkg']}|layername=shape_points", "r",
                                 "ogr"))
    ref = reorder(ref, "point_id", mine["point_id"])
    for f in ("X", "Y", "Z", "Vx", "Vy", "Vz", "AdjX", "AdjY", "AdjZ", "CE90", "LE90",
              "Adjusted"):
        assert_same_values(mine[f], ref[f], f)


def test_qgis_process_runs_accuracy_control(qgis_process, sample, tmp_path):
    proc = qgis_process("--json", "run", "vectoradjust:accuracycontrol", "--",
                        f"PROJECT={sample / 'project.toml'}", "PRODUCT=0", "SCALE=2000",
                        "CONTOUR_INTERVAL=1", f"OUTPUT={tmp_path / 'qa.csv'}",
                        f"QA_JSON={tmp_path / 'qa.json'}")
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    result = json.loads(proc.stdout[proc.stdout.index("{"):])["results"]
    with open(tmp_path / "qa.json", encoding="utf-8") as fh:
        doc = json.load(fh)
    assert result["VERDICT"] == doc["verdict"] and result["PASSED"] == doc["passed"]
    assert (tmp_path / "qa.csv").is_file()


def test_qgis_process_reports_user_errors(qgis_process, sample, tmp_path):
    proc = qgis_process("run", "vectoradjust:adjustroadvectors", "--",
                        f"INPUT={sample / 'osm_roads.shp'}", f"PROJECT={sample / 'project.toml'}",
                        "ID_FIELD=no_such_field", f"SHAPE_POINTS={tmp_path / 'x.gpkg'}")
    assert proc.returncode != 0
    assert "'no_such_field' is not a field" in proc.stdout + proc.stderr


def test_qgis_process_without_outputs_stops_at_once(qgis_process, sample):
    """Only INPUT and PROJECT: no sink is created by default outside the dialog, so the
    run stops before reading anything, naming the output parameters."""
    import time

    t0 = time.perf_counter()
    proc = qgis_process("run", "vectoradjust:adjustroadvectors", "--",
                        f"INPUT={sample / 'osm_roads.shp'}", f"PROJECT={sample / 'project.toml'}")
    seconds = time.perf_counter() - t0
    text = proc.stdout + proc.stderr
    assert proc.returncode != 0, text[-2000:]
    assert "No output is requested" in text
    for name in ("SHAPE_POINTS", "FEATURES", "CONTROL_POINTS", "RESIDUALS", "SUMMARY",
                 "REPORT"):
        assert name in text, name
    assert "reading the inputs" not in text  # stopped before the adjustment
    assert seconds < 60.0, seconds  # qgis_process's own start included
