#!/usr/bin/env bash
# The main job: measures the emulated machine, fits the twin, then cuts the paper's bicuspid
# surface at 40 Hz with the real firmware running in QEMU in the loop, without and with the
# twin, and prints the form and phase errors. Extra arguments go to `sts-twin demo`
# (e.g. --freq 30, --sim).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
cargo --locked xtask firmware --locked --only qemu
export STS_TWIN_FIRMWARE_ELF="$PWD/firmware/target/thumbv7em-none-eabihf/firmware/sts-twin-firmware"
exec cargo run --locked --release -p sts-twin -- demo "$@"
