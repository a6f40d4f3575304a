//! Symbolic regression's integration tests as one binary (as ripgrep's `tests/tests.rs`). Run
//! one group with `cargo test -p sts-symreg --release --test tests -- planted::`.

mod determinism;
mod export;
mod planted;
