//! The core's integration tests as one binary (as ripgrep's `tests/tests.rs`): the features
//! against their f64 oracle (`reference`), the servo pipeline, and the tick's outputs on the
//! runs of `tick_scenarios` against their f64 oracle (`synth_reference`, in `tick_reference`)
//! and pinned bit for bit (`tick_golden`). Run one group with
//! `cargo test -p sts-twin-core --release --test tests -- tick_golden::`.

mod features_freq;
mod features_prop;
mod features_robust;
mod features_unit;
mod features_util;
#[path = "support/reference.rs"]
mod reference;
mod servo;
mod servo_recovery;
#[path = "support/synth_reference.rs"]
mod synth_reference;
mod tick_golden;
mod tick_reference;
#[path = "support/tick_scenarios.rs"]
mod tick_scenarios;
