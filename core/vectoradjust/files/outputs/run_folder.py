"""The run's output folder: locked, staged, committed with its manifest last.

A whole run (the command line's layers, tables, report, ...) is written through
:class:`RunFolder`: its output folder locked (:class:`DirLock`), the files staged and
moved into place at the end, ``run_manifest.json`` (:data:`MANIFEST`) last; a full disk
is recognised (:func:`is_disk_full`) and said as such. :func:`json_default` encodes
numpy values in the manifest and ``summary.json``.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import tempfile
from pathlib import Path
from typing import Optional

import numpy as np

from vectoradjust.errors import CancelledError, InputFileError
from vectoradjust.files.jsonfile import FEATURE_ACCURACY_CSV

__all__ = [
    "json_default",
    "RunFolder",
    "DirLock",
    "MANIFEST",
    "LOCK_NAME",
    "is_disk_full",
    "read_manifest",
    "NEARLY_FULL_BYTES",
]


def json_default(o):
    """JSON encoder fallback for numpy scalars and arrays (NaN -> null)."""
    if isinstance(o, np.integer):
        return int(o)
    if isinstance(o, np.floating):
        v = float(o)
        return v if math.isfinite(v) else None
    if isinstance(o, np.bool_):
        return bool(o)
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serialisable: {type(o)}")


#: the record of a finished run, moved into its folder last: every file of the run with
#: its size and SHA-256 and ``"complete": true``. A folder whose manifest is missing, or
#: says ``"complete": false``, or does not match the files, holds no complete result.
MANIFEST = "run_manifest.json"
#: the lock of a folder while a run writes into it (the writing process's pid inside)
LOCK_NAME = ".vectoradjust.lock"
#: the staging folder of a run inside its output folder (hidden; removed at the end)
_STAGE_PREFIX = ".vectoradjust-stage-"
#: temporaries of runs (staging folders, band shares, probes) left by a killed run
_LEFTOVER_PREFIXES = (".vectoradjust-", ".vectoradjust-probe-")
#: file names the commands write: such files in a folder that no manifest claims are
#: reported (they may be left by a run of an older version, or be the user's)
_PRODUCT_NAMES = frozenset(
    ["adjusted.gpkg", "summary.json", "report.html", "qa.json", "flagged_observations.csv",
     FEATURE_ACCURACY_CSV, "truth_points.csv", "truth_line_points.csv", "compare.csv",
     "compare.json", "common_points.csv"]
    + [f"{stem}.{ext}" for stem in ("shape_points", "features", "control_points",
                                    "uncertainty_bands")
       for ext in ("shp", "shx", "dbf", "prj", "cpg")])
#: the files a user opens first are moved into place last
_LAST = ("report.html", "summary.json")

_ACTIVE: dict = {}  # real path of a folder -> its RunFolder open in this process
_LOCK_FDS: set = set()  # descriptors of the locks this process holds


def _close_locks_in_child() -> None:
    """A forked child (band shares, the report) holds no lock of its parent: the lock
    ends with the run's own process, not with a child left running after a kill."""
    for fd in list(_LOCK_FDS):
        try:
            os.close(fd)
        except OSError:
            pass
    _LOCK_FDS.clear()


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_close_locks_in_child)


def _now() -> str:
    import datetime

    return datetime.datetime.now().astimezone().isoformat(timespec="seconds")


def _try_lock(fd: int) -> bool:
    """An exclusive, non-blocking lock on the open file ``fd`` (False: held elsewhere).
    The system lets go of it when the holding process ends, however it ends."""
    try:
        import fcntl
    except ImportError:  # Windows: a byte far beyond the text, so the pid stays readable
        import msvcrt

        os.lseek(fd, 1 << 20, os.SEEK_SET)
        try:
            msvcrt.locking(fd, msvcrt.LK_NBLCK, 1)
        except OSError:
            return False
        return True
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:  # BlockingIOError: another process holds it
        return False
    return True


def _holder(fd: int) -> dict:
    """The lock file's record of its holder (empty when unreadable)."""
    try:
        os.lseek(fd, 0, os.SEEK_SET)
        doc = json.loads(os.read(fd, 4096).decode("utf-8") or "{}")
    except (OSError, ValueError):
        return {}
    return doc if isinstance(doc, dict) else {}


def _same_file(fd: int, path: Path) -> bool:
    try:
        a, b = os.fstat(fd), os.stat(path)
    except OSError:
        return False
    return (a.st_dev, a.st_ino) == (b.st_dev, b.st_ino)


def _busy_error(folder: Path, lock: Path, holder: dict) -> InputFileError:
    who = []
    if holder.get("pid"):
        who.append(f"pid {holder['pid']}")
    if holder.get("host") and holder.get("host") != _hostname():
        who.append(f"on {holder['host']}")
    if holder.get("command"):
        who.append(str(holder["command"]))
    if holder.get("started"):
        who.append(f"since {holder['started']}")
    return InputFileError(
        f"Another vectoradjust run{' (' + ', '.join(who) + ')' if who else ''} is writing "
        f"into the output directory {str(folder)!r}",
        "Wait until it has finished, or give this run another output directory (--out): "
        "two runs into one folder would mix their files",
        path=str(folder), details={"lock": str(lock), **holder})


def _hostname() -> str:
    import socket

    return socket.gethostname()


class DirLock:
    """An exclusive lock on an output folder: the file ``.vectoradjust.lock`` in it,
    holding the pid, host, command and start of the run that writes there.

    The lock itself is the system's (``flock``; on Windows ``msvcrt.locking``), which
    ends with the holding process however it ends: a run that was killed leaves the file,
    with its dead pid, and the next run takes it over. A second run while the first
    lives gets a clear error (:class:`~vectoradjust.errors.InputFileError`) naming the
    first one's pid. Forked children do not hold their parent's lock.

    Parameters
    ----------
    folder : str or os.PathLike
        An existing folder.
    command : str
        What holds it (shown to a second run).
    """

    def __init__(self, folder, command: str = "vectoradjust") -> None:
        self.folder = Path(folder)
        self.path = self.folder / LOCK_NAME
        self.command = command
        self.fd: Optional[int] = None
        self.pid: Optional[int] = None
        #: the record of the lock's previous holder, a run that ended without letting go
        #: (killed), or None
        self.taken_over: Optional[dict] = None

    def acquire(self) -> DirLock:
        """Take the lock (OSError: the folder is not writable; InputFileError: held)."""
        for _ in range(100):
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
            if not _try_lock(fd):
                holder = _holder(fd)
                os.close(fd)
                raise _busy_error(self.folder, self.path, holder)
            if _same_file(fd, self.path):  # not removed by its holder meanwhile
                break
            os.close(fd)
        else:  # pragma: no cover - a lock file replaced a hundred times in a row
            raise _busy_error(self.folder, self.path, {})
        old = _holder(fd)
        self.taken_over = old if old.get("pid") else None
        record = {"pid": os.getpid(), "host": _hostname(), "command": self.command,
                  "started": _now()}
        os.lseek(fd, 0, os.SEEK_SET)
        os.ftruncate(fd, 0)
        os.write(fd, json.dumps(record).encode("utf-8"))
        self.fd, self.pid = fd, os.getpid()
        _LOCK_FDS.add(fd)
        return self

    def release(self) -> None:
        """Let go (the file is removed); nothing in a forked child or when not held."""
        if self.fd is None or self.pid != os.getpid():
            return
        fd, self.fd = self.fd, None
        _LOCK_FDS.discard(fd)
        if os.name == "posix":  # removed while held: no other run takes a removed file
            if _same_file(fd, self.path):
                _unlink(self.path)
            os.close(fd)
        else:
            os.close(fd)
            _unlink(self.path)

    def __enter__(self) -> DirLock:
        try:
            return self.acquire()
        except InputFileError:  # held by another run (an OSError too): says so itself
            raise
        except OSError as exc:
            raise InputFileError(
                f"Cannot write into the output directory {str(self.folder)!r} ({exc})",
                "Choose a writable directory with --out", path=str(self.folder)) from exc

    def __exit__(self, *exc) -> bool:
        self.release()
        return False


def _unlink(path: Path) -> None:
    try:
        os.unlink(path)
    except OSError:
        pass


def _real(path) -> Path:
    return Path(os.path.realpath(os.fspath(path)))


def is_disk_full(exc: BaseException) -> bool:
    """True when ``exc`` (or an exception it was raised from) says the disk is full."""
    import errno

    seen = 0
    while exc is not None and seen < 10:
        if isinstance(exc, OSError) and exc.errno in (errno.ENOSPC,
                                                      getattr(errno, "EDQUOT", -1)):
            return True
        text = str(exc).lower()
        if any(s in text for s in ("no space left", "disk is full", "disk quota",
                                   "disk full")):
            return True
        exc = exc.__cause__ or exc.__context__
        seen += 1
    return False


#: a write error (GDAL, SQLite, OS) with less than this free on the disk is a full disk:
#: SQLite's own message can be lost ("cannot rollback - no transaction is active")
NEARLY_FULL_BYTES = 4 * 1024 * 1024


def _write_error_on_a_full_disk(exc: BaseException, folder: Path) -> bool:
    """A GDAL/OGR, SQLite or OS write error while the disk of ``folder`` is (nearly)
    full."""
    names = {type(e).__name__ for e in (exc, exc.__cause__, exc.__context__) if e is not None}
    if not (names & {"DataLayerError", "DataSourceError", "FieldError", "GeometryError",
                     "CPLE_AppDefinedError", "CPLE_FileIOError", "OperationalError"}
            or (isinstance(exc, OSError) and not isinstance(exc, InputFileError))):
        return False  # (an InputFileError is an OSError too: the user's, not the disk's)
    try:
        probe = Path(folder)
        while not probe.exists() and probe != probe.parent:
            probe = probe.parent
        return shutil.disk_usage(probe).free < NEARLY_FULL_BYTES
    except OSError:
        return False


def _disk_full_error(folder: Path, exc: BaseException) -> InputFileError:
    import errno

    text = " ".join(str(exc).split())[:200]
    cause = exc
    for _ in range(10):  # the system's own words, without the staging folder's name
        if cause is None:
            break
        if isinstance(cause, OSError) and cause.errno == errno.ENOSPC and cause.strerror:
            text = cause.strerror
            break
        cause = cause.__cause__ or cause.__context__
    return InputFileError(
        f"The disk of the output directory {str(folder)!r} is full ({text})",
        "Free some space or choose another directory with --out: a run needs room for all "
        "its new files beside the previous run's until it has finished (the previous "
        "result in the folder is left as it was)", path=str(folder))


def read_manifest(folder) -> Optional[dict]:
    """The :data:`MANIFEST` of ``folder`` (None: none, or not one of vectoradjust's)."""
    try:
        doc = json.loads((Path(folder) / MANIFEST).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    if not isinstance(doc, dict) or doc.get("written_by") != "vectoradjust" or \
            not isinstance(doc.get("files"), dict):
        return None
    return doc


def _inside(folder: Path, rel: str) -> bool:
    """``rel`` names a file in ``folder`` (a manifest cannot point outside it)."""
    from pathlib import PurePosixPath

    p = PurePosixPath(rel)
    return bool(rel) and not p.is_absolute() and ".." not in p.parts and \
        not p.parts[0].startswith(".") and rel != MANIFEST


def _staged_files(stage: Path) -> list:
    """The run's files in its staging folder (relative POSIX paths; hidden ones, the
    temporaries, left out)."""
    out = []
    for root, dirs, files in os.walk(stage):
        dirs[:] = sorted(d for d in dirs if not d.startswith("."))
        rel = Path(root).relative_to(stage)
        out += [(rel / f).as_posix() for f in sorted(files) if not f.startswith(".")]
    return out


def _file_entry(path: Path) -> dict:
    import hashlib

    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return {"size": path.stat().st_size, "sha256": h.hexdigest()}


def _write_doc(path: Path, doc: dict) -> None:
    with open(path, "w", encoding="utf-8") as fh:
        json.dump(doc, fh, indent=1, default=json_default)


def _listed(names: list, n: int = 8) -> str:
    return ", ".join(names[:n]) + (f" and {len(names) - n} more" if len(names) > n else "")


class RunFolder:
    """An output folder written as one whole: locked, staged, moved into place, recorded.

    Inside ``with RunFolder(out) as folder:`` every file of the run is written into
    ``folder.stage`` (a hidden folder in ``out``); :meth:`commit` moves them into place
    and writes :data:`MANIFEST` last. A run that fails, is cancelled or interrupted
    (Ctrl-C) leaves the folder as it was: the staging folder is removed on the way out.
    A run killed outright leaves its hidden staging folder and lock file, which the next
    run into the folder removes and takes over; the previous result stays complete.

    The commit removes the files of the previous run (those its manifest lists, and the
    :meth:`claim`-ed names) that this run did not write: a re-run in another format
    leaves no old layers beside the new ones. Files named like outputs but claimed by
    no manifest are left and reported in :attr:`notes`. While the commit moves the files
    (milliseconds), the manifest says ``"complete": false``: a run killed right then
    leaves a folder that says it is incomplete, never a mix that looks complete.

    :func:`write_outputs` called on ``out`` (or a folder inside it) while it is open
    writes into the staging folder (:meth:`holding`).

    Parameters
    ----------
    path : str or os.PathLike
        The output folder; created if missing (and removed again if the run left it
        empty).
    command : str
        The command writing it (in the lock and the manifest).

    Raises
    ------
    InputFileError
        On entering: the folder cannot be made or written, or another run holds it
        (:class:`DirLock`). On leaving with an exception that says the disk is full: that,
        with what to do.
    """

    def __init__(self, path, command: str = "adjust") -> None:
        self.path = Path(path)
        self.command = command
        self.stage: Optional[Path] = None
        #: what the run should be told: ``(kind, text)``, kind ``"info"`` or ``"warning"``
        self.notes: list = []
        self.claimed: set = set()
        self.committed = False
        self._lock = DirLock(self.path, command)
        self._made = False
        self._pid: Optional[int] = None
        self._started = _now()

    @staticmethod
    def holding(path) -> Optional[RunFolder]:
        """The open RunFolder of this process that ``path`` lies in, or None."""
        p = _real(path)
        for q in (p, *p.parents):
            f = _ACTIVE.get(q)
            if f is not None and f._pid == os.getpid():
                return f
        return None

    def staged(self, path) -> Path:
        """Where a file or folder meant for ``path`` (in this folder) is written now."""
        return self.stage / _real(path).relative_to(_real(self.path))

    def final(self, path) -> Path:
        """Where a file written into the staging folder ends up."""
        return self.path / _real(path).relative_to(_real(self.stage))

    def claim(self, *names, under=None) -> None:
        """Names of files this run owns in the folder (``under`` a folder in it) whether
        it writes them or not: left from an earlier run and not written now, they go."""
        base = _real(under if under is not None else self.path).relative_to(_real(self.path))
        self.claimed.update((base / n).as_posix() for n in names)

    def __enter__(self) -> RunFolder:
        self._made = False
        try:
            self._made = not self.path.exists()  # (PermissionError above an unsearchable folder)
            self.path.mkdir(parents=True, exist_ok=True)
            self._lock.acquire()
        except InputFileError:  # held by another run (an OSError too): says so itself
            self._drop_made()
            raise
        except OSError as exc:
            self._drop_made()
            raise InputFileError(
                f"Cannot write into the output directory {str(self.path)!r} ({exc})",
                "Choose a writable directory with --out", path=str(self.path)) from exc
        except BaseException:
            self._drop_made()
            raise
        self._pid = os.getpid()
        try:
            self._clear_leftovers()
            self.stage = Path(tempfile.mkdtemp(prefix=_STAGE_PREFIX, dir=self.path))
        except OSError as exc:
            self._lock.release()
            self._drop_made()
            raise InputFileError(
                f"Cannot write into the output directory {str(self.path)!r} ({exc})",
                "Choose a writable directory with --out", path=str(self.path)) from exc
        _ACTIVE[_real(self.path)] = self
        return self

    def __exit__(self, exc_type, exc, tb) -> bool:
        if self._pid != os.getpid():  # a forked child leaving the parent's frame
            return False
        _ACTIVE.pop(_real(self.path), None)
        if self.stage is not None:
            shutil.rmtree(self.stage, ignore_errors=True)
            self.stage = None
        self._lock.release()
        self._drop_made()
        if exc is not None and not isinstance(exc, (CancelledError, KeyboardInterrupt)) \
                and (is_disk_full(exc) or _write_error_on_a_full_disk(exc, self.path)):
            raise _disk_full_error(self.path, exc) from exc
        return False

    def _drop_made(self) -> None:
        """The folder removed again when this run made it and left nothing in it."""
        if self._made:
            try:
                self.path.rmdir()
            except OSError:
                pass

    def _clear_leftovers(self) -> None:
        """The temporaries of a run into this folder that was killed (its staging folder,
        its band shares): nobody else writes there while the lock is ours."""
        gone = []
        for p in self.path.iterdir():
            if p.name != LOCK_NAME and p.name.startswith(_LEFTOVER_PREFIXES):
                if p.is_dir() and not p.is_symlink():
                    shutil.rmtree(p, ignore_errors=True)
                else:
                    _unlink(p)
                gone.append(p.name)
        old = self._lock.taken_over
        if gone or (old and old.get("pid") != os.getpid()):
            pid = f" (pid {old['pid']})" if old and old.get("pid") else ""
            self.notes.append(("info", f"an earlier run into {self.path}{pid} did not finish; "
                               "its lock and temporary files were taken over and removed"))

    def commit(self) -> list:
        """Move the staged files into place, remove the previous run's files this run did
        not write, and write the manifest last.

        Returns
        -------
        list of (str, str)
            :attr:`notes`: the previous run's files removed, files named like outputs that
            no manifest claims (left where they are).
        """
        new = _staged_files(self.stage)
        entries = {rel: _file_entry(self.stage / rel) for rel in new}
        ours, sizes = self._previous_files()
        stale = sorted(r for r in ours - set(new) if (self.path / r).is_file()
                       and (sizes.get(r) is None or (self.path / r).stat().st_size == sizes[r]))
        foreign = sorted(p.name for p in self.path.iterdir()
                         if p.name in _PRODUCT_NAMES and p.is_file()
                         and p.name not in entries and p.name not in ours)
        doc = {"written_by": "vectoradjust", "command": self.command, "complete": False,
               "started": self._started, "files": entries, "earlier": sorted(ours)}
        pending, done = self.stage / ".pending.json", self.stage / ".done.json"
        _write_doc(pending, doc)
        doc.pop("earlier")
        doc.update(complete=True, finished=_now(), removed=stale, not_of_this_run=foreign)
        _write_doc(done, doc)
        os.replace(pending, self.path / MANIFEST)  # from now on: incomplete
        for rel in stale:
            _unlink(self.path / rel)
            self._prune(Path(rel).parent)
        for rel in sorted(new, key=lambda r: (_LAST.index(Path(r).name) + 1
                                              if Path(r).name in _LAST else 0, r)):
            (self.path / rel).parent.mkdir(parents=True, exist_ok=True)
            os.replace(self.stage / rel, self.path / rel)
        os.replace(done, self.path / MANIFEST)  # complete
        self.committed = True
        if stale:
            self.notes.append(("info", f"removed {len(stale)} file(s) of the previous run "
                               f"that this run did not write: {_listed(stale)}"))
        if foreign:
            self.notes.append(("warning", f"{self.path} holds {len(foreign)} file(s) named like "
                               f"vectoradjust outputs that this run did not write and no "
                               f"{MANIFEST} claims: {_listed(foreign)}; they are not part of "
                               "this result (delete them if an earlier run left them)"))
        return self.notes

    def _previous_files(self) -> tuple:
        """The files the folder's manifest claims (also those an interrupted commit was
        replacing) and the claimed names, with the sizes the manifest gives."""
        doc = read_manifest(self.path) or {"files": {}, "complete": True}
        # (an interrupted commit: some files old, some new; all of them the runs')
        sizes = {r: (e.get("size") if isinstance(e, dict) and doc.get("complete") is True
                     else None) for r, e in doc["files"].items()}
        earlier = doc.get("earlier") if isinstance(doc.get("earlier"), list) else []
        ours = {r for r in [*sizes, *earlier, *self.claimed]
                if isinstance(r, str) and _inside(self.path, r)}
        return ours, {r: s for r, s in sizes.items() if isinstance(s, int)}

    def _prune(self, rel: Path) -> None:
        """Empty folders left by removed files (up to the run's folder)."""
        while rel.parts:
            try:
                (self.path / rel).rmdir()
            except OSError:
                return
            rel = rel.parent
