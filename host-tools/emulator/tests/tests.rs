//! The emulator's integration tests as one binary (as ripgrep's `tests/tests.rs`). Run one
//! group with `cargo test -p sts-emulator --release --test tests -- effects::`.

mod analog_input;
mod effects;
mod paper_and_determinism;
