//! The core's integration tests as one binary (as ripgrep's `tests/tests.rs`): the features
//! against their f64 oracle (`reference`), the servo tick and the golden DAC codes. Run one
//! group with `cargo test -p sts-twin-core --release --test tests -- tick_golden::`.

mod features_freq;
mod features_prop;
mod features_robust;
mod features_unit;
mod features_util;
#[path = "support/reference.rs"]
mod reference;
mod servo;
mod servo_recovery;
mod tick_golden;
#[path = "support/tick_scenarios.rs"]
mod tick_scenarios;
