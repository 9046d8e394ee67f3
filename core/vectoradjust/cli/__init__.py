"""The ``vectoradjust`` command line: one module per command group.

- :mod:`~vectoradjust.cli.commands` - ``demo``, ``adjust``, ``compare`` and the parser
  (the run itself and its forked processes: :mod:`vectoradjust.runner`).
- :mod:`~vectoradjust.cli.qa` - ``qa``.
- :mod:`~vectoradjust.cli.propagate` - ``propagate``, ``equal-error``, ``two-step``.
- :mod:`~vectoradjust.cli.buffer` - ``buffer-test``.
- :mod:`~vectoradjust.cli.measure` - ``measure``.
- :mod:`~vectoradjust.cli.study` - ``study``.
- :mod:`~vectoradjust.cli.dtm` - ``dtm``.
- :mod:`~vectoradjust.cli.drone` - ``import-images``.
- :mod:`~vectoradjust.cli.many` - ``adjust-many``.
- :mod:`~vectoradjust.cli.conflate` - ``conflate``.
- :mod:`~vectoradjust.cli.progress` - the progress bar; :mod:`~vectoradjust.cli.tools` -
  error handling and table formatting.
- ``__main__`` - ``python -m vectoradjust.cli``.
"""

from __future__ import annotations


def main(argv=None) -> int:
    """Run the ``vectoradjust`` command (the console script's entry point)."""
    from vectoradjust.cli.commands import main as _main

    return _main(argv)


def __getattr__(name: str):  # the pre-0.2 module vectoradjust.cli (kept: see _compat)
    import importlib

    if name.startswith("__"):
        raise AttributeError(name)
    _main_module = importlib.import_module("vectoradjust.cli.commands")

    if name in _main_module.__all__:
        return getattr(_main_module, name)
    raise AttributeError(f"module 'vectoradjust.cli' has no attribute {name!r}")
