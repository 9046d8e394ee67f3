"""The stages of a project's run that go on in forked processes beside the parent.

:func:`vectoradjust.runner.project_run.run_project` starts them (each on
:class:`vectoradjust.runner.background.Background`) and waits for them where it needs
their results:

- :class:`TruthBeforeAlongside` - the ``[truth]`` tests' half on the database lines,
  while the parent adjusts;
- :class:`KernelsAlongside` - the compiled band kernels looked for (the first time:
  compiled) while the parent adjusts;
- :class:`BandsAlongside` - the uncertainty bands, one share of the features per
  process, once the adjustment is final (each process saves its share's covariances
  in a temporary file, :func:`covariance_file`, and lets the factorisation go);
- :class:`ReportAlongside` - ``report.html`` while the parent writes the layers (and,
  with ``run_into(reports=...)``, while it adjusts the next database: ``compare``,
  ``demo``).

Without ``fork`` (not Linux), with one worker or ``enabled=False`` every stage runs in
the parent where its result is needed: the outputs are the same either way.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path
from typing import Optional

__all__ = ["BandsAlongside", "KernelsAlongside", "ReportAlongside", "TruthBeforeAlongside",
           "bands_alongside", "band_share", "compile_kernels", "covariance_file",
           "load_covariances", "save_covariances", "summarised", "PLOTTING"]

#: the report's plotting modules, loaded in a thread while the statistics are computed
PLOTTING = ("matplotlib.figure", "matplotlib.backends.backend_agg")


class TruthBeforeAlongside:
    """The ``[truth]`` tests' half before the adjustment
    (:func:`vectoradjust.files.truth.truth_before`: the database lines inside the true
    lines' buffers, the database vertices' distances to them) computed by a forked
    process while the parent adjusts (the second core is idle during the solve).

    :meth:`result` gives it to ``truth_buffer(before=...)`` and
    ``truth_tables(before=...)``, which then measure only the adjusted coordinates.
    Without a child (no ``fork``, ``VECTORADJUST_WORKERS=1``, ``enabled=False``) or when
    it failed, :meth:`result` is None and they measure both halves as without it: the
    same values.

    Parameters
    ----------
    data : vectoradjust.model.ProjectData
        The project's inputs, as read.
    truth_path : str
        The true centrelines (``[truth] path``).
    widths : list of float
        The buffer widths.
    preload : vectoradjust.runner.background.Preload, optional
        Imports running in a thread: waited for before the fork (no module half
        imported in the child).
    enabled : bool
        False: no child.
    """

    def __init__(self, data, truth_path, widths, preload=None, enabled: bool = True) -> None:
        from vectoradjust.files.truth import truth_before
        from vectoradjust.runner.background import Background

        if preload is not None and enabled:
            preload.wait()
        self.job = Background(truth_before, data, truth_path, widths, enabled=enabled)

    def result(self, progress=None):
        """The :class:`vectoradjust.files.truth.TruthBefore` of the child (waits for it,
        forwarding its progress), or None (no child, or it failed)."""
        return self.job.result(progress, rerun=False)

    def close(self) -> None:
        """Stop the child if it still runs (an error or Ctrl-C in the parent)."""
        self.job.close()


class BandsAlongside:
    """The uncertainty bands built by forked processes (one share of the features each)
    while the parent runs the ``[truth]`` tests and writes the other layers.

    Parameters
    ----------
    result : vectoradjust.results.AdjustmentRun
        The run, adjusted (its factorisation still held).
    out_dir : str or os.PathLike
        Where the processes write their shares (a hidden temporary folder in it).
    n : int, optional
        Processes (default :func:`vectoradjust.runner.background.workers`; 1: the bands
        are built in the parent when asked for).
    """

    def __init__(self, result, out_dir, n: Optional[int] = None) -> None:
        from vectoradjust.files import derived_outputs as do
        from vectoradjust.runner.background import Background, workers

        self.run, self.folder = result, None
        n = workers() if n is None else n
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
        self.jobs = ([Background(band_share, make, result, pid, part=p, **kw)
                      for p in self.parts] if n > 1
                     else [Background(band_share, make, result, pid, enabled=False, **kw)])
        self.forked = [j.forked for j in self.jobs]  # (a job forgets its process at the end)

    def keep(self, progress=None) -> None:
        """Keep what the bands take from the factorisation, so that every share can
        still be built here after it is let go: the file a band process saved its
        share's covariances in (:func:`band_share`), else the covariances computed now
        (``progress(1.0, message)`` says so)."""
        from vectoradjust.accuracy.derived import segment_covariances

        for part, forked in zip(self.parts, self.forked):
            saved = covariance_file(self.folder, part) if forked else None
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
        from vectoradjust.files import derived_outputs as do
        from vectoradjust.runner.background import gather

        merge = do.merge_band_files if self.folder else do.merge_band_parts
        return merge(self.run, gather(self.jobs, progress))

    def close(self) -> None:
        """Stop the processes still running and remove their temporary folder."""
        for j in self.jobs:
            j.close()
        if self.folder is not None:
            shutil.rmtree(self.folder, ignore_errors=True)


def covariance_file(folder, part: tuple) -> Optional[Path]:
    """Where the band process of ``part`` saves its share's covariances (None: nowhere)."""
    return None if folder is None else Path(folder) / f"covariances_{part[0]}_of_{part[1]}.npz"


def save_covariances(path: Path, kept: dict) -> None:
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


def load_covariances(path: Path) -> dict:
    """The covariances :func:`save_covariances` saved, by database name."""
    import dataclasses

    import numpy as np

    from vectoradjust.accuracy.derived import SegmentCovariances

    names = [f.name for f in dataclasses.fields(SegmentCovariances)]
    with np.load(path) as z:
        return {str(z[f"name_{i}"]): SegmentCovariances(
            **{k: z[f"{k}_{i}"] for k in names if f"{k}_{i}" in z.files})
            for i in range(int(z["n"]))}


def band_share(make, result, parent: int, kept: dict, part: tuple = (0, 1), **kwargs):
    """``make(result, part=part, **kwargs)`` with the covariances ``kept[part]`` (if any).

    In a process of its own (not ``parent``) the covariances of its share are taken from
    the factorisation first and the factorisation is let go: its copy-on-write pages are
    not held by the band processes too. With a ``folder`` the covariances are saved there
    (:func:`covariance_file`) before the bands are built: the parent then need not
    compute them again for the case that this process fails."""
    if os.getpid() != parent:
        from vectoradjust.accuracy.derived import segment_covariances

        if kwargs.get("progress") is not None:
            kwargs["progress"](0.0, "uncertainty bands: covariances of the segments")
        mine = {d.name: segment_covariances(result, d, part) for d in result.databases}
        result.result.release_factorisation()
        path = covariance_file(kwargs.get("folder"), part)
        if path is not None:
            try:
                save_covariances(path, mine)
            except OSError:  # the parent computes them itself (keep)
                pass
    else:
        mine = kept.get(part)
        if isinstance(mine, Path):
            mine = load_covariances(mine)
    return make(result, part=part, covariances=mine or None, **kwargs)


def summarised(result, started: list, conflation_raster: bool = False, progress=None):
    """The bands' processes once the run is summarised (None: no bands), and the
    factorisation let go: nothing after the adjustment needs it but the conflation rasters
    (the bands took their covariances), so about 1 GB at 10^6 shape points is free for
    the tests and the layers."""
    bands = started[0] if started else None
    if not conflation_raster:
        if bands is not None:
            bands.keep(progress)
        result.result.release_factorisation()
    return bands


def bands_alongside(result, out_dir, preload=None, progress=None, kernels=None,
                    n: Optional[int] = None):
    """The uncertainty bands, started in other processes (None: the run has no database);
    their files go into ``out_dir`` (the run's staging folder). ``n``: processes (default
    :func:`vectoradjust.runner.background.workers`)."""
    if not result.databases:
        if kernels is not None:
            kernels.close()
        return None
    if preload is not None:  # no module half imported in the children
        preload.wait()
    from vectoradjust.accuracy.derived import warm_ring_kernel
    from vectoradjust.runner.background import workers

    n = workers() if n is None else n
    # the compiled band kernels (rings, union) loaded once here, not in every band process
    say = None if progress is None else (lambda m: progress(0.75, f"uncertainty bands: {m}"))
    if kernels is not None:  # compiled or found by a child meanwhile: loaded from the cache
        kernels.wait(say)
    warm_ring_kernel(sum(len(d.vertex_point) for d in result.databases) // n, say)
    return BandsAlongside(result, out_dir, n)


def compile_kernels(n_segments: int, progress=None) -> bool:
    """The band kernels compiled into numba's cache, or found there (in a child)."""
    from vectoradjust.accuracy.derived import warm_ring_kernel

    return warm_ring_kernel(n_segments)


class KernelsAlongside:
    """The compiled band kernels (:func:`vectoradjust.accuracy.derived.warm_ring_kernel`)
    looked for by a forked child while the parent adjusts: numba compiles them there the
    first time after installing (on the core the solve leaves idle) and writes them into
    its cache, from which the parent then loads them. Nothing is started when the bands
    will not use them (too few segments per band process, numba missing or switched off,
    ``enabled=False``).

    Parameters
    ----------
    data : vectoradjust.model.ProjectData
    preload : vectoradjust.runner.background.Preload, optional
        Waited for before the fork.
    n : int, optional
        Band processes to come (default :func:`vectoradjust.runner.background.workers`).
    enabled : bool
        False: nothing started.
    """

    def __init__(self, data, preload=None, n: Optional[int] = None,
                 enabled: bool = True) -> None:
        import importlib.util

        from vectoradjust.accuracy.derived import band_kernels as derived
        from vectoradjust.runner.background import Background, workers

        self.job = None
        n = sum(len(layer.coords) for _, layer in data.vectors) // (n or workers())
        if not enabled or n < derived._KERNEL_MIN or derived._numba_off() or \
                importlib.util.find_spec("numba") is None:
            return
        if preload is not None:  # no module half imported in the child
            preload.wait()
        job = Background(compile_kernels, n)
        self.job = job if job.forked else None  # without a child: the parent loads them

    def wait(self, say=None) -> None:
        """Until the child has ended (it may still be compiling)."""
        if self.job is not None:
            if self.job.proc is not None and self.job.proc.is_alive() and say is not None:
                say("waiting for the compiled band kernels (compiled once after installing)")
            self.job.result(rerun=False)
            self.close()

    def close(self) -> None:
        """Stop the child if it still runs."""
        if self.job is not None:
            self.job.close()
            self.job = None


def write_report_html(run, path, qa, progress=None, colors=None, section: bool = False):
    """``report.html`` of ``run`` (with the ``[qa]`` verdict ``qa``, if any) at ``path``.

    ``colors``: each database's colour in the figures. ``section``: also the run's part
    of the comparison report (:func:`vectoradjust.files.report.page.compare_section`,
    with the same colours), drawn in the same figure memo (the figures the two share
    are drawn once); then ``(path, section)`` is returned."""
    from vectoradjust.files.report import write_report
    from vectoradjust.files.report.figures import figure_memo
    from vectoradjust.files.report.page import compare_section

    say = progress if progress is None or not section else (
        lambda f, m="": progress(0.8 * f, m))
    with figure_memo():
        path = write_report(run, path, reliability=run.reliability, qa=qa, progress=say,
                            colors=colors)
        if not section:
            return path
        part = compare_section(run, colors=colors)
    if progress is not None:
        progress(1.0, "report and its section of the comparison report written")
    return path, part


class ReportAlongside:
    """``report.html`` written by a forked process while the parent writes the layers
    (and, when :meth:`result` is asked for later, adjusts the next database).

    Writing the layers may add GDAL's warnings to the run's; the report shows them, so
    when they changed after the fork the parent writes the report again (the child's
    would lack them). Without a child it is written by the parent at the end.

    Parameters
    ----------
    run : vectoradjust.results.AdjustmentRun
    out_dir : str or os.PathLike
        ``report.html`` goes there.
    qa : dict or None
        The accuracy-control verdict.
    enabled : bool
        False: written by the parent when :meth:`result` is asked for.
    colors : dict, optional
        Each database's colour in the figures.
    section : bool
        Also the run's part of the comparison report (:attr:`section` once
        :meth:`result` has returned).
    """

    def __init__(self, run, out_dir, qa, enabled: bool = True, colors=None,
                 section: bool = False) -> None:
        from vectoradjust.runner.background import Background

        self.run, self.qa, self.colors, self.want = run, qa, colors, section
        self.section = None
        self.path = Path(out_dir) / "report.html"
        self.warnings = list(run.summary.get("warnings") or [])
        self.job = Background(write_report_html, run, self.path, qa, colors=colors,
                              section=section, enabled=enabled)
        self.forked = self.job.forked  # (the job forgets its process once it has ended)

    def result(self, progress=None) -> Path:
        """The report written (waits for the child, forwarding its progress)."""
        value = self.job.result(progress)
        if self.forked and self.job.done and \
                list(self.run.summary.get("warnings") or []) != self.warnings:
            value = write_report_html(self.run, self.path, self.qa, progress, self.colors,
                                      self.want)
        if self.want:
            value, self.section = value
        return value

    def close(self) -> None:
        """Stop the child if it still runs."""
        self.job.close()
