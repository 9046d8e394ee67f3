"""The ``vectoradjust`` command line: one module per command, the way rasterio's ``rio``
is built; :func:`build_parser` puts them together and :func:`main` runs one.

- :mod:`~vectoradjust.cli.adjust` - ``adjust`` (and the run options, progress bars per
  stage and output folder that ``compare`` and ``demo`` share with it; the run itself and
  its forked processes: :mod:`vectoradjust.runner`).
- :mod:`~vectoradjust.cli.compare` - ``compare``.
- :mod:`~vectoradjust.cli.demo` - ``demo``.
- :mod:`~vectoradjust.cli.qa` - ``qa``.
- :mod:`~vectoradjust.cli.propagate` - ``propagate``, ``equal-error``, ``two-step``.
- :mod:`~vectoradjust.cli.buffer` - ``buffer-test``.
- :mod:`~vectoradjust.cli.measure` - ``measure``.
- :mod:`~vectoradjust.cli.study` - ``study``.
- :mod:`~vectoradjust.cli.dtm` - ``dtm``.
- :mod:`~vectoradjust.cli.drone` - ``import-images``.
- :mod:`~vectoradjust.cli.many` - ``adjust-many``.
- :mod:`~vectoradjust.cli.conflate` - ``conflate``.
- :mod:`~vectoradjust.cli.options` - the options several commands share (``-o/--out``,
  ``-q/--quiet``, ``--format``, ``--vectors``, ...) and the help formatter.
- :mod:`~vectoradjust.cli.printing` - the adjustment summary and comparison table printed.
- :mod:`~vectoradjust.cli.progress` - the progress bar; :mod:`~vectoradjust.cli.tools` -
  error handling and table formatting.
- :mod:`~vectoradjust.cli.commands` - the names of the former single module, re-exported.
- ``__main__`` - ``python -m vectoradjust.cli``.

User errors print one clear message and exit with status 1; usage errors exit with 2; an
interrupted run exits with 130 (:func:`vectoradjust.cli.tools.run_command`).
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from typing import Optional

__all__ = ["build_parser", "main"]


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of the ``vectoradjust`` command (the command modules are
    imported here: ``import vectoradjust.cli`` stays cheap)."""
    from vectoradjust import __version__
    from vectoradjust.cli import (
        adjust,
        buffer,
        compare,
        conflate,
        demo,
        drone,
        dtm,
        many,
        measure,
        propagate,
        qa,
        study,
    )
    from vectoradjust.cli.options import HelpFormatter

    p = argparse.ArgumentParser(
        prog="vectoradjust", formatter_class=HelpFormatter,
        description="Photogrammetric adjustment of road vectors: how far each vertex is from "
                    "the truth, where it belongs, and how sure that is.",
    )
    p.add_argument("--version", action="version", version=f"vectoradjust {__version__}")
    sub = p.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for module in (demo, adjust, compare, qa):
        module.add_parser(sub)
    propagate.add_parsers(sub)
    for module in (buffer, study, many, measure, drone, dtm, conflate):
        module.add_parser(sub)
    return p


def main(argv: Optional[Sequence[str]] = None) -> int:
    """Run the ``vectoradjust`` command (the console script's entry point).

    Parameters
    ----------
    argv : sequence of str, optional
        The arguments (default: ``sys.argv[1:]``).

    Returns
    -------
    int
        The exit status: 0 done, 1 a user error (its message printed), 2 a usage error,
        130 interrupted.
    """
    from vectoradjust.cli.tools import run_command

    args = build_parser().parse_args(argv)
    return run_command(args)


def __getattr__(name: str):  # the pre-0.2 module vectoradjust.cli (kept: see _compat)
    import importlib

    if name.startswith("__"):
        raise AttributeError(name)
    _main_module = importlib.import_module("vectoradjust.cli.commands")

    if name in _main_module.__all__:
        return getattr(_main_module, name)
    raise AttributeError(f"module 'vectoradjust.cli' has no attribute {name!r}")
