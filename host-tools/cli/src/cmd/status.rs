//! The co-processor's status for people, as `hil status` and `board status` print it.

use sts_twin_core::counters::Counters;
use sts_twin_core::supervisor::Trip;
use sts_twin_core::wire::Status;

/// Prints `status`: compensation, the model, the parameters and path table, the features,
/// the supervisor, the counters, and every fault in words.
pub(crate) fn print_status(status: &Status) {
    println!("config: the co-processor {}", sts_rig::calibrate::describe_config_source(status.config_source));
    println!(
        "compensation: {} (gain {:.3}), program {} (staged {}), inputs {}",
        if status.enabled { "enabled" } else { "disabled" },
        status.gain,
        status.program_id.map_or("none".to_string(), |id| id.to_string()),
        status.staged_program_id.map_or("none".to_string(), |id| id.to_string()),
        if status.degraded == 0 { "trusted".to_string() } else { format!("degraded (bits {:#06b})", status.degraded) }
    );
    print_params(status);
    println!(
        "features: window {} samples at {} Hz, {} m/s^2 per LSB",
        status.feature_config.window_samples,
        status.feature_config.sample_rate_hz,
        status.feature_config.acc_mps2_per_lsb
    );
    println!(
        "prediction: amplitude {:.4} um, phase {:.3} deg at {:.2} Hz",
        status.amp_um, status.phase_deg, status.features[0]
    );
    let s = &status.supervisor;
    println!(
        "supervisor: {}{}{}",
        if status.supervisor_params.active { "active" } else { "off" },
        s.tripped.map_or(String::new(), |trip| format!(", tripped ({})", trip_text(trip))),
        if s.gated { ", gated (below)" } else { "" }
    );
    println!("counters: {}", counters_summary(&status.counters));
    for line in sts_rig::fault_report(status) {
        println!("  - {line}");
    }
    if let Some(gate) = sts_rig::gate_report(status) {
        println!("now: {gate}");
    }
}

/// Prints the feedforward parameters and the analogue-path table.
pub(crate) fn print_params(status: &Status) {
    let p = &status.params;
    println!(
        "feedforward: K_dv {} um/V, K_vc {} pulses/V, offset {} V, slew {} V/tick, DAC full scale {} V, enable ramp {} ticks",
        p.k_dv_um_per_v, p.k_vc_pulses_per_v, p.offset_v, p.slew_v_per_tick, p.dac_full_scale_v, p.enable_ramp_ticks
    );
    if p.analogue_path.count == 0 {
        println!("analogue path: not measured (calibrate-offset measures it)");
        return;
    }
    println!("analogue path ({} points, measured with a {} um sine):", p.analogue_path.count, p.analogue_path.amp_um);
    for (freq_hz, gain, phase_deg) in p.analogue_path.points() {
        let gain = if gain > 0.0 { format!("gain {gain:.4}") } else { "gain not measured".to_string() };
        println!("  {freq_hz:6.1} Hz  {gain}, phase {phase_deg:+.3} deg");
    }
}

/// Why the supervisor switched compensation off, in a few words.
pub(crate) fn trip_text(trip: Trip) -> &'static str {
    match trip {
        Trip::WorseThanBare => "worse than bare",
        Trip::Shaking => "shaking",
        Trip::Saturation => "DAC saturation",
    }
}

/// Every counter with its name for people, events first, then faults (each fault counter
/// in [`Counters::fault_sum`]).
pub(crate) fn counter_rows(c: &Counters) -> [(&'static str, u64, bool); 19] {
    [
        ("servo ticks", c.ticks, false),
        ("model updates", c.model_updates.into(), false),
        ("late model results", c.model_late.into(), false),
        ("slew-limited ticks", c.slew_limited_ticks.into(), false),
        ("degraded entries", c.degraded_entries.into(), false),
        ("bus underruns", c.bus_underruns.into(), true),
        ("bus overruns", c.bus_overruns.into(), true),
        ("DAC saturations", c.dac_saturations.into(), true),
        ("frame errors", c.frame_errors.into(), true),
        ("rejected programs", c.rejected_programs.into(), true),
        ("rejected parameters", c.rejected_params.into(), true),
        ("rejected feature settings", c.rejected_feature_configs.into(), true),
        ("model faults", c.model_faults.into(), true),
        ("axis twin resets", c.axis_resets.into(), true),
        ("stuck input episodes", c.input_stuck.into(), true),
        ("saturated input episodes", c.input_saturated.into(), true),
        ("config store errors", c.config_store_errors.into(), true),
        ("supervisor trips", c.supervisor_trips.into(), true),
        ("fault sum", c.fault_sum().into(), false),
    ]
}

/// The counters on one line: ticks and model updates, then the faults that are not zero.
pub(crate) fn counters_summary(c: &Counters) -> String {
    let faults: Vec<String> = counter_rows(c)
        .iter()
        .filter(|(_, n, fault)| *fault && *n > 0)
        .map(|(name, n, _)| format!("{name} {n}"))
        .collect();
    format!(
        "{} servo ticks, {} model updates ({} late); faults: {}",
        c.ticks,
        c.model_updates,
        c.model_late,
        if faults.is_empty() { "none".to_string() } else { faults.join(", ") }
    )
}

/// Every counter, one a line, as `board counters` prints them.
pub(crate) fn print_counters(c: &Counters) {
    for (name, n, _) in counter_rows(c) {
        println!("{name:>26}  {n}");
    }
}
