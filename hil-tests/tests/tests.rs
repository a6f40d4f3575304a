//! The HIL tests as one test binary (as ripgrep's `tests/tests.rs`): each module boots the
//! firmware ELF (from `cargo xtask firmware`) in QEMU; `sts_hil_tests::serial` runs them one
//! at a time. Run one group with `cargo test -p sts-hil-tests --release -- twin_hil::`.

mod board_pty;
mod calibrate_hil;
mod cortex_m7;
mod firmware_paths;
mod platform_bench;
mod platform_boot;
mod platform_determinism;
mod platform_faults;
mod platform_orphans;
mod platform_underrun;
mod riscv_virt;
mod supervisor_hil;
mod trial_hil;
mod twin_bench;
mod twin_faults;
mod twin_hil;
