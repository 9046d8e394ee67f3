"""The package's layering (docs/architecture.md), checked on the source.

Every import in ``core/vectoradjust`` - at module level or inside a function - goes to
the same layer or a lower one; there is no import circle; the numerical heart (every
layer up to :mod:`vectoradjust.pipeline`) imports no third-party package but numpy and
scipy; nothing in ``core/`` imports qgis; no function is longer than 80 lines of code.
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
    "accuracy": 3,
    "qa": 4,
    "pipeline": 5,
    "files": 6, "simulate": 6,
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
    "vectoradjust.accuracy._bandkernel": ({"numba"}, "vectoradjust.accuracy.derived"),
    "vectoradjust.accuracy._unionkernel": ({"numba"}, "vectoradjust.accuracy.derived"),
}
#: functions allowed over MAX_FUNCTION_LINES, with the reason
LONG_FUNCTIONS_ALLOWED: dict = {}
MAX_FUNCTION_LINES = 80


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
    n = node.end_lineno - node.lineno + 1
    body = node.body
    if (body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant)
            and isinstance(body[0].value.value, str)):
        n -= body[0].end_lineno - body[0].lineno + 1
    return n


@pytest.mark.parametrize("tree", ["core/vectoradjust", "qgis_plugin"])
def test_no_function_longer_than_80_lines(tree):
    long = []
    for path in sorted((ROOT / tree).rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                name = f"{path.relative_to(ROOT)}:{node.name}"
                if _code_lines(node) > MAX_FUNCTION_LINES and name not in LONG_FUNCTIONS_ALLOWED:
                    long.append(f"{name} ({_code_lines(node)} lines of code)")
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
