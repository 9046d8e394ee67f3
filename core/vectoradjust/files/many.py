"""Many independent projects at once, on Dask: :func:`adjust_many`.

A county or a state is covered by many stereo models or blocks that share nothing: each
is a project of its own. :func:`adjust_many` adjusts every project exactly as
``vectoradjust adjust`` does (:func:`vectoradjust.runner.project_run.run_project`:
outputs, ``[truth]`` buffer test and truth tables, ``[qa]`` verdict, report) into
``DIR/<project name>/`` and writes one combined summary, ``DIR/many_summary.csv`` and
``DIR/many_summary.json``: per project sigma0^2, the chi-square test, the check-point
RMSE, the shape-point counts and the rows merged, or the error of a project that failed
(the others go on; ``many_summary.json`` lists the failed ones and why under
``failures``).

The merged output (``merge=True``, the default): one GeoPackage per database,
``DIR/merged_<database>.gpkg``, with the ``shape_points`` and ``features`` rows of every
project and a ``project`` column (:mod:`vectoradjust.files.many_merge`). Each worker
reads its project's layers back and returns them as Arrow tables with the project's
row; the parent alone appends them, as each project finishes, and lets them go. So the
merged files land on the client's disk even when a cluster's workers do not share it
(the per-project folders are written by the workers at the path given: on a cluster,
give a path every worker can write, a shared file system, or accept the folders on the
workers' disks).

Each project's folder is written as ``adjust`` writes its own
(:class:`~vectoradjust.files.outputs.RunFolder`): staged, moved into place when
complete, ``run_manifest.json`` last; a project that fails leaves its previous result as
it was. ``DIR`` itself is locked while the projects run, so a second ``adjust-many`` into
it is refused with a clear error.

The projects run as Dask tasks: by default on a ``distributed.LocalCluster`` of
``workers`` processes with one thread each (``memory_limit`` each), else (distributed
not installed, or ``scheduler="processes"``) on Dask's local multi-process scheduler
(``"threads"`` and ``"sync"`` also work), or on a running cluster given by its scheduler
address (``"tcp://host:8786"``) or a ``distributed.Client``. Dask is an optional extra
(``pip install "vectoradjust[many]"``), imported only here and only when called.

Example
-------
>>> from vectoradjust.files.many import adjust_many
>>> rows = adjust_many(["north/project.toml", "south/project.toml"], "out")  # doctest: +SKIP
>>> [(r["name"], r["status"], r["sigma0_squared"]) for r in rows]  # doctest: +SKIP
"""

from __future__ import annotations

import csv
import json
import os
import re
import time
import traceback
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Callable, Optional

from vectoradjust.errors import VectorAdjustError

__all__ = ["adjust_many", "adjust_one", "adjust_collect", "project_names", "write_many_summary",
           "MANY_COLUMNS"]

#: columns of many_summary.csv (and keys of every row of many_summary.json)
MANY_COLUMNS = [
    "name", "project", "out_dir", "status", "seconds", "sigma0_squared", "degrees_of_freedom",
    "iterations", "converged", "chi_square_statistic", "chi_square_lower",
    "chi_square_upper", "chi_square_passed", "check_points", "check_rmse_x", "check_rmse_y",
    "check_rmse_z", "check_rmse_horizontal", "shape_points_measured", "shape_points_total",
    "databases", "merged_rows", "error",
]

_LOCAL = ("processes", "threads", "sync", "synchronous", "single-threaded")


def _dask():
    try:
        import dask
    except ImportError as exc:
        raise VectorAdjustError(
            "adjust-many runs the projects on Dask, which is not installed",
            'Install the extra: pip install "vectoradjust[many]" (or pip install '
            '"dask[distributed]")') from exc
    return dask


def project_names(projects: Sequence) -> list:
    """A directory name per project: its ``name`` (or the file's stem, or the folder of a
    ``project.toml``), made safe for file systems and unique (``-2``, ``-3``...)."""
    from vectoradjust.files.project import tomllib

    out: list = []
    seen: set = set()
    for p in projects:
        path = Path(p)
        name = None
        try:
            with open(path, "rb") as fh:
                name = tomllib.load(fh).get("name")
        except (OSError, ValueError):
            pass  # the run reports the unreadable project; any name will do here
        if not isinstance(name, str) or not name.strip():
            name = path.parent.name if path.stem == "project" and path.parent.name else path.stem
        base = re.sub(r"[^\w.-]+", "_", name.strip()).strip("._") or "project"
        label, k = base, 2
        while label.lower() in seen:
            label, k = f"{base}-{k}", k + 1
        seen.add(label.lower())
        out.append(label)
    return out


def _row(name: str, project: str, out_dir: str) -> dict:
    return {c: None for c in MANY_COLUMNS} | {"name": name, "project": project,
                                              "out_dir": out_dir}


def _fill(row: dict, result) -> None:
    s = result.summary
    chi = s.get("chi_square") or {}
    chk = s.get("check_points") or {}
    row.update({
        "sigma0_squared": s.get("sigma0_squared"),
        "degrees_of_freedom": s.get("degrees_of_freedom"),
        "iterations": s.get("iterations"), "converged": s.get("converged"),
        "chi_square_statistic": chi.get("statistic"), "chi_square_lower": chi.get("lower"),
        "chi_square_upper": chi.get("upper"), "chi_square_passed": chi.get("passed"),
        "check_points": chk.get("count"), "check_rmse_x": chk.get("rmse_x"),
        "check_rmse_y": chk.get("rmse_y"), "check_rmse_z": chk.get("rmse_z"),
        "check_rmse_horizontal": chk.get("rmse_horizontal"),
        "shape_points_measured": (s.get("shape_points") or {}).get("count"),
        "shape_points_total": int(sum(len(d.vertices.get("X", [])) for d in result.databases)),
        "databases": ";".join(d.name for d in result.databases),
    })


def adjust_one(project, out_dir, name: Optional[str] = None, fmt: str = "gpkg",
               bands: bool = True, report: bool = True) -> dict:
    """Adjust one project into ``out_dir`` as ``vectoradjust adjust`` does; never raises.

    Returns
    -------
    dict
        The project's row of the combined summary (:data:`MANY_COLUMNS`): ``status`` is
        ``"ok"`` or ``"failed"`` with the message in ``error``.
    """
    from vectoradjust.files.jsonfile import clean_json
    from vectoradjust.files.outputs import MANIFEST, read_manifest

    t0 = time.perf_counter()
    row = _row(name or Path(project).stem, str(project), str(out_dir))
    try:
        _fill(row, _adjust(project, out_dir, fmt, bands, report))
        row["status"] = "ok"
    except VectorAdjustError as exc:
        row.update(status="failed", error=str(exc))
    except Exception as exc:  # noqa: BLE001 - one broken project must not stop the others
        tb = traceback.format_exception_only(type(exc), exc)[-1].strip()
        row.update(status="failed", error=f"unexpected error: {tb}")
    if row["status"] != "ok" and read_manifest(out_dir) is not None:
        row["error"] += (f" (the result in {out_dir} is an earlier run's, left as it was; "
                         f"see its {MANIFEST})")
    row["seconds"] = round(time.perf_counter() - t0, 3)
    return clean_json(row)


def _adjust(project, out_dir, fmt: str, bands: bool, report: bool):
    """The project run as ``vectoradjust adjust`` runs it
    (:func:`vectoradjust.runner.project_run.run_project`: the same files), without a
    console and without processes of its own (the Dask workers are the parallelism)."""
    from vectoradjust.runner.project_run import RunOptions, run_project

    options = RunOptions(fmt=fmt, bands=bands, report=report, quiet=True, background=False,
                         command="adjust-many")
    return run_project(project, out_dir, options).run


def adjust_collect(project, out_dir, name: str, fmt: str = "gpkg", bands: bool = True,
                   report: bool = True, layers: Optional[Sequence[str]] = None) -> dict:
    """:func:`adjust_one`, and the project's layers read back for the merged output.

    Runs on a Dask worker. ``layers`` (e.g.
    :data:`~vectoradjust.files.many_merge.MERGE_LAYERS`) are read from the folder just
    written (:func:`~vectoradjust.files.many_merge.project_layers`) and returned under
    the row's ``"_layers"`` key (Arrow tables: they travel to the client, whose disk
    need not be the worker's); the parent merges them and removes the key. A project
    whose layers cannot be read is still ``"ok"`` (its folder is complete) with the
    reason in ``error``. Never raises.
    """
    row = adjust_one(project, out_dir, name, fmt, bands, report)
    row["_layers"] = []
    if row["status"] == "ok" and layers:
        from vectoradjust.files.many_merge import project_layers

        try:
            row["_layers"] = project_layers(out_dir, name, fmt, layers)
        except Exception as exc:  # noqa: BLE001 - the project itself is adjusted
            row["error"] = f"adjusted, but not merged: its layers could not be read ({exc})"
    return row


def _client(scheduler):
    """A ``distributed.Client`` for an address (or the client given), else None."""
    if scheduler is None or (isinstance(scheduler, str) and scheduler in _LOCAL):
        return None
    try:
        from distributed import Client
    except ImportError as exc:
        raise VectorAdjustError(
            f"A scheduler address ({scheduler!r}) needs dask.distributed, which is not "
            "installed", 'Install the extra: pip install "vectoradjust[many]"') from exc
    if isinstance(scheduler, Client):
        return scheduler
    if not isinstance(scheduler, str):
        raise VectorAdjustError(f"scheduler {scheduler!r} is neither an address nor a Client",
                                "Give tcp://host:port, or leave it out for the local scheduler")
    try:
        return Client(scheduler, timeout="30s")
    except (OSError, TimeoutError) as exc:
        raise VectorAdjustError(f"Cannot connect to the Dask scheduler {scheduler!r} ({exc})",
                                "Check the address and that the scheduler is running") from exc


def _check_memory_limit(memory_limit) -> None:
    """A memory limit Dask can read (``"1GB"``, ``"700MB"``, bytes, a fraction of the
    machine's memory, ``"auto"``), before any worker starts: else a clear error."""
    if memory_limit is None or memory_limit == "auto":
        return
    from dask.utils import parse_bytes

    try:
        ok = float(memory_limit) > 0 if not isinstance(memory_limit, str) \
            else parse_bytes(memory_limit) > 0
    except (ValueError, TypeError):
        ok = False
    if not ok:
        raise VectorAdjustError(f"--memory-limit {memory_limit!r} is not a memory size",
                                "Give the memory of each worker as a size, e.g. "
                                "--memory-limit 1GB or 700MB")


def _local_cluster(workers: Optional[int], memory_limit, n_projects: int):
    """A ``distributed.LocalCluster`` of worker processes (one thread each) and its
    client; ``(None, None)`` when distributed is not installed."""
    try:
        import logging

        from distributed import Client, LocalCluster
    except ImportError:
        return None, None
    n = workers or min(os.cpu_count() or 1, n_projects)
    cluster = LocalCluster(n_workers=max(1, n), threads_per_worker=1, processes=True,
                           memory_limit=memory_limit or "auto", dashboard_address=None,
                           silence_logs=logging.ERROR)
    return cluster, Client(cluster)


def adjust_many(projects: Sequence, out_dir, *, scheduler: Any = None,
                workers: Optional[int] = None, fmt: str = "gpkg", bands: bool = True,
                report: bool = True, merge: bool = True,
                merge_layers: Sequence[str] = ("shape_points", "features"),
                memory_limit: Any = None,
                progress: Optional[Callable[[float, str], None]] = None) -> list:
    """Adjust independent projects on Dask, each into ``out_dir/<name>/``.

    Parameters
    ----------
    projects : sequence of str or os.PathLike
        Project files (TOML).
    out_dir : str or os.PathLike
        Every project's outputs go to ``out_dir/<name>`` (:func:`project_names`); the
        combined summary to ``out_dir/many_summary.csv`` and ``.json``, the merged
        layers to ``out_dir/merged_<database>.gpkg``.
    scheduler : None, str or distributed.Client
        None: a ``LocalCluster`` of ``workers`` processes (Dask's local multi-process
        scheduler when distributed is not installed); ``"processes"``, ``"threads"``,
        ``"sync"``: Dask's local schedulers; an address such as
        ``"tcp://10.0.0.5:8786"`` or a ``distributed.Client``: that cluster.
    workers : int, optional
        Worker processes of the LocalCluster or of the local scheduler (default: the
        number of cores, at most one per project).
    fmt : {"gpkg", "shp"}
    bands, report : bool
        Write the uncertainty bands layer and report.html (as ``adjust`` does).
    merge : bool
        Write the merged output (:mod:`vectoradjust.files.many_merge`).
    merge_layers : sequence of str
        The layers merged (``"uncertainty_bands"`` may be added).
    memory_limit : str or float, optional
        Memory of each LocalCluster worker (``"1GB"``; default: Dask's, the machine's
        memory shared by the workers); a worker over it is restarted and its project
        listed as failed.
    progress : callable, optional
        ``progress(fraction, message)`` as each project finishes.

    Returns
    -------
    list of dict
        One row per project (:data:`MANY_COLUMNS`), in the order given.

    Raises
    ------
    VectorAdjustError
        Dask is missing, the scheduler cannot be reached, or no project was given. A
        failing project does not raise: its row says ``status = "failed"`` and why.
    """
    from vectoradjust.files.outputs import DirLock

    dask = _dask()
    _check_memory_limit(memory_limit)
    projects = [str(p) for p in projects]
    if not projects:
        raise VectorAdjustError("adjust-many was given no project", "Name project files")
    out = Path(out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise VectorAdjustError(f"Cannot create the output directory {str(out)!r} ({exc})",
                                "Choose a writable directory with --out") from exc
    with DirLock(out, "adjust-many"):  # a second adjust-many into DIR: a clear error
        job = _Job(projects, out, fmt, bands, report, merge_layers if merge else ())
        rows = _adjust_all(dask, job, scheduler, workers, memory_limit, progress)
        write_many_summary(rows, out, extra=job.merged_info())
    if progress is not None:
        progress(1.0, "all projects done")
    return rows


class _Job:
    """The projects' tasks and the merged output they feed (the parent's side)."""

    def __init__(self, projects: list, out: Path, fmt: str, bands: bool, report: bool,
                 layers: Sequence[str]) -> None:
        from vectoradjust.files.many_merge import MergedOutput

        self.projects, self.out, self.layers = projects, out, tuple(layers)
        self.names = project_names(projects)
        self.args = (fmt, bands, report)
        self.merged = MergedOutput(out) if self.layers else None
        self.files: dict = {}

    def tasks(self, dask) -> list:
        return [dask.delayed(adjust_collect, pure=False)(
            p, str(self.out / n), n, *self.args, self.layers)
            for p, n in zip(self.projects, self.names)]

    def meta(self, i: int) -> tuple:
        return self.names[i], self.projects[i], str(self.out / self.names[i])

    def arrived(self, row: dict) -> dict:
        """Merge a finished project's tables (removed from ``row``); ``row``."""
        tables = row.pop("_layers", None) or []
        if self.merged is None or row.get("status") != "ok" or not tables:
            return row
        try:
            row["merged_rows"] = self.merged.add(row["name"], tables)
        except Exception as exc:  # noqa: BLE001 - e.g. a full disk: the others go on
            row["error"] = f"adjusted, but not merged: {type(exc).__name__}: {exc}"
            self.merged.notes.append(f"{row['name']}: {row['error']}")
        return row

    def commit(self) -> None:
        if self.merged is not None:
            self.files = self.merged.commit()

    def merged_info(self) -> dict:
        if self.merged is None:
            return {}
        return {"merged": self.files, "merged_rows": self.merged.counts(),
                "merge_notes": list(self.merged.notes)}


def _adjust_all(dask, job: _Job, scheduler, workers, memory_limit, progress) -> list:
    """Every project adjusted on Dask, merged as it arrives; their rows in the order
    given."""
    tasks = job.tasks(dask)
    cluster = None
    client = _client(scheduler)
    if client is None and scheduler is None:
        cluster, client = _local_cluster(workers, memory_limit, len(tasks))
    try:
        if client is None:
            rows = _run_local(dask, tasks, scheduler or "processes", workers, progress,
                              job.arrived)
        else:
            rows = _run_distributed(client, tasks, job, progress,
                                    close=client is not scheduler)
        job.commit()
    except BaseException:
        if job.merged is not None:
            job.merged.discard()
        raise
    finally:
        if cluster is not None:
            cluster.close()
    return rows


def _run_local(dask, tasks: list, scheduler: str, workers, progress, arrived) -> list:
    from dask.callbacks import Callback

    done = [0]

    class _Done(Callback):
        def _posttask(self, key, result, dsk, state, worker_id):
            if isinstance(result, dict) and "status" in result:
                arrived(result)  # merged now, its tables let go (not held to the end)
                done[0] += 1
                if progress is not None:
                    progress(done[0] / len(tasks), f"{result['name']}: {result['status']} "
                             f"({done[0]}/{len(tasks)})")

    kw = {"num_workers": workers} if workers else {}
    with _Done():
        return list(dask.compute(*tasks, scheduler=scheduler, **kw))


def _run_distributed(client, tasks: list, job: _Job, progress, close: bool) -> list:
    """The tasks on a cluster; each result gathered, merged and released as it
    finishes (the client never holds more than one project's tables)."""
    from distributed import as_completed

    rows: list = [None] * len(tasks)
    try:
        futures = client.compute(tasks)
        index = {f.key: i for i, f in enumerate(futures)}
        for n, fut in enumerate(as_completed(futures), start=1):
            i = index[fut.key]
            rows[i] = job.arrived(_future_row(fut, job.meta(i)))
            fut.release()
            if progress is not None:
                progress(n / len(tasks), f"{rows[i]['name']}: {rows[i]['status']} "
                         f"({n}/{len(tasks)})")
        return rows
    finally:
        if close:
            client.close()


def _future_row(future, meta: tuple) -> dict:
    """The row of a finished future; a task lost on the cluster (a worker died) is a
    failed row, not an exception that would hide the other projects' results."""
    try:
        return future.result()
    except Exception as exc:  # noqa: BLE001 - e.g. distributed.KilledWorker
        row = _row(*meta)
        row.update(status="failed", error=f"the Dask task failed: {type(exc).__name__}: {exc}")
        return row


def write_many_summary(rows: Sequence[dict], out_dir, extra: Optional[dict] = None) -> tuple:
    """Write ``many_summary.csv`` and ``many_summary.json`` (one row per project).

    ``many_summary.json`` holds ``projects`` (how many), ``failed`` (their names),
    ``failures`` (``name``, ``project``, ``error`` of each failed one), ``rows`` and
    ``extra`` (the merged output: ``merged`` files by database, ``merged_rows`` per
    ``database/layer``, ``merge_notes``). Each file is written beside its place and moved
    there when complete.
    """
    out = Path(out_dir)
    csv_path, json_path = out / "many_summary.csv", out / "many_summary.json"
    bad = [r for r in rows if r.get("status") != "ok"]
    doc = {"projects": len(rows), "failed": [r["name"] for r in bad],
           "failures": [{k: r.get(k) for k in ("name", "project", "error")} for r in bad],
           "rows": list(rows), **(extra or {})}
    tmp = [out / ".many_summary.csv.part", out / ".many_summary.json.part"]
    try:
        with open(tmp[0], "w", newline="", encoding="utf-8") as fh:
            w = csv.DictWriter(fh, fieldnames=MANY_COLUMNS, extrasaction="ignore")
            w.writeheader()
            for r in rows:
                w.writerow({k: ("" if r.get(k) is None else r.get(k)) for k in MANY_COLUMNS})
        with open(tmp[1], "w", encoding="utf-8") as fh:
            json.dump(doc, fh, indent=2)
        os.replace(tmp[0], csv_path)
        os.replace(tmp[1], json_path)
    except OSError as exc:
        raise VectorAdjustError(f"Cannot write the combined summary in {str(out)!r} ({exc})",
                                "Choose a writable directory with --out") from exc
    finally:
        for t in tmp:
            if t.exists():
                t.unlink()
    return csv_path, json_path
