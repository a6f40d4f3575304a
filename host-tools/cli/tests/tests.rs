//! The `sts-twin` command's integration tests as one binary (as ripgrep's `tests/tests.rs`):
//! each module drives the built command as a user does. Run one module with
//! `cargo test -p sts-twin --release --test tests -- foreign_machine::`. The board tests, which
//! boot the firmware in QEMU, are a binary of their own (`board_cli`).

mod compare_model;
mod explain_ladder;
mod export;
mod foreign;
mod foreign_ball_screw;
mod foreign_machine;
mod foreign_suite;
mod import;
mod machine_report;
mod never_panics;
mod report_browser;
mod trial_table_json;
mod untrusted;
