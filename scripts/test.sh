#!/usr/bin/env bash
# Runs every test of sts-twin: formatting and lints, the firmware for QEMU and the real board,
# the core for RISC-V, then the host, core and HIL test suites (the HIL tests boot the
# firmware in QEMU), and the Python package's (built with maturin, tested with pytest).
#
# On a 2-core machine the work is packed around the QEMU tests (BENCHMARKS.md, "CI time"):
# they are the longest chain (firmware, the HIL test binary, then some 160 s of tests, most
# of it QEMU on one core), so they start as soon as their binary is built, at normal
# priority, and everything else (the rest of the builds, the other tests, pytest) runs beside
# them at idle priority (SCHED_IDLE): it takes only the core QEMU leaves, and a QEMU thread
# that wakes preempts it at once.
set -euo pipefail
cd "$(dirname "$0")/.."
STS_TWIN_PYTHON_LATER=1 bash scripts/setup.sh

export CARGO_TERM_COLOR=${CARGO_TERM_COLOR:-never}
step() { printf '\n== %s (%s)\n' "$*" "$(date -u +%H:%M:%S)"; }

# Idle priority: util-linux's chrt (in every Debian and Ubuntu base), else the lowest nice.
if chrt --idle 0 true 2>/dev/null; then idle=(chrt --idle 0); else idle=(nice -n 19); fi

# Background steps: each runs in a process group of its own and writes a log, printed when
# `finish` waits for it; a failure ends the run with the step's status. Whatever is still
# running when the script exits (a test binary and the QEMU it started included) is stopped.
declare -A job_pid job_log
background() {
    local name=$1
    shift
    job_log[$name]=$(mktemp)
    printf '\n== %s: started in the background (%s)\n' "$name" "$(date -u +%H:%M:%S)"
    setsid "$@" >"${job_log[$name]}" 2>&1 &
    job_pid[$name]=$!
}
finish() {
    local name=$1 status=0
    wait "${job_pid[$name]}" || status=$?
    unset "job_pid[$name]"
    step "$name (in the background)"
    cat "${job_log[$name]}"
    rm -f "${job_log[$name]}"
    if [ "$status" -ne 0 ]; then
        echo "error: $name failed (exit status $status)" >&2
        exit "$status"
    fi
}
stop_background() {
    local pid
    for pid in "${job_pid[@]}"; do
        kill -- "-$pid" 2>/dev/null || true
    done
}
trap stop_background EXIT

# The Python packages download while the builds below use the cores.
background "Python packages for the tests" bash scripts/setup-python.sh

step "formatting (the root workspace and the two firmware apps, which are workspaces of their own)"
cargo fmt --all -- --check
(cd firmware/qemu-app && cargo fmt -- --check)
(cd firmware/stm32h7-app && cargo fmt -- --check)
step "layering: no import cycle between the top-level modules of any crate"
cargo --locked xtask layering >/dev/null
# The firmware has a target directory of its own, so it builds beside the root's clippy (its
# fat-LTO links leave a core free).
background "firmware: QEMU mps2-an386 twin and bring-up, STM32H7 board (thumbv7em-none-eabihf)" \
    cargo --locked xtask firmware --locked
step "clippy (root workspace)"
# In the release profile, so that the build scripts and proc macros it compiles are the ones
# the release test build below uses (no code here depends on debug_assertions): the two
# steps 244 -> 237 s from scratch (BENCHMARKS.md, "CI time").
cargo clippy --workspace --all-targets --locked --release -- -D warnings
# The test binaries that boot QEMU; every other runs in the second group. All are built with
# `--workspace`, so that no crate is built again with other features.
qemu_tests=(hil board_cli)
step "the HIL test binary (release)"
cargo test --workspace --locked --release --no-run --test=hil
finish "firmware: QEMU mps2-an386 twin and bring-up, STM32H7 board (thumbv7em-none-eabihf)"

# The HIL harness finds the ELFs at these places by itself; named here to be explicit.
export STS_TWIN_FIRMWARE_ELF="$PWD/firmware/target/thumbv7em-none-eabihf/firmware/sts-twin-firmware"
export STS_TWIN_BRINGUP_ELF="$PWD/firmware/target/bringup/thumbv7em-none-eabihf/firmware/sts-twin-firmware"
# One test at a time: each binary's tests take turns on QEMU anyway (a lock), and the HIL
# suite took 199 s so against 223 s with the default threads.
background "tests that boot the firmware in QEMU: HIL, one at a time, at normal priority" \
    cargo test --workspace --locked --release --test=hil -- --test-threads=1

step "clippy (the firmware apps, each a workspace of its own; the QEMU app also as bring-up), idle priority"
(cd firmware/qemu-app && "${idle[@]}" cargo clippy --locked -- -D warnings && "${idle[@]}" cargo clippy --locked --features bringup -- -D warnings)
(cd firmware/stm32h7-app && "${idle[@]}" cargo clippy --locked -- -D warnings)
step "core library for RISC-V (riscv32imac-unknown-none-elf), idle priority"
"${idle[@]}" cargo build --locked -p sts-twin-core --target riscv32imac-unknown-none-elf --release
step "the release test build, idle priority"
"${idle[@]}" cargo test --workspace --locked --release --no-run
finish "Python packages for the tests"
# The wheel's crates have the test build's features (host-tools/python/Cargo.toml unifies
# them), so maturin reuses every one of them and builds only pyo3 and the module itself.
step "the Python package's wheel (maturin), idle priority"
"${idle[@]}" bash scripts/python-package.sh build

mapfile -t other_tests < <(cargo metadata --locked --no-deps --format-version 1 | python3 -c '
import json, sys
skip = set(sys.argv[1:])
for package in json.load(sys.stdin)["packages"]:
    for target in package["targets"]:
        if "test" in target["kind"] and target["name"] not in skip:
            print(target["name"])
' "${qemu_tests[@]}" | sort -u)
background "the other tests: core and host tools (unit, integration, doc), idle priority" \
    "${idle[@]}" bash -c 'cargo test --workspace --locked --release --lib --bins "$@" &&
        cargo test --workspace --locked --release --doc' tests "${other_tests[@]/#/--test=}"
background "Python package: pytest against the CLI, docs/python-loop.py, idle priority" \
    "${idle[@]}" bash scripts/python-package.sh test

finish "tests that boot the firmware in QEMU: HIL, one at a time, at normal priority"
step "tests that boot the firmware in QEMU: the CLI's boards, one at a time, at normal priority"
cargo test --workspace --locked --release --test=board_cli -- --test-threads=1
finish "the other tests: core and host tools (unit, integration, doc), idle priority"
finish "Python package: pytest against the CLI, docs/python-loop.py, idle priority"
