"""The package's layering (docs/architecture.md), checked on the source.

Every import in ``core/vectoradjust`` - at module level or inside a function - goes to
the same layer or a lower one; there is no import circle; the numerical heart (every
layer up to :mod:`vectoradjust.pipeline`) imports no third-party package but numpy and
scipy; nothing in ``core/`` imports qgis; no function is longer than 80 lines, its
docstring included.
"""

from __future__ import annotations

import ast
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PKG = ROOT / "core" / "vectoradjust"

#: layer of each top-level module or subpackage of vectoradjust (docs/architecture.md)
LAYERS = {
    "errors": 0, "model": 0, "results": 0, "formatting": 0, "_compat": 0,
    "sensor": 1,
    "adjust": 2, "measure": 2,
    "accuracy": 3, "conflation": 3,
    "qa": 4,
    "pipeline": 5,
    "files": 6, "simulate": 6, "runner": 6,
    "cli": 7,
    "__init__": 8, "__main__": 8,
}
HEART_MAX_LAYER = LAYERS["pipeline"]
HEART_THIRD_PARTY = {"numpy", "scipy"}
#: lazily imported optional packages allowed in the heart, module -> packages
HEART_LAZY_ALLOWED = {"vectoradjust.accuracy.buffer": {"shapely"}}
#: modules of the heart that import an optional package at their top and are themselves
#: only imported lazily, by one module that falls back when the import fails
HEART_OPTIONAL_MODULES = {
    "vectoradjust.accuracy._bandkernel": ({"numba"}, "vectoradjust.accuracy.derived.band_kernels"),
    "vectoradjust.accuracy._unionkernel": ({"numba"},
                                           "vectoradjust.accuracy.derived.band_kernels"),
}
#: functions allowed over MAX_FUNCTION_LINES, with the reason
LONG_FUNCTIONS_ALLOWED: dict = {}
MAX_FUNCTION_LINES = 80
#: a module is a room one can know: at most this many lines (issue 33)
MAX_MODULE_LINES = 800
#: modules still over MAX_MODULE_LINES, to be split by topic (this list only shrinks)
LARGE_MODULES_LEFT: set = set()


def _modules():
    for path in sorted(PKG.rglob("*.py")):
        rel = path.relative_to(PKG).with_suffix("")
        parts = list(rel.parts)
        if parts[-1] == "__init__" and len(parts) > 1:
            parts = parts[:-1]
        yield "vectoradjust." + ".".join(parts) if parts != ["__init__"] else "vectoradjust", path


def _imports(path: Path, modname: str):
    """(imported module, lazy?) for every import statement of the file."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    is_pkg = path.name == "__init__.py"
    top_level = set(id(n) for n in tree.body)
    # imports under `if TYPE_CHECKING:` are for annotations only
    type_only = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            type_only.update(id(n) for n in ast.walk(node))
    for node in ast.walk(tree):
        if id(node) in type_only:
            continue
        lazy = id(node) not in top_level
        if isinstance(node, ast.Import):
            for a in node.names:
                yield a.name, lazy
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = modname.split(".")
                base = base if is_pkg else base[:-1]
                base = base[: len(base) - node.level + 1]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module or ""
            yield mod, lazy
            for a in node.names:  # from vectoradjust.accuracy import stats
                yield f"{mod}.{a.name}", lazy


def _layer(modname: str):
    parts = modname.split(".")
    if parts[0] != "vectoradjust":
        return None
    key = parts[1] if len(parts) > 1 else "__init__"
    return LAYERS.get(key)


MODULES = dict(_modules())


def _internal_edges():
    edges = {}
    for mod, path in MODULES.items():
        targets = set()
        for imp, _lazy in _imports(path, mod):
            # resolve to the longest known module name
            parts = imp.split(".")
            while parts and ".".join(parts) not in MODULES:
                parts.pop()
            target = ".".join(parts)
            # a module's own parent packages are imported before it anyway
            if parts and target != mod and not mod.startswith(target + "."):
                targets.add(target)
        edges[mod] = targets
    return edges


def test_every_module_has_a_layer():
    missing = [m for m in MODULES if _layer(m) is None and m != "vectoradjust"]
    assert not missing, f"add these to LAYERS and docs/architecture.md: {missing}"


def test_no_import_goes_to_a_higher_layer():
    bad = []
    for mod, targets in _internal_edges().items():
        lm = _layer(mod) if mod != "vectoradjust" else LAYERS["__init__"]
        for t in targets:
            if t == "vectoradjust":
                continue
            if _layer(t) > lm:
                bad.append(f"{mod} (layer {lm}) imports {t} (layer {_layer(t)})")
    assert not bad, "\n".join(bad)


def _cycles(edges: dict) -> list:
    """Strongly connected components with more than one module (Tarjan)."""
    index, low, stack, on_stack, cycles = {}, {}, [], set(), []
    counter = [0]
    sys.setrecursionlimit(max(sys.getrecursionlimit(), 10000))

    def strong(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on_stack.add(v)
        for w in edges.get(v, ()):
            if w not in edges:
                continue
            if w not in index:
                strong(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                cycles.append(sorted(comp))

    for v in edges:
        if v not in index:
            strong(v)
    return cycles


def test_cycle_finder_finds_circles():
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert _cycles({"a": {"b"}, "b": set()}) == []


def test_no_import_circles():
    cycles = _cycles(_internal_edges())
    assert not cycles, f"import circles: {cycles}"


@pytest.mark.skipif(not hasattr(sys, "stdlib_module_names"), reason="Python >= 3.10")
def test_heart_imports_only_numpy_and_scipy():
    # tomli: the backport of the standard library's tomllib for Python < 3.11
    stdlib = set(sys.stdlib_module_names) | {"__future__", "tomli"}
    bad = []
    for mod, path in MODULES.items():
        layer = _layer(mod)
        if layer is None or layer > HEART_MAX_LAYER:
            continue
        for imp, lazy in _imports(path, mod):
            top = imp.split(".")[0]
            if top in stdlib or top == "vectoradjust" or top in HEART_THIRD_PARTY:
                continue
            if lazy and top in HEART_LAZY_ALLOWED.get(mod, set()):
                continue
            if top in HEART_OPTIONAL_MODULES.get(mod, (set(),))[0]:
                continue
            bad.append(f"{mod} imports {imp}" + (" (lazily)" if lazy else ""))
    assert not bad, "\n".join(sorted(set(bad)))


def test_optional_heart_modules_are_imported_lazily_by_their_one_user():
    for opt, (_, user) in HEART_OPTIONAL_MODULES.items():
        assert opt in MODULES
        users = {(mod, lazy) for mod, path in MODULES.items()
                 for imp, lazy in _imports(path, mod) if imp == opt}
        assert users == {(user, True)}, (opt, users)


def test_core_never_imports_qgis():
    bad = [f"{mod} imports {imp}" for mod, path in MODULES.items()
           for imp, _ in _imports(path, mod) if imp.split(".")[0] in ("qgis", "PyQt5")]
    assert not bad, bad


def _code_lines(node) -> int:
    """Lines of a function from its ``def`` to its last line: docstring, comments and
    blank lines included (issue 33: "no function over 80 lines including its docstring")."""
    return node.end_lineno - node.lineno + 1


@pytest.mark.parametrize("tree", ["core/vectoradjust", "qgis_plugin"])
def test_no_function_longer_than_80_lines(tree):
    long = []
    for path in sorted((ROOT / tree).rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                name = f"{path.relative_to(ROOT)}:{node.name}"
                if _code_lines(node) > MAX_FUNCTION_LINES and name not in LONG_FUNCTIONS_ALLOWED:
                    long.append(f"{name} ({_code_lines(node)} lines)")
    assert not long, "\n".join(long)


def test_old_module_names_still_import_with_a_warning():
    import importlib

    import vectoradjust.adjust.bundle as new

    sys.modules.pop("vectoradjust.bundle", None)
    with pytest.warns(DeprecationWarning, match="vectoradjust.adjust.bundle"):
        old = importlib.import_module("vectoradjust.bundle")
    assert old is new
    from vectoradjust import _compat

    for name, target in _compat.MOVED.items():
        assert ("vectoradjust." + target) in MODULES, (name, target)
    with pytest.warns(DeprecationWarning):
        from vectoradjust.accuracy import accuracy_statements
    from vectoradjust.accuracy.statements import accuracy_statements as new_fn

    assert accuracy_statements is new_fn
    # a moved package: the package and its modules (0.3: accuracy.conflation -> conflation)
    import vectoradjust.conflation.covariance as new_cov

    for old_name in ("vectoradjust.accuracy.conflation.covariance", "vectoradjust.accuracy.smart"):
        sys.modules.pop(old_name, None)
    with pytest.warns(DeprecationWarning, match="vectoradjust.conflation.covariance"):
        old_cov = importlib.import_module("vectoradjust.accuracy.conflation.covariance")
    assert old_cov is new_cov
    with pytest.warns(DeprecationWarning, match="vectoradjust.conflation.smart"):
        importlib.import_module("vectoradjust.accuracy.smart")


def test_plugin_uses_layers_below_the_cli():
    bad = []
    for path in sorted((ROOT / "qgis_plugin").rglob("*.py")):
        if "tests" in path.relative_to(ROOT).parts:
            continue
        for imp, _ in _imports(path, "vectoradjust_qgis." + path.stem):
            layer = _layer(imp)
            if layer is not None and layer > LAYERS["files"]:
                bad.append(f"{path.relative_to(ROOT)} imports {imp}")
    assert not bad, "\n".join(bad)


def test_core_never_imports_scipy_stats():
    # scipy.stats takes about 0.5 s to import, on the serial path of every run; the few
    # distribution functions the core needs are scipy.special's (ndtr, ndtri, gammaincinv)
    bad = [f"{mod} imports {imp}" for mod, path in MODULES.items()
           for imp, _ in _imports(path, mod)
           if imp == "scipy.stats" or imp.startswith("scipy.stats.")]
    assert not bad, bad


# ------------------------------------------------------------- the plugin does no math
#: numpy names the QGIS plugin may call or use: converting between QGIS and the core's
#: arrays and bookkeeping of rows (masks, indexes, counts, sorting) - no arithmetic of
#: coordinates, no statistics, no linear algebra (those live in the core, tested there)
PLUGIN_NUMPY_ALLOWED = {
    "asarray", "array", "frombuffer", "ravel", "stack", "column_stack", "concatenate",
    "r_", "zeros", "full", "full_like", "empty", "arange", "where", "isfinite", "isin",
    "flatnonzero", "unique", "diff", "any", "count_nonzero", "argsort", "bincount", "size",
    "shape", "nan_to_num", "nan", "inf", "ndarray", "integer", "floating", "bool_", "str_",
    "float32", "float64", "int8", "int16", "int32", "int64", "uint8", "uint16", "uint32",
    "uint64", "errstate",
}
#: the only names of :mod:`math` the plugin uses (tests of values, no computation)
PLUGIN_MATH_ALLOWED = {"isfinite", "isnan", "inf", "nan"}
#: math left in plugin files outside issue 33's three (file, name) -> why it is allowed
#: for now; the test fails when one of these is gone (remove it here then)
PLUGIN_MATH_KNOWN: dict = {}


def _plugin_numeric_uses(path: Path):
    """``(name, line)`` of every numpy, math or scipy name a plugin file uses that is
    not in the allowed sets above (calls and attributes; operators are not seen)."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    alias = {}  # local name -> "numpy" / "math" / "scipy"
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for a in node.names:
                top = a.name.split(".")[0]
                if top in ("numpy", "math", "scipy"):
                    alias[a.asname or top] = top
                if top == "scipy" or a.name.startswith("numpy."):
                    yield a.name, node.lineno
        elif isinstance(node, ast.ImportFrom) and node.module:
            top = node.module.split(".")[0]
            if top == "scipy" or node.module.startswith("numpy."):
                yield node.module, node.lineno
            elif top in ("numpy", "math"):
                allowed = PLUGIN_NUMPY_ALLOWED if top == "numpy" else PLUGIN_MATH_ALLOWED
                for a in node.names:
                    if a.name not in allowed:
                        yield a.name, node.lineno
    for node in ast.walk(tree):
        if (isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name)
                and node.value.id in alias):
            allowed = {"numpy": PLUGIN_NUMPY_ALLOWED, "math": PLUGIN_MATH_ALLOWED}.get(
                alias[node.value.id], set())
            if node.attr not in allowed:
                yield node.attr, node.lineno


def _plugin_files():
    return [p for p in sorted((ROOT / "qgis_plugin").rglob("*.py"))
            if "tests" not in p.relative_to(ROOT).parts]


def test_plugin_contains_no_numerical_code():
    """qgis_plugin/ converts and calls: numpy only to convert and index, math only to
    test values, no scipy (docs/architecture.md); the math is the core's."""
    bad, seen = [], set()
    for path in _plugin_files():
        rel = path.relative_to(ROOT).as_posix()
        for name, line in _plugin_numeric_uses(path):
            if (rel, name) in PLUGIN_MATH_KNOWN:
                seen.add((rel, name))
            else:
                bad.append(f"{rel}:{line} uses {name}")
    assert not bad, "numerical code in the plugin (move it into the core):\n" + "\n".join(bad)
    gone = sorted(set(PLUGIN_MATH_KNOWN) - seen)
    assert not gone, f"no longer in the plugin, remove from PLUGIN_MATH_KNOWN: {gone}"


def test_plugin_math_check_catches_math(tmp_path):
    f = tmp_path / "x.py"
    f.write_text("import math\nimport numpy as np\nfrom scipy.spatial import cKDTree\n"
                 "a = math.atan2(1, 2) + math.isfinite(3)\nb = np.hypot(1, 2)\n"
                 "c = np.linalg.norm([1])\nd = np.asarray([1.0])\nfrom numpy import sqrt\n",
                 encoding="utf-8")
    found = sorted(name for name, _ in _plugin_numeric_uses(f))
    assert found == ["atan2", "hypot", "linalg", "scipy.spatial", "sqrt"]


# ------------------------------------------------------- package docstrings, documents
def test_every_package_docstring_names_all_its_modules():
    """A newcomer reading a package's __init__ docstring learns of every module in it."""
    import re

    missing = []
    for init in sorted(PKG.glob("*/__init__.py")):
        doc = ast.get_docstring(ast.parse(init.read_text(encoding="utf-8"))) or ""
        for mod in sorted(p.stem for p in init.parent.glob("*.py") if p.stem != "__init__"):
            if not re.search(rf"(?<![\w]){re.escape(mod)}(?![\w])", doc):
                missing.append(f"{init.parent.relative_to(ROOT).as_posix()}: {mod}")
    assert not missing, "modules not named in their package's docstring:\n" + "\n".join(missing)


#: suffixes of the files whose text is searched for references to documents
_TEXT_SUFFIXES = {".py", ".md", ".toml", ".txt", ".cfg", ".sh", ".yml", ".yaml", ".rst",
                  ".ini"}
#: top-level folders of the repository that paths in the text start with
_REPO_FOLDERS = ("docs", "benchmarks", "validation", "resources", "tests", "core",
                 "qgis_plugin")
#: documents outside the repository that files may name (they are not to be copied in)
_OUTSIDE_DOCUMENTS = {"shared/data/aerial/README.md", "shared/data/rpc/README.md"}


def _repository_files():
    """Every file of the repository (not virtual environments, caches or build output)."""
    skip = {"__pycache__", "node_modules", "build", "dist"}
    for path in ROOT.rglob("*"):
        rel = path.relative_to(ROOT).parts
        if any(p.startswith(".") or p in skip or p.endswith(".egg-info") for p in rel[:-1]):
            continue
        if path.is_file():
            yield path


def _document_references(text: str):
    """Names of ``.md`` documents and repository paths (``docs/...``) in a text."""
    import re

    for m in re.finditer(r"(?<![\w/.\-])([\w./\-]*[\w\-]\.md)\b", text):
        yield m.group(1)
    folders = "|".join(_REPO_FOLDERS)
    for m in re.finditer(rf"(?<![\w/.\-])((?:{folders})/[\w./\-]*[\w\-])", text):
        yield m.group(1)


def _missing_documents():
    files = list(_repository_files())
    rels = {p.relative_to(ROOT).as_posix() for p in files}
    dirs = {q.as_posix() for r in rels for q in Path(r).parents}
    names = {p.name for p in files}
    bad = []
    for path in files:
        if path.suffix not in _TEXT_SUFFIXES:
            continue
        here = path.parent.relative_to(ROOT)
        text = path.read_text(encoding="utf-8", errors="replace")
        for ref in set(_document_references(text)):
            if any(ref.endswith(o) for o in _OUTSIDE_DOCUMENTS) or "*" in ref:
                continue
            ref = ref.rstrip("./")
            near = Path(*(here / ref).parts).as_posix()
            import os

            near = os.path.normpath(near).replace(os.sep, "/")
            if ref in rels or ref in dirs or near in rels or near in dirs:
                continue
            if "/" not in ref and ref in names:  # "README.md" of a folder named nearby
                continue
            bad.append(f"{path.relative_to(ROOT).as_posix()}: {ref}")
    return sorted(bad)


def test_no_file_refers_to_a_document_not_in_the_repository():
    bad = _missing_documents()
    assert not bad, "references to documents that are not in the repository:\n" + \
        "\n".join(bad)


def test_document_reference_finder_finds_references():
    md = ".md"  # (built so that this file names no missing document itself)
    docs, bench = "do" + "cs/", "bench" + "marks/"
    text = (f"see DESIGN{md} section 3, {docs}no_such{md} and `{docs}architecture{md}`; "
            f"the table in {bench}README{md}; core/vectoradjust/errors.py")
    refs = set(_document_references(text))
    assert {f"DESIGN{md}", f"{docs}no_such{md}", f"{docs}architecture{md}",
            f"{bench}README{md}", "core/vectoradjust/errors.py"} <= refs


def test_no_module_is_too_big_to_know():
    """Every module of core/ and qgis_plugin/ holds at most MAX_MODULE_LINES lines, but
    those still listed in LARGE_MODULES_LEFT; a listed module that got small must leave
    the list (so it only shrinks)."""
    sizes = {}
    for top in ("core/vectoradjust", "qgis_plugin"):
        for path in (ROOT / top).rglob("*.py"):
            rel = path.relative_to(ROOT).as_posix()
            if "/tests/" in rel:
                continue
            sizes[rel] = len(path.read_text(encoding="utf-8").splitlines())
    big = {m for m, n in sizes.items() if n > MAX_MODULE_LINES}
    new = sorted(big - LARGE_MODULES_LEFT)
    assert not new, f"over {MAX_MODULE_LINES} lines: {new}"
    small = sorted(m for m in LARGE_MODULES_LEFT if sizes.get(m, 0) <= MAX_MODULE_LINES)
    assert not small, f"no longer large (or gone): remove from LARGE_MODULES_LEFT: {small}"


def test_every_package_is_installed_by_pyproject():
    """``pip install .`` installs exactly the packages listed in pyproject.toml: every
    package directory of core/vectoradjust must be there (an editable install would
    hide a missing one; a plain install then fails to import it)."""
    import re

    text = (ROOT / "pyproject.toml").read_text(encoding="utf-8")
    listed = set(re.findall(r'"(vectoradjust[\w.]*)"', text.split("packages = [", 1)[1]
                            .split("]", 1)[0]))
    present = {"vectoradjust" + "".join("." + p for p in d.relative_to(PKG).parts)
               for d in (f.parent for f in PKG.rglob("__init__.py"))
               if "__pycache__" not in d.parts}
    missing = sorted(present - listed)
    assert not missing, f"add to [tool.setuptools] packages in pyproject.toml: {missing}"
    assert "vectoradjust.resources" in listed
