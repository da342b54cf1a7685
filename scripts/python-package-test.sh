#!/usr/bin/env bash
# Installs the Python package (python/) into a fresh venv, as a user would from PyPI plus this
# checkout, and runs its tests: `pip install ./python[test]` (pytest, gymnasium), then
# `pytest python/tests`.
# The venv is made anew on every run in target/python-package-venv (override with
# JSAE_PACKAGE_VENV); the interpreter is $PYTHON or python3. Extra arguments go to pytest.
# The tests against a real `jsae recommender` use $JSAE_BIN, else target/release/jsae, else
# target/debug/jsae, and are skipped when none is built. Needs no terminal (CI=true works).
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
venv="${JSAE_PACKAGE_VENV:-$root/target/python-package-venv}"

mkdir -p "$(dirname "$venv")"
exec 9>"$venv.lock"
flock 9

rm -rf "$venv"
"${PYTHON:-python3}" -m venv "$venv"
"$venv/bin/python" -m pip install --quiet --no-input --disable-pip-version-check \
    "$root/python[test]" </dev/null

cd "$root"
# pytest's own entry point, so the checkout's python/ is not on sys.path: the tests import
# the installed package
"$venv/bin/pytest" python/tests -q "$@" </dev/null
