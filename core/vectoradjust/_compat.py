"""Old module names (vectoradjust 0.1) that still import, with a DeprecationWarning.

0.2 moved the flat modules into subpackages (``docs/architecture.md``). ``import
vectoradjust.bundle`` still works: it returns the module ``vectoradjust.adjust.bundle``
itself (same object, so attributes and monkeypatching behave as before) and warns with
a :class:`DeprecationWarning` naming the new place. Likewise the 0.1 names of the
``accuracy``, ``qa`` and ``cli`` packages (their ``__getattr__``), and 0.2's
``vectoradjust.accuracy.conflation`` and ``accuracy.smart``, now :mod:`vectoradjust.conflation`.

They were announced "for one release" in 0.2 and are still here in 0.3: they stay for
scripts written against 0.1 until a release whose notes say they are gone. Nothing in
this repository uses them (the core, the QGIS plugin and the tests import the new
names; ``tests/test_architecture.py`` imports old names only to check that they warn).
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.machinery
import sys
import warnings

#: old module name -> new module name (both relative to ``vectoradjust``)
MOVED = {
    "collinearity": "sensor.collinearity", "camera": "sensor.camera",
    "refine": "sensor.refine", "interior": "sensor.interior",
    "bundle": "adjust.bundle", "vce": "adjust.vce", "reliability": "adjust.reliability",
    "orientation": "adjust.orientation", "shapepoints": "adjust.shapepoints",
    "dem": "adjust.dem",
    "stats": "accuracy.stats", "propagate": "accuracy.propagate",
    "derived": "accuracy.derived", "buffer_test": "accuracy.buffer",
    "qa_run": "qa.verdict",
    "project": "files.project", "tables": "files.csv_tables", "assemble": "files.assemble",
    "io": "files.readers", "outputs": "files.outputs", "report": "files.report",
    "derived_io": "files.derived_outputs",
    "cli_buffer": "cli.buffer", "cli_propagate": "cli.propagate", "cli_qa": "cli.qa",
    "clitools": "cli.tools",
}
#: old package -> new package: the package and every module below it (0.3: conflation
#: corrects the databases and left ``accuracy``)
MOVED_PACKAGES = {"accuracy.conflation": "conflation"}
MOVED.update({"accuracy.smart": "conflation.smart", "files.tables": "files.csv_tables"})
# ``accuracy``, ``qa``, ``cli`` and ``simulate`` are packages now; their __init__ modules
# give the old modules' public names.

_PREFIX = "vectoradjust."


class _AliasLoader(importlib.abc.Loader):
    def __init__(self, target: str) -> None:
        self.target = target

    def create_module(self, spec):
        warnings.warn(f"{spec.name} is deprecated: import {self.target} instead",
                      DeprecationWarning, stacklevel=2)
        return importlib.import_module(self.target)

    def exec_module(self, module) -> None:  # the target module is already executed
        return None


class _AliasFinder(importlib.abc.MetaPathFinder):
    def find_spec(self, fullname, path=None, target=None):
        if not fullname.startswith(_PREFIX):
            return None
        name = fullname[len(_PREFIX):]
        new = MOVED.get(name)
        for old_pkg, new_pkg in MOVED_PACKAGES.items():
            if name == old_pkg or name.startswith(old_pkg + "."):
                new = new_pkg + name[len(old_pkg):]
        if new is None:
            return None
        return importlib.machinery.ModuleSpec(fullname, _AliasLoader(_PREFIX + new))


def install() -> None:
    """Put the alias finder on ``sys.meta_path`` (once)."""
    if not any(isinstance(f, _AliasFinder) for f in sys.meta_path):
        sys.meta_path.insert(0, _AliasFinder())  # before the path finder: a moved
        # package's old name must not load its modules a second time from the new folder
