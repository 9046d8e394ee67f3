"""report.html: structure, self-containment, embedded figures and numbers.

The report is parsed with html.parser; the numbers in its tables are compared with the
run's own arrays and summary (to the printed precision), the figures are decoded and
checked to be real PNG images, and nothing may load a remote resource.
"""

from __future__ import annotations

import base64
import struct
import zlib
from dataclasses import replace
from html.parser import HTMLParser

import numpy as np
import pytest

from vectoradjust.accuracy.tables import one_vertex_per_point

pytest.importorskip("matplotlib")

from vectoradjust.errors import InputFileError  # noqa: E402
from vectoradjust.files import report  # noqa: E402
from vectoradjust.pipeline import run  # noqa: E402
from vectoradjust.simulate import make_scenario  # noqa: E402

SECTIONS = ["Summary", "Images: exterior orientation", "Control points", "Check points",
            "Road databases", "Accuracy statements", "Precision of the adjusted points",
            "Image residuals", "Flagged observations", "Features", "Shape points", "Warnings"]
EVIL = '<script>alert("x")</script> & Co'


class _Page(HTMLParser):
    """Headings, images, attributes, tables (by id) and text of an HTML page."""

    def __init__(self):
        super().__init__(convert_charrefs=True)
        self.headings = []
        self.images = []
        self.tags = []
        self.attrs = []
        self.ids = []
        self.tables = {}
        self.text = []
        self._stack = []
        self._heading = None
        self._table = None
        self._row = None
        self._cell = None
        self._row_key = None

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        self.tags.append(tag)
        self.attrs.extend(attrs)
        if "id" in a:
            self.ids.append(a["id"])
        if tag in ("h1", "h2", "h3", "h4"):
            self._heading = []
        elif tag == "img":
            self.images.append(a)
        elif tag == "table" and self._table is None:
            self._table = a.get("id") or f"table{len(self.tables)}"
            self.tables[self._table] = []
            self._depth = 0
        elif tag == "table":
            self._depth += 1
        elif tag == "tr" and self._table is not None and self._depth == 0:
            self._row = []
            self._row_key = a.get("data-key")
        elif tag in ("td", "th") and self._row is not None and self._depth == 0:
            self._cell = []

    def handle_endtag(self, tag):
        if tag in ("h1", "h2", "h3", "h4") and self._heading is not None:
            self.headings.append("".join(self._heading).strip())
            self._heading = None
        elif tag in ("td", "th") and self._cell is not None and self._depth == 0:
            self._row.append("".join(self._cell).strip())
            self._cell = None
        elif tag == "tr" and self._row is not None and self._depth == 0:
            self.tables[self._table].append((self._row_key, self._row))
            self._row = None
        elif tag == "table" and self._table is not None:
            if self._depth == 0:
                self._table = None
            else:
                self._depth -= 1

    def handle_data(self, data):
        self.text.append(data)
        if self._heading is not None:
            self._heading.append(data)
        if self._cell is not None:
            self._cell.append(data)

    def table(self, ident):
        rows = self.tables[ident]
        return rows[0][1], [r for _, r in rows[1:]], {k: r for k, r in rows if k}


def _parse(path):
    p = _Page()
    p.feed(path.read_text(encoding="utf-8"))
    p.close()
    return p


def _png_info(src):
    assert src.startswith("data:image/png;base64,")
    raw = base64.b64decode(src.split(",", 1)[1], validate=True)
    assert raw[:8] == b"\x89PNG\r\n\x1a\n"
    length, kind = struct.unpack(">I4s", raw[8:16])
    assert kind == b"IHDR" and length == 13
    w, h = struct.unpack(">II", raw[16:24])
    assert zlib.crc32(raw[12:29]) == struct.unpack(">I", raw[29:33])[0]  # IHDR CRC
    assert raw[-12:] == b"\x00\x00\x00\x00IEND\xaeB`\x82"
    return w, h, len(raw)


@pytest.fixture(scope="module")
def scenario():
    return make_scenario(4)


@pytest.fixture(scope="module")
def adj_run(scenario):
    data = scenario.to_project_data()
    data.settings.reweight = "two-pass"
    # a hostile attribute value must come out escaped
    spec, layer = data.vectors[0]
    key = next(k for k in layer.attributes if "name" in k.lower())
    attrs = dict(layer.attributes)
    attrs[key] = [EVIL] + list(attrs[key][1:])
    data.vectors[0] = (spec, replace(layer, attributes=attrs))
    return run(data)


@pytest.fixture(scope="module")
def page(adj_run, tmp_path_factory):
    path = tmp_path_factory.mktemp("report") / "out" / "report.html"
    written = report.write_report(adj_run, path)
    assert written == path and path.is_file()
    return _parse(path)


def test_every_section_heading(page):
    for title in SECTIONS:
        assert title in page.headings, title
    assert page.headings[0].startswith("vectoradjust report")


def test_self_contained(page):
    assert "script" not in page.tags and "link" not in page.tags and "iframe" not in page.tags
    for name, value in page.attrs:
        if name in ("src", "href"):
            assert not value.lower().startswith(("http", "//", "file:")), value
            assert value.startswith(("data:image/png;base64,", "#")), value
    text = "".join(page.text).lower()
    assert "@import" not in text and "url(" not in text
    assert len(page.ids) == len(set(page.ids)), "duplicate element ids"


def test_figures_are_valid_pngs(page):
    # residual vectors, RMSE bars, conflation field, error ellipses, residual histogram
    assert len(page.images) == 5
    for img in page.images:
        w, h, size = _png_info(img["src"])
        assert w >= 400 and h >= 250
        assert size > 15_000  # a real plot, not an empty canvas
        assert img.get("alt")


def test_summary_numbers(adj_run, page):
    s = adj_run.summary
    _, _, rows = page.table("summary-table")

    def val(key):
        return rows[key][1]

    assert float(val("sigma0_squared")) == pytest.approx(s["sigma0_squared"], abs=5e-5)
    assert float(val("sigma0")) == pytest.approx(np.sqrt(s["sigma0_squared"]), abs=5e-5)
    assert int(val("degrees_of_freedom")) == s["degrees_of_freedom"]
    assert int(val("iterations")) == s["iterations"]
    chi = s["chi_square"]
    assert float(val("chi_square_statistic")) == pytest.approx(chi["statistic"], abs=5e-3)
    assert float(val("chi_square_lower")) == pytest.approx(chi["lower"], abs=5e-3)
    assert float(val("chi_square_upper")) == pytest.approx(chi["upper"], abs=5e-3)
    assert val("chi_square_passed") == ("passed" if chi["passed"] else "FAILED")
    assert int(val("observations_total")) == s["observations"]["total"]
    assert int(val("unknowns")) == s["observations"]["unknowns"]
    assert float(val("shape_rmse_horizontal")) == pytest.approx(
        s["shape_points"]["rmse_horizontal"], abs=5e-4)
    h, v = (float(x) for x in val("check_rmse").split("/"))
    assert h == pytest.approx(s["check_points"]["rmse_horizontal"], abs=5e-4)
    assert v == pytest.approx(s["check_points"]["rmse_z"], abs=5e-4)
    assert val("crs") == s["crs"]


def test_image_and_point_tables(adj_run, page):
    head, rows, _ = page.table("images-table")
    assert len(rows) == len(adj_run.summary["images"])
    for r, im in zip(rows, adj_run.summary["images"]):
        assert r[0] == im["id"]
        assert float(r[2]) == pytest.approx(im["position"][0], abs=5e-4)
        assert float(r[5]) == pytest.approx(im["sigma_position"][0], abs=5e-4)
        assert float(r[10]) == pytest.approx(im["attitude"][2], abs=5e-6)
    cp = adj_run.control_points
    for role in ("control", "check"):
        head, rows, _ = page.table(f"{role}-table")
        sel = np.flatnonzero(cp["role"] == role)
        assert [r[0] for r in rows] == [str(cp["point_id"][i]) for i in sel]
        j = head.index("Vx (m)")
        assert np.allclose([float(r[j]) for r in rows], cp["Vx"][sel], atol=5e-4)


def test_database_tables(adj_run, page):
    head, rows, _ = page.table("databases-table")
    assert [r[0] for r in rows] == [d.name for d in adj_run.databases]
    j = head.index("RMSE V horiz. (m)")
    for r, d in zip(rows, adj_run.databases):
        adj = one_vertex_per_point(d.vertex_point)  # each object point once
        rh = np.sqrt(np.mean(d.vertices["Vx"][adj] ** 2 + d.vertices["Vy"][adj] ** 2))
        assert float(r[j]) == pytest.approx(rh, abs=5e-4)
    head, rows, _ = page.table("truth-table")
    j = head.index("recovery")
    for r, d in zip(rows, adj_run.databases):
        assert float(r[j]) == pytest.approx(d.truth["recovery_rate"], abs=5e-4)


def test_features_and_shape_points(adj_run, page):
    for d in adj_run.databases:
        head, rows, _ = page.table(f"features-{d.name}")
        assert len(rows) == d.shape.layer.n_features
        assert [r[0] for r in rows] == list(d.shape.layer.feature_ids)
        j = head.index("RMSE horiz. (m)")
        got = np.array([float(r[j]) if r[j] != "\u2013" else np.nan for r in rows])
        assert np.allclose(got, d.features["RMSE"], atol=5e-4, equal_nan=True)
    # every vertex listed (small run)
    head, rows, _ = page.table("shape-table")
    assert len(rows) == sum(len(d.vertices["X"]) for d in adj_run.databases)


def test_text_is_escaped(page, tmp_path, adj_run, no_figures):
    assert EVIL in "".join(page.text)  # shown literally, as text
    assert page.tags.count("script") == 0
    html = report.report_html(adj_run, title="<b>T&T</b>")
    assert "<b>T&T</b>" not in html and "&lt;b&gt;T&amp;T&lt;/b&gt;" in html


def test_accuracy_section(adj_run, page):
    text = " ".join(page.text)
    for d in adj_run.databases:
        assert f"Database {d.name}" in page.headings
    assert "Tested" in text and "ASPRS" in text and "RMSE_3D" in text
    assert "on average the database lies" in text


@pytest.fixture()
def no_figures(monkeypatch):
    """Skip rendering the figures where a test looks at the text only (``_img`` is
    looked up in each of these report modules)."""
    from vectoradjust.files.report import listings, page, sections

    for mod in (sections, listings, page):
        monkeypatch.setattr(mod, "_img", lambda fig, alt, caption: "<p>figure</p>")


def test_flagged_and_qa(adj_run, tmp_path, no_figures):
    no_rel = replace(adj_run, summary={k: v for k, v in adj_run.summary.items()
                                       if k != "reliability"})
    p = _parse(report.write_report(no_rel, tmp_path / "a.html"))
    assert "not computed" in " ".join(p.text)
    assert "Quality assurance" not in p.headings
    k = len(adj_run.result.v_image)
    w = np.random.default_rng(1).normal(size=(k, 2))
    w[3, 1] = 5.5
    rel = {"w_image": w, "critical": 3.2905,
           "flagged": [{"kind": "image", "image": "L", "point": "P<1>", "component": "y",
                        "w": 5.5, "suspected_error_um": -12.3}]}
    qa = {"verdict": "fail", "passed": False,
          "stages": [{"name": "block: GCP XY", "status": "fail", "measured": 0.21,
                      "tolerance": 0.2, "points": [{"id": "GCP01", "value": 0.5,
                                                    "passed": False}]}]}
    p = _parse(report.write_report(adj_run, tmp_path / "b.html", reliability=rel, qa=qa))
    head, rows, _ = p.table("flagged-table")
    assert head[:3] == ["kind", "image", "point"] and rows[0][2] == "P<1>"
    assert "Quality assurance" in p.headings
    assert "REJECTED" in " ".join(p.text) and "block: GCP XY" in " ".join(p.text)
    # the histogram gets a second panel for the w-tests, with the critical value
    fig = report.residual_histogram_figure(adj_run, rel)
    assert len(fig.axes) == 2 and len(report.residual_histogram_figure(adj_run).axes) == 1
    n_over = int(np.sum(np.abs(w) > 3.2905))
    assert f"{n_over} flagged" in " ".join(t.get_text()
                                           for t in fig.axes[1].get_legend().get_texts())
    # flagged observations stored in the summary are found there
    run2 = replace(adj_run, summary={**adj_run.summary, "reliability": {"flagged": []}})
    p = _parse(report.write_report(run2, tmp_path / "c.html"))
    assert "No observation is flagged" in " ".join(p.text)


def test_large_runs_list_the_largest_residuals(adj_run, tmp_path, monkeypatch, no_figures):
    monkeypatch.setattr(report.listings, "MAX_FULL_SHAPE_ROWS", 50)
    monkeypatch.setattr(report.listings, "LARGEST_SHAPE_ROWS", 25)
    p = _parse(report.write_report(adj_run, tmp_path / "r.html"))
    head, rows, _ = p.table("shape-table")
    assert len(rows) == 25
    vh = np.concatenate([np.hypot(d.vertices["Vx"], d.vertices["Vy"])
                         for d in adj_run.databases])
    expected = np.sort(vh[np.isfinite(vh)])[::-1][:25]
    j = head.index("|V| horiz. (m)")
    assert np.allclose([float(r[j]) for r in rows], expected, atol=5e-4)
    assert "largest horizontal residual" in " ".join(p.text)


def test_figures_subsample_and_say_so(adj_run):
    fig = report.residual_vector_figure(adj_run, max_arrows=40)
    axes = [a for a in fig.axes if a.get_visible()]
    assert len(axes) == len(adj_run.databases)
    from matplotlib.quiver import Quiver

    for ax in axes:

        q = [c for c in ax.collections if isinstance(c, Quiver)][0]
        assert len(q.U) == 40
        assert "40 of" in ax.get_title()
        assert ax.get_aspect() == 1.0 and "Easting" in ax.get_xlabel()
    fig = report.error_ellipse_figure(adj_run, max_ellipses=100)
    assert "points shown" in fig.axes[0].get_title()
    assert "exaggerated" in fig.axes[0].get_title()


def test_arrow_scale_is_stated_and_true(adj_run):
    fig = report.residual_vector_figure(adj_run, exaggeration=3.0)
    from matplotlib.quiver import Quiver

    ax = fig.axes[0]
    q = [c for c in ax.collections if isinstance(c, Quiver)][0]
    d = adj_run.databases[0]
    adj = d.vertices["Adjusted"] == 1
    # arrow lengths in data units are 3 x the residual lengths
    lengths = np.hypot(q.U, q.V)
    res = np.hypot(d.vertices["Vx"][adj], d.vertices["Vy"][adj])
    assert lengths.max() == pytest.approx(3.0 * res.max(), rel=1e-9)
    sup = fig.get_suptitle() if hasattr(fig, "get_suptitle") else fig._suptitle.get_text()
    assert "\u00d73" in sup


def test_compare_report(scenario, tmp_path):
    data = scenario.to_project_data()
    runs = [run(data, vectors=[n]) for n in ("OSM", "TIGER")]
    rows = [{"database": r.databases[0].name,
             "rmse_horizontal": r.summary["databases"][0]["residuals"]["rmse_horizontal"],
             "chi_square_passed": r.summary["chi_square"]["passed"]} for r in runs]
    path = report.write_compare_report(runs, rows, tmp_path / "compare" / "report.html")
    p = _parse(path)
    assert "Database comparison" in p.headings
    for n in ("OSM", "TIGER"):
        assert f"Database {n}" in p.headings
    head, body, _ = p.table("compare-table")
    assert [r[0] for r in body] == ["OSM", "TIGER"]
    j = head.index("RMSE h (m)")
    assert float(body[1][j]) == pytest.approx(rows[1]["rmse_horizontal"], abs=5e-4)
    # bars across databases + per database: vectors, conflation field, ellipses, histogram
    assert len(p.images) == 1 + 4 * len(runs)
    for img in p.images:
        _png_info(img["src"])
    assert len(p.ids) == len(set(p.ids))
    assert p.headings.count("Summary") == len(runs)


def test_unwritable_path(adj_run, tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    with pytest.raises(InputFileError,
                       match=r"Cannot create the directory of the report.*writable"):
        report.write_report(adj_run, blocker / "report.html")


def test_with_the_reliability_module(adj_run, tmp_path, no_figures):
    rel_mod = pytest.importorskip("vectoradjust.adjust.reliability")
    rel = rel_mod.reliability(adj_run.result)
    expected = rel_mod.flagged_observations(rel, adj_run.result, adj_run.point_ids,
                                            adj_run.image_ids, adj_run.point_kind)
    p = _parse(report.write_report(adj_run, tmp_path / "rel.html", reliability=rel))
    text = " ".join(p.text)
    assert "not computed" not in text
    if expected:
        head, rows, _ = p.table("flagged-table")
        assert len(rows) == len(expected)
        assert [r[head.index("point")] for r in rows] == [str(e["point"] or "\u2013")
                                                          for e in expected]
    else:
        assert "No observation is flagged" in text
    fig = report.residual_histogram_figure(adj_run, rel)
    assert len(fig.axes) == 2


# --------------------------------------------------------------------------- bounded size
def test_report_tables_are_bounded_with_the_count_left_out(adj_run, tmp_path, no_figures,
                                                            monkeypatch):
    monkeypatch.setattr(report.listings, "LARGEST_FLAGGED_ROWS", 2)
    monkeypatch.setattr(report.listings, "MAX_FEATURE_ROWS", 4)
    monkeypatch.setattr(report.listings, "LARGEST_FEATURE_ROWS", 3)
    flagged = [{"kind": "image", "image": "L", "point": f"P{i}", "w": 9.0 - i}
               for i in range(5)]
    p = _parse(report.write_report(adj_run, tmp_path / "b.html", reliability=flagged))
    _, rows, _ = p.table("flagged-table")
    assert [r[2] for r in rows] == ["P0", "P1"]  # the largest |w| first
    text = " ".join(p.text)
    assert "5 observation(s) flagged" in text and "(3 left out)" in text
    for d in adj_run.databases:
        nf = d.shape.layer.n_features
        _, rows, _ = p.table(f"features-{d.name}")
        assert len(rows) == 3 and f"({nf - 3} left out)" in text
        rm = np.nan_to_num(np.asarray(d.features["RMSE"], float), nan=-1.0)
        assert rows[0][0] == str(d.shape.layer.feature_ids[int(np.argmax(rm))])


def test_figure_lines_sample_whole_features_above_the_limit(adj_run, monkeypatch):
    d = adj_run.databases[0]
    lay = d.shape.layer
    full = report._segments(lay.coords, lay.vertex_feature, lay.vertex_part, (0.0, 0.0))
    monkeypatch.setattr(report.figures, "MAX_SEGMENTS", len(full) // 3)
    few = report._segments(lay.coords, lay.vertex_feature, lay.vertex_part, (0.0, 0.0))
    assert 0 < len(few) < len(full) // 2
    again = report._segments(d.adjusted_coords, lay.vertex_feature, lay.vertex_part,
                             (0.0, 0.0))
    assert len(again) == len(few)  # the same features in the database and adjusted lines
    # every kept segment is a segment of the full set (whole features, nothing invented)
    keys = {tuple(np.round(s.ravel(), 6)) for s in full}
    assert all(tuple(np.round(s.ravel(), 6)) in keys for s in few)
