"""Shared pieces of the command-line modules: JSON output and error handling."""

from __future__ import annotations

import sys

from vectoradjust.errors import CancelledError, VectorAdjustError
from vectoradjust.files.jsonfile import clean_json, write_json
from vectoradjust.formatting import fmt_number

__all__ = ["clean_json", "write_json", "run_command", "fmt_number"]


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
