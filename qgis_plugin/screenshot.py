"""Screenshots of the plugin in a real QGIS desktop under Xvfb (for the README).

Run outside QGIS (needs ``qgis``, ``xvfb-run``)::

    python3 qgis_plugin/screenshot.py [--out docs]

It starts the QGIS desktop on a virtual X display with a throw-away profile in which
the plugin (this folder, as ``vectoradjust_qgis``) is enabled, and QGIS runs this same
file as its startup code (``--code``): the sample roads and DEM are loaded, the
*Adjust road vectors* dialog is opened with the sample project filled in and grabbed
(``docs/adjust_dialog.png``), then the algorithm is run, its styled outputs are added
to the map and the map window is grabbed (``docs/adjust_result.png``); QGIS then quits.
"""

import os
import shutil
import subprocess
import sys
import tempfile

try:
    HERE = os.path.dirname(os.path.abspath(__file__))
except NameError:  # exec'd by QGIS --code without __file__
    HERE = os.environ["VECTORADJUST_PLUGIN_DIR"]
REPO = os.path.dirname(HERE)
SAMPLE = os.path.join(REPO, "resources", "sample")


def launch(out_dir):
    """Start QGIS under Xvfb with this file as startup code."""
    root = tempfile.mkdtemp(prefix="vectoradjust-shot-")
    try:
        plugins = os.path.join(root, "plugins")
        os.makedirs(plugins)
        os.symlink(HERE, os.path.join(plugins, "vectoradjust_qgis"))
        profile = os.path.join(root, "profiles", "default", "QGIS")
        os.makedirs(profile)
        with open(os.path.join(profile, "QGIS3.ini"), "w", encoding="utf-8") as fh:
            fh.write("[PythonPlugins]\nvectoradjust_qgis=true\nprocessing=true\n\n"
                     "[qgis]\ncheckVersion=false\nshowTips=false\n"
                     "allowVersionCheck=false\n\n[core]\nNewsFeed\\httpsfeedqgisorg\\"
                     "disabled=true\n")
        env = dict(os.environ)
        env.update({"QGIS_PLUGINPATH": plugins, "VECTORADJUST_SHOT_OUT": os.path.abspath(out_dir),
                    "VECTORADJUST_PLUGIN_DIR": HERE,
                    "PYTHONPATH": os.pathsep.join(
                        [os.path.join(REPO, "core")]
                        + [p for p in [env.get("PYTHONPATH")] if p]),
                    "GDAL_PAM_ENABLED": "NO"})
        env.pop("QT_QPA_PLATFORM", None)
        # QGIS's embedded Python must find the system Python, not a pyenv/venv first
        env["PATH"] = "/usr/bin:/bin"
        for k in ("PYTHONHOME", "VIRTUAL_ENV", "PYENV_VERSION"):
            env.pop(k, None)
        exe = (shutil.which("qgis.bin", path="/usr/bin:/usr/local/bin") or shutil.which("qgis")
               or "qgis")
        cmd = ["xvfb-run", "-a", "-s", "-screen 0 1600x1000x24", exe,
               "--profiles-path", root, "--nologo",
               "--skipbadlayers", "--code", os.path.join(HERE, "screenshot.py")]
        proc = subprocess.run(cmd, env=env, timeout=600)
        return proc.returncode
    finally:
        shutil.rmtree(root, ignore_errors=True)


def in_qgis():
    """Startup code run by the QGIS desktop (``--code``): take the screenshots."""
    import processing
    from qgis.core import QgsProject, QgsRasterLayer, QgsVectorLayer
    from qgis.PyQt.QtCore import QTimer
    from qgis.PyQt.QtWidgets import QApplication
    from qgis.utils import iface

    out_dir = os.environ.get("VECTORADJUST_SHOT_OUT", os.path.join(REPO, "docs"))
    os.makedirs(out_dir, exist_ok=True)
    project = QgsProject.instance()
    dem = QgsRasterLayer(os.path.join(SAMPLE, "dem.tif"), "dem", "gdal")
    roads = QgsVectorLayer(os.path.join(SAMPLE, "osm_roads.shp"), "osm_roads", "ogr")
    project.addMapLayers([dem, roads])
    mw = iface.mainWindow()
    mw.resize(1600, 1000)
    mw.showMaximized()
    iface.mapCanvas().setExtent(roads.extent().buffered(60))
    params = {"INPUT": roads.id(), "ID_FIELD": "osm_id", "DEM": dem.id(),
              "PROJECT": os.path.join(SAMPLE, "project.toml")}
    dialog = processing.createAlgorithmDialog("vectoradjust:adjustroadvectors", params)
    dialog.resize(1180, 860)
    dialog.show()
    state = {}

    def grab_dialog():
        QApplication.processEvents()
        dialog.grab().save(os.path.join(out_dir, "adjust_dialog.png"))
        dialog.close()
        QTimer.singleShot(500, run_and_grab_map)

    def run_and_grab_map():
        from qgis.core import QgsProcessingOutputLayerDefinition

        p = dict(params)
        for k in ("FEATURES", "SHAPE_POINTS", "RESIDUALS"):
            p[k] = QgsProcessingOutputLayerDefinition("TEMPORARY_OUTPUT", project)
        p["RESIDUAL_SCALE"] = 3.0
        state["result"] = processing.runAndLoadResults("vectoradjust:adjustroadvectors", p)
        project.layerTreeRoot().findLayer(roads.id()).setItemVisibilityChecked(False)
        from qgis.core import QgsRectangle

        # the middle of the street grid
        iface.mapCanvas().setExtent(QgsRectangle(506100, 4474770, 506700, 4475130))
        iface.mapCanvas().refreshAllLayers()
        QTimer.singleShot(4000, grab_map)

    def grab_map():
        QApplication.processEvents()
        iface.mapCanvas().grab().save(os.path.join(out_dir, "adjust_result.png"))
        QTimer.singleShot(500, iface.actionExit().trigger)

    QTimer.singleShot(4000, grab_dialog)


if __name__ == "__main__":
    if "qgis.utils" in sys.modules and getattr(sys.modules["qgis.utils"], "iface", None):
        in_qgis()
    else:
        import argparse

        ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
        ap.add_argument("--out", default=os.path.join(REPO, "docs"))
        sys.exit(launch(ap.parse_args().out))
else:  # executed by QGIS --code (module name is not "__main__" there in some versions)
    try:
        from qgis.utils import iface as _iface

        if _iface is not None:
            in_qgis()
    except ImportError:
        pass
