#!/usr/bin/env bash
# Runs every test of sts-twin, as CI does (.ci/run):
#   1. formatting;
#   2. the root workspace built for its tests and linted; beside it, the firmware apps built and
#      linted, and the packages the tests need (QEMU, Chromium, Python's) installed; then the
#      layering check;
#   3. the tests that boot the firmware in QEMU, one at a time: each lockstep tick is a hand-off
#      between the host and QEMU's threads, which any load of the same priority on the 2 cores
#      delays many times over. The command's board tests alone, then the HIL tests with, beside
#      them at idle priority (SCHED_IDLE) so that they take only the CPU QEMU leaves, every
#      other test binary (unit, integration), and the Python package's wheel and pytest;
#   4. the doc tests, then the logs of the tests beside.
# Every test binary of the workspace runs in step 3: those the QEMU steps do not name run beside.
set -euo pipefail
cd "$(dirname "$0")/.."
step() { printf '\n== %s (%s)\n' "$*" "$(date -u +%H:%M:%S)"; }
step "setup: rustup's clippy and rustfmt, where this machine lacks them (scripts/setup.sh toolchain)"
bash scripts/setup.sh toolchain
export CARGO_TERM_COLOR=${CARGO_TERM_COLOR:-never}
# The `ci` profile (Cargo.toml); scripts/python-package.sh builds the wheel and finds the CLI in it.
export STS_TWIN_CARGO_PROFILE=ci
source scripts/pyo3-env.sh

# A step run beside the next ones: its log is printed, and a failure ends the run, at `finish`.
# Each is a process group of its own, stopped with all it started when the script exits.
set -m
declare -A job_pid job_log
beside() {
    local name=$1
    shift
    job_log[$name]=$(mktemp)
    step "$name: started beside the next steps"
    "$@" >"${job_log[$name]}" 2>&1 &
    job_pid[$name]=$!
}
finish() {
    local name=$1 status=0
    wait "${job_pid[$name]}" || status=$?
    unset "job_pid[$name]"
    step "$name: its log"
    cat "${job_log[$name]}"
    rm -f "${job_log[$name]}"
    [ "$status" -eq 0 ] || { echo "error: $name failed (exit status $status)" >&2; exit "$status"; }
}
# The lock under which the test binaries run beside print their outputs (run_binary).
RUN_BINARY_LOCK=$(mktemp)
trap 'rm -f "$RUN_BINARY_LOCK"; for pid in "${job_pid[@]}"; do kill -- "-$pid" 2>/dev/null || true; done' EXIT

# clippy-driver compiles each workspace's own crates (cargo's hook for a wrapper), so that one
# build both lints them and makes the test binaries or the firmware images; `cargo clippy`
# would check them once more. Exported before the first cargo build, so nothing builds twice.
export RUSTFLAGS="-D warnings" RUSTC_WORKSPACE_WRAPPER
RUSTC_WORKSPACE_WRAPPER=$(rustup which clippy-driver)

step "formatting (the root workspace and each firmware app, a workspace of its own)"
cargo fmt --all -- --check
for app in firmware/*-app; do (cd "$app" && cargo fmt -- --check); done

# The build tasks (xtask/) in a target directory of their own: building them never waits on
# the test build's lock on target/, nor the test build on theirs.
xtask() { CARGO_TARGET_DIR=target/xtask cargo --locked xtask "$@"; }
# QEMU, Chromium and the Python packages: only the tests need them, and on a fresh machine
# their download and unpacking takes a minute or more that the builds need not wait for.
beside "setup: the packages the tests need (scripts/setup.sh packages)" bash scripts/setup.sh packages
# Without DWARF (the firmware profile's `debug = 2`): the same code and sections in flash and
# RAM, 35 CPU-s less to build; a failing test's firmware log lines lose their file:line.
firmware() { bash scripts/setup.sh targets && CARGO_PROFILE_FIRMWARE_DEBUG=0 xtask firmware --locked; }
beside "the firmware's Rust targets (scripts/setup.sh targets), then its images, linted" firmware
# Every target but the Python extension's, which holds no tests (maturin builds it below).
step "the root workspace's test build, linted (tests, benches, examples)"
cargo test --workspace --tests --benches --examples --locked --profile ci --no-run
finish "the firmware's Rust targets (scripts/setup.sh targets), then its images, linted"
step "layering: no import cycle between the top-level modules of any crate"
xtask layering >/dev/null
finish "setup: the packages the tests need (scripts/setup.sh packages)"

export STS_TWIN_FIRMWARE_ELF="$PWD/firmware/target/thumbv7em-none-eabihf/firmware/sts-twin-firmware"
export STS_TWIN_BRINGUP_ELF="$PWD/firmware/target/bringup/thumbv7em-none-eabihf/firmware/sts-twin-firmware"
export STS_TWIN_RISCV_FIRMWARE_ELF="$PWD/firmware/target/riscv32imac-unknown-none-elf/firmware/sts-twin-firmware-riscv"
# The test binaries that boot the firmware in QEMU. board_cli steps a board tick by tick from
# the test while the CLI waits on its ticks (a lab's calibration on a serial port): even load at
# idle priority slows that lockstep 2-5 times (measured: 9 s alone, 17-45 s beside two
# SCHED_IDLE busy loops), so it runs alone, before the rest starts beside the HIL tests.
qemu_alone=(board_cli)
qemu_with_rest_beside=(hil)
# Every test binary (every target with `test = true`: unit and integration), as built above,
# with its package's folder, where cargo would run it ("folder<TAB>executable"): the QEMU ones
# by name, the others in `other_runs`, a line each. They run without cargo, which would hold
# its lock on target/ until they end (the wheel's build needs it beside them).
binaries=$(cargo test --workspace --tests --locked --profile ci --no-run --message-format=json \
    | python3 -c '
import json, os, sys
qemu = set(sys.argv[1:])
for line in sys.stdin:
    m = json.loads(line)
    if m.get("reason") == "compiler-artifact" and m.get("executable") and m["profile"]["test"]:
        name = m["target"]["name"] if "test" in m["target"]["kind"] and m["target"]["name"] in qemu else "-"
        print(name, os.path.dirname(m["manifest_path"]), m["executable"], sep="\t")' \
    "${qemu_alone[@]}" "${qemu_with_rest_beside[@]}")
declare -A qemu_run
other_runs=
while IFS=$'\t' read -r name dir exe; do
    if [ "$name" = - ]; then other_runs+=$dir$'\t'$exe$'\n'; else qemu_run[$name]=$dir$'\t'$exe; fi
done <<<"$binaries"
for name in "${qemu_alone[@]}" "${qemu_with_rest_beside[@]}"; do
    [ -n "${qemu_run[$name]:-}" ] || { echo "error: no test binary named $name" >&2; exit 1; }
done
other_runs=${other_runs%$'\n'}
[ -n "$other_runs" ] || { echo "error: no test binary to run" >&2; exit 1; }
# One test binary ("folder<TAB>executable", then its arguments), run as cargo would run it.
run_here() {
    local dir=${1%%$'\t'*} exe=${1#*$'\t'}
    shift
    printf '\n     Running %s in %s\n' "${exe#"$PWD/"}" "${dir#"$PWD/"}"
    (cd "$dir" && CARGO_MANIFEST_DIR=$dir "$exe" "$@")
}
# The same beside other steps: the output printed whole when it ends, with its time, under a
# lock, so that two binaries' outputs never interleave.
run_binary() {
    local log status=0 start=$SECONDS
    log=$(mktemp)
    run_here "$@" >"$log" 2>&1 || status=$?
    { cat "$log" && printf '     (%s s, ended %s)\n' "$((SECONDS - start))" "$(date -u +%H:%M:%S)"; } \
        | flock "$RUN_BINARY_LOCK" cat
    rm -f "$log"
    [ "$status" -eq 0 ] || { echo "error: ${1#*$'\t'} failed (exit status $status)" | flock "$RUN_BINARY_LOCK" cat >&2; return 1; }
}
export -f run_here run_binary
export RUN_BINARY_LOCK
other_binaries() {
    # Idle priority: they take only the CPU the QEMU tests leave, so each lockstep hand-off
    # still finds a core (measured: the QEMU tests about as fast as alone, the rest on the
    # idle core). Two binaries at a time, so that both cores stay busy after QEMU ends.
    chrt --idle --pid 0 "$BASHPID"
    printf '%s\n' "$other_runs" | xargs -d '\n' -P 2 -I{} bash -c 'run_binary "$1"' run_binary {}
}
step "the QEMU tests that run alone (${qemu_alone[*]})"
for name in "${qemu_alone[@]}"; do run_here "${qemu_run[$name]}" --test-threads=1; done
beside "every other test binary: unit, integration" other_binaries
python_job="the Python package's wheel (maturin, from the test build's crates), then pytest: the package against the CLI"
beside "$python_job" chrt --idle 0 bash scripts/python-package.sh all
step "the QEMU tests (${qemu_with_rest_beside[*]}), one at a time, the others beside them at idle priority"
for name in "${qemu_with_rest_beside[@]}"; do run_here "${qemu_run[$name]}" --test-threads=1; done
step "the doc tests"
cargo test --workspace --locked --profile ci --doc
finish "every other test binary: unit, integration"
finish "$python_job"
