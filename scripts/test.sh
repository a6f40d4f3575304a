#!/usr/bin/env bash
# Runs every test of sts-twin: formatting and lints, the firmware for QEMU and the real board,
# the core for RISC-V, then the host, core and HIL test suites (the HIL tests boot the
# firmware in QEMU), and the Python package's (built with maturin, tested with pytest).
set -euo pipefail
cd "$(dirname "$0")/.."
STS_TWIN_PYTHON_LATER=1 bash scripts/setup.sh
# The Python packages download while the builds below use the cores.
python_log=$(mktemp)
bash scripts/setup-python.sh >"$python_log" 2>&1 &
python_setup=$!

export CARGO_TERM_COLOR=${CARGO_TERM_COLOR:-never}
step() { printf '\n== %s (%s)\n' "$*" "$(date -u +%H:%M:%S)"; }

step "formatting (the root workspace and the two firmware apps, which are workspaces of their own)"
cargo fmt --all -- --check
(cd firmware/qemu-app && cargo fmt -- --check)
(cd firmware/stm32h7-app && cargo fmt -- --check)
step "layering: no import cycle between the top-level modules of any crate"
cargo --locked xtask layering >/dev/null
step "clippy (root workspace)"
cargo clippy --workspace --all-targets --locked -- -D warnings
step "clippy (the firmware apps, each a workspace of its own; the QEMU app also as bring-up)"
(cd firmware/qemu-app && cargo clippy --locked -- -D warnings && cargo clippy --locked --features bringup -- -D warnings)
(cd firmware/stm32h7-app && cargo clippy --locked -- -D warnings)
step "Python packages for the tests (installed in the background)"
if ! wait "$python_setup"; then
    cat "$python_log" >&2
    exit 1
fi
cat "$python_log"
step "firmware: QEMU mps2-an386 twin and bring-up, STM32H7 board (thumbv7em-none-eabihf)"
cargo --locked xtask firmware --locked
step "core library for RISC-V (riscv32imac-unknown-none-elf)"
cargo build --locked -p sts-twin-core --target riscv32imac-unknown-none-elf --release
step "the release test build"
cargo test --workspace --locked --release --no-run
# The wheel's crates have the test build's features (host-tools/python/Cargo.toml unifies
# them), so maturin reuses every one of them and builds only pyo3 and the module itself.
step "the Python package's wheel (maturin)"
bash scripts/python-package.sh build
step "tests: core, host tools, HIL"
# The HIL harness finds the ELFs at these places by itself; named here to be explicit.
STS_TWIN_FIRMWARE_ELF="$PWD/firmware/target/thumbv7em-none-eabihf/firmware/sts-twin-firmware" \
STS_TWIN_BRINGUP_ELF="$PWD/firmware/target/bringup/thumbv7em-none-eabihf/firmware/sts-twin-firmware" \
    cargo test --workspace --locked --release
step "Python package: pytest against the CLI, docs/python-loop.py"
bash scripts/python-package.sh test
