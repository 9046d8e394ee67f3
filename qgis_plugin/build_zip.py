"""Build the installable QGIS plugin zip.

Usage (any Python 3.9+, no QGIS needed)::

    python3 qgis_plugin/build_zip.py [--out DIR]

writes ``DIR/vectoradjust_qgis-<version>.zip`` (default ``dist/``) holding one folder,
``vectoradjust_qgis/``: the plugin, its QML styles (``styles/``, from
``resources/styles``), the vectoradjust core package vendored in ``ext/`` (the
plugin puts ``ext`` first on ``sys.path``) and ``LICENSE`` (the GNU GPL version 2, from
the repository root). Install it in QGIS with *Plugins > Manage and
Install Plugins > Install from ZIP*. QGIS's Python must have numpy and scipy.
"""

import argparse
import configparser
import os
import sys
import zipfile

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(HERE)
PLUGIN_NAME = "vectoradjust_qgis"

# plugin files and folders (relative to qgis_plugin/) that go into the zip
PLUGIN_FILES = ["__init__.py", "plugin.py", "provider.py", "qgis_io.py", "results.py",
                "rpc_io.py", "styles.py", "gdal_log.py", "metadata.txt", "icon.png"]
PLUGIN_DIRS = ["algorithms"]
EXCLUDE_DIRS = {"__pycache__", "tests"}


def version():
    """The plugin version from metadata.txt."""
    cp = configparser.ConfigParser()
    cp.read(os.path.join(HERE, "metadata.txt"), encoding="utf-8")
    return cp["general"]["version"]


def _walk(root):
    for dirpath, dirnames, filenames in os.walk(root):
        dirnames[:] = sorted(d for d in dirnames if d not in EXCLUDE_DIRS)
        for f in sorted(filenames):
            if f.endswith((".pyc", ".pyo")):
                continue
            yield os.path.join(dirpath, f)


def members():
    """(source path, name in the zip) of every file of the plugin zip."""
    out = []
    for f in PLUGIN_FILES:
        out.append((os.path.join(HERE, f), f"{PLUGIN_NAME}/{f}"))
    for d in PLUGIN_DIRS:
        for p in _walk(os.path.join(HERE, d)):
            out.append((p, f"{PLUGIN_NAME}/{os.path.relpath(p, HERE)}"))
    styles = os.path.join(REPO, "resources", "styles")
    for p in _walk(styles):
        if p.endswith(".qml"):
            out.append((p, f"{PLUGIN_NAME}/styles/{os.path.basename(p)}"))
    core = os.path.join(REPO, "core", "vectoradjust")
    for p in _walk(core):
        if p.endswith(".py"):
            out.append((p, f"{PLUGIN_NAME}/ext/vectoradjust/{os.path.relpath(p, core)}"))
    # the plugin repository wants the licence in the plugin folder (a missing one fails)
    out.append((os.path.join(REPO, "LICENSE"), f"{PLUGIN_NAME}/LICENSE"))
    return [(src, arc.replace(os.sep, "/")) for src, arc in out]


def build(out_dir):
    """Write the zip and return its path."""
    missing = [src for src, _ in members() if not os.path.isfile(src)]
    if missing:
        raise SystemExit(f"missing files: {', '.join(missing)}")
    if not any(a.endswith("ext/vectoradjust/pipeline.py") for _, a in members()):
        raise SystemExit("the vectoradjust core (core/vectoradjust) was not found")
    os.makedirs(out_dir, exist_ok=True)
    path = os.path.join(out_dir, f"{PLUGIN_NAME}-{version()}.zip")
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as zf:
        for src, arc in members():
            zf.write(src, arc)
    return path


def main(argv=None):
    p = argparse.ArgumentParser(description="Build the vectoradjust QGIS plugin zip.")
    p.add_argument("--out", default=os.path.join(REPO, "dist"), help="output folder "
                   "(default dist/)")
    args = p.parse_args(argv)
    path = build(args.out)
    print(path)
    return 0


if __name__ == "__main__":
    sys.exit(main())
