#!/usr/bin/env bash
# Builds the sts_twin Python package (host-tools/python) with maturin, installs it, and runs its
# tests with pytest: every result against the CLI's (target/PROFILE/sts-twin, which
# `cargo test` builds in that profile; built here when missing) and docs/python-loop.py end to
# end. PROFILE: $STS_TWIN_CARGO_PROFILE, else release (scripts/test.sh sets `ci`).
#
#   scripts/python-package.sh [build|test|all] [PYTEST ARGS...]   (default: all)
#
# `build` alone makes the wheel in target/wheels; `test` installs it and runs pytest (scripts/
# test.sh builds it after the test build, whose crates it reuses: host-tools/python/
# Cargo.toml gives them the test build's features).
set -euo pipefail
cd "$(dirname "$0")/.."
mode=all
profile=${STS_TWIN_CARGO_PROFILE:-release}
case "${1:-}" in
    build | test | all) mode=$1; shift ;;
esac
bash scripts/setup-python.sh
source scripts/pyo3-env.sh
if [ "$mode" != test ]; then
    rm -rf target/wheels
    python3 -m maturin build --locked --profile "$profile" -i "$PYO3_PYTHON" \
        -m host-tools/python/Cargo.toml -o target/wheels
fi
if [ "$mode" != build ]; then
    wheels=(target/wheels/sts_twin-*.whl)
    if [ ! -f "${wheels[0]}" ]; then
        echo "error: no wheel in target/wheels: run scripts/python-package.sh build first" >&2
        exit 1
    fi
    # A wheel older than the sources it is built from would be tested against a CLI built
    # from newer ones.
    newer=$(find host-tools firmware/core Cargo.lock host-tools/python/python \
        \( -name '*.rs' -o -name Cargo.toml -o -name Cargo.lock -o -path '*/python/python/*.py' \) \
        -newer "${wheels[0]}" -print -quit)
    if [ -n "$newer" ]; then
        echo "error: ${wheels[0]} is older than $newer: run scripts/python-package.sh build (or all) first" >&2
        exit 1
    fi
    cli=${STS_TWIN_CLI:-$PWD/target/$profile/sts-twin}
    if [ ! -x "$cli" ]; then
        cargo build --locked --profile "$profile" -p sts-twin
    fi
    python3 -m pip install --quiet --root-user-action=ignore --force-reinstall --no-deps "${wheels[0]}"
    STS_TWIN_CLI=$cli python3 -m pytest -q -p no:cacheprovider host-tools/python/tests "$@"
fi
