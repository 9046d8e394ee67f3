"""``vectoradjust demo``, README's first command, run end to end: the tables it prints
carry the same numbers as README's (issue 35).

Compared: the frame compare table under "Set-up: two commands" and the satellite block
under "The satellite sample" (bias per image, then the OSM row). Both sides are parsed
into rows of tokens; numbers are compared with a tolerance of one unit in the last
printed decimal (a last-bit difference of another BLAS may round the other way),
integers exactly, words (yes/no, NW, file names) exactly. The column headers must be
the same words, so that a value cannot move into another column unnoticed. If a change
of the code moves a number, update README from the demo's output.
"""

from __future__ import annotations

import contextlib
import io
import re
from pathlib import Path

import pytest

pytest.importorskip("geopandas")
pytest.importorskip("rasterio")

from vectoradjust.cli import main  # noqa: E402

pytestmark = [pytest.mark.io, pytest.mark.slow]

README = Path(__file__).resolve().parents[1] / "README.md"
_NUMBER = re.compile(r"^(\+-)?([+-]?\d+)(?:\.(\d+))?$")
_HEADERS = ("database ", "image ")


def _section(text: str, start: str, end: str) -> str:
    """The text from the line ``start`` up to ``end`` (both must be there)."""
    i = text.index(start)
    j = text.index(end, i + len(start))
    return text[i:j]


def _code_blocks(text: str) -> list[str]:
    return re.findall(r"^```[^\n]*\n(.*?)^```", text, flags=re.S | re.M)


def _is_row(tokens: list[str]) -> bool:
    return len(tokens) >= 4 and sum(bool(_NUMBER.match(t)) for t in tokens[1:]) >= 3


def parse_tables(text: str) -> list[tuple[list[str], list[list[str]]]]:
    """Every table in ``text``: (header words, rows of tokens), in order.

    A table starts at a line beginning with ``database`` or ``image`` and runs over the
    following lines that look like rows (a name and at least three numbers).
    """
    tables: list[tuple[list[str], list[list[str]]]] = []
    rows = None
    for line in text.splitlines():
        stripped = line.strip()
        if stripped.startswith(_HEADERS):
            rows = []
            tables.append((stripped.split(), rows))
        elif rows is not None and _is_row(stripped.split()):
            rows.append(stripped.split())
        else:
            rows = None
    return tables


def readme_tables(text: str) -> dict[str, list]:
    """README's frame table and satellite block, parsed."""
    setup = _section(text, "## Set-up: two commands", "\n## ")
    frame = [t for b in _code_blocks(setup) for t in parse_tables(b)]
    sat_text = _section(text, "**The satellite sample**", "**Real data**")
    sat = [t for b in _code_blocks(sat_text) for t in parse_tables(b)]
    return {"frame": frame, "satellite": sat}


def demo_tables(stdout: str) -> dict[str, list]:
    """The tables the demo printed: the compare table, then the satellite block."""
    frame = _section(stdout, "each database alone (compare)", "satellite triplet with RPCs")
    sat = stdout[stdout.index("satellite triplet with RPCs"):]
    return {"frame": parse_tables(frame), "satellite": parse_tables(sat)}


def _same_token(a: str, b: str) -> bool:
    ma, mb = _NUMBER.match(a), _NUMBER.match(b)
    if not (ma and mb):
        return a == b
    if ma.group(1) != mb.group(1):  # "+-" before one sigma only
        return False
    decimals = max(len(ma.group(3) or ""), len(mb.group(3) or ""))
    if decimals == 0:
        return int(ma.group(2)) == int(mb.group(2))
    return abs(float(a.lstrip("+-") if ma.group(1) else a)
               - float(b.lstrip("+-") if mb.group(1) else b)) <= 10.0 ** -decimals + 1e-12


def assert_same_tables(got: dict[str, list], want: dict[str, list]) -> None:
    """Every table, header and row of ``want`` (README) in ``got`` (the demo), same numbers."""
    for part in ("frame", "satellite"):
        g, w = got[part], want[part]
        assert w, f"README: no {part} table found"
        assert len(g) == len(w), f"{part}: the demo printed {len(g)} tables, README has {len(w)}"
        for (gh, grows), (wh, wrows) in zip(g, w):
            assert gh == wh, (f"{part}: columns differ:\n demo   {' '.join(gh)}\n"
                              f" README {' '.join(wh)}")
            assert [r[0] for r in grows] == [r[0] for r in wrows], (
                f"{part}: rows {[r[0] for r in grows]} printed, README has {[r[0] for r in wrows]}")
            for gr, wr in zip(grows, wrows):
                assert len(gr) == len(wr), f"{part} row {wr[0]}: {gr} vs README {wr}"
                bad = [(i, x, y) for i, (x, y) in enumerate(zip(gr, wr)) if not _same_token(x, y)]
                assert not bad, (f"{part} row {wr[0]}: demo vs README differ at "
                                 + ", ".join(f"token {i} {x} != {y}" for i, x, y in bad)
                                 + f"\n demo   {' '.join(gr)}\n README {' '.join(wr)}")


@pytest.fixture(scope="module")
def demo_stdout(tmp_path_factory):
    """``vectoradjust demo -o DIR`` run once through ``cli.main``, its standard output."""
    out = tmp_path_factory.mktemp("demo")
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        rc = main(["demo", "-o", str(out)])
    assert rc == 0
    return buf.getvalue()


def test_demo_prints_readme_tables(demo_stdout):
    got = demo_tables(demo_stdout)
    want = readme_tables(README.read_text(encoding="utf-8"))
    # what README shows: three databases, three satellite images and the OSM row
    assert [[r[0] for r in rows] for _, rows in want["frame"]] == [["OSM", "TNM", "TIGER"]]
    assert [[r[0] for r in rows] for _, rows in want["satellite"]] == [["S1", "S2", "S3"],
                                                                       ["OSM"]]
    assert_same_tables(got, want)


def test_a_changed_readme_number_is_caught():
    """The comparison is not vacuous: one README number moved by two units in its last
    decimal, a count by one, or a word changed, and it fails."""
    text = README.read_text(encoding="utf-8")
    want = readme_tables(text)
    assert_same_tables(want, want)
    for old, new in (("3.033", "3.035"), ("  183  ", "  184  "), ("-13.961", "-13.959"),
                     ("+-0.21 (significant)", "+-0.23 (significant)"), (" NW ", " NE ")):
        assert old in text
        changed = readme_tables(text.replace(old, new, 1))
        with pytest.raises(AssertionError, match="differ at"):
            assert_same_tables(changed, want)
