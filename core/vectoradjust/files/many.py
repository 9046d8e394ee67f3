"""Many independent projects at once, on Dask: :func:`adjust_many`.

A county or a state is covered by many stereo models or blocks that share nothing: each
is a project of its own. :func:`adjust_many` adjusts every project exactly as
``vectoradjust adjust`` does (:func:`vectoradjust.runner.project_run.run_project`:
outputs, ``[truth]`` buffer test and truth tables, ``[qa]`` verdict, report) into
``DIR/<project name>/`` and writes one combined summary, ``DIR/many_summary.csv`` and
``DIR/many_summary.json``: per project sigma0^2, the chi-square test, the check-point
RMSE and the shape-point counts, or the error of a project that failed (the others go
on; ``many_summary.json`` lists the failed ones and why under ``failures``).

Each project's folder is written as ``adjust`` writes its own
(:class:`~vectoradjust.files.outputs.RunFolder`): staged, moved into place when
complete, ``run_manifest.json`` last; a project that fails leaves its previous result as
it was. ``DIR`` itself is locked while the projects run, so a second ``adjust-many`` into
it is refused with a clear error.

The projects run as Dask tasks: by default on the local multi-process scheduler
(``scheduler=None`` or ``"processes"``; ``"threads"`` and ``"sync"`` also work), or on
a distributed cluster given by its scheduler address (``"tcp://host:8786"``) or a
``distributed.Client``. Dask is an optional extra (``pip install
"vectoradjust[many]"``), imported only here and only when called.

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

__all__ = ["adjust_many", "adjust_one", "project_names", "write_many_summary", "MANY_COLUMNS"]

#: columns of many_summary.csv (and keys of every row of many_summary.json)
MANY_COLUMNS = [
    "name", "project", "out_dir", "status", "seconds", "sigma0_squared", "degrees_of_freedom",
    "iterations", "converged", "chi_square_statistic", "chi_square_lower",
    "chi_square_upper", "chi_square_passed", "check_points", "check_rmse_x", "check_rmse_y",
    "check_rmse_z", "check_rmse_horizontal", "shape_points_measured", "shape_points_total",
    "databases", "error",
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


def adjust_many(projects: Sequence, out_dir, *, scheduler: Any = None,
                workers: Optional[int] = None, fmt: str = "gpkg", bands: bool = True,
                report: bool = True,
                progress: Optional[Callable[[float, str], None]] = None) -> list:
    """Adjust independent projects on Dask, each into ``out_dir/<name>/``.

    Parameters
    ----------
    projects : sequence of str or os.PathLike
        Project files (TOML).
    out_dir : str or os.PathLike
        Every project's outputs go to ``out_dir/<name>`` (:func:`project_names`); the
        combined summary to ``out_dir/many_summary.csv`` and ``.json``.
    scheduler : None, str or distributed.Client
        None or ``"processes"``: the local multi-process scheduler; ``"threads"``,
        ``"sync"``: the other local schedulers; an address such as
        ``"tcp://10.0.0.5:8786"`` or a ``distributed.Client``: that cluster.
    workers : int, optional
        Processes of the local scheduler (default: Dask's, the number of cores).
    fmt : {"gpkg", "shp"}
    bands, report : bool
        Write the uncertainty bands layer and report.html (as ``adjust`` does).
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
        rows = _adjust_all(dask, projects, out, scheduler, workers, fmt, bands, report,
                           progress)
        write_many_summary(rows, out)
    if progress is not None:
        progress(1.0, "all projects done")
    return rows


def _adjust_all(dask, projects: list, out: Path, scheduler, workers, fmt: str, bands: bool,
                report: bool, progress) -> list:
    """Every project adjusted on Dask; their rows in the order given."""
    names = project_names(projects)
    tasks = [dask.delayed(adjust_one, pure=False)(p, str(out / n), n, fmt, bands, report)
             for p, n in zip(projects, names)]
    client = _client(scheduler)
    if client is None:
        rows = _run_local(dask, tasks, scheduler or "processes", workers, progress)
    else:
        meta = [(n, p, str(out / n)) for p, n in zip(projects, names)]
        rows = _run_distributed(client, tasks, meta, progress, close=client is not scheduler)
    return rows


def _run_local(dask, tasks: list, scheduler: str, workers, progress) -> list:
    from dask.callbacks import Callback

    done = [0]

    class _Done(Callback):
        def _posttask(self, key, result, dsk, state, worker_id):
            if isinstance(result, dict) and "status" in result:
                done[0] += 1
                if progress is not None:
                    progress(done[0] / len(tasks), f"{result['name']}: {result['status']} "
                             f"({done[0]}/{len(tasks)})")

    kw = {"num_workers": workers} if workers else {}
    with _Done():
        return list(dask.compute(*tasks, scheduler=scheduler, **kw))


def _run_distributed(client, tasks: list, meta: list, progress, close: bool) -> list:
    from distributed import as_completed

    try:
        futures = client.compute(tasks)
        names = {f.key: m[0] for f, m in zip(futures, meta)}
        for i, fut in enumerate(as_completed(futures), start=1):
            if progress is not None:
                progress(i / len(tasks), f"{names.get(fut.key, '?')}: {fut.status} "
                         f"({i}/{len(tasks)})")
        return [_future_row(f, m) for f, m in zip(futures, meta)]
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


def write_many_summary(rows: Sequence[dict], out_dir) -> tuple:
    """Write ``many_summary.csv`` and ``many_summary.json`` (one row per project).

    ``many_summary.json`` holds ``projects`` (how many), ``failed`` (their names),
    ``failures`` (``name``, ``project``, ``error`` of each failed one) and ``rows``. Each
    file is written beside its place and moved there when complete.
    """
    out = Path(out_dir)
    csv_path, json_path = out / "many_summary.csv", out / "many_summary.json"
    bad = [r for r in rows if r.get("status") != "ok"]
    doc = {"projects": len(rows), "failed": [r["name"] for r in bad],
           "failures": [{k: r.get(k) for k in ("name", "project", "error")} for r in bad],
           "rows": list(rows)}
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
