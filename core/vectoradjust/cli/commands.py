"""The ``vectoradjust`` command line.

Subcommands (``DESIGN.md`` section 9): ``demo``, ``adjust``, ``compare``. User errors
print one clear message and exit with status 1; usage errors exit with 2; an
interrupted run exits with 130.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import shutil
import sys
import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import Optional

from vectoradjust import __version__
from vectoradjust.cli import buffer as cli_buffer
from vectoradjust.cli import drone as cli_drone
from vectoradjust.cli import dtm as cli_dtm
from vectoradjust.cli import many as cli_many
from vectoradjust.cli import measure as cli_measure
from vectoradjust.cli import propagate as cli_propagate
from vectoradjust.cli import qa as cli_qa
from vectoradjust.cli import study as cli_study
from vectoradjust.cli.progress import ProgressBar
from vectoradjust.cli.tools import run_command
from vectoradjust.errors import NothingAdjustedError, VectorAdjustError

__all__ = ["main", "ProgressBar", "sample_project_dir", "compare", "compare_row", "print_table"]


def compare_row(summary: dict) -> dict:
    """:func:`vectoradjust.accuracy.summary.compare_row` (imported when first used: the
    command line starts reading its inputs without loading the statistics)."""
    from vectoradjust.accuracy.summary import compare_row as row

    return row(summary)


def compare_columns(rows: list) -> list:
    """:func:`vectoradjust.accuracy.summary.compare_columns` (imported when used)."""
    from vectoradjust.accuracy.summary import compare_columns as cols

    return cols(rows)


def sample_project_dir() -> Path:
    """Directory of the embedded sample project."""
    try:
        from importlib.resources import files

        p = Path(str(files("vectoradjust.resources"))) / "sample"
        if (p / "project.toml").is_file():
            return p
    except (ModuleNotFoundError, TypeError):
        pass
    p = Path(__file__).resolve().parents[3] / "resources" / "sample"
    if (p / "project.toml").is_file():
        return p
    raise VectorAdjustError("The sample project is not installed (resources/sample/project.toml "
                            "is missing)", "Reinstall vectoradjust with 'pip install .'")


def _fmt(v, nd=3) -> str:
    if v is None:
        return "-"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, (int,)):
        return str(v)
    try:
        return f"{float(v):.{nd}f}"
    except (TypeError, ValueError):
        return str(v)


def _print_summary(summary: dict, out=None) -> None:
    out = out or sys.stdout
    chi = summary["chi_square"]
    print(f"  sigma0^2 = {_fmt(summary['sigma0_squared'], 4)} with {summary['degrees_of_freedom']}"
          f" degrees of freedom, {summary['iterations']} iterations", file=out)
    if chi.get("lower") is not None:
        print(f"  chi-square test (alpha = {chi['alpha']}): v'Pv = {_fmt(chi['statistic'], 2)} in "
              f"[{_fmt(chi['lower'], 2)}, {_fmt(chi['upper'], 2)}]: "
              f"{'passed' if chi['passed'] else 'FAILED'}", file=out)
    for key, label in (("shape_points", "shape points (residuals)"),
                       ("control_points", "control points"),
                       ("check_points", "check points")):
        s = summary.get(key) or {}
        if s.get("count"):
            print(f"  {label:26s} n = {s['count']:5d}  RMSE x {_fmt(s['rmse_x'])}  y "
                  f"{_fmt(s['rmse_y'])}  z {_fmt(s['rmse_z'])}  horizontal "
                  f"{_fmt(s['rmse_horizontal'])} m", file=out)
    if summary.get("mean_ce90") is not None:
        print(f"  mean CE90 {_fmt(summary['mean_ce90'])} m, mean LE90 "
              f"{_fmt(summary['mean_le90'])} m", file=out)
    interior = summary.get("interior_orientation")
    if interior:
        from vectoradjust.sensor.interior import describe_interior

        for line in describe_interior(interior):
            print(f"  {line}", file=out)
    for w in summary.get("warnings", []):
        print(f"  warning: {w}", file=out)


def print_table(rows: list, out=None) -> None:
    """Print the side-by-side comparison table."""
    out = out or sys.stdout
    cols = [(k, h) for k, h in compare_columns(rows) if k != "error"]
    heads = [h for _, h in cols]
    cells = [[_fmt(r.get(k)) if k != "database" else str(r.get(k)) for k, _ in cols]
             for r in rows]
    widths = [max(len(h), *(len(c[i]) for c in cells)) for i, h in enumerate(heads)]
    print("  ".join(h.rjust(w) for h, w in zip(heads, widths)), file=out)
    for c in cells:
        print("  ".join(v.rjust(w) for v, w in zip(c, widths)), file=out)


class _BandsAlongside:
    """The uncertainty bands built by forked processes (one share of the features each)
    while the parent runs the ``[truth]`` tests and writes the other layers."""

    def __init__(self, result, out_dir) -> None:
        from vectoradjust.cli.background import Background, workers
        from vectoradjust.files import derived_outputs as do

        self.run, self.folder = result, None
        n = workers()
        if do.arrow_layers():  # each process writes its share to a file the parent maps
            try:
                Path(out_dir).mkdir(parents=True, exist_ok=True)
                self.folder = tempfile.mkdtemp(prefix=".vectoradjust-bands-", dir=out_dir)
            except OSError:  # not writable: write_outputs says so, with what to do
                self.folder = None
        if self.folder is not None:
            make, kw = do.uncertainty_bands_file, {"folder": self.folder}
        else:  # the polygons come back through the pipe
            make, kw = do.uncertainty_bands_frame, {}
        # the covariances the bands take from the factorisation, for building a share here
        # once it is let go (a failed process, no fork): filled in by keep(), per share
        self.kept: dict = {}
        kw["kept"] = self.kept
        pid = os.getpid()
        self.parts = [(i, n) for i in range(n)] if n > 1 else [(0, 1)]
        self.jobs = ([Background(_band_share, make, result, pid, part=p, **kw)
                      for p in self.parts] if n > 1
                     else [Background(_band_share, make, result, pid, enabled=False, **kw)])
        self.forked = [j.forked for j in self.jobs]  # (a job forgets its process at the end)

    def keep(self, progress=None) -> None:
        """Keep what the bands take from the factorisation, so that every share can
        still be built here after it is let go: the file a band process saved its
        share's covariances in (:func:`_band_share`), else the covariances computed now
        (``progress(1.0, message)`` says so)."""
        from vectoradjust.accuracy.derived import segment_covariances

        for part, forked in zip(self.parts, self.forked):
            saved = _covariance_file(self.folder, part) if forked else None
            if saved is not None and saved.is_file():
                self.kept[part] = saved  # read only if the process fails
            else:
                if progress is not None:
                    progress(1.0, "uncertainty bands: covariances of the segments "
                                  f"(share {part[0] + 1} of {part[1]})")
                self.kept[part] = {d.name: segment_covariances(self.run, d, part)
                                   for d in self.run.databases}

    def result(self, progress=None):
        """The whole layer (waits for the processes, forwarding their progress)."""
        from vectoradjust.cli.background import gather
        from vectoradjust.files import derived_outputs as do

        merge = do.merge_band_files if self.folder else do.merge_band_parts
        return merge(self.run, gather(self.jobs, progress))

    def close(self) -> None:
        for j in self.jobs:
            j.close()
        if self.folder is not None:
            shutil.rmtree(self.folder, ignore_errors=True)


def _covariance_file(folder, part: tuple) -> Optional[Path]:
    """Where the band process of ``part`` saves its share's covariances (None: nowhere)."""
    return None if folder is None else Path(folder) / f"covariances_{part[0]}_of_{part[1]}.npz"


def _save_covariances(path: Path, kept: dict) -> None:
    """The :class:`SegmentCovariances` of every database in one ``.npz`` file, moved into
    place when complete (the parent takes the file as soon as it exists)."""
    import dataclasses

    import numpy as np

    arrays = {}
    for i, (name, c) in enumerate(kept.items()):
        arrays[f"name_{i}"] = np.array(name)
        arrays.update({f"{f.name}_{i}": getattr(c, f.name) for f in dataclasses.fields(c)
                       if getattr(c, f.name) is not None})  # (asdict would copy them)
    tmp = path.with_name("." + path.name + ".part")
    with open(tmp, "wb") as f:
        np.savez(f, n=np.array(len(kept)), **arrays)
    os.replace(tmp, path)


def _load_covariances(path: Path) -> dict:
    """The covariances :func:`_save_covariances` saved, by database name."""
    import dataclasses

    import numpy as np

    from vectoradjust.accuracy.derived import SegmentCovariances

    names = [f.name for f in dataclasses.fields(SegmentCovariances)]
    with np.load(path) as z:
        return {str(z[f"name_{i}"]): SegmentCovariances(
            **{k: z[f"{k}_{i}"] for k in names if f"{k}_{i}" in z.files})
            for i in range(int(z["n"]))}


def _band_share(make, result, parent: int, kept: dict, part: tuple = (0, 1), **kwargs):
    """``make(result, part=part, **kwargs)`` with the covariances ``kept[part]`` (if any).

    In a process of its own (not ``parent``) the covariances of its share are taken from
    the factorisation first and the factorisation is let go: its copy-on-write pages are
    not held by the band processes too. With a ``folder`` the covariances are saved there
    (:func:`_covariance_file`) before the bands are built: the parent then need not
    compute them again for the case that this process fails."""
    if os.getpid() != parent:
        from vectoradjust.accuracy.derived import segment_covariances

        if kwargs.get("progress") is not None:
            kwargs["progress"](0.0, "uncertainty bands: covariances of the segments")
        mine = {d.name: segment_covariances(result, d, part) for d in result.databases}
        result.result.release_factorisation()
        path = _covariance_file(kwargs.get("folder"), part)
        if path is not None:
            try:
                _save_covariances(path, mine)
            except OSError:  # the parent computes them itself (keep)
                pass
    else:
        mine = kept.get(part)
        if isinstance(mine, Path):
            mine = _load_covariances(mine)
    return make(result, part=part, covariances=mine or None, **kwargs)


def _summarised(result, started: list, args, progress=None):
    """The bands' processes once the run is summarised (None: no bands), and the
    factorisation let go: nothing after the adjustment needs it but the conflation rasters
    (the bands took their covariances), so about 1 GB at 10^6 shape points is free for
    the tests and the layers."""
    bands = started[0] if started else None
    if not getattr(args, "conflation_raster", False):
        if bands is not None:
            bands.keep(progress)
        result.result.release_factorisation()
    return bands


def _bands_alongside(result, args, preload=None, progress=None, kernels=None,
                     out_dir=None):
    """The uncertainty bands, started in other processes (None: ``--no-bands``); their
    files go into ``out_dir`` (default ``args.out``: the run's staging folder)."""
    if getattr(args, "no_bands", False) or not result.databases:
        if kernels is not None:
            kernels.close()
        return None
    if preload is not None:  # no module half imported in the children
        preload.wait()
    from vectoradjust.accuracy.derived import warm_ring_kernel
    from vectoradjust.cli.background import workers

    # the compiled band kernels (rings, union) loaded once here, not in every band process
    say = None if progress is None else (lambda m: progress(0.75, f"uncertainty bands: {m}"))
    if kernels is not None:  # compiled or found by a child meanwhile: loaded from the cache
        kernels.wait(say)
    warm_ring_kernel(sum(len(d.vertex_point) for d in result.databases) // workers(), say)
    return _BandsAlongside(result, args.out if out_dir is None else out_dir)


def _compile_kernels(n_segments: int, progress=None) -> bool:
    """The band kernels compiled into numba's cache, or found there (in a child)."""
    from vectoradjust.accuracy.derived import warm_ring_kernel

    return warm_ring_kernel(n_segments)


class _KernelsAlongside:
    """The compiled band kernels (:func:`vectoradjust.accuracy.derived.warm_ring_kernel`)
    looked for by a forked child while the parent adjusts: numba compiles them there the
    first time after installing (about 20 s, on the core the solve leaves idle) and writes
    them into its cache, from which the parent then loads them (about 0.5 s). Nothing is
    started when the bands will not use them (too few segments per band process, numba
    missing or switched off)."""

    def __init__(self, data, preload=None) -> None:
        import importlib.util

        from vectoradjust.accuracy import derived
        from vectoradjust.cli.background import Background, workers

        self.job = None
        n = sum(len(layer.coords) for _, layer in data.vectors) // workers()
        if n < derived._KERNEL_MIN or derived._numba_off() or \
                importlib.util.find_spec("numba") is None:
            return
        if preload is not None:  # no module half imported in the child
            preload.wait()
        job = Background(_compile_kernels, n)
        self.job = job if job.forked else None  # without a child: the parent loads them

    def wait(self, say=None) -> None:
        """Until the child has ended (it may still be compiling)."""
        if self.job is not None:
            if self.job.proc is not None and self.job.proc.is_alive() and say is not None:
                say("waiting for the compiled band kernels (compiled once after installing)")
            self.job.result(rerun=False)
            self.close()

    def close(self) -> None:
        if self.job is not None:
            self.job.close()
            self.job = None


def _output_folder(path, command: str = "adjust"):
    """``--out`` as a :class:`~vectoradjust.files.outputs.RunFolder`: entered before the
    work, it creates the folder and takes its lock (a folder that cannot be written, or
    that another run is writing into, is a clear error before the work, not after it);
    the run writes into its staging folder, and its commit moves the files into place."""
    from vectoradjust.files.outputs import RunFolder

    return RunFolder(path, command=command)


def _say_notes(folder, quiet: bool) -> None:
    """What the commit of ``folder`` said: the previous run's files removed (unless
    quiet), files of earlier runs left in place (always, on stderr)."""
    for kind, text in folder.notes:
        if kind == "warning":
            print(f"vectoradjust: warning: {text}", file=sys.stderr)
        elif not quiet:
            print(f"  note: {text}")


def _qa_verdict(result, data):
    """The accuracy-control verdict of a project with ``[qa]`` (a dict), else None."""
    if not data.qa:
        return None
    from vectoradjust.qa.verdict import accuracy_control, spec_from_table

    return accuracy_control(result, spec_from_table(data.qa, source=data.source)).as_dict()


def _report(run, path, qa, progress=None):
    from vectoradjust.files.report import write_report

    return write_report(run, path, reliability=run.reliability, qa=qa, progress=progress)


class _ReportAlongside:
    """``report.html`` written by a forked process while the parent writes the layers.

    Writing the layers may add GDAL's warnings to the run's; the report shows them, so
    when they changed after the fork the parent writes the report again (the child's
    would lack them). Without a child it is written by the parent at the end.
    """

    def __init__(self, run, out_dir, qa) -> None:
        from vectoradjust.cli.background import Background

        self.run, self.qa = run, qa
        self.path = Path(out_dir) / "report.html"
        self.warnings = list(run.summary.get("warnings") or [])
        self.job = Background(_report, run, self.path, qa)
        self.forked = self.job.forked  # (the job forgets its process once it has ended)

    def result(self, progress=None) -> Path:
        """The report written (waits for the child, forwarding its progress)."""
        path = self.job.result(progress)
        if self.forked and self.job.done and \
                list(self.run.summary.get("warnings") or []) != self.warnings:
            path = _report(self.run, self.path, self.qa, progress)
        return path


#: the report's plotting modules, loaded in a thread while the statistics are computed
_PLOTTING = ("matplotlib.figure", "matplotlib.backends.backend_agg")


def cmd_adjust(args) -> int:
    from vectoradjust.cli.background import workers

    workers()  # a wrong VECTORADJUST_WORKERS is said before the work, not after it
    from vectoradjust.files.project import load_project

    # a project that cannot be read (missing, a folder, permissions, encoding, a wrong
    # key) is said as such before --out is touched, not as an output folder's problem
    load_project(args.project)
    # the folder made and locked before the work; everything is written into its staging
    # folder and moved into place at the end: an interrupted or failed run leaves the
    # previous result as it was
    with _output_folder(args.out, "adjust") as folder:
        result, written = _adjust_into(args, folder)
    if not args.quiet:
        print(f"vectoradjust adjust: {args.project}")
        _print_summary(result.summary)
        for name in written.values():
            print(f"  wrote {name}")
    _say_notes(folder, args.quiet)
    return 0


def _adjust_into(args, folder):
    """Read, adjust and write a project into ``folder`` (a
    :class:`~vectoradjust.files.outputs.RunFolder`, open); the run and the paths written."""
    from vectoradjust.cli.background import Preload
    from vectoradjust.files.project import load_project
    from vectoradjust.files.readers import load_project_data

    # the adjustment's modules load on the other core while the inputs are read; the
    # report's plotting library once the adjustment is final (an import holds the
    # interpreter: during the adjustment it would hold up the one busy core)
    warm = Preload(("vectoradjust.pipeline",))
    bar = ProgressBar("adjust", enabled=not args.quiet)
    bar(0.0, "reading inputs")
    # every database is read, so that measurements of the databases not selected with
    # --vectors are recognised as their shape points and left out (as in compare),
    # not turned into tie points
    spec = load_project(args.project)
    if getattr(args, "datum", None):  # the command line overrides [adjustment] datum
        spec.settings.datum = args.datum
    data = load_project_data(spec, progress=lambda f, m: bar(0.02 * f, m))
    truth = cli_buffer.project_truth(spec)
    # true centrelines: their tests' half on the database lines runs beside the adjustment
    pre = cli_buffer.TruthBeforeAlongside(data, *truth, warm) if truth is not None else None
    kernels = _KernelsAlongside(data, warm)  # compiled or found while the adjustment runs
    from vectoradjust.pipeline import run

    started: list = []  # the bands start in other processes once the adjustment is final
    try:
        result = run(data, vectors=args.vectors, progress=bar,
                     on_adjusted=lambda r: started.append(
                         _bands_alongside(r, args, warm, bar, kernels, folder.stage)))
    except BaseException:
        for b in (b for b in [*started, pre, kernels.job] if b is not None):
            b.close()
        raise
    kernels.close()  # (ended by now, unless no band was started)
    bands = _summarised(result, started, args, bar)
    written = _write_adjusted(args, folder, result, spec, data, (truth, pre), bands)
    return result, written


def _write_adjusted(args, folder, result, spec, data, truth_pre, bands) -> dict:
    """The outputs of ``adjust`` written into ``folder``'s staging folder and committed;
    the paths where they end up, by name."""
    from vectoradjust.cli.background import Preload
    from vectoradjust.files.outputs import write_outputs

    truth, pre = truth_pre
    stage = folder.stage
    warm = Preload(_PLOTTING)  # the bands' processes have started (forked without it)
    report = None
    try:
        before = None
        if truth is not None:  # true centrelines: buffer test before/after the adjustment
            tbar = ProgressBar("truth", enabled=not args.quiet)
            before = pre.result(lambda f, m: tbar(0.5 * f, m))
            cli_buffer.truth_buffer(result, *truth, before=before,
                                    progress=lambda f, m="": tbar(0.5 + 0.5 * f, m))
        truth_csv = cli_study.truth_tables(  # per-point truth tables
            result, spec, stage, before=before,
            progress=ProgressBar("truth tables", enabled=not args.quiet))
        qa_doc = _qa_verdict(result, data)
        warm.wait()  # no module half imported in the report's process
        report = _ReportAlongside(result, stage, qa_doc)  # while the layers are written
        written = write_outputs(result, args.out, fmt=args.format,
                                bands=bands.result if bands is not None else False,
                                progress=ProgressBar("write", enabled=not args.quiet))
    except BaseException:
        if report is not None:  # the report's process is not left running
            report.job.close()
        if pre is not None:
            pre.close()
        raise
    finally:
        if bands is not None:
            bands.close()
    written.update({k: str(folder.final(v)) for k, v in truth_csv.items()})
    if getattr(args, "conflation_raster", False):
        from vectoradjust.files.derived_outputs import write_conflation_rasters

        written.update({k: str(folder.final(v))
                        for k, v in write_conflation_rasters(result, stage).items()})
    if qa_doc is not None:  # [qa] in the project: the accuracy-control verdict goes along
        from vectoradjust.cli.qa import write_qa_json

        written["qa.json"] = str(folder.final(write_qa_json(
            qa_doc, stage, extra={"project": str(args.project)})))
    written["report.html"] = str(folder.final(
        report.result(ProgressBar("report", enabled=not args.quiet))))
    folder.commit()
    return written


def compare(project, out_dir, fmt: str = "gpkg", quiet: bool = False) -> list:
    """Adjust every ``[[vectors]]`` entry alone and tabulate the results.

    A database that cannot be adjusted (no measured shape point, a DEM hole at a measured
    vertex, ...) gets a row with the reason in ``error``; the others are compared. All
    files are written into a staging folder and moved into ``out_dir`` at the end
    (:class:`~vectoradjust.files.outputs.RunFolder`).

    Returns
    -------
    list of dict
        One row per database (the columns of ``compare.csv``).

    Raises
    ------
    VectorAdjustError
        The project cannot be read, ``out_dir`` cannot be written or is locked by
        another run, or no database could be adjusted (each one's reason is named).
    """
    with _output_folder(out_dir, "compare") as folder:
        rows, _ = _compare_into(project, folder, fmt, quiet)
    return rows


def _compare_into(project, folder, fmt: str, quiet: bool) -> tuple:
    """:func:`compare` into an open RunFolder; (rows, names of the databases that failed
    with an error, not merely for want of measurements)."""
    from vectoradjust.files.project import load_project
    from vectoradjust.files.readers import load_project_data

    spec = load_project(project)
    if not spec.vectors:
        raise VectorAdjustError(f"{project}: there are no [[vectors]] entries to compare",
                                "Add [[vectors]] entries (one per road database)")
    from vectoradjust.files.report import write_compare_report

    data = load_project_data(spec)
    runs, rows, failed = _compare_each(spec, data, folder, fmt, quiet)
    errors = [r["database"] for r in failed if r.pop("_error", False)]
    if not runs:
        if errors:
            raise VectorAdjustError(
                f"{project}: no road database could be adjusted: "
                + "; ".join(r["error"] for r in failed),
                "Mend the inputs named above (the previous result in the output folder is "
                "left as it was)")
        raise NothingAdjustedError(
            f"{project}: no road database has a measured shape point",
            "See the messages above: set id_field, or measure the shape points")
    stage = folder.stage
    cli_study.write_common_points(runs, stage)  # points used by several databases
    write_compare_report(runs, rows, stage / "report.html",
                         progress=ProgressBar("  report", enabled=not quiet))
    rows = rows + failed  # the databases that could not be adjusted, with the reason
    with open(stage / "compare.csv", "w", newline="", encoding="utf-8") as fh:
        cols = compare_columns(rows)
        w = csv.DictWriter(fh, fieldnames=[k for k, _ in cols])
        w.writeheader()
        for r in rows:
            w.writerow({k: ("" if r.get(k) is None else r.get(k)) for k, _ in cols})
    with open(stage / "compare.json", "w", encoding="utf-8") as fh:
        json.dump(rows, fh, indent=2)
    folder.commit()
    return rows, errors


def _compare_each(spec, data, folder, fmt: str, quiet: bool) -> tuple:
    """Each database adjusted alone into ``folder``/<name>; (runs, rows, failed rows).

    A database that fails (any :class:`VectorAdjustError` but a cancel or a full disk) is
    reported and left out; the others go on. A failed row has ``_error`` true unless
    the database merely had no measured shape point."""
    from vectoradjust.errors import CancelledError
    from vectoradjust.files.outputs import is_disk_full, write_outputs
    from vectoradjust.files.report import write_report
    from vectoradjust.pipeline import run

    truth = cli_buffer.project_truth(spec)
    runs, rows, failed = [], [], []
    for i, v in enumerate(spec.vectors):
        bar = ProgressBar(f"{v.name:>8s} ({i + 1}/{len(spec.vectors)})", enabled=not quiet)
        target = folder.path / v.name
        try:
            result = run(data, vectors=[v.name], progress=bar)
            if truth is not None:
                cli_buffer.truth_buffer(result, *truth, progress=ProgressBar(
                    f"{v.name:>8s} truth", enabled=not quiet))
            write_outputs(result, target, fmt=fmt,
                          progress=ProgressBar(f"{v.name:>8s} write", enabled=not quiet))
            write_report(result, folder.staged(target) / "report.html",
                         reliability=result.reliability,
                         progress=ProgressBar(f"{v.name:>8s} report", enabled=not quiet))
        except CancelledError:
            raise
        except VectorAdjustError as exc:  # this database only: the others go on
            if is_disk_full(exc):
                raise
            shutil.rmtree(folder.staged(target), ignore_errors=True)  # nothing half of it
            print(f"\nvectoradjust compare: {v.name}: {exc}", file=sys.stderr)
            failed.append({"database": v.name, "adjusted": 0, "error": str(exc),
                           "_error": not isinstance(exc, NothingAdjustedError)})
            continue
        rows.append(compare_row(result.summary))
        runs.append(result)
    return runs, rows, failed


def cmd_compare(args) -> int:
    with _output_folder(args.out, "compare") as folder:
        rows, errors = _compare_into(args.project, folder, args.format, args.quiet)
    print(f"vectoradjust compare: {args.project} (each database adjusted alone)")
    print_table(rows)
    for r in rows:
        if r.get("error"):
            print(f"  {r['database']}: not adjusted (see compare.csv, column error)")
    print(f"  wrote {Path(args.out) / 'compare.csv'} and {Path(args.out) / 'report.html'}")
    _say_notes(folder, args.quiet)
    if errors:  # finished what it could; the exit status says that some failed
        print(f"vectoradjust compare: {len(errors)} of {len(rows)} databases failed: "
              f"{', '.join(errors)} (the reasons are above and in compare.csv)",
              file=sys.stderr)
        return 1
    return 0


def cmd_demo(args) -> int:
    project = sample_project_dir() / "project.toml"
    out = Path(args.out)
    print(f"vectoradjust demo: sample project {project}")
    print("  all road databases adjusted together ->", out / "all")
    ns = argparse.Namespace(project=str(project), out=str(out / "all"), format=args.format,
                            vectors=None, quiet=args.quiet)
    cmd_adjust(ns)
    print("\n  each database alone (compare) ->", out / "compare")
    rows = compare(project, out / "compare", fmt=args.format, quiet=args.quiet)
    print_table(rows)
    print("\n  (RMSE x/y/z/h: of the residuals V = adjusted - database; recovery = the smaller "
          "of RMSE(V) and RMSE(database - truth) over the larger; improvement = 1 - "
          "RMSE(adjusted - truth) / RMSE(database - truth))")
    print(f"  reports: {out / 'all' / 'report.html'}, {out / 'compare' / 'report.html'}")
    _demo_satellite(sample_project_dir() / "satellite", out / "satellite", args)
    return 0


def _demo_satellite(folder: Path, out: Path, args) -> None:
    """The demo's second part: the satellite sample (RPC triplet) adjusted, its bias and
    its OSM row printed."""
    import csv
    import json

    print(f"\n  satellite triplet with RPCs ({folder / 'project.toml'}) ->", out)
    ns = argparse.Namespace(project=str(folder / "project.toml"), out=str(out),
                            format=args.format, vectors=None, quiet=True)
    cmd_adjust(ns)
    summary = json.loads((out / "summary.json").read_text(encoding="utf-8"))
    with open(folder / "truth_bias.csv", newline="", encoding="utf-8") as fh:
        truth = {r["image_id"]: r for r in csv.DictReader(fh)}
    print("  image   bias  a0 (columns)      b0 (rows)  px   true a0     b0   corrected RPC")
    for e in summary["images"]:
        b, sd, t = e["bias"], e["sigma_bias"], truth.get(e["id"], {})
        print(f"  {e['id']:>5s}  {b['a0']:7.3f} +-{sd['a0']:.3f}  {b['b0']:7.3f} +-{sd['b0']:.3f}"
              f"     {float(t.get('a0', 'nan')):7.3f} {float(t.get('b0', 'nan')):7.3f}   "
              f"{e.get('corrected_rpc', {}).get('file', '-')}")
    print_table([compare_row(summary)])
    print(f"  report: {out / 'report.html'}")


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of the ``vectoradjust`` command."""
    p = argparse.ArgumentParser(
        prog="vectoradjust",
        description="Photogrammetric adjustment of road vectors: how far each vertex is from "
                    "the truth, where it belongs, and how sure that is.",
    )
    p.add_argument("--version", action="version", version=f"vectoradjust {__version__}")
    sub = p.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True

    def common(sp):
        sp.add_argument("--format", choices=("gpkg", "shp"), default="gpkg",
                        help="output format (default gpkg)")
        sp.add_argument("-q", "--quiet", action="store_true", help="no progress bar or summary")

    d = sub.add_parser("demo", help="run the embedded sample project end to end")
    d.add_argument("-o", "--out", default="vectoradjust-demo", help="output directory "
                   "(default ./vectoradjust-demo)")
    common(d)
    d.set_defaults(func=cmd_demo)

    a = sub.add_parser("adjust", help="adjust the road vectors of a project")
    a.add_argument("project", help="project file (TOML)")
    a.add_argument("-o", "--out", required=True, help="output directory")
    a.add_argument("--vectors", action="append", metavar="NAME",
                   help="adjust only this [[vectors]] entry (repeatable)")
    a.add_argument("--no-bands", action="store_true",
                   help="do not write the uncertainty_bands layer (saves time on large runs)")
    a.add_argument("--datum", choices=("auto", "free"), default=None,
                   help="auto: the datum from control points, camera priors and control "
                        "databases (checked before the solve); free: a free network (no "
                        "priors, inner constraints), relative precision only (default: the "
                        "project's [adjustment] datum, else auto)")
    a.add_argument("--conflation-raster", action="store_true",
                   help="also write each database's conflation field as a GeoTIFF "
                        "(conflation_<name>.tif: dX, dY, dZ, CE90, LE90)")
    common(a)
    a.set_defaults(func=cmd_adjust)

    c = sub.add_parser("compare", help="adjust each road database alone and compare")
    c.add_argument("project", help="project file (TOML)")
    c.add_argument("-o", "--out", required=True, help="output directory")
    common(c)
    c.set_defaults(func=cmd_compare)

    cli_qa.add_parser(sub)
    cli_propagate.add_parsers(sub)
    cli_buffer.add_parser(sub)
    cli_study.add_parser(sub)
    cli_many.add_parser(sub)
    cli_measure.add_parser(sub)
    cli_drone.add_parser(sub)
    cli_dtm.add_parser(sub)
    return p


def main(argv: Optional[Sequence[str]] = None) -> int:
    """Entry point of the ``vectoradjust`` console script."""
    parser = build_parser()
    args = parser.parse_args(argv)
    return run_command(args)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
