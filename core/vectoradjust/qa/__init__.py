"""Production accuracy control (docs/method.md section 7).

- :mod:`~vectoradjust.qa.tolerances` - tolerances from the product specification.
- :mod:`~vectoradjust.qa.verdict` - the pass/fail verdict on an adjustment.
- :mod:`~vectoradjust.qa.text` - the verdict as readable text.
- :mod:`~vectoradjust.qa.zones` - tie-point zones of the overlaps, strips, inter-strip ties.
- :mod:`~vectoradjust.qa.free_model` - the free-model stage (measurements before control).

``vectoradjust.qa`` was the tolerance module until 0.1; its names are still reachable
here, with a DeprecationWarning (the package's ``__getattr__``; see
:mod:`vectoradjust._compat` for how long).
"""

from __future__ import annotations


def __getattr__(name: str):  # the pre-0.2 module vectoradjust.qa (kept: see _compat)
    import importlib

    if name.startswith("__"):
        raise AttributeError(name)
    tolerances = importlib.import_module("vectoradjust.qa.tolerances")

    if name in tolerances.__all__:
        import warnings

        warnings.warn(f"vectoradjust.qa.{name} moved to vectoradjust.qa.tolerances.{name}",
                      DeprecationWarning, stacklevel=2)
        return getattr(tolerances, name)
    raise AttributeError(f"module 'vectoradjust.qa' has no attribute {name!r}")
