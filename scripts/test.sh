#!/usr/bin/env bash
# Runs every test of sts-twin: builds the firmware for QEMU and the real board, the core for
# RISC-V, then the host, core and HIL test suites (the HIL tests boot the firmware in QEMU).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh

export CARGO_TERM_COLOR=${CARGO_TERM_COLOR:-never}
step() { printf '\n== %s\n' "$*"; }

step "firmware for QEMU mps2-an386 (thumbv7em-none-eabihf)"
cargo build --locked -p sts-twin-firmware --target thumbv7em-none-eabihf --profile firmware
step "firmware for the real board (STM32H7, build only)"
cargo build --locked -p sts-twin-board-stm32h7 --target thumbv7em-none-eabihf --profile firmware
step "core library for RISC-V (riscv32imac-unknown-none-elf)"
cargo build --locked -p sts-twin-core --target riscv32imac-unknown-none-elf --release
step "tests: core, host tools, HIL"
STS_TWIN_FIRMWARE_ELF="$PWD/target/thumbv7em-none-eabihf/firmware/sts-twin-firmware" \
    cargo test --locked --release
