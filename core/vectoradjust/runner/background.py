"""Run one stage of a project's run in a forked child process while the parent goes on.

A run has more cores to use: :func:`vectoradjust.run_project` (``adjust``) builds the
uncertainty bands (the longest stage after the solve) in children, one share of the
features each, while the parent runs the ``[truth]`` tests and writes the other layers.
A child is a ``fork`` of the parent (it sees the adjusted run without copying it), sends
its progress and then its result back through a pipe, and the parent waits only where
it needs the result.

Where ``fork`` is not safe or not available (anything but Linux: macOS's system
libraries may not survive a fork; Windows has none), with ``VECTORADJUST_WORKERS=1``, or
when a child fails, the stage runs in the parent: the outputs are the same
either way, and an error is raised where it would have been raised without the child.
"""

from __future__ import annotations

import gc
import importlib
import multiprocessing
import multiprocessing.connection
import os
import sys
import threading
import time
import traceback
from typing import Callable, Optional

from vectoradjust.errors import VectorAdjustError

__all__ = ["Background", "Preload", "gather", "workers"]


def workers() -> int:
    """Processes a run may use: ``VECTORADJUST_WORKERS``, else the CPUs.

    Raises
    ------
    VectorAdjustError
        ``VECTORADJUST_WORKERS`` is set but not a whole number >= 1.
    """
    env = os.environ.get("VECTORADJUST_WORKERS", "").strip()
    if env:
        if not (env.isdigit() and int(env) >= 1):
            raise VectorAdjustError(
                f"VECTORADJUST_WORKERS={env!r} is not a whole number >= 1",
                "Set it to the number of processes to use (1: no second process), or unset it")
        return int(env)
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not on Linux
        return max(1, os.cpu_count() or 1)


#: seconds between two progress messages of a child: the parent may read its pipe only
#: after minutes of other work, and a full pipe (64 KiB) would stop the child
PROGRESS_INTERVAL = 1.0


def _child(conn, fn, args, kwargs) -> None:
    last = [0.0]

    def progress(fraction: float, message: str = "") -> None:
        now = time.monotonic()
        # ~100 bytes a second at most, and the end always (a bar left short of 100 %)
        if now - last[0] >= PROGRESS_INTERVAL or fraction >= 1.0:
            last[0] = now
            conn.send(("progress", float(fraction), str(message)[:200]))

    try:
        value = fn(*args, progress=progress, **kwargs)
        conn.send(("result", value))
    except BaseException:  # noqa: BLE001 - reported to the parent, which runs it again
        try:
            conn.send(("failed", traceback.format_exc()))
        except Exception:  # noqa: BLE001 - the pipe is gone: the parent sees EOF
            pass
    finally:
        conn.close()


class Background:
    """``fn(*args, progress=..., **kwargs)`` started in a forked child.

    Parameters
    ----------
    fn : callable
        Takes a ``progress(fraction, message)`` keyword; its result must pickle.
    *args, **kwargs
        Passed to ``fn``.
    enabled : bool
        False (or no ``fork``, or a single worker) runs nothing now: :meth:`result`
        then calls ``fn`` in the parent.
    """

    def __init__(self, fn: Callable, *args, enabled: bool = True, **kwargs) -> None:
        self.fn, self.args, self.kwargs = fn, args, kwargs
        self.proc = None
        self.conn = None
        self.failure: Optional[str] = None
        self.done, self.value = False, None
        if not (enabled and workers() > 1 and sys.platform.startswith("linux")
                and "fork" in multiprocessing.get_all_start_methods()):
            return
        ctx = multiprocessing.get_context("fork")
        recv, send = ctx.Pipe(duplex=False)
        self.proc = ctx.Process(target=_child, args=(send, fn, args, kwargs), daemon=True)
        # the parent's objects are left out of the child's garbage collections: a
        # collection writes into every object it visits, which would copy the page of
        # each one from the parent (time and memory) although the child never uses them
        gc.freeze()
        try:
            self.proc.start()
        finally:
            gc.unfreeze()
        send.close()
        self.conn = recv

    @property
    def forked(self) -> bool:
        """True when the stage runs in a child process."""
        return self.proc is not None

    def result(self, progress: Optional[Callable] = None, rerun: bool = True):
        """Wait for the child (forwarding its progress) and return ``fn``'s result; run
        ``fn`` here instead when there is no child or it failed (with ``rerun=False``
        return None then: the caller has a cheaper way)."""
        say = progress or (lambda fraction, message="": None)
        while self.proc is not None and not self._receive(say):
            pass
        if self.done:
            return self.value
        return self.fn(*self.args, progress=say, **self.kwargs) if rerun else None

    def _receive(self, say) -> bool:
        """Read one message of the child; True when it has ended (result or failure)."""
        try:
            kind, *rest = self.conn.recv()
        except EOFError:  # the child died (e.g. out of memory)
            self.failure = f"the child process ended with code {self.proc.exitcode}"
            self.close()
            return True
        if kind == "progress":
            say(*rest)
            return False
        if kind == "result":
            self.done, self.value = True, rest[0]
        else:
            self.failure = rest[0]
        self.close()
        return True

    def close(self) -> None:
        """Stop the child if it still runs (e.g. the parent was interrupted)."""
        if self.conn is not None:
            self.conn.close()
            self.conn = None
        if self.proc is not None:
            self.proc.join(timeout=5)
            if self.proc.is_alive():
                self.proc.terminate()
                self.proc.join()
            self.proc = None


def gather(jobs: list, progress: Optional[Callable] = None) -> list:
    """The results of several :class:`Background` jobs, in order.

    Their pipes are read as messages arrive (a child never waits for the parent to
    finish reading another), and their progress is forwarded as the mean fraction.
    """
    say = progress or (lambda fraction, message="": None)
    frac = [0.0] * len(jobs)

    def sayer(i):
        def s(fraction, message=""):
            frac[i] = fraction
            say(sum(frac) / len(frac), message)
        return s

    live = {j.conn: (i, j) for i, j in enumerate(jobs) if j.proc is not None}
    while live:
        for conn in multiprocessing.connection.wait(list(live)):
            i, j = live[conn]
            if j._receive(sayer(i)):
                del live[conn]
    return [j.result(sayer(i)) for i, j in enumerate(jobs)]


class Preload:
    """Import modules in a thread while the main thread computes.

    Reading the inputs spends much of its time in C code that lets other threads run,
    so the adjustment's modules load meanwhile; matplotlib (for the report) loads once
    the adjustment is final, while the statistics run. An import holds the interpreter
    most of the time, so it costs the main thread some of its time wherever it runs.
    :meth:`wait` before a ``fork``: a child must not inherit a module half imported by a
    thread it does not have. An import that fails is left to fail again, with its
    message, where the module is used.
    """

    def __init__(self, names) -> None:
        self.thread = threading.Thread(target=self._load, args=(tuple(names),), daemon=True)
        self.thread.start()

    @staticmethod
    def _load(names) -> None:
        for name in names:
            try:
                importlib.import_module(name)
            except Exception:  # noqa: BLE001 - reported where the module is used
                return

    def wait(self) -> None:
        """Until every import has ended."""
        self.thread.join()
