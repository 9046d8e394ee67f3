"""Accuracy: statistics of the adjusted points and quantities derived from them.

- :mod:`~vectoradjust.accuracy.stats` - CE90/LE90, RMSE, NSSDA, Ager, chi-square
  (docs/method.md section 4).
- :mod:`~vectoradjust.accuracy.tables` - the per-vertex, per-feature and control-point
  tables of a run (the contract's fields).
- :mod:`~vectoradjust.accuracy.summary` - the run summary (summary.json).
- :mod:`~vectoradjust.accuracy.statements` - accuracy statements per database, feature
  and check points.
- :mod:`~vectoradjust.accuracy.propagate` - error propagation to derived quantities
  (docs/method.md section 6).
- :mod:`~vectoradjust.accuracy.derived` - derived quantities of an adjustment (length
  sigma, uncertainty bands, equal-error map, two-step comparison).
- :mod:`~vectoradjust.accuracy.buffer` - the buffer test (shapely, imported lazily).
- :mod:`~vectoradjust.accuracy.capped_buffer` - the buffer test with flat or square end
  caps, exactly, by segments (numpy only).
- :mod:`~vectoradjust.accuracy.line_distances` - distances to the nearest reference line
  when only the lines near the points were read.
- :mod:`~vectoradjust.accuracy._bandkernel`, :mod:`~vectoradjust.accuracy._unionkernel` -
  the compiled (numba) G-band rings and band unions, used by ``derived`` when numba is
  installed.
- :mod:`~vectoradjust.accuracy.consistency` - do the road databases and the control
  agree.
- :mod:`~vectoradjust.accuracy.identification` - the identification error estimated from
  the data.
- :mod:`~vectoradjust.accuracy.dtm` - DTM and contour accuracy.
- :mod:`~vectoradjust.accuracy.study` - the numerical pieces of the dissertation's
  experiments.
- :mod:`~vectoradjust.accuracy.residual_vectors` - residual vectors as map lines (start,
  scaled end, length, azimuth; the QGIS plugin's residual layer).

``vectoradjust.accuracy`` was a module until 0.1; its names (``accuracy_statements`` ...)
are still reachable here, with a DeprecationWarning (the package's ``__getattr__``;
see :mod:`vectoradjust._compat` for how long).
"""

from __future__ import annotations


def __getattr__(name: str):  # the pre-0.2 module vectoradjust.accuracy (kept: see _compat)
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
