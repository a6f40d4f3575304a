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
for module in sympy pandas scipy nptdms h5py pytest maturin; do
    if ! python3 -c "import $module" 2>/dev/null; then
        echo "setup: pip install $module"
        python3 -m pip install --quiet --root-user-action=ignore "$module"
    fi
done
