"""Option definitions shared by the ``vectoradjust`` subcommands (the way rasterio's
``rio`` shares its options): each option that more than one command takes is declared
here once, with one help text and one default, and every command module adds it with
the function of this module.

Help style: lower case start, no trailing period; :class:`HelpFormatter` appends
``(default: ...)`` to every option that has a default other than None or False, so
help strings do not state defaults themselves (an option whose default is computed
says ``(default: ...)`` in its own words).
"""

from __future__ import annotations

import argparse
from typing import Callable, Optional

__all__ = ["HelpFormatter", "add_command", "add_project_command", "add_project", "add_out",
           "add_quiet", "add_format", "add_vectors", "add_no_bands", "add_seed", "add_repeats",
           "add_pair", "add_crs", "add_contour_interval", "FORMATS"]

FORMATS = ("gpkg", "shp")  # the output formats of the vector layers


class HelpFormatter(argparse.ArgumentDefaultsHelpFormatter):
    """:class:`argparse.ArgumentDefaultsHelpFormatter` that states a default only when
    there is one: not for None, False (a flag) or positional arguments, nor when the
    help text already says ``(default``."""

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        if (not action.option_strings or "(default" in text or "%(default)" in text
                or any(action.default is v for v in (None, False, argparse.SUPPRESS))):
            return text
        return text + " (default: %(default)s)"


def add_command(subparsers, name: str, func: Callable, help: str,
                description: Optional[str] = None) -> argparse.ArgumentParser:
    """Add subcommand ``name`` running ``func(args)``.

    Parameters
    ----------
    subparsers : argparse._SubParsersAction
        From ``ArgumentParser.add_subparsers()``.
    name : str
        The subcommand.
    func : callable
        Runs the command; set as the ``func`` default of its namespace.
    help : str
        One line for the list of commands (lower case start, no trailing period).
    description : str, optional
        The longer text of ``vectoradjust NAME --help`` (default: ``help``).

    Returns
    -------
    argparse.ArgumentParser
        The subcommand's parser (formatted by :class:`HelpFormatter`).
    """
    p = subparsers.add_parser(name, help=help, description=description or help,
                              formatter_class=HelpFormatter)
    if func is not None:
        p.set_defaults(func=func)
    return p


def add_project_command(subparsers, name: str, func: Callable, help: str,
                        description: Optional[str] = None,
                        out_help: str = "output directory") -> argparse.ArgumentParser:
    """:func:`add_command` for a command on a project file: with the positional
    ``project`` (:func:`add_project`) and ``-o/--out`` (:func:`add_out`, required,
    ``out_help``) already added."""
    p = add_command(subparsers, name, func, help, description)
    add_project(p)
    add_out(p, help=out_help)
    return p


def add_project(parser, help: str = "project file (TOML)") -> None:
    """The positional ``project`` (a project file)."""
    parser.add_argument("project", help=help)


def add_out(parser, required: bool = True, default: Optional[str] = None,
            help: str = "output directory") -> None:
    """``-o/--out``: where the command writes (a folder, or the file ``help`` names)."""
    parser.add_argument("-o", "--out", required=required, default=default, help=help)


def add_quiet(parser, help: str = "no progress bar") -> None:
    """``-q/--quiet``: print less (``help`` says what is left out)."""
    parser.add_argument("-q", "--quiet", action="store_true", help=help)


def add_format(parser, help: str = "output format of the vector layers") -> None:
    """``--format gpkg|shp`` (default gpkg)."""
    parser.add_argument("--format", choices=FORMATS, default="gpkg", help=help)


def add_vectors(parser, help: str = "adjust only this [[vectors]] entry (repeatable)") -> None:
    """``--vectors NAME`` (repeatable): the [[vectors]] entries the command uses."""
    parser.add_argument("--vectors", action="append", metavar="NAME", help=help)


def add_no_bands(parser, help: str = "do not write the uncertainty_bands layer (saves time "
                                     "on large runs)") -> None:
    """``--no-bands``: no uncertainty_bands layer."""
    parser.add_argument("--no-bands", action="store_true", help=help)


def add_seed(parser, default: int = 0, help: str = "random seed") -> None:
    """``--seed N``."""
    parser.add_argument("--seed", type=int, default=default, help=help)


def add_repeats(parser, default: int, help: str) -> None:
    """``--repeats N``."""
    parser.add_argument("--repeats", type=int, default=default, help=help)


def add_pair(parser, help: str = "the stereo pair (default: the first two images)") -> None:
    """``--images A B``: a stereo pair of image ids."""
    parser.add_argument("--images", nargs=2, metavar=("A", "B"), help=help)


def add_crs(parser, help: str) -> None:
    """``--crs CRS``: a projected CRS in metres (EPSG code, WKT, PROJ string)."""
    parser.add_argument("--crs", help=help)


def add_contour_interval(parser, default: Optional[float] = None,
                         help: str = "contour interval in m") -> None:
    """``--contour-interval H`` (metres)."""
    parser.add_argument("--contour-interval", type=float, default=default, metavar="H",
                        help=help)
