"""Shared pieces of the command-line modules: JSON output and error handling."""

from __future__ import annotations

import sys

from vectoradjust.errors import CancelledError, VectorAdjustError
from vectoradjust.files.jsonfile import clean_json, write_json
from vectoradjust.formatting import fmt_number

__all__ = ["clean_json", "write_json", "run_command", "run_alone", "fmt_number"]


def run_command(args) -> int:
    """Call ``args.func(args)``; user errors become one message and an exit status.

    Returns 0 on success, 1 for a :class:`VectorAdjustError`, 130 when cancelled or
    interrupted.
    """
    try:
        return int(args.func(args) or 0)
    except CancelledError as exc:
        print(f"\nvectoradjust: cancelled: {exc}", file=sys.stderr)
        return 130
    except VectorAdjustError as exc:
        print(f"\nvectoradjust: error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("\nvectoradjust: interrupted", file=sys.stderr)
        return 130


def run_alone(add_parser, command: str, argv=None) -> int:
    """Run one subcommand as its own program (``python -m vectoradjust.cli.<module>``):
    its parser alone, ``command`` put in front of ``argv`` when it is missing."""
    import argparse

    parser = argparse.ArgumentParser(prog="vectoradjust")
    add_parser(parser.add_subparsers(dest="command"))
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] != command:
        argv = [command, *argv]
    return run_command(parser.parse_args(argv))
