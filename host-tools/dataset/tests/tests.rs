//! The dataset format's integration tests as one binary (as ripgrep's `tests/tests.rs`). Run
//! one group with `cargo test -p sts-dataset --release --test tests -- never_panics::`.

mod checks_and_output;
mod never_panics;
mod roundtrip_and_errors;
