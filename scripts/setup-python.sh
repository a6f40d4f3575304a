#!/usr/bin/env bash
# Installs what the tests need of Python and a fresh machine lacks. Idempotent.
set -euo pipefail
# Independent tools for the tests: `export --to sympy` is checked by importing what it writes
# (SymPy), and `import` by reading recordings that pandas, SciPy's `savemat`, npTDMS and h5py
# wrote. The Python package (host-tools/python) is built with maturin and tested with pytest.
if ! command -v python3 >/dev/null; then
    echo "error: python3 not found; install Python 3 (the export and import tests run it)" >&2
    exit 1
fi
missing=()
for module in sympy pandas scipy nptdms h5py pytest maturin; do
    python3 -c "import $module" 2>/dev/null || missing+=("$module")
done
# One pip run for all of them; without byte-compiling every module at install (some 17 CPU-s
# for these packages): Python compiles the few the tests import when they first import them.
if [ ${#missing[@]} -gt 0 ]; then
    echo "setup: pip install ${missing[*]}"
    python3 -m pip install --quiet --no-compile --root-user-action=ignore "${missing[@]}"
fi
