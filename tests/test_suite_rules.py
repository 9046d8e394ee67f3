"""Rules the test suite itself keeps (issue 35).

Every ``pytest.raises`` pins the message with ``match=``: an error test that only checks
the exception class passes as well when the user is told the wrong thing (another file,
another key, no mend). The rule is read from the test sources with :mod:`ast`, so a
``pytest.raises`` spread over several lines counts like one on a single line, and a
``match`` that matches every message (``None``, ``""``, ``".*"``) counts as missing.

There is no exemption list: every ``pytest.raises`` in ``tests/`` and
``qgis_plugin/tests/`` has a ``match``.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
TEST_DIRS = (ROOT / "tests", ROOT / "qgis_plugin" / "tests")
VACUOUS = {"", ".", ".*", ".+", "(?s).*", r"[\s\S]*"}


def _raises_names(tree: ast.AST) -> set[str]:
    """Names under which ``pytest.raises`` is called bare (``from pytest import raises``)."""
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module == "pytest":
            names.update(a.asname or a.name for a in node.names if a.name == "raises")
    return names


def _is_raises(call: ast.Call, bare: set[str]) -> bool:
    f = call.func
    if isinstance(f, ast.Attribute) and f.attr == "raises":
        return isinstance(f.value, ast.Name) and f.value.id == "pytest"
    return isinstance(f, ast.Name) and f.id in bare


def _problem(call: ast.Call) -> str | None:
    """Why this ``pytest.raises(...)`` call does not pin the message, or None."""
    if len(call.args) > 1:
        return "the call form pytest.raises(E, func, ...) cannot take match=; use `with`"
    match = next((k.value for k in call.keywords if k.arg == "match"), None)
    if match is None:
        if any(k.arg is None for k in call.keywords):  # **kwargs: cannot tell
            return "match= must be written out, not passed in **kwargs"
        return "no match="
    if isinstance(match, ast.Constant):
        if match.value is None or (isinstance(match.value, str)
                                   and match.value.strip() in VACUOUS):
            return f"match={match.value!r} matches every message"
        if isinstance(match.value, str):
            try:
                re.compile(match.value)
            except re.error as exc:
                return f"match={match.value!r} is not a regular expression ({exc})"
    return None


def raises_without_match(source: str, name: str = "<source>") -> list[str]:
    """``file:line: reason`` for every ``pytest.raises`` in ``source`` without a real match."""
    tree = ast.parse(source, filename=name)
    bare = _raises_names(tree)
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Call) and _is_raises(node, bare):
            why = _problem(node)
            if why:
                found.append(f"{name}:{node.lineno}: {why}: {ast.unparse(node)}")
    return sorted(found, key=lambda s: (s.split(":")[0], int(s.split(":")[1])))


def _test_sources() -> list[Path]:
    return sorted(p for d in TEST_DIRS for p in d.rglob("*.py"))


def test_the_scanner_finds_every_form_of_a_missing_match():
    src = '''
import pytest
from pytest import raises as r

def test_x():
    with pytest.raises(ValueError):
        pass
    with pytest.raises(
            ValueError,
    ) as e:
        pass
    with r(KeyError):
        pass
    pytest.raises(ValueError, int, "x")
    with pytest.raises(ValueError, match=".*"):
        pass
    with pytest.raises(ValueError, match=None):
        pass
    with pytest.raises(ValueError, match="[unclosed"):
        pass
    with pytest.raises(ValueError, **kw):
        pass
    with pytest.raises(ValueError, match="invalid literal for int"):
        pass
    with pytest.raises(ValueError, match=rf"{name!r} is not"):
        pass
'''
    found = raises_without_match(src, "t.py")
    lines = [int(f.split(":")[1]) for f in found]
    assert lines == [6, 8, 12, 14, 15, 17, 19, 21], found
    assert "no match=" in found[0] and "call form" in found[3]
    assert "matches every message" in found[4] and "not a regular expression" in found[6]


def test_the_scanner_reads_every_test_file():
    files = _test_sources()
    names = {p.name for p in files}
    assert {"test_architecture.py", "test_qgis_algorithms.py", "conftest.py"} <= names
    n = sum(len(re.findall(r"\bpytest\.raises\(", p.read_text(encoding="utf-8")))
            for p in files)
    assert n >= 200  # 244 when this rule was written


def test_every_pytest_raises_pins_the_message():
    bad = []
    for path in _test_sources():
        rel = path.relative_to(ROOT).as_posix()
        bad += raises_without_match(path.read_text(encoding="utf-8"), rel)
    if bad:
        pytest.fail(f"{len(bad)} pytest.raises without a match= that pins the message (say "
                    "what the user is told: the thing named and the mend):\n" + "\n".join(bad))
