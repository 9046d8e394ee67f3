"""vectoradjust for QGIS: a Processing provider over the vectoradjust core.

QGIS imports this package (installed as the plugin folder ``vectoradjust_qgis``) and
calls :func:`classFactory`. The numerical core (the ``vectoradjust`` package, numpy
and scipy only) is either vendored in the plugin's ``ext/`` folder (the installable
zip built by ``build_zip.py``) or importable from QGIS's Python (``pip install
vectoradjust`` into it, or ``PYTHONPATH``). A vendored copy wins, so the plugin runs
the core it was built and tested with.
"""

import os
import sys

_EXT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "ext")
if os.path.isdir(_EXT) and _EXT not in sys.path:
    sys.path.insert(0, _EXT)


def classFactory(iface):
    """Create the plugin object (called by QGIS with its interface)."""
    from .plugin import VectorAdjustPlugin

    return VectorAdjustPlugin(iface)
