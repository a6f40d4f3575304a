//! The fit's integration tests as one binary (as ripgrep's `tests/tests.rs`). Run one group
//! with `cargo test -p sts-fit --release --test tests -- fit_twin::`.

mod axis_twin;
mod fit_model_file;
mod fit_twin;
mod identification_spread;
mod linear_terms;
