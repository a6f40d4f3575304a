#!/usr/bin/env sh
# The cargo runner of this app (.cargo/config.toml): boots the firmware ELF "$1" in QEMU
# RISC-V virt with the machine and semihosting flags of the HIL harness
# (host-tools/hil/src/harness.rs), but without the analogue bus, which only the harness
# provides: the firmware boots, logs that it finds no bus and ends QEMU with a failing
# status. Its logs are defmt frames on QEMU's stdout: decoded here when defmt-print is on
# the PATH (`cargo install defmt-print`), else kept in a file next to the ELF. To run the
# firmware for real, with the bus: `sts-twin hil --board riscv-virt status --logs`, or the
# HIL tests.
set -eu
elf="$1"
shift
set -- qemu-system-riscv32 -machine virt -bios none -rtc clock=vm -display none -monitor none -serial null \
    -semihosting-config enable=on,target=native -icount shift=2,sleep=off -no-reboot \
    -kernel "$elf" "$@"
if command -v defmt-print >/dev/null 2>&1; then
    # The exit status is QEMU's (the firmware's), not defmt-print's.
    status_file=$(mktemp)
    trap 'rm -f "$status_file"' EXIT
    { status=0; "$@" || status=$?; echo "$status" >"$status_file"; } | defmt-print -e "$elf"
    exit "$(cat "$status_file")"
fi
frames="$elf.defmt"
echo "run-qemu.sh: defmt-print not found (cargo install defmt-print); the raw defmt log goes to $frames" >&2
echo "run-qemu.sh: decode it with: defmt-print -e $elf < $frames" >&2
status=0
"$@" >"$frames" || status=$?
echo "run-qemu.sh: QEMU exited with status $status ($(wc -c <"$frames") bytes of log)" >&2
exit "$status"
