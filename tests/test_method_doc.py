"""``docs/method.md`` holds every section the code cites (issue 33).

The code cites the method as "``docs/method.md`` section N" (also "sections 2-3",
"sections 1, 9", "sections 5 and 7", "sections 7.4-7.5"). Every cited number must be a
heading of ``docs/method.md`` (``## 4. ...`` or ``### 7.4 ...``), so that a citation
cannot point to a section that is not there; the headings keep the numbers and titles of
the handed-over design (``DESIGN.md``), so a citation means the same in both; and no
source file still cites the design itself by section.
"""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
METHOD = ROOT / "docs" / "method.md"
DESIGN = ROOT / "DESIGN.md"
#: where the citations live (the checked code)
CITING = ("core/vectoradjust", "qgis_plugin")

_NUMBER = r"\d+(?:\.\d+)?"
_CITATION = re.compile(
    r"docs[/]method\.md`{0,2}\s+sections?\s+"  # [/]: no path for the document finder
    rf"({_NUMBER}(?:\s*(?:-|,|and)\s*{_NUMBER})*)")
_HEADING = re.compile(rf"^#{{2,4}}\s+({_NUMBER})\.?\s+(.*?)\s*$", re.MULTILINE)
_OLD_CITATION = re.compile(r"\bDESIGN(?:\.md)?`{0,2}\s+(?:sections?\s+)?\d")


def cited_sections(text: str) -> set[str]:
    """Section numbers cited as ``docs/method.md section(s) ...`` in a text.

    A range of whole sections (``2-3``) stands for every section in it; a range of
    subsections (``7.4-7.5``) for its two ends.
    """
    found = set()
    for m in _CITATION.finditer(text):
        for part in re.split(r"\s*(?:,|and)\s*", m.group(1)):
            ends = [e.strip() for e in part.split("-")]
            if len(ends) == 2 and all(e.isdigit() for e in ends):
                found.update(str(n) for n in range(int(ends[0]), int(ends[1]) + 1))
            else:
                found.update(e for e in ends if e)
    return found


def headings(text: str) -> dict[str, str]:
    """Numbered headings of a markdown text: number -> title."""
    return {m.group(1): m.group(2) for m in _HEADING.finditer(text)}


def _sources():
    for top in CITING:
        for path in sorted((ROOT / top).rglob("*.py")):
            yield path, path.read_text(encoding="utf-8")


def test_the_citation_finder_reads_every_form():
    text = ("(``docs/method.md`` section 7.4) and docs/method.md sections 2-3; "
            "docs/method.md\n    sections 1, 9 and docs/method.md sections 5 and 12; "
            "(docs/method.md sections 7.4-7.5). DESIGN.md section 4 is not a citation here")
    assert cited_sections(text) == {"7.4", "2", "3", "1", "9", "5", "12", "7.5"}
    assert headings("# Title\n## 10. Error model\n### 7.4 Zones (`qa/zones.py`)\n") == {
        "10": "Error model", "7.4": "Zones (`qa/zones.py`)"}


def test_a_missing_section_is_found():
    have = headings("## 1. One\n## 2. Two\n")
    assert cited_sections("see docs/method.md section 13") - set(have) == {"13"}


def test_every_cited_section_is_a_heading_of_method_md():
    have = set(headings(METHOD.read_text(encoding="utf-8")))
    cited = {}
    for path, text in _sources():
        for number in cited_sections(text):
            cited.setdefault(number, []).append(path.relative_to(ROOT).as_posix())
    assert len(cited) >= 10, f"too few citations found: {sorted(cited)}"
    missing = {n: files for n, files in cited.items() if n not in have}
    assert not missing, f"cited sections not in docs/method.md: {missing}"


def test_method_md_keeps_the_sections_of_the_design():
    ours = headings(METHOD.read_text(encoding="utf-8"))
    design = headings(DESIGN.read_text(encoding="utf-8"))
    assert set(design) >= {str(n) for n in range(1, 13)} | {"7.4", "7.5"}
    assert ours == design


def test_no_source_cites_the_design_by_section():
    old = []
    for path, text in _sources():
        for m in _OLD_CITATION.finditer(text):
            line = text.count("\n", 0, m.start()) + 1
            old.append(f"{path.relative_to(ROOT).as_posix()}:{line}: {m.group(0)!r}")
    assert not old, "cite docs/method.md instead:\n" + "\n".join(old)
