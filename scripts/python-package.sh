#!/usr/bin/env bash
# Builds the sts_twin Python package (host-tools/python) with maturin, installs it, and runs its
# tests with pytest: every result against the CLI's (target/release/sts-twin, which
# `cargo test --release` builds; built here when missing) and docs/python-loop.py end to end.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup-python.sh
cli=${STS_TWIN_CLI:-$PWD/target/release/sts-twin}
if [ ! -x "$cli" ]; then
    cargo build --locked --release -p sts-twin
fi
rm -rf target/wheels
python3 -m maturin build --locked --release -m host-tools/python/Cargo.toml -o target/wheels
python3 -m pip install --quiet --root-user-action=ignore --force-reinstall --no-deps target/wheels/sts_twin-*.whl
STS_TWIN_CLI=$cli python3 -m pytest -q -p no:cacheprovider host-tools/python/tests "$@"
