//! The analysis' integration tests as one binary (as ripgrep's `tests/tests.rs`). Run one
//! group with `cargo test -p sts-analysis --release --test tests -- repeatability::`.

mod fit_start_transient;
mod repeatability;
