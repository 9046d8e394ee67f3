"""docs/architecture.md "Where each output is computed": complete and true.

A newcomer looks an output field up there and finds the one function that computes it
(issue 33). These tests keep the map complete (every field of the layers' contracts,
of the bands layer and every key of summary.json is named) and true (every
``path::name`` it cites is a function or class defined in that file).
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

from vectoradjust.files.outputs.fields import CONTROL_FIELDS, FEATURE_FIELDS, SHAPE_FIELDS

ROOT = Path(__file__).resolve().parents[1]
PKG = ROOT / "core" / "vectoradjust"
HEADING = "## Where each output is computed"

#: the uncertainty_bands layer's own fields (files/derived_outputs.py)
BAND_FIELDS = ["database", "feature_id", "confidence", "NSeg"]


def output_map() -> str:
    """The section's text (up to the next heading of the same level)."""
    text = (ROOT / "docs" / "architecture.md").read_text(encoding="utf-8")
    assert HEADING in text, f"docs/architecture.md lost its section {HEADING!r}"
    return text.split(HEADING, 1)[1].split("\n## ", 1)[0]


def named(section: str) -> set[str]:
    """Every name written in backticks in ``section``."""
    return set(re.findall(r"`([^`]+)`", section))


def citations(section: str) -> list[tuple[str, str]]:
    """The ``path::name`` citations (``path`` relative to core/vectoradjust)."""
    return [(p, n.split(".")[0]) for p, n in re.findall(r"([\w/]+\.py)::(\w[\w.]*)", section)]


def defined(path: Path) -> set[str]:
    """Names of the functions and classes defined anywhere in ``path``."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    return {n.name for n in ast.walk(tree)
            if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef))}


def test_the_map_names_every_layer_field():
    names = named(output_map())
    missing = [f for f in (*SHAPE_FIELDS, *FEATURE_FIELDS, *CONTROL_FIELDS, *BAND_FIELDS)
               if f not in names]
    assert not missing, f"not in docs/architecture.md {HEADING!r}: {missing}"


def test_every_cited_function_exists():
    cites = citations(output_map())
    assert len(cites) > 20, "the map cites too few functions: did the citation form change?"
    bad = [f"{p}::{n}" for p, n in cites
           if not (PKG / p).is_file() or n not in defined(PKG / p)]
    assert not bad, f"cited in docs/architecture.md but not defined there: {bad}"


def test_the_citation_reader_finds_a_wrong_citation(tmp_path):
    section = "| x | `A` | `accuracy/tables.py::no_such_function`, `pipeline.py::run` |"
    cites = citations(section)
    assert cites == [("accuracy/tables.py", "no_such_function"), ("pipeline.py", "run")]
    assert "no_such_function" not in defined(PKG / "accuracy" / "tables.py")
    assert "run" in defined(PKG / "pipeline.py")


@pytest.mark.io
def test_the_map_names_every_summary_key(sample_dir):
    import vectoradjust
    from vectoradjust import pipeline

    project = vectoradjust.read_project(sample_dir / "project.toml")
    keys = list(pipeline.run(project.data).summary) + ["renamed_input_fields"]
    names = named(output_map())
    missing = [k for k in keys if k not in names]
    assert not missing, f"summary.json keys not in docs/architecture.md {HEADING!r}: {missing}"
