#!/usr/bin/env bash
# Installs what sts-twin needs and a fresh machine lacks. Idempotent: does nothing when
# everything is present.
#
#   scripts/setup.sh [rust|toolchain|targets|packages]   (default: rust and packages)
#
# `rust`: `toolchain` and `targets`. `toolchain`: rustup's clippy and rustfmt, which every
# check needs; `targets`: the firmware's Rust targets, which only the firmware build needs.
# `packages`: QEMU (Arm and RISC-V) for the HIL rig, Chromium when STS_TWIN_WITH_BROWSER=1,
# and the Python packages the tests use; only the tests need them, so scripts/test.sh installs
# them beside the build.
set -euo pipefail
part=${1:-all}
case "$part" in
    rust | toolchain | targets | packages | all) ;;
    *) echo "usage: scripts/setup.sh [rust|toolchain|targets|packages]" >&2; exit 2 ;;
esac

as_root() {
    if [ "$(id -u)" -eq 0 ]; then "$@"; elif command -v sudo >/dev/null; then sudo "$@"; else
        echo "error: need root to run: $*" >&2; exit 1; fi
}

need_rustup() {
    if ! command -v rustup >/dev/null; then
        echo "error: rustup not found; install Rust from https://rustup.rs first" >&2
        exit 1
    fi
}

toolchain() {
    need_rustup
    # clippy lints, rustfmt checks the format.
    components=$(rustup component list --installed)
    for component in clippy rustfmt; do
        if ! grep -q "^$component-" <<<"$components"; then
            echo "setup: rustup component add $component"
            rustup component add "$component"
        fi
    done
}

targets() {
    need_rustup
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
        # Without the recommended packages: QEMU's would bring some 400 MB of UEFI firmware, its
        # GTK display and Ceph's and GlusterFS's block drivers, none of which a board booted
        # with `-bios none`, `-nographic` and a file for RAM uses.
        as_root env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends --allow-downgrades \
            "${apt_packages[@]}" >/dev/null
    fi

    # Python and the packages the tests use.
    bash "$(dirname "$0")/setup-python.sh"
}

case "$part" in
    toolchain) toolchain ;;
    targets) targets ;;
    rust) toolchain && targets ;;
    packages) packages ;;
    all) toolchain && targets && packages ;;
esac
