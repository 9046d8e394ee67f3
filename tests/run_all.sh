#!/usr/bin/env bash
# The whole vectoradjust test suite, on a fresh machine.
#
# Installs what it needs, then runs
#   1. the core suite with pytest in a virtual environment (current numpy/scipy/geopandas),
#   2. the numerical core again under Debian's system Python (numpy 1.24 / scipy 1.10, what
#      QGIS uses) together with the QGIS plugin tests inside a real, offscreen QGIS 3.22.
# Needs root (or sudo) once, for `apt-get install python3-qgis qgis`.
set -euo pipefail
cd "$(dirname "$0")/.."

VENV=${VECTORADJUST_TEST_VENV:-.venv-test}
PY=${PYTHON:-python3}
SUDO=""
if [ "$(id -u)" != 0 ] && command -v sudo >/dev/null 2>&1; then SUDO="sudo"; fi

echo "== installing Debian packages (QGIS for the plugin tests)"
need_apt=0
for pkg in python3-qgis qgis python3-pytest python3-scipy python3-matplotlib xvfb xauth; do
  dpkg -s "$pkg" >/dev/null 2>&1 || need_apt=1
done
if [ "$need_apt" = 1 ]; then
  $SUDO apt-get update -q
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -q \
    python3-qgis qgis qgis-providers python3-pytest python3-scipy python3-matplotlib xvfb xauth
fi

echo "== creating $VENV and installing vectoradjust[test]"
"$PY" -m venv "$VENV"
"$VENV/bin/python" -m pip install -q --upgrade pip
"$VENV/bin/python" -m pip install -q ".[test]"

status=0
run_pytest() {  # pytest exit 5 (no tests collected) is a failure too
  set +e
  "$@"
  local rc=$?
  set -e
  if [ "$rc" = 5 ]; then echo "pytest collected no tests: failing" >&2; rc=1; fi
  [ "$rc" = 0 ] || status=$rc
}

echo "== ruff"
"$VENV/bin/ruff" check core tests qgis_plugin benchmarks validation || status=1

# The core leg in parallel (pytest-xdist, one worker per core, at most 4; 0 = serial).
# Every test writes into its own tmp_path; tests that must share one worker would carry
# @pytest.mark.xdist_group(name="...") (--dist loadgroup; none needs it so far).
# VECTORADJUST_TEST_WORKERS overrides the count.
workers=${VECTORADJUST_TEST_WORKERS:-$(nproc 2>/dev/null || echo 1)}
if [ "$workers" -gt 4 ]; then workers=4; fi
if [ "$workers" -le 1 ]; then workers=0; fi
echo "== core suite ($("$VENV/bin/python" -c 'import numpy, scipy; print("numpy", numpy.__version__, "scipy", scipy.__version__)'), $workers pytest workers)"
run_pytest "$VENV/bin/python" -m pytest -q -p no:cacheprovider -n "$workers" --dist loadgroup tests

echo "== numerical core and QGIS plugin under Debian's Python ($(/usr/bin/python3 -c 'import numpy, scipy; print("numpy", numpy.__version__, "scipy", scipy.__version__)'))"
export VECTORADJUST_VENV_PYTHON="$PWD/$VENV/bin/python"
# VECTORADJUST_REQUIRE_QGIS=1: here the plugin tests must run, not skip. A qgis.core that
# does not import stops this leg (qgis_plugin/tests/conftest.py, pytest exit 4), and a
# plugin test module or test skipped for want of QGIS, qgis_process, the headless venv or
# the sample project fails it (exit 1); the count of plugin tests run is printed.
# This leg stays serial: Debian's python3-pytest-xdist (3.1.0) was not tried with the
# plugin tests, whose session fixtures (headless runs in the venv) would run per worker.
VECTORADJUST_REQUIRE_QGIS=1 QT_QPA_PLATFORM=offscreen PYTHONPATH="$PWD/core:$PWD" \
  run_pytest /usr/bin/python3 -m pytest -q -p no:cacheprovider -m "not io" tests qgis_plugin/tests

exit $status
