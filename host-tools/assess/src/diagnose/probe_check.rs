//! The probe's scale, checked on the data before any candidate is scored on the residual.
//!
//! A capacitance probe that reads `g` times the tool's motion adds `(g - 1)` times the
//! motion to the measured error. A twin fitted on those readings (the lab's workflow) learns
//! it as dynamics where the accelerometer sees the motion, bends its formulas around it and
//! misses it where the accelerometer does not, so what is left in the residual has no shape a
//! candidate could name (hysteresis was named in its place). The data shows it plainly at the
//! slowest groups, where the servo follows the command to a small fraction of a percent: the
//! error there is in phase with the motion and the same fraction of it at every stroke
//! ([`sts_analysis::probe_scale`]).

use sts_analysis::probe_scale::probe_scale_of;
use sts_model::Effect;

use super::{GroupCtx, Ranked, MIN_EXPLAINED};

/// The sensor-gain result when the slowest groups show a scale error of the probe that holds
/// at least [`MIN_EXPLAINED`] of their measured error.
pub fn probe_scale_error(ctx: &[GroupCtx]) -> Option<Ranked> {
    let scale = probe_scale_of(ctx.iter().map(|c| (c.data, &c.sample.info)))?;
    let split = scale.scale_error()?;
    let k = split.constant;
    // What it explains of the slowest groups' measured error (second halves, as read).
    let (mut total_ss, mut left_ss) = (0.0, 0.0);
    for g in scale.slowest_groups() {
        let data = ctx[g.index].data;
        let half = data.len() / 2;
        let cmd = &data.z_cmd_um[half..];
        let mean = cmd.iter().sum::<f64>() / cmd.len().max(1) as f64;
        for (c, t) in cmd.iter().zip(&data.z_tcp_um[half..]) {
            let error = t - c;
            total_ss += error * error;
            left_ss += (error - k * (c - mean)).powi(2);
        }
    }
    // A scale error is the error there, not a part of it: a friction's in-phase part can
    // look like a constant fraction of the motion too (a LuGre friction's at 2 Hz: +1.4% at
    // the large strokes) but its steps and harmonics hold most of the error.
    let explained_fraction = if total_ss > 0.0 { 1.0 - left_ss / total_ss } else { 0.0 };
    if explained_fraction < MIN_EXPLAINED {
        return None;
    }
    // What it adds to every group's error: k times the motion, over the scored windows.
    let (mut motion_ss, mut n) = (0.0, 0usize);
    for c in ctx {
        let cmd = &c.data.z_cmd_um[c.start..];
        let mean = cmd.iter().sum::<f64>() / cmd.len().max(1) as f64;
        motion_ss += cmd.iter().map(|z| (z - mean).powi(2)).sum::<f64>();
        n += cmd.len();
    }
    let t = k / split.constant_se;
    let (lo, hi) = scale
        .slowest_groups()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), g| (lo.min(g.ratio - 1.0), hi.max(g.ratio - 1.0)));
    let amps = scale.slowest_groups().map(|g| g.amp_um);
    let (amp_lo, amp_hi) = amps.fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), a| (lo.min(a), hi.max(a)));
    Some(Ranked {
        effect: Effect::SensorGain.name().to_string(),
        explained_fraction,
        p_value: libm::erfc(t.abs() / std::f64::consts::SQRT_2),
        groups_improved: scale.slowest_groups().filter(|g| (g.ratio - 1.0) * k > 0.0).count(),
        params: vec![("probe_gain".into(), 1.0 + k)],
        evidence: format!(
            "at the slowest groups ({} Hz, {} strokes of {} um{}), where the servo follows the command, the measured error is in phase with the motion and {:+.2}% of it at every stroke ({:+.2}% to {:+.2}% per group; {:.0}% of the error there; {:.0} standard errors from zero; the part that falls with the stroke, the machine's own, {:.1} nm): the capacitance probe reads {:.1}% {} (scale error); a twin fitted on these readings learns it as dynamics, so it comes before every other candidate (which are scored on readings it distorts)",
            scale.slowest_freq_hz,
            scale.slowest_groups().count(),
            sts_analysis::repeat::range_text(format!("{amp_lo}"), format!("{amp_hi}")),
            scale.next_freq_hz.map_or(String::new(), |f| format!(
                "; beside those at {f} Hz, the machine's own in-phase error taken out as it grows with the frequency squared"
            )),
            k * 100.0,
            lo * 100.0,
            hi * 100.0,
            explained_fraction * 100.0,
            t.abs(),
            split.per_inverse_amp_um * 1e3,
            k.abs() * 100.0,
            if k >= 0.0 { "too much" } else { "too little" }
        ),
        significant: true,
        explained_rms_um: k.abs() * (motion_ss / n.max(1) as f64).sqrt(),
        without_fundamental: false,
    })
}
