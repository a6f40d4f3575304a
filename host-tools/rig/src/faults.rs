//! The co-processor's faults for people: every fault counter, every reason the inputs are
//! not trusted now, a missing model and where the configuration came from, one line each;
//! and, apart from them, the supervisor's gate, which holds compensation off where the
//! accelerometer sees mostly noise (at the centre of every bicuspid cut, where the stroke
//! shrinks to nothing): the design working, not a fault.
//!
//! ```
//! use sts_rig::fault_report;
//! # use sts_twin_core::{features::FeatureConfig, feedforward::FeedforwardParams};
//! # use sts_twin_core::wire::{ConfigSource, Status};
//! # let mut status = Status {
//! #     counters: Default::default(), enabled: true, gain: 1.0, degraded: 0, program_id: Some(1),
//! #     staged_program_id: None, params: FeedforwardParams::default(),
//! #     feature_config: FeatureConfig::DEFAULT, config_source: ConfigSource::Stored,
//! #     amp_um: 0.0, phase_deg: 0.0, features: [0.0; 12],
//! #     supervisor_params: Default::default(), supervisor: Default::default(),
//! # };
//! status.counters.frame_errors = 3;
//! let lines = fault_report(&status);
//! assert_eq!(lines.len(), 1);
//! assert!(lines[0].starts_with("3 control frames"));
//! ```

use sts_twin_core::servo::{
    Counters, DEGRADED_GATED, DEGRADED_MODEL, DEGRADED_NO_INPUT, DEGRADED_RECOVERING, DEGRADED_SATURATED,
    DEGRADED_STUCK, DEGRADED_SUPERVISED,
};
use sts_twin_core::supervisor::Trip;
use sts_twin_core::wire::{ConfigSource, Status};

use super::{Coprocessor, RigError};

/// Every fault `status` shows, one sentence each, most urgent first: why compensation is
/// ramped out now (the degraded bits but the gate's, [`gate_report`]), a missing model, a
/// configuration that fell back to defaults, then each non-zero fault counter with what it
/// means. Empty when there is nothing to report.
pub fn fault_report(status: &Status) -> Vec<String> {
    let mut lines = Vec::new();
    let reasons = degraded_reasons(status.degraded & !DEGRADED_GATED);
    if !reasons.is_empty() {
        lines.push(format!("compensation is ramped out now: {}", reasons.join("; ")));
    }
    if let Some(trip) = status.supervisor.tripped {
        let why = match trip {
            Trip::WorseThanBare => format!(
                "the error the accelerometer sees with compensation ({:.0}% of the stroke at {:.1} Hz) exceeded the \
                 bare machine's ({:.0}%)",
                100.0 * status.supervisor.last.error_ratio,
                status.supervisor.last.freq_hz.abs(),
                100.0 * status.supervisor.bare_error_ratio
            ),
            Trip::Shaking => "the correction shook the structure at other frequencies than the command's (the \
                              accelerometer's power there grew beyond the bare machine's)"
                .to_string(),
            Trip::Saturation => "the DAC target was clamped at full scale too often".to_string(),
        };
        lines.push(format!(
            "the supervisor switched compensation off: {why}; it resumes at a new operating point (the command \
             frequency changed by more than {:.0}%), with new parameters or a new model, or when switched on again",
            100.0 * status.supervisor_params.new_point_freq_change
        ));
    }
    if status.program_id.is_none() {
        lines.push(
            "no twin model is active: the prediction is zero and nothing is compensated (upload a model)".to_string(),
        );
    }
    match status.config_source {
        ConfigSource::DefaultsAfterCorrupt => lines.push(
            "the stored configuration was corrupt or invalid (magic, version, CRC or a value such as K_dv): \
             running on safe defaults; calibrate and save again"
                .to_string(),
        ),
        ConfigSource::Defaults | ConfigSource::Stored => {}
    }
    lines.extend(counter_lines(&status.counters));
    lines
}

/// The supervisor's gate, when it is closed now: where the accelerometer sees mostly noise
/// the twin's features would be measured on noise, so compensation fades out until the
/// motion is back (all of it, or only the formulas' part where a servo-axis twin's
/// correction, which reads no feature, stays on). Not a fault (no counter counts it; a cut
/// reports the share of its ticks held off): `None` when the gate is open.
pub fn gate_report(status: &Status) -> Option<String> {
    status.supervisor.gated.then(|| {
        let what = if status.degraded & DEGRADED_GATED != 0 {
            "compensation is faded out"
        } else {
            "the formulas' part of compensation is faded out (a servo-axis twin's correction, which comes from \
             the command, stays on)"
        };
        format!(
            "{what} by the supervisor's gate: the accelerometer sees mostly noise at {:.1} Hz \
             (what repeats with the command holds {:.0}% of its power; the twin's features would be \
             measured on noise); it fades back in when the motion is back",
            status.supervisor.last.freq_hz.abs(),
            100.0 * status.supervisor.last.motion_share
        )
    })
}

/// The `servo::DEGRADED_*` bits of `degraded` as phrases (unknown bits named by value).
pub fn degraded_reasons(degraded: u16) -> Vec<String> {
    const KNOWN: [(u16, &str); 7] = [
        (DEGRADED_STUCK, "the accelerometer is stuck or dead (its code does not change)"),
        (DEGRADED_SATURATED, "the accelerometer is saturated (full-scale codes)"),
        (DEGRADED_NO_INPUT, "the host's samples stopped arriving (bus underruns)"),
        (DEGRADED_MODEL, "the model's last evaluation failed"),
        (DEGRADED_RECOVERING, "inputs are healthy again, waiting for a clean feature window"),
        (DEGRADED_SUPERVISED, "the supervisor holds compensation off (see below)"),
        (DEGRADED_GATED, "the supervisor's gate holds compensation off (the accelerometer sees mostly noise)"),
    ];
    let mut reasons: Vec<String> =
        KNOWN.iter().filter(|(bit, _)| degraded & bit != 0).map(|(_, text)| text.to_string()).collect();
    let unknown = KNOWN.iter().fold(degraded, |rest, (bit, _)| rest & !bit);
    if unknown != 0 {
        reasons.push(format!("unknown degraded bits {unknown:#06x}"));
    }
    reasons
}

/// One line per non-zero fault counter of `c` (informational counters such as ticks,
/// model updates and slew-limited ticks are not faults and are left out).
fn counter_lines(c: &Counters) -> Vec<String> {
    let entries: [(u32, &str); 15] = [
        (c.input_stuck, "episodes of a stuck or dead accelerometer (compensation ramped out until it recovered)"),
        (c.input_saturated, "episodes of accelerometer saturation (compensation ramped out until it recovered)"),
        (
            c.bus_underruns,
            "bus underruns: the host's sample for a tick came late or not at all (the DAC held its value)",
        ),
        (c.bus_overruns, "bus overruns: a servo tick ran into the next period"),
        (
            c.model_faults,
            "failed model evaluations (a non-finite output or a torn feature snapshot; the prediction ramped out)",
        ),
        (c.model_late, "model results applied after their due tick"),
        (c.rejected_programs, "uploaded models rejected as malformed (the previous model stayed in force)"),
        (
            c.rejected_params,
            "parameter sets rejected (e.g. K_dv zero or not finite; the previous parameters stayed in force)",
        ),
        (
            c.rejected_feature_configs,
            "feature settings rejected (a zero or too long window; the previous settings stayed in force)",
        ),
        (
            c.axis_resets,
            "servo-axis twin restarts after it diverged (its identified loop is unstable on this motion; refit it)",
        ),
        (
            c.supervisor_trips,
            "supervisor trips: compensation made the error worse than the bare machine's or saturated the DAC",
        ),
        (c.frame_errors, "control frames dropped as corrupt (CRC, stuffing or length; the host retries)"),
        (c.dac_saturations, "ticks with the DAC target clamped at full scale"),
        (c.config_store_errors, "config store errors (a corrupt record at boot or a failed save)"),
        (c.degraded_entries, "times the servo entered the degraded state"),
    ];
    entries.iter().filter(|(n, _)| *n != 0).map(|(n, text)| format!("{n} {text}")).collect()
}

/// Asks `coprocessor` for its status and prints [`fault_report`] to stderr (stdout stays
/// free for reports and JSON), then the gate's state ([`gate_report`]) as the state it is.
pub fn print_fault_report(coprocessor: &mut dyn Coprocessor) -> Result<(), RigError> {
    let status = crate::status(coprocessor)?;
    let lines = fault_report(&status);
    if lines.is_empty() {
        eprintln!("co-processor ({}): no faults in {} ticks", coprocessor.kind(), status.counters.ticks);
    } else {
        eprintln!("co-processor ({}) faults in {} ticks:", coprocessor.kind(), status.counters.ticks);
        for line in &lines {
            eprintln!("  - {line}");
        }
    }
    if let Some(gate) = gate_report(&status) {
        eprintln!("co-processor ({}) now: {gate}", coprocessor.kind());
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use sts_twin_core::features::FeatureConfig;
    use sts_twin_core::feedforward::FeedforwardParams;
    use sts_twin_core::wire::{Request, Response};

    fn clean() -> Status {
        Status {
            counters: Counters { ticks: 80_000, model_updates: 90, slew_limited_ticks: 12, ..Default::default() },
            enabled: true,
            gain: 1.0,
            degraded: 0,
            program_id: Some(7),
            staged_program_id: None,
            params: FeedforwardParams::default(),
            feature_config: FeatureConfig::DEFAULT,
            config_source: ConfigSource::Stored,
            amp_um: 1.0,
            phase_deg: 2.0,
            features: [0.0; 12],
            supervisor_params: Default::default(),
            supervisor: Default::default(),
        }
    }

    #[test]
    fn a_clean_status_reports_nothing() {
        assert_eq!(fault_report(&clean()), Vec::<String>::new());
        let defaults = Status { config_source: ConfigSource::Defaults, ..clean() };
        assert!(fault_report(&defaults).is_empty(), "an empty store is not a fault");
    }

    #[test]
    fn every_fault_counter_is_reported_with_its_count() {
        type SetCounter = fn(&mut Counters);
        let set: [(SetCounter, &str); 15] = [
            (|c| c.input_stuck = 2, "2 episodes of a stuck or dead accelerometer"),
            (|c| c.input_saturated = 3, "3 episodes of accelerometer saturation"),
            (|c| c.bus_underruns = 40, "40 bus underruns"),
            (|c| c.bus_overruns = 1, "1 bus overruns"),
            (|c| c.model_faults = 5, "5 failed model evaluations"),
            (|c| c.model_late = 6, "6 model results applied after"),
            (|c| c.rejected_programs = 7, "7 uploaded models rejected"),
            (|c| c.rejected_params = 8, "8 parameter sets rejected (e.g. K_dv"),
            (|c| c.rejected_feature_configs = 13, "13 feature settings rejected"),
            (|c| c.axis_resets = 14, "14 servo-axis twin restarts"),
            (|c| c.supervisor_trips = 15, "15 supervisor trips"),
            (|c| c.frame_errors = 9, "9 control frames dropped as corrupt"),
            (|c| c.dac_saturations = 10, "10 ticks with the DAC target clamped"),
            (|c| c.config_store_errors = 11, "11 config store errors"),
            (|c| c.degraded_entries = 12, "12 times the servo entered the degraded state"),
        ];
        for (apply, expected) in set {
            let mut status = clean();
            apply(&mut status.counters);
            let lines = fault_report(&status);
            assert_eq!(lines.len(), 1, "{lines:?}");
            assert!(lines[0].starts_with(expected), "{lines:?} should start with {expected:?}");
        }
    }

    #[test]
    fn degraded_bits_missing_model_and_corrupt_config_are_reported_first() {
        let mut status = clean();
        status.degraded = DEGRADED_STUCK | DEGRADED_NO_INPUT | 0x0100;
        status.program_id = None;
        status.config_source = ConfigSource::DefaultsAfterCorrupt;
        status.counters.input_stuck = 1;
        let lines = fault_report(&status);
        assert_eq!(lines.len(), 4, "{lines:?}");
        assert!(lines[0].contains("stuck or dead") && lines[0].contains("stopped arriving"), "{}", lines[0]);
        assert!(lines[0].contains("unknown degraded bits 0x0100"), "{}", lines[0]);
        assert!(!lines[0].contains("saturated"), "{}", lines[0]);
        assert!(lines[1].starts_with("no twin model is active"), "{}", lines[1]);
        assert!(lines[2].contains("corrupt or invalid") && lines[2].contains("safe defaults"), "{}", lines[2]);
        assert!(lines[3].starts_with("1 episodes of a stuck"), "{}", lines[3]);
    }

    #[test]
    fn a_supervisor_trip_and_the_gate_say_why_and_what_brings_compensation_back() {
        use sts_twin_core::supervisor::{MotionEstimate, SupervisorState};
        let mut status = clean();
        status.supervisor = SupervisorState {
            tripped: Some(Trip::WorseThanBare),
            gated: true,
            bare_error_ratio: 0.9,
            bare_freq_hz: 80.0,
            last: MotionEstimate {
                freq_hz: 80.0,
                cmd_amp_nm: 3000.0,
                error_ratio: 1.5,
                error_ratio_sd: 0.01,
                motion_share: 0.3,
                motion_power_m2ps4: 0.03,
                other_power_m2ps4: 0.07,
                harmonic_power_m2ps4: 0.0,
            },
            ..Default::default()
        };
        status.degraded = DEGRADED_SUPERVISED | DEGRADED_GATED;
        let lines = fault_report(&status);
        // The trip is a fault, said once: the degraded bit points to the line below; the
        // gate is not one, and is said apart.
        assert_eq!(lines.len(), 2, "{lines:?}");
        assert!(lines.iter().all(|l| !l.contains("mostly noise")), "{lines:?}");
        assert!(lines[0].starts_with("compensation is ramped out now") && lines[0].contains("see below"), "{lines:?}");
        assert!(lines[1].contains("150% of the stroke at 80.0 Hz") && lines[1].contains("(90%)"), "{}", lines[1]);
        assert!(lines[1].contains("changed by more than 10%"), "{}", lines[1]);
        let gate = gate_report(&status).expect("the gate is closed");
        assert!(gate.contains("mostly noise at 80.0 Hz") && gate.contains("30%"), "{gate}");
    }

    #[test]
    fn the_gate_alone_is_no_fault() {
        use sts_twin_core::supervisor::{MotionEstimate, SupervisorState};
        let mut status = clean();
        assert_eq!(gate_report(&status), None);
        // The end of a bicuspid cut: at the centre the stroke, and the motion the
        // accelerometer sees, shrink to nothing.
        status.supervisor = SupervisorState {
            gated: true,
            last: MotionEstimate { freq_hz: 40.0, motion_share: 0.26, ..Default::default() },
            ..Default::default()
        };
        status.degraded = DEGRADED_GATED;
        assert_eq!(fault_report(&status), Vec::<String>::new());
        let gate = gate_report(&status).expect("the gate is closed");
        assert!(gate.contains("mostly noise at 40.0 Hz") && gate.contains("26%"), "{gate}");
        assert!(gate.starts_with("compensation is faded out"), "{gate}");
        // An axis twin's correction stays on: only the formulas fade out.
        status.degraded = 0;
        let gate = gate_report(&status).expect("the gate is closed");
        assert!(gate.starts_with("the formulas' part") && gate.contains("stays on"), "{gate}");
        status.degraded = DEGRADED_GATED;
        // With a real fault beside it, the fault is reported and the gate is still not.
        status.degraded |= DEGRADED_STUCK;
        let lines = fault_report(&status);
        assert_eq!(lines.len(), 1, "{lines:?}");
        assert!(lines[0].contains("stuck") && !lines[0].contains("gate"), "{lines:?}");
    }

    #[test]
    fn each_degraded_bit_has_its_own_reason() {
        let bits = [
            DEGRADED_STUCK,
            DEGRADED_SATURATED,
            DEGRADED_NO_INPUT,
            DEGRADED_MODEL,
            DEGRADED_RECOVERING,
            DEGRADED_SUPERVISED,
            DEGRADED_GATED,
        ];
        let texts: Vec<String> = bits.iter().map(|&b| degraded_reasons(b).concat()).collect();
        for (i, text) in texts.iter().enumerate() {
            assert!(!text.is_empty() && !text.contains("unknown"), "{text}");
            assert!(texts[i + 1..].iter().all(|other| other != text), "bits share a reason: {text}");
        }
        assert_eq!(degraded_reasons(0), Vec::<String>::new());
        assert_eq!(degraded_reasons(DEGRADED_SATURATED | DEGRADED_MODEL).len(), 2);
    }

    #[test]
    fn the_simulated_coprocessor_can_be_reported_on() {
        let mut sim = super::super::SimCoprocessor::boot(&[]);
        // No model and an empty store: the only line is the missing model.
        let status = match sim.request(Request::GetStatus).unwrap() {
            Response::Status(s) => s,
            other => panic!("{other:?}"),
        };
        let lines = fault_report(&status);
        assert_eq!(lines.len(), 1, "{lines:?}");
        assert!(lines[0].starts_with("no twin model"));
        print_fault_report(&mut sim).unwrap();
    }
}
