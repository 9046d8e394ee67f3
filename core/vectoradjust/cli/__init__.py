"""The ``vectoradjust`` command line: one module per command group.

- :mod:`~vectoradjust.cli.commands` - ``demo``, ``adjust``, ``compare`` and the parser.
- :mod:`~vectoradjust.cli.qa` - ``qa``.
- :mod:`~vectoradjust.cli.propagate` - ``propagate``, ``equal-error``, ``two-step``.
- :mod:`~vectoradjust.cli.buffer` - ``buffer-test``.
- :mod:`~vectoradjust.cli.progress` - the progress bar; :mod:`~vectoradjust.cli.tools` -
  error handling and table formatting.
"""

from __future__ import annotations


def main(argv=None) -> int:
    """Run the ``vectoradjust`` command (the console script's entry point)."""
    from vectoradjust.cli.commands import main as _main

    return _main(argv)


def __getattr__(name: str):  # the pre-0.2 module vectoradjust.cli, for one release
    import importlib

    if name.startswith("__"):
        raise AttributeError(name)
    _main_module = importlib.import_module("vectoradjust.cli.commands")

    if name in _main_module.__all__:
        return getattr(_main_module, name)
    raise AttributeError(f"module 'vectoradjust.cli' has no attribute {name!r}")
