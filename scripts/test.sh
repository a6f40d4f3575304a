#!/usr/bin/env bash
# Runs every test of sts-twin: formatting and lints, the firmware for QEMU and the real board,
# the core for RISC-V, then the host, core and HIL test suites (the HIL tests boot the
# firmware in QEMU), and the Python package's (built with maturin, tested with pytest).
set -euo pipefail
cd "$(dirname "$0")/.."
STS_TWIN_PYTHON_LATER=1 bash scripts/setup.sh

export CARGO_TERM_COLOR=${CARGO_TERM_COLOR:-never}
step() { printf '\n== %s (%s)\n' "$*" "$(date -u +%H:%M:%S)"; }
logs=$(mktemp -d)
# A failing step ends the jobs that run beside it, too.
trap 'kill $(jobs -p) 2>/dev/null || true; rm -rf "$logs"' EXIT

# Waits for background job $1 (named $2), prints its log $3, and fails if it failed.
join() {
    local status=0
    wait "$1" || status=$?
    cat "$3"
    if [ "$status" -ne 0 ]; then
        echo "error: $2 failed (status $status)" >&2
        exit "$status"
    fi
}

step "formatting (the root workspace and the two firmware apps, which are workspaces of their own)"
cargo fmt --all -- --check
(cd firmware/qemu-app && cargo fmt -- --check)
(cd firmware/stm32h7-app && cargo fmt -- --check)
step "layering: no import cycle between the top-level modules of any crate"
cargo --locked xtask layering >/dev/null

# The Python packages download, and the firmware side lints and builds, beside the host
# side's builds: each side alone leaves a core idle for part of its time (single-threaded
# fat-LTO links, a crate's last codegen unit). The firmware side uses its own target
# directory throughout (the RISC-V core's build too) and runs xtask's binary (built by the
# layering step) rather than `cargo xtask`, so that it never waits for the host side's
# lock on target/.
bash scripts/setup-python.sh >"$logs/python" 2>&1 &
python_setup=$!
(
    set -euo pipefail
    step "clippy (the firmware apps, each a workspace of its own; the QEMU app also as bring-up)"
    (cd firmware/qemu-app && cargo clippy --locked -- -D warnings && cargo clippy --locked --features bringup -- -D warnings)
    (cd firmware/stm32h7-app && cargo clippy --locked -- -D warnings)
    step "firmware: QEMU mps2-an386 twin and bring-up, STM32H7 board (thumbv7em-none-eabihf)"
    target/debug/xtask firmware --locked
    step "core library for RISC-V (riscv32imac-unknown-none-elf)"
    cargo build --locked -p sts-twin-core --target riscv32imac-unknown-none-elf --release --target-dir firmware/target
    step "firmware side done"
) >"$logs/firmware" 2>&1 &
firmware_side=$!

step "clippy (root workspace)"
cargo clippy --workspace --all-targets --locked -- -D warnings
step "Python packages for the tests (installed in the background)"
join "$python_setup" "installing the Python packages" "$logs/python"
# The release test build below reuses most of the wheel's third-party crates (59 of 87: nalgebra,
# rustfft, fixed, ...); serde, rayon and the project's crates build again, with the features
# the whole workspace asks of them.
step "the Python package's wheel (maturin)"
bash scripts/python-package.sh build
step "the release test build"
cargo test --workspace --locked --release --no-run
step "the firmware side, built beside the host side (its log follows)"
join "$firmware_side" "the firmware side" "$logs/firmware"
step "tests: core, host tools, HIL"
# The HIL harness finds the ELFs at these places by itself; named here to be explicit.
STS_TWIN_FIRMWARE_ELF="$PWD/firmware/target/thumbv7em-none-eabihf/firmware/sts-twin-firmware" \
STS_TWIN_BRINGUP_ELF="$PWD/firmware/target/bringup/thumbv7em-none-eabihf/firmware/sts-twin-firmware" \
    cargo test --workspace --locked --release
step "Python package: pytest against the CLI, docs/python-loop.py"
bash scripts/python-package.sh test
