#!/usr/bin/env bash
# Installs what sts-twin needs and a fresh machine lacks. Idempotent: does nothing when
# everything is present.
#
#   scripts/setup.sh [rust|packages]   (default: both)
#
# `rust`: rustup's clippy and rustfmt and the firmware's Rust targets, which every build needs.
# `packages`: QEMU (Arm and RISC-V) for the HIL rig, Chromium when STS_TWIN_WITH_BROWSER=1,
# and the Python packages the tests use; only the tests need them, so scripts/test.sh installs
# them beside the build.
set -euo pipefail
part=${1:-all}
case "$part" in
    rust | packages | all) ;;
    *) echo "usage: scripts/setup.sh [rust|packages]" >&2; exit 2 ;;
esac

as_root() {
    if [ "$(id -u)" -eq 0 ]; then "$@"; elif command -v sudo >/dev/null; then sudo "$@"; else
        echo "error: need root to run: $*" >&2; exit 1; fi
}

rust() {
    if ! command -v rustup >/dev/null; then
        echo "error: rustup not found; install Rust from https://rustup.rs first" >&2
        exit 1
    fi
    # clippy lints, rustfmt checks the format.
    components=$(rustup component list --installed)
    for component in clippy rustfmt; do
        if ! grep -q "^$component-" <<<"$components"; then
            echo "setup: rustup component add $component"
            rustup component add "$component"
        fi
    done
    installed=$(rustup target list --installed)
    for target in thumbv7em-none-eabihf riscv32imac-unknown-none-elf; do
        if ! grep -qx "$target" <<<"$installed"; then
            echo "setup: rustup target add $target"
            rustup target add "$target"
        fi
    done
}

packages() {
    apt_packages=()
    command -v qemu-system-arm >/dev/null || apt_packages+=(qemu-system-arm)
    # qemu-system-riscv32, for the RISC-V firmware on QEMU virt.
    command -v qemu-system-riscv32 >/dev/null || apt_packages+=(qemu-system-misc)
    # A qemu-utils from backports breaks the distribution's QEMU system packages (it requires
    # QEMU 8 or later): it is brought back to the distribution's release beside them.
    if [ ${#apt_packages[@]} -gt 0 ] && dpkg-query -W -f='${Version}' qemu-utils 2>/dev/null | grep -q '~bpo'; then
        apt_packages+=("qemu-utils/$(. /etc/os-release && echo "$VERSION_CODENAME")")
    fi
    if [ "${STS_TWIN_WITH_BROWSER:-0}" = 1 ] && ! command -v chromium >/dev/null; then
        apt_packages+=(chromium)
    fi
    if [ ${#apt_packages[@]} -gt 0 ]; then
        if ! command -v apt-get >/dev/null; then
            echo "error: please install ${apt_packages[*]} with your package manager" >&2
            exit 1
        fi
        echo "setup: installing ${apt_packages[*]}"
        as_root apt-get update -qq
        as_root env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --allow-downgrades "${apt_packages[@]}" >/dev/null
    fi

    # Python and the packages the tests use.
    bash "$(dirname "$0")/setup-python.sh"
}

[ "$part" = packages ] || rust
[ "$part" = rust ] || packages
