"""The report as a page and a file: the public API of ``report.html``.

:func:`report_html` / :func:`write_report` for one adjustment and
:func:`compare_report_html` / :func:`write_compare_report` for ``vectoradjust compare``:
the order of the sections, the page (title, contents, CSS, footer) and the atomic write.
"""

from __future__ import annotations

import datetime as _dt
import os
import re
import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Optional

from vectoradjust.errors import InputFileError
from vectoradjust.files.report.figures import (
    _db_colors,
    _img,
    _Later,
    _run_key,
    rmse_bar_figure,
)
from vectoradjust.files.report.listings import (
    _features_body,
    _flagged_body,
    _qa_body,
    _residuals_body,
    _shape_body,
)
from vectoradjust.files.report.maps import error_ellipse_figure
from vectoradjust.files.report.markup import _CSS, _badge, _e, _fmt, _generic, _note, _table
from vectoradjust.files.report.sections import (
    _accuracy_body,
    _conflation_body,
    _control_body,
    _databases_body,
    _Doc,
    _error_model_body,
    _images_body,
    _reporting,
    _section_done,
    _summary_body,
    _warnings_body,
)

__all__ = [
    "write_report",
    "write_compare_report",
    "report_html",
    "compare_report_html",
    "compare_section",
]


def _run_sections(doc: _Doc, run, *, acc: Optional[dict], qa: Any, reliability: Any,
                  prefix: str = "", level: int = 2, colors: Optional[dict] = None,
                  with_bars: bool = True) -> None:
    colors = _db_colors([d.name for d in run.databases], colors)
    sec = doc.section
    sec(f"{prefix}summary", "Summary", _summary_body(run, prefix), level)
    sec(f"{prefix}images", "Images: exterior orientation", _images_body(run, prefix), level)
    sec(f"{prefix}control-points", "Control points", _control_body(run, "control", prefix), level)
    sec(f"{prefix}check-points", "Check points", _control_body(run, "check", prefix), level)
    sec(f"{prefix}databases", "Road databases", _databases_body(run, prefix, colors,
                                                                 with_bars=with_bars), level)
    sec(f"{prefix}error-model", "Error model: identification, offsets, variance factors",
        _error_model_body(run), level)
    if (run.summary or {}).get("conflation"):
        sec(f"{prefix}conflation", "Conflation: every vertex corrected", _conflation_body(run),
            level)
    sec(f"{prefix}accuracy", "Accuracy statements", _accuracy_body(acc), level)
    sec(f"{prefix}precision", "Precision of the adjusted points",
        _img(_Later(_run_key("error ellipses", run, colors),
                    lambda: error_ellipse_figure(run, colors=colors)), "error ellipses",
             "90 % confidence ellipses (semi-axes 2.1460 \u221a\u03bb of the a-posteriori "
             "2\u00d72 covariance) at the adjusted positions, exaggerated by the stated "
             "factor; the circle gives the scale."), level)
    sec(f"{prefix}residuals", "Image residuals", _residuals_body(run, reliability), level)
    sec(f"{prefix}flagged", "Flagged observations", _flagged_body(run, reliability, prefix), level)
    sec(f"{prefix}features", "Features", _features_body(run, acc, prefix), level)
    sec(f"{prefix}shape-points", "Shape points", _shape_body(run, prefix), level)
    interior = run.summary.get("interior_orientation")
    if interior:
        sec(f"{prefix}interior", "Interior orientation", _generic(interior), level)
    if qa is not None:
        sec(f"{prefix}qa", "Quality assurance", _qa_body(qa), level)
    sec(f"{prefix}warnings", "Warnings", _warnings_body(run), level)


def _page(title: str, doc: _Doc, subtitle: str) -> str:
    indent = ' class="sub"'
    toc = "".join(f'<li{indent if lvl > 2 else ""}><a href="#{_e(i)}">{_e(t)}</a></li>'
                  for lvl, i, t in doc.toc)
    from vectoradjust import __version__

    stamp = _dt.datetime.now().strftime("%Y-%m-%d %H:%M")
    return (
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
        "<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">"
        f"<title>{_e(title)}</title><style>{_CSS}</style></head><body><main>"
        f"<h1>{_e(title)}</h1><p class=\"meta\">{_e(subtitle)} \u00b7 vectoradjust "
        f"{_e(__version__)} \u00b7 {_e(stamp)}</p>"
        f"<nav><strong>Contents</strong><ol>{toc}</ol></nav>"
        + "".join(doc.parts)
        + "<footer>Self-contained report written by vectoradjust: figures are embedded; the "
          "full per-vertex data are in adjusted.gpkg and summary.json.</footer>"
        "</main></body></html>\n"
    )


def _accuracy_for(run, accuracy: Optional[dict]) -> Optional[dict]:
    if accuracy is not None:
        return accuracy
    acc = (run.summary or {}).get("accuracy")
    if isinstance(acc, dict):
        return acc
    from vectoradjust.accuracy.statements import accuracy_statements

    return accuracy_statements(run)


def _compare_table(rows: Sequence[dict]) -> str:
    if not rows:
        return _note("(no rows)")
    keys: list = []
    for r in rows:
        for k in r:
            if k not in keys:
                keys.append(k)
    labels = {"database": "database", "adjusted": "adjusted vertices", "rmse_x": "RMSE x (m)",
              "rmse_y": "RMSE y (m)", "rmse_z": "RMSE z (m)", "rmse_horizontal": "RMSE h (m)",
              "mean_ce90": "mean CE90 (m)", "mean_le90": "mean LE90 (m)",
              "sigma0_squared": "\u03c3\u2080\u00b2", "chi_square_passed": "chi-square test",
              "check_rmse_horizontal": "check points RMSE h (m)",
              "true_rmse": "RMSE db\u2212truth (m)", "recovery": "recovery",
              "adjusted_truth_rmse": "RMSE adj\u2212truth (m)", "improvement": "improvement"}
    body = []
    for r in rows:
        line = []
        for k in keys:
            v = r.get(k)
            if k == "chi_square_passed":
                line.append(_badge(v))
            elif k == "sigma0_squared":
                line.append(_fmt(v, 4))
            else:
                line.append(_fmt(v, 3))
        body.append(line)
    return _table([labels.get(k, k.replace("_", " ")) for k in keys], body,
                  ident="compare-table")


def _project_label(project: str) -> str:
    """``<directory>/<file>`` of a project path (``<simulated ...>`` labels as they are)."""
    if not project or project.startswith("<"):
        return project
    p = Path(project)
    return f"{p.parent.name}/{p.name}" if p.parent.name else p.name


def report_html(run, *, title: Optional[str] = None, accuracy: Optional[dict] = None,
                compare_rows: Optional[Sequence[dict]] = None, qa: Any = None,
                reliability: Any = None, colors: Optional[dict] = None) -> str:
    """The report of one adjustment as an HTML string (see :func:`write_report`)."""
    acc = _accuracy_for(run, accuracy)
    project = str((run.summary or {}).get("project", ""))
    title = title or f"vectoradjust report: {_project_label(project) or 'adjustment'}"
    doc = _Doc()
    if compare_rows:
        doc.section("comparison", "Database comparison", _compare_table(compare_rows))
    _run_sections(doc, run, acc=acc, qa=qa, reliability=reliability, colors=colors)
    return _page(title, doc, f"project {project}" if project else "adjustment")


def write_report(run, path, *, title: Optional[str] = None, accuracy: Optional[dict] = None,
                 compare_rows: Optional[Sequence[dict]] = None, qa: Any = None,
                 reliability: Any = None, progress=None, is_cancelled=None,
                 colors: Optional[dict] = None) -> Path:
    """Write ``report.html``: one self-contained HTML file of an adjustment.

    Parameters
    ----------
    run : vectoradjust.pipeline.AdjustmentRun
    path : str or os.PathLike
        Output file (its directory is created); written atomically.
    title : str, optional
        Default ``"vectoradjust report: <project file name>"``.
    accuracy : dict, optional
        :func:`vectoradjust.accuracy.statements.accuracy_statements` of the run (default:
        ``run.summary["accuracy"]`` if present, else computed here).
    compare_rows : list of dict, optional
        Rows of a database comparison to show first.
    qa : dict or object with ``as_dict()``, optional
        QA verdict (rendered generically: verdict, stages, non-conformities).
    reliability : optional
        Reliability result: an object or dict with ``w_image`` (and ``critical``) for
        the w-test histogram, and ``flagged`` (list of dicts), or the list of flagged
        observations itself. Default: ``run.summary["reliability"]["flagged"]`` when
        present, else the report says "not computed".
    progress : callable, optional
        ``progress(fraction, message)`` after each section (figures and tables).
    is_cancelled : callable, optional
        Polled after each section; true raises :class:`CancelledError`.
    colors : dict, optional
        Colour of each road database in the figures (``compare`` gives every database
        its colour in the comparison); default: the palette in the run's order.

    Returns
    -------
    pathlib.Path
        The file written.

    Raises
    ------
    InputFileError
        If the file cannot be written.
    CancelledError
        If ``is_cancelled`` says so (nothing is written).
    """
    path = _prepare(Path(path))
    with _reporting(progress, is_cancelled):
        text = report_html(run, title=title, accuracy=accuracy, compare_rows=compare_rows,
                           qa=qa, reliability=reliability, colors=colors)
    if progress is not None:
        progress(1.0, "report written")
    return _write_text(path, text)


def compare_section(run, index: int = 0, *, colors: Optional[dict] = None,
                    accuracy: Optional[dict] = None) -> _Doc:
    """The part of the comparison report about one run: its heading and sections.

    :func:`compare_report_html` takes it ready-made (``sections``): the process that
    writes the run's own report builds it too, inside one
    :func:`~vectoradjust.files.report.figures.figure_memo`, so that the figures the two
    share are drawn once.

    Parameters
    ----------
    run : vectoradjust.pipeline.AdjustmentRun
    index : int
        The run's place in the comparison (names a run without databases).
    colors : dict, optional
        Colour of each database in the figures (those of the whole comparison).
    accuracy : dict, optional
        The run's accuracy statements (default: as :func:`write_report`).

    Returns
    -------
    _Doc
        Its table-of-contents entries and its HTML parts.
    """
    doc = _Doc()
    label = ", ".join(d.name for d in run.databases) or f"run {index + 1}"
    ident = re.sub(r"[^A-Za-z0-9_-]+", "-", label) or f"run-{index + 1}"
    prefix = f"{ident}-"
    doc.section(f"{prefix}run", f"Database {label}", "", 2)
    _run_sections(doc, run, acc=_accuracy_for(run, accuracy), qa=None, reliability=None,
                  prefix=prefix, level=3, colors=_db_colors([d.name for d in run.databases],
                                                            colors), with_bars=False)
    return doc


def compare_report_html(runs: Sequence, rows: Sequence[dict], *,
                        title: Optional[str] = None,
                        accuracies: Optional[Sequence[Optional[dict]]] = None,
                        colors: Optional[dict] = None,
                        sections: Optional[Sequence] = None) -> str:
    """The comparison report as an HTML string (see :func:`write_compare_report`)."""
    runs = list(runs)
    names = [d.name for r in runs for d in r.databases]
    colors = _db_colors(names, colors)
    project = str((runs[0].summary or {}).get("project", "")) if runs else ""
    title = title or f"vectoradjust comparison: {_project_label(project) or 'databases'}"
    doc = _Doc()
    entries = [e for r in runs for e in (r.summary.get("databases") or [])]
    body = (_note("Each road database adjusted alone with the same control and images.")
            + _compare_table(rows)
            + _img(rmse_bar_figure(entries, colors=colors,
                                   title="Horizontal RMSE per road database (each adjusted "
                                         "alone)"),
                   "RMSE per database", "Horizontal RMSE per road database across the runs."))
    doc.section("comparison", "Database comparison", body)
    accs = list(accuracies) if accuracies is not None else [None] * len(runs)
    ready = list(sections or [])
    for i, r in enumerate(runs):
        part = ready[i] if i < len(ready) else None
        if part is None:
            part = compare_section(r, i, colors=colors,
                                   accuracy=accs[i] if i < len(accs) else None)
        else:  # built beforehand: its sections are counted here
            for _, _, heading in part.toc:
                _section_done(heading)
        doc.toc.extend(part.toc)
        doc.parts.extend(part.parts)
    return _page(title, doc, f"project {project}" if project else "comparison")


def write_compare_report(runs: Sequence, rows: Sequence[dict], path, *,
                         title: Optional[str] = None,
                         accuracies: Optional[Sequence[Optional[dict]]] = None, progress=None,
                         is_cancelled=None, colors: Optional[dict] = None,
                         sections: Optional[Sequence] = None) -> Path:
    """Write the report of ``vectoradjust compare`` (each database adjusted alone).

    Parameters
    ----------
    runs : list of vectoradjust.pipeline.AdjustmentRun
        One run per database.
    rows : list of dict
        The comparison rows (``compare.csv``), shown as the first table.
    path : str or os.PathLike
    title : str, optional
    accuracies : list of dict, optional
        Accuracy statements per run (default: computed).
    progress, is_cancelled : callable, optional
        As in :func:`write_report`.
    colors : dict, optional
        Colour of each database in the figures (default: the palette in the runs' order).
    sections : list, optional
        Per run, its part of the report built beforehand (:func:`compare_section`, with
        the same ``colors``), or None: built here.

    Returns
    -------
    pathlib.Path

    Raises
    ------
    InputFileError
        If the file cannot be written.
    CancelledError
        If ``is_cancelled`` says so (nothing is written).
    """
    path = _prepare(Path(path))
    with _reporting(progress, is_cancelled):
        text = compare_report_html(runs, rows, title=title, accuracies=accuracies,
                                   colors=colors, sections=sections)
    if progress is not None:
        progress(1.0, "report written")
    return _write_text(path, text)


def _prepare(path: Path) -> Path:
    """Create the report's directory up front (fail before the work, not after)."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputFileError(f"Cannot create the directory of the report {str(path)!r} ({exc})",
                             "Choose a writable output directory", path=str(path)) from exc
    if path.is_dir():
        raise InputFileError(f"The report path {str(path)!r} is a directory",
                             "Give a file name such as report.html", path=str(path))
    return path


def _new_file_mode() -> int:
    """The mode ``open()`` gives a new file: 0666 less the process's umask (e.g. 0644)."""
    mask = os.umask(0o022)
    os.umask(mask)
    return 0o666 & ~mask


def _write_text(path: Path, text: str) -> Path:
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=".report-", suffix=".html", dir=path.parent)
        try:
            with os.fdopen(fd, "w", encoding="utf-8") as fh:
                fh.write(text)
            # mkstemp makes the file 0600; the report gets a new file's usual mode
            os.chmod(tmp, _new_file_mode())
            os.replace(tmp, path)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise
    except OSError as exc:
        raise InputFileError(f"Cannot write the report {str(path)!r} ({exc})",
                             "Choose a writable output directory", path=str(path)) from exc
    return path
