"""Accuracy: statistics of the adjusted points and quantities derived from them.

- :mod:`~vectoradjust.accuracy.stats` - CE90/LE90, RMSE, NSSDA, Ager, chi-square
  (DESIGN section 4).
- :mod:`~vectoradjust.accuracy.tables` - the per-vertex, per-feature and control-point
  tables of a run (the contract's fields).
- :mod:`~vectoradjust.accuracy.summary` - the run summary (summary.json).
- :mod:`~vectoradjust.accuracy.statements` - accuracy statements per database, feature
  and check points.
- :mod:`~vectoradjust.accuracy.propagate` - error propagation to derived quantities
  (DESIGN section 6).
- :mod:`~vectoradjust.accuracy.derived` - derived quantities of an adjustment (length
  sigma, uncertainty bands, equal-error map, two-step comparison).
- :mod:`~vectoradjust.accuracy.buffer` - the buffer test (shapely, imported lazily).

``vectoradjust.accuracy`` was a module until 0.1; its names (``accuracy_statements`` ...)
are still reachable here for one release.
"""

from __future__ import annotations


def __getattr__(name: str):  # the pre-0.2 module vectoradjust.accuracy, for one release
    import importlib

    if name.startswith("__"):
        raise AttributeError(name)
    statements = importlib.import_module("vectoradjust.accuracy.statements")

    if name in statements.__all__:
        import warnings

        warnings.warn(f"vectoradjust.accuracy.{name} moved to "
                      f"vectoradjust.accuracy.statements.{name}", DeprecationWarning,
                      stacklevel=2)
        return getattr(statements, name)
    raise AttributeError(f"module 'vectoradjust.accuracy' has no attribute {name!r}")
