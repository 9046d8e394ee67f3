"""Production accuracy control (DESIGN section 7).

- :mod:`~vectoradjust.qa.tolerances` - tolerances from the product specification.
- :mod:`~vectoradjust.qa.verdict` - the pass/fail verdict on an adjustment.
- :mod:`~vectoradjust.qa.text` - the verdict as readable text.

``vectoradjust.qa`` was the tolerance module until 0.1; its names are still reachable
here for one release.
"""

from __future__ import annotations


def __getattr__(name: str):  # the pre-0.2 module vectoradjust.qa, for one release
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
