"""One project to a finished output folder: :func:`run_project`.

The whole job of ``vectoradjust adjust`` in one place, used by every command that
writes a project's folder (``adjust``, ``demo``, ``compare`` per database,
``adjust-many``) and by the Python API (``vectoradjust.run_project``)::

    project -> read (files.readers) -> adjust (pipeline.run) -> [truth] buffer test
            -> truth tables -> outputs (layers, CSVs, summary.json) -> [qa] verdict
            -> report.html -> commit (run_manifest.json)

beside which the forked stages of :mod:`vectoradjust.runner.alongside` run (the truth
tests' half on the database lines and the band kernels during the solve, the
uncertainty bands and the report while the parent writes the layers; with
``run_into(reports=...)`` the report goes on while the caller does its next work, and
is taken before the commit: :class:`PendingReport`, :func:`finish_reports`). Everything is
written into the folder's staging folder and moved into place at the end
(:class:`vectoradjust.files.outputs.RunFolder`): a failed, cancelled or interrupted
run leaves the previous result as it was.

Progress: ``progress(fraction, message)`` over the whole run, or an object with a
``stage(name)`` method giving one such callable per stage (``"adjust"``, ``"truth"``,
``"truth tables"``, ``"write"``, ``"report"``): the command line's progress bars.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Optional

from vectoradjust.errors import CancelledError, InputFileError, VectorAdjustError

__all__ = ["RunOptions", "Project", "ProjectResult", "PendingReport", "read_project",
           "run_project", "run_into", "finish_reports", "close_reports", "truth_tables",
           "qa_verdict", "sample_project_dir", "STAGES"]

#: the stages of a run and their share of a single ``progress(fraction, message)``
STAGES = {"adjust": (0.0, 0.75), "truth": (0.75, 0.8), "truth tables": (0.8, 0.85),
          "write": (0.85, 0.97), "report": (0.97, 1.0)}


@dataclass
class RunOptions:
    """How a project is run: what the flags of ``vectoradjust adjust`` set.

    Attributes
    ----------
    fmt : {"gpkg", "shp"}
        Output format (``--format``).
    vectors : list of str, optional
        Adjust only these ``[[vectors]]`` entries (``--vectors``; default all).
    bands : bool
        Write the ``uncertainty_bands`` layer (``--no-bands``: False).
    datum : {"auto", "free"}, optional
        Overrides the project's ``[adjustment] datum`` (``--datum``).
    conflation_raster : bool
        Also write ``conflation_<name>.tif`` per database (``--conflation-raster``).
    report : bool
        Write ``report.html`` (``adjust-many --no-report``: False).
    quiet : bool
        No progress (``-q``): the ``progress`` given to :func:`run_project` is not called.
    background : bool
        Run stages in forked processes beside the parent where possible (Linux; their
        number is ``VECTORADJUST_WORKERS``, else the CPUs). False: everything in this
        process (``adjust-many``, whose Dask workers are the parallelism). The outputs
        are the same either way.
    command : str
        The command recorded in the folder's lock and ``run_manifest.json``.
    compare_colors : dict, optional
        In a comparison (``compare``): each database's colour in the figures; the
        run's report then also builds its part of the comparison report
        (:attr:`PendingReport.section`; the figures the two share are drawn once).
    """

    fmt: str = "gpkg"
    vectors: Optional[list] = None
    bands: bool = True
    datum: Optional[str] = None
    conflation_raster: bool = False
    report: bool = True
    quiet: bool = False
    background: bool = True
    command: str = "adjust"
    compare_colors: Optional[dict] = None


@dataclass
class Project:
    """A project as read: its file (``spec``, None for inputs made in memory) and every
    file it refers to as arrays (``data``).

    Attributes
    ----------
    spec : vectoradjust.files.project.ProjectSpec or None
        The validated project file (its ``[truth]`` centrelines, its folder).
    data : vectoradjust.model.ProjectData
        The inputs of :func:`vectoradjust.pipeline.run`.
    """

    spec: Any
    data: Any

    @property
    def label(self) -> str:
        """The project file as given (``data.source`` without one)."""
        return str(self.spec.path) if self.spec is not None else str(self.data.source)

    def truth(self) -> Optional[tuple]:
        """``(path, widths)`` of the ``[truth]`` centrelines, or None."""
        if self.spec is None:
            return None
        from vectoradjust.files.truth import project_truth

        return project_truth(self.spec)


@dataclass
class ProjectResult:
    """What :func:`run_project` made.

    Attributes
    ----------
    run : vectoradjust.results.AdjustmentRun
        The adjustment and its statistics (``run.summary`` is ``summary.json``).
    out : pathlib.Path
        The output folder.
    written : dict
        Path of every file written (where it ended up), by name.
    qa : dict or None
        The ``[qa]`` accuracy-control verdict (``qa.json``), if the project has ``[qa]``.
    notes : list of (str, str)
        What the folder's commit said: ``("info", text)`` (an earlier run's files
        removed) or ``("warning", text)`` (files of unknown runs left in place).
    """

    run: Any
    out: Path
    written: dict = field(default_factory=dict)
    qa: Optional[dict] = None
    notes: list = field(default_factory=list)

    @property
    def summary(self) -> dict:
        """``summary.json`` as a dict."""
        return self.run.summary


@dataclass
class PendingReport:
    """A run's ``report.html`` still being written (by another process, where it can
    fork) after :func:`run_into` returned with ``reports=``: the caller goes on (e.g.
    adjusts the next database) and takes it with :meth:`result` before the folder's
    commit (:func:`finish_reports`), or stops it (:func:`close_reports`).

    Attributes
    ----------
    job : vectoradjust.runner.alongside.ReportAlongside
    bar : callable
        Gives the progress callable of the report's stage (called when it is waited for).
    """

    job: Any
    bar: Callable

    def result(self) -> Path:
        """The report's path in the staging folder (waits for it, showing its progress)."""
        return self.job.result(self.bar())

    @property
    def section(self):
        """The run's part of the comparison report (``compare_colors`` given; once
        :meth:`result` has returned), else None."""
        return self.job.section

    def close(self) -> None:
        """Stop its process if it still runs."""
        self.job.close()


def finish_reports(reports: list) -> list:
    """Wait for every :class:`PendingReport` in ``reports`` (in order); their paths.
    Whatever happens, none is left running (a cancel or an error stops the others)."""
    try:
        return [r.result() for r in reports]
    finally:
        close_reports(reports)


def close_reports(reports: list) -> None:
    """Stop the processes of the reports in ``reports`` that still run."""
    for r in reports:
        r.close()


def sample_project_dir() -> Path:
    """Directory of the embedded sample project (its ``project.toml``).

    Raises
    ------
    VectorAdjustError
        The sample is not installed.
    """
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


def read_project(path, datum: Optional[str] = None, progress=None) -> Project:
    """Read a project file and every file it refers to.

    Parameters
    ----------
    path : str or os.PathLike
        The TOML project file.
    datum : {"auto", "free"}, optional
        Overrides ``[adjustment] datum``.
    progress : callable, optional
        ``progress(fraction, message)`` while the files are read.

    Returns
    -------
    Project

    Raises
    ------
    VectorAdjustError
        The project or a file it names cannot be read (:class:`ProjectError`,
        :class:`InputFileError`, :class:`CRSError`, ...), naming the file and what to do.
    """
    from vectoradjust.files.project import load_project

    return _read(load_project(path), datum, progress)


def _read(source, datum: Optional[str], progress) -> Project:
    """``source`` (a ProjectSpec, a path, a :class:`Project` or a ProjectData) as a
    :class:`Project` with ``datum`` (if given) in its settings."""
    from vectoradjust.model import ProjectData

    if isinstance(source, Project):
        project = source
    elif isinstance(source, ProjectData):
        project = Project(None, source)
    else:
        from vectoradjust.files.project import ProjectSpec, load_project
        from vectoradjust.files.readers import load_project_data

        spec = source if isinstance(source, ProjectSpec) else load_project(source)
        project = Project(spec, load_project_data(spec, progress=progress))
    if datum is not None and datum != project.data.settings.datum:
        settings = dataclasses.replace(project.data.settings, datum=datum)
        project = Project(project.spec, dataclasses.replace(project.data, settings=settings))
    return project


def _check_options(options: RunOptions) -> None:
    if options.fmt not in ("gpkg", "shp"):
        raise InputFileError(f"Output format {options.fmt!r} is not supported",
                             "Use gpkg or shp")
    if options.datum not in (None, "auto", "free"):
        raise VectorAdjustError(f"datum {options.datum!r} is neither auto nor free",
                                "Give datum='auto' or datum='free' (or leave it out)")
    if options.background:  # a wrong VECTORADJUST_WORKERS is said before the work
        from vectoradjust.runner.background import workers

        workers()


def run_project(project, out, options: Optional[RunOptions] = None,
                progress: Optional[Callable] = None,
                cancel: Optional[Callable[[], bool]] = None) -> ProjectResult:
    """Run a project into a finished output folder, as ``vectoradjust adjust`` does.

    Reads the project, adjusts it, runs the ``[truth]`` tests, writes the per-point truth
    tables, the layers (``adjusted.gpkg`` or shapefiles, with the uncertainty bands), the
    CSVs and ``summary.json``, the ``[qa]`` verdict (``qa.json``), ``report.html`` and
    ``run_manifest.json``.

    Parameters
    ----------
    project : str, os.PathLike, Project, ProjectSpec or ProjectData
        The project file (its inputs are read after ``out`` is taken), or a project
        already read. A ProjectData alone has no ``[truth]`` centrelines: no buffer test.
    out : str or os.PathLike
        The output folder (created; locked while the run writes; the previous result
        stays until this one is complete).
    options : RunOptions, optional
        Default ``RunOptions()``: as ``vectoradjust adjust PROJECT --out OUT``.
    progress : callable, optional
        ``progress(fraction, message)``, or an object whose ``stage(name)`` gives one
        per stage (see the module's description).
    cancel : callable, optional
        Polled between iterations and stages; true raises :class:`CancelledError` and
        leaves ``out`` as it was.

    Returns
    -------
    ProjectResult

    Raises
    ------
    VectorAdjustError
        The project cannot be read or adjusted (the subclass names the cause: a wrong
        project file, an unreadable input, a CRS, the control, ...), ``out`` cannot be
        written or another run holds it, or the disk is full.
    CancelledError
        ``cancel()`` said so.
    """
    from vectoradjust.files.outputs import RunFolder
    from vectoradjust.files.project import ProjectSpec, load_project

    opts = options if options is not None else RunOptions()
    _check_options(opts)
    # a project that cannot be read (missing, a folder, permissions, encoding, a wrong
    # key) is said as such before `out` is touched, not as an output folder's problem
    source = project if isinstance(project, (Project, ProjectSpec)) or not isinstance(
        project, (str, Path)) else load_project(project)
    with RunFolder(out, command=opts.command) as folder:
        result, written, qa = run_into(source, folder, folder.path, opts, progress, cancel)
        folder.commit()
    return ProjectResult(result, Path(out), written, qa, list(folder.notes))


def _stage(progress, name: str, options: RunOptions) -> Callable:
    """The progress callable of one stage (see the module's description)."""
    if progress is None or options.quiet:
        return lambda fraction, message="": None
    make = getattr(progress, "stage", None)
    if callable(make):
        return make(name)
    lo, hi = STAGES[name]

    def say(fraction, message=""):
        f = min(max(float(fraction), 0.0), 1.0)
        progress(lo + (hi - lo) * f, f"{name}: {message}" if message else name)

    return say


def _check(cancel) -> None:
    if cancel is not None and cancel():
        raise CancelledError("The run was cancelled", "Run it again to finish it")


def run_into(source, folder, target, options: RunOptions, progress=None, cancel=None,
             reports: Optional[list] = None):
    """Read, adjust and write a project into ``target`` of an open ``folder``.

    Parameters
    ----------
    source : path, ProjectSpec, Project or ProjectData
    folder : vectoradjust.files.outputs.RunFolder
        Entered; its :meth:`commit` is the caller's (``compare`` writes every database
        into a folder of its own inside one RunFolder).
    target : pathlib.Path
        ``folder.path`` or a folder inside it.
    options, progress, cancel
        As :func:`run_project`.
    reports : list, optional
        Given: ``report.html`` is not waited for; a :class:`PendingReport` is appended
        instead, for the caller to finish (:func:`finish_reports`) before the commit.

    Returns
    -------
    tuple
        (the AdjustmentRun, the paths written by name, the ``[qa]`` verdict or None).
    """
    from vectoradjust.runner.alongside import (
        KernelsAlongside,
        TruthBeforeAlongside,
        bands_alongside,
        summarised,
    )
    from vectoradjust.runner.background import Preload, workers

    # the adjustment's modules load on the other core while the inputs are read; the
    # report's plotting library once the adjustment is final (an import holds the
    # interpreter: during the adjustment it would hold up the one busy core)
    warm = Preload(("vectoradjust.pipeline",))
    bar = _stage(progress, "adjust", options)
    bar(0.0, "reading inputs")
    # every database is read, so that measurements of the databases not selected with
    # `vectors` are recognised as their shape points and left out, not made tie points
    project = _read(source, options.datum, lambda f, m: bar(0.02 * f, m))
    _check(cancel)
    truth, bg = project.truth(), options.background
    n = workers() if bg else 1
    # true centrelines: their tests' half on the database lines runs beside the adjustment
    pre = TruthBeforeAlongside(project.data, *truth, warm, enabled=bg) if truth else None
    kernels = KernelsAlongside(project.data, warm, n, enabled=bg and options.bands)
    stage = folder.staged(target)
    started: list = []  # the bands start in other processes once the adjustment is final
    from vectoradjust.pipeline import run

    def adjusted(r) -> None:
        if options.bands:
            started.append(bands_alongside(r, stage, warm, bar, kernels, n))

    try:
        result = run(project.data, vectors=options.vectors, progress=bar,
                     is_cancelled=cancel, on_adjusted=adjusted)
    except BaseException:
        for b in (b for b in [*started, pre, kernels.job] if b is not None):
            b.close()
        raise
    kernels.close()  # (ended by now, unless no band was started)
    bands = summarised(result, started, options.conflation_raster, bar)
    written, qa = _write(result, project, folder, target, options, (truth, pre), bands,
                         (progress, cancel, reports))
    return result, written, qa


def qa_verdict(result, data) -> Optional[dict]:
    """The accuracy-control verdict of a project with ``[qa]`` (a dict), else None."""
    if not data.qa:
        return None
    from vectoradjust.qa.verdict import accuracy_control, spec_from_table

    return accuracy_control(result, spec_from_table(data.qa, source=data.source)).as_dict()


def _truth(result, project, stage, truth_pre, progress, options, cancel) -> tuple:
    """The ``[truth]`` buffer test (into the summary) and the per-point truth tables
    (into ``stage``); (the tables written by name, the half before the adjustment)."""
    from vectoradjust.files.truth import truth_buffer

    truth, pre = truth_pre
    before = None
    if truth is not None:  # true centrelines: buffer test before/after the adjustment
        tbar = _stage(progress, "truth", options)
        before = pre.result(lambda f, m: tbar(0.5 * f, m))
        truth_buffer(result, *truth, before=before, is_cancelled=cancel,
                     progress=lambda f, m="": tbar(0.5 + 0.5 * f, m))
    _check(cancel)
    tables = truth_tables(result, project.spec, stage, before=before,
                          progress=_stage(progress, "truth tables", options))
    return tables, before


def _write(result, project, folder, target, options, truth_pre, bands, hooks) -> tuple:
    """The outputs written into ``target``'s staging folder; (the paths where they end
    up by name, the ``[qa]`` verdict). ``hooks``: (progress, cancel, reports) as given
    to :func:`run_into`."""
    from vectoradjust.files.jsonfile import write_json
    from vectoradjust.files.outputs import write_outputs
    from vectoradjust.runner.alongside import PLOTTING, ReportAlongside
    from vectoradjust.runner.background import Preload

    progress, cancel, reports = hooks
    stage = folder.staged(target)
    stage.mkdir(parents=True, exist_ok=True)
    warm = Preload(PLOTTING if options.report else ())  # the bands' processes have started
    report, pre = None, truth_pre[1]
    try:
        truth_csv, _ = _truth(result, project, stage, truth_pre, progress, options, cancel)
        qa_doc = qa_verdict(result, project.data)
        if options.report:
            warm.wait()  # no module half imported in the report's process
            report = ReportAlongside(result, stage, qa_doc, enabled=options.background,
                                     colors=options.compare_colors,
                                     section=options.compare_colors is not None)
        written = write_outputs(result, target, fmt=options.fmt,
                                bands=bands.result if bands is not None else False,
                                progress=_stage(progress, "write", options),
                                is_cancelled=cancel)
    except BaseException:
        if report is not None:  # the report's process is not left running
            report.close()
        if pre is not None:
            pre.close()
        raise
    finally:
        if bands is not None:
            bands.close()
    written.update({k: str(folder.final(v)) for k, v in truth_csv.items()})
    try:
        if options.conflation_raster:
            from vectoradjust.files.derived_outputs import write_conflation_rasters

            written.update({k: str(folder.final(v))
                            for k, v in write_conflation_rasters(result, stage).items()})
        if qa_doc is not None:  # [qa] in the project: the accuracy-control verdict goes along
            written["qa.json"] = str(folder.final(write_json(
                stage, "qa.json", {**qa_doc, "project": project.label})))
    except BaseException:
        if report is not None:
            report.close()
        raise
    if report is not None and reports is not None:  # the caller takes it later
        reports.append(PendingReport(report, lambda: _stage(progress, "report", options)))
        written["report.html"] = str(folder.final(report.path))
    elif report is not None:
        written["report.html"] = str(folder.final(
            report.result(_stage(progress, "report", options))))
    return written, qa_doc


def truth_tables(run, spec, out_dir, label: str = "", progress=None, before=None) -> dict:
    """The per-point truth tables of a run into ``out_dir``.

    ``truth_points.csv``: per adjusted object point with vertex truth (``[[vectors]]
    truth``) the database and adjusted coordinates against the true ones and whether it
    moved closer. ``truth_line_points.csv``: with ``[truth]`` centrelines, each adjusted
    vertex's distance to the nearest true line before and after; the share moved closer
    goes into the summary (``databases[].truth.lines``).

    ``progress(fraction, message)`` is called before each table and while it is written.
    ``before`` (:func:`vectoradjust.files.truth.truth_before`, optional): the database
    vertices' distances to the true lines, computed beforehand.

    Returns
    -------
    dict
        Names of the files written.
    """
    from vectoradjust.files.study import truth_point_columns, write_csv

    say = progress or (lambda fraction, message="": None)
    out = Path(out_dir)
    written = {}
    say(0.0, "truth_points.csv")
    rows = truth_point_columns(run)
    if rows:
        written[f"{label}truth_points.csv"] = str(write_csv(
            rows, out / "truth_points.csv",
            progress=lambda f: say(0.5 * f, "writing truth_points.csv")))
    truth = None if spec is None else spec.raw.get("truth")
    if truth:
        from vectoradjust.files.truth import project_truth, truth_line_distances

        say(0.5, "distances to the true centrelines")
        path, _ = project_truth(spec)
        rows = truth_line_distances(run, path, as_columns=True, before=before,
                                    progress=lambda f, m: say(0.5 + 0.25 * f, m))
        if rows:
            written[f"{label}truth_line_points.csv"] = str(write_csv(
                rows, out / "truth_line_points.csv",
                progress=lambda f: say(0.75 + 0.25 * f, "writing truth_line_points.csv")))
    say(1.0, "truth tables written")
    return written
