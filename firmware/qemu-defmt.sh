#!/usr/bin/env sh
# The QEMU apps' cargo runners (firmware/*/run-qemu.sh) end here: runs the QEMU command given
# after the firmware ELF "$1" and shows the firmware's logs, defmt frames on QEMU's stdout:
# decoded when defmt-print is on the PATH (`cargo install defmt-print`), else kept in a file
# next to the ELF. The exit status is QEMU's, which the firmware sets.
#   qemu-defmt.sh ELF QEMU-COMMAND...
set -eu
elf="$1"
shift
if command -v defmt-print >/dev/null 2>&1; then
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
