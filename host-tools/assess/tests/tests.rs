//! The assessment's integration tests as one binary (as ripgrep's `tests/tests.rs`): the
//! hidden-effect suite, the several-effects sets and the unexplained structure. Run one with
//! `cargo test -p sts-assess --release --test tests -- diagnose_hidden_effects::`.

mod diagnose_hidden_effects;
mod explain_several_effects;
mod support;
mod unexplained_structure;
