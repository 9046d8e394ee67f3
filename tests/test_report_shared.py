"""The report drawn cheaper (issue 32): figures shared between a run's report and its
part of the comparison report are drawn once, the comparison report takes those parts
ready-made with the same result, and a run's report can be left to finish later
(``run_into(reports=...)``) while the caller goes on.
"""

from __future__ import annotations

import re

import pytest

pytest.importorskip("matplotlib")

from vectoradjust.files import report  # noqa: E402
from vectoradjust.files.report import figures  # noqa: E402
from vectoradjust.pipeline import run  # noqa: E402
from vectoradjust.simulate import make_scenario  # noqa: E402


@pytest.fixture(scope="module")
def runs():
    """Two databases of one scenario, each adjusted alone (as ``compare`` does)."""
    data = make_scenario(4).to_project_data()
    return [run(data, vectors=[n]) for n in ("OSM", "TIGER")]


def _unstamped(text: str) -> str:
    """The page without the minute it was written."""
    return re.sub(r"\d{4}-\d\d-\d\d \d\d:\d\d</p>", "</p>", text)


@pytest.fixture()
def drawn(monkeypatch):
    """Every figure rendered (a list of its PNG's size), the rendering kept cheap."""
    calls: list = []
    real = figures.figure_png

    def count(fig, dpi=None):
        png = real(fig, dpi=20)
        calls.append(len(png))
        return png

    monkeypatch.setattr(figures, "figure_png", count)
    return calls


def test_a_figure_asked_for_again_in_the_memo_is_drawn_once(runs, drawn):
    r = runs[0]
    later = [figures._Later(("conflation", id(r)), lambda: report.conflation_figure(r))
             for _ in range(2)]
    with figures.figure_memo():
        first = figures._img(later[0], "conflation field", "caption")
        again = figures._img(later[1], "conflation field", "caption")
        other = figures._img(later[1], "conflation field", "another caption")
    assert first == again and len(drawn) == 2  # a new caption is another figure
    assert other != first
    figures._img(later[0], "conflation field", "caption")  # no memo: drawn again
    assert len(drawn) == 3


def test_report_and_comparison_part_share_their_figures(runs, tmp_path, drawn):
    """One process writes a database's report and its part of the comparison: the
    residual vectors, the conflation field and the ellipses are drawn once (the
    histogram differs: the part has no w-tests)."""
    from vectoradjust.runner.alongside import write_report_html

    colors = figures.database_colors(["OSM", "TIGER"])
    r = runs[1]  # TIGER: its colour is the comparison's second, not the palette's first
    path, part = write_report_html(r, tmp_path / "report.html", None, colors=colors,
                                   section=True)
    alone = len(drawn)
    assert path.is_file() and alone == 6  # 5 of the report + the part's histogram
    assert colors["TIGER"] != figures.database_colors(["TIGER"])["TIGER"]
    html = "".join(part.parts)
    assert html.count("data:image/png") == 4 and [t for _, _, t in part.toc][0] == \
        "Database TIGER"
    # the report of the database carries the very figures of its part (same colours)
    page = path.read_text(encoding="utf-8")
    shared = set(re.findall(r'src="(data:image/png[^"]+)"', html)) & set(
        re.findall(r'src="(data:image/png[^"]+)"', page))
    assert len(shared) == 3


def test_comparison_report_from_parts_is_the_same_page(runs, tmp_path, drawn):
    colors = figures.database_colors(["OSM", "TIGER"])
    rows = [{"database": r.databases[0].name} for r in runs]
    with figures.figure_memo():  # (the same figures on both pages: compared as text)
        here = report.write_compare_report(runs, rows, tmp_path / "a.html", colors=colors)
        parts = [report.compare_section(r, i, colors=colors) for i, r in enumerate(runs)]
        said: list = []
        ready = report.write_compare_report(runs, rows, tmp_path / "b.html", colors=colors,
                                            sections=[parts[0], None],
                                            progress=lambda f, m="": said.append(m))
    a, b = (_unstamped(p.read_text(encoding="utf-8")) for p in (here, ready))
    assert a == b and "Database TIGER" in a
    # the parts made beforehand still count in the progress, section by section
    assert "report: Database OSM" in said and "report: Database TIGER" in said


@pytest.mark.io
def test_a_report_left_to_finish_later_is_written_before_the_commit(sample_dir, tmp_path):
    """``run_into(reports=...)`` returns before the report is written (by another
    process where one can fork); :func:`finish_reports` waits for it, and only then
    does the commit move the folder into place; :func:`close_reports` stops it."""
    pytest.importorskip("geopandas")
    from vectoradjust.files.outputs import RunFolder
    from vectoradjust.runner.project_run import (
        PendingReport,
        RunOptions,
        close_reports,
        finish_reports,
        run_into,
    )

    project = str(sample_dir / "project.toml")
    out = tmp_path / "out"
    pending: list = []
    with RunFolder(out) as folder:
        _, written, _ = run_into(project, folder, folder.path,
                                 RunOptions(quiet=True, bands=False, vectors=["OSM"]),
                                 reports=pending)
        assert len(pending) == 1 and isinstance(pending[0], PendingReport)
        assert written["report.html"] == str(out / "report.html")
        assert not (out / "report.html").exists()  # nothing moved into place yet
        paths = finish_reports(pending)
        assert paths[0].is_file() and pending[0].section is None
        folder.commit()
    assert "<h2>Summary</h2>" in (out / "report.html").read_text(encoding="utf-8")
    stopped: list = []
    with RunFolder(tmp_path / "other") as folder:
        run_into(project, folder, folder.path,
                 RunOptions(quiet=True, bands=False, vectors=["OSM"]), reports=stopped)
        close_reports(stopped)  # e.g. a later stage failed: nothing left running
    proc = stopped[0].job.job.proc
    assert proc is None or not proc.is_alive()
    assert not (tmp_path / "other" / "report.html").exists()
