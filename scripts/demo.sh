#!/usr/bin/env bash
# The main job: measures the emulated machine, fits the paper's formula twin and the range
# twin (the servo-axis twin over 1-100 Hz), then cuts the paper's bicuspid surface at 40 Hz
# with the real firmware running in QEMU in the loop, bare and with each twin, and prints
# their form and phase errors side by side. Extra arguments go to `sts-twin demo`
# (e.g. --freq 30, --sim).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
cargo --locked xtask firmware --locked --only qemu
export STS_TWIN_FIRMWARE_ELF="$PWD/firmware/target/thumbv7em-none-eabihf/firmware/sts-twin-firmware"
exec cargo run --locked --release -p sts-twin -- demo "$@"
