"""The names of the former ``vectoradjust.cli.commands`` module (kept for imports written
before the command line was split into one module per command; new code imports from
:mod:`vectoradjust.cli`, :mod:`~vectoradjust.cli.adjust`,
:mod:`~vectoradjust.cli.compare`, :mod:`~vectoradjust.cli.demo` and
:mod:`~vectoradjust.cli.printing`)."""

from __future__ import annotations

from vectoradjust.cli import build_parser, main
from vectoradjust.cli.adjust import StageBars, cmd_adjust, run_options
from vectoradjust.cli.compare import cmd_compare, compare
from vectoradjust.cli.demo import cmd_demo, sample_project_dir
from vectoradjust.cli.printing import compare_row, print_table
from vectoradjust.cli.progress import ProgressBar

__all__ = ["main", "build_parser", "ProgressBar", "StageBars", "sample_project_dir", "compare",
           "compare_row", "print_table", "run_options", "cmd_adjust", "cmd_compare",
           "cmd_demo"]
