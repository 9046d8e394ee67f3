"""The console progress bar shared by every command."""

from __future__ import annotations

import sys
import time

__all__ = ["ProgressBar"]


class ProgressBar:
    """A one-line progress bar on stderr (plain lines when stderr is not a terminal)."""

    def __init__(self, label: str, enabled: bool = True, stream=None, width: int = 30) -> None:
        self.label = label
        self.enabled = enabled
        self.stream = stream or sys.stderr
        self.width = width
        self.tty = hasattr(self.stream, "isatty") and self.stream.isatty()
        self._last_msg = None
        self.t0 = time.perf_counter()
        self._last_line = -1e9
        self._done = 0.0  # the bar never moves back (the adjustment's passes restart lower)
        #: seconds between two lines of the same stage when stderr is not a terminal
        self.every = 2.0

    def __call__(self, fraction: float, message: str = "") -> None:
        if not self.enabled:
            return
        fraction = min(max(float(fraction), 0.0, self._done), 1.0)
        self._done = fraction
        filled = int(round(fraction * self.width))
        bar = "#" * filled + "-" * (self.width - filled)
        elapsed = time.perf_counter() - self.t0
        line = f"{self.label} [{bar}] {fraction * 100:5.1f}% {elapsed:6.1f}s {message}"
        if self.tty:
            self.stream.write("\r" + line[:120].ljust(120))
            if fraction >= 1.0:
                self.stream.write("\n")
        elif message != self._last_msg and (
                _stage(message) != _stage(self._last_msg) or fraction >= 1.0
                or time.perf_counter() - self._last_line >= self.every):
            # a log gets a line per stage, and within a stage (messages that differ only
            # in their numbers: "uncertainty bands: OSM 12 %") one every `every` seconds
            self.stream.write(line + "\n")
            self._last_line = time.perf_counter()
        self._last_msg = message
        self.stream.flush()


def _stage(message) -> str:
    """A message without its numbers (``"iteration 3: v'Pv = 12.5"`` -> ``"iteration :
    v'Pv = ."``): messages of one stage compare equal."""
    return "".join(c for c in str(message) if not c.isdigit())
