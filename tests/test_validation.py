"""The validation scripts as tests: a fast tier in the suite, the full tier on demand.

Every script in ``validation/`` states its acceptance criteria in its docstring, checks
them, prints one ``PASS``/``FAIL`` line per criterion and exits with status 1 when one
is missed (2: its data are missing); ``validation/acceptance.py`` makes the bands.

- **Fast tier** (here, in the normal suite): each script with ``--fast`` - one seed,
  a few runs, a smaller rendered pair or tie grid - about 40 s of CPU in all. The bands
  are computed from the sample the script has (binomial quantiles over the design
  effect, ``z`` standard errors of the per-seed scatter, Bonferroni over the script's
  statistical criteria), so a correct implementation passes each script with >= 99 %
  probability whatever its seed; deterministic criteria (invariants, the fixed real
  Pleiades pair) have fixed bounds.
- **Full tier** (marked ``validation``, skipped unless asked for): each script with its
  default arguments, the runs that README.md and docs/ quote. Hours (the Monte Carlo
  of 2000 adjustments alone about an hour on this 2-core machine)::

      pytest -m validation --validation tests/test_validation.py [--validation-out DIR]
      VECTORADJUST_VALIDATION=1 pytest -m validation tests/test_validation.py

  ``--validation-out DIR`` keeps each script's printout (``DIR/<script>.txt``) and
  its criteria and figures (``DIR/<script>.json``).

:func:`test_a_missed_criterion_fails` shows that a criterion can fail: every radius
0.8 times its value (a covariance stated 0.64 times too small) fails the coverage
criteria; :func:`test_fast_bands_reject_a_sigma_20_percent_small` computes that the fast
tier's coverage bands reject that error with >= 99 % probability.
"""

from __future__ import annotations

import ast
import importlib.util
import math
import os
import subprocess
import sys
from pathlib import Path

import pytest
from scipy.stats import binom

ROOT = Path(__file__).resolve().parents[1]
VALIDATION = ROOT / "validation"
PLEIADES = ROOT.parent / "shared" / "data" / "rpc" / "pleiades_pair"
NGI = ROOT.parent / "shared" / "data" / "aerial" / "ngi_dmc"
#: scripts that read ../shared/data (skipped with a reason where it is absent)
NEEDS = {"pleiades": PLEIADES / "img_01.tif", "aerial_gnss": NGI / "camera_pos_ori.txt"}
SCRIPTS = ("blunder_detection", "ce90_coverage", "conflation", "conflation_noise", "measure",
           "monte_carlo_coverage", "pleiades", "real_roads", "satellite", "drone_roads",
           "aerial_gnss", "smart_conflation")
#: at least this many criteria in a fast run (so that a script cannot pass by checking
#: nothing)
MIN_CRITERIA = {"blunder_detection": 13, "ce90_coverage": 10, "conflation": 28,
                "conflation_noise": 5, "measure": 5, "monte_carlo_coverage": 5,
                "pleiades": 18, "real_roads": 7, "satellite": 3, "drone_roads": 20,
                "aerial_gnss": 14, "smart_conflation": 8}

sys.path.insert(0, str(VALIDATION))
from acceptance import coverage_1d, coverage_2d, share_band  # noqa: E402

sys.path.remove(str(VALIDATION))


def run_script(name: str, args: list, timeout: float | None = 900) -> tuple[int, str]:
    """Run ``validation/<name>.py`` with ``args`` in a fresh interpreter: status, output."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(ROOT / "core"),
                                                     env.get("PYTHONPATH", "")) if p)
    env.setdefault("OPENBLAS_NUM_THREADS", "1")
    env["MPLBACKEND"] = "Agg"
    proc = subprocess.run([sys.executable, str(VALIDATION / f"{name}.py"), *args],
                          capture_output=True, text=True, env=env, timeout=timeout,
                          cwd=str(ROOT))
    return proc.returncode, proc.stdout + ("\n" + proc.stderr if proc.stderr else "")


def criteria_lines(out: str) -> list:
    """The PASS/FAIL lines of a script's output."""
    return [ln.strip() for ln in out.splitlines() if ln.strip().startswith(("PASS", "FAIL"))]


def _needs_data(name: str) -> None:
    if name not in NEEDS:
        return
    if not NEEDS[name].is_file():
        pytest.skip(f"validation/{name}.py: its real data not found: {NEEDS[name].parent}")
    if importlib.util.find_spec("rasterio") is None:
        pytest.skip(f"validation/{name}.py needs rasterio, not installed here")


def _assert_passed(name: str, status: int, out: str) -> list:
    lines = criteria_lines(out)
    failed = [ln for ln in lines if ln.startswith("FAIL")]
    tail = "\n".join(out.splitlines()[-60:])
    assert len(lines) >= MIN_CRITERIA[name], f"{name}: {len(lines)} criteria printed\n{tail}"
    assert not failed and status == 0, f"{name} exit status {status}:\n" + "\n".join(
        failed) + f"\n---\n{tail}"
    return lines


#: scripts that read or build geometries with the geodata packages (shapely, geopandas):
#: not in the leg without them (Debian's Python beside QGIS)
GEODATA = {"smart_conflation"}


def _params():
    return [pytest.param(n, marks=pytest.mark.io) if n in NEEDS or n in GEODATA else n
            for n in SCRIPTS]


@pytest.mark.slow
@pytest.mark.parametrize("name", _params())
def test_fast_tier(name):
    """The script's own criteria on its fast sample: all PASS, exit status 0."""
    _needs_data(name)
    status, out = run_script(name, ["--fast"])
    _assert_passed(name, status, out)


@pytest.mark.validation
@pytest.mark.parametrize("name", _params())
def test_full_tier(name, request, tmp_path):
    """The full runs that README.md and docs/ quote: all criteria PASS."""
    _needs_data(name)
    out_dir = Path(request.config.getoption("--validation-out") or tmp_path)
    out_dir.mkdir(parents=True, exist_ok=True)
    status, out = run_script(name, ["--json", str(out_dir / f"{name}.json")], timeout=None)
    (out_dir / f"{name}.txt").write_text(out, encoding="utf-8")
    _assert_passed(name, status, out)


def test_a_missed_criterion_fails():
    """Every CE90/LE90 radius 0.8 times its value: the coverage criteria FAIL, status 1."""
    status, out = run_script("ce90_coverage", ["--fast", "--cases", "3", "--sigma-scale",
                                               "0.8"])
    failed = [ln for ln in criteria_lines(out) if ln.startswith("FAIL")]
    assert status == 1, out[-3000:]
    assert len(failed) == 3 and all("coverage" in ln for ln in failed), failed
    assert "VALIDATION FAILED: 3 of" in out


@pytest.mark.parametrize("name", SCRIPTS)
def test_every_script_states_and_checks_its_criteria(name):
    """Docstring with the acceptance criteria, ``--fast``, and a non-zero exit path."""
    text = (VALIDATION / f"{name}.py").read_text(encoding="utf-8")
    doc = ast.get_docstring(ast.parse(text)) or ""
    assert "Acceptance" in doc and "--fast" in doc, name
    assert '"--fast"' in text and "report(" in text, name
    assert "sys.exit(main())" in text or "raise SystemExit(main())" in text, name


def _module(name: str):
    """``validation/<name>.py`` imported (its constants)."""
    spec = importlib.util.spec_from_file_location(f"validation_{name}", VALIDATION / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    sys.path.insert(0, str(VALIDATION))
    try:
        spec.loader.exec_module(mod)
    finally:
        sys.path.remove(str(VALIDATION))
    return mod


@pytest.mark.parametrize("quantity", ["CE90", "LE90"])
def test_fast_bands_reject_a_sigma_20_percent_small(quantity):
    """monte_carlo_coverage --fast (10 runs, 2112 points): a correct coverage (sigma
    within +-5 %) passes its band with >= 1 - alpha (alpha = 0.01 / 5), and a sigma 20 %
    too small (coverage 0.771 for CE90, 0.812 for LE90) is rejected with >= 99 %."""
    mc = _module("monte_carlo_coverage")
    c = coverage_2d if quantity == "CE90" else coverage_1d
    n, deff, alpha = 2112, mc.DEFF[quantity], 0.01 / mc.N_CRITERIA
    lo, hi = share_band(n, c(1 - mc.TOL), c(1 + mc.TOL), alpha, deff)
    m = int(n / deff)
    for p in (c(1 - mc.TOL), c(1 + mc.TOL)):
        inside = binom.cdf(math.floor(hi * m), m, p) - binom.cdf(math.ceil(lo * m) - 1, m, p)
        assert inside >= 1 - alpha, (p, lo, hi, inside)
    assert binom.sf(math.ceil(lo * m) - 1, m, c(0.8)) < 0.01, (c(0.8), lo)
