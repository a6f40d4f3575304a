#!/usr/bin/env sh
# The cargo runner of this app (.cargo/config.toml): boots the firmware ELF "$1" in QEMU
# mps2-an386 with the machine and semihosting flags of the HIL harness
# (host-tools/hil/src/harness.rs), but without the analogue bus, which only the harness
# provides: the firmware boots, logs that it finds no bus and ends QEMU with a failing
# status. Its logs: see ../qemu-defmt.sh. To run the firmware for real, with the bus:
# `sts-twin hil status --firmware <elf> --logs`, or the HIL tests.
set -eu
elf="$1"
shift
exec "$(dirname "$0")/../qemu-defmt.sh" "$elf" \
    qemu-system-arm -machine mps2-an386 -display none -monitor none -serial null \
    -semihosting-config enable=on,target=native -icount shift=2,sleep=off -no-reboot \
    -kernel "$elf" "$@"
