//! Identifies the servo-axis twin ([`sts_twin_core::axis`]) from a measurement: the
//! controller, slide, current loop, structural mode and the nonlinear effect's parameters,
//! all per kg of moving mass, by Levenberg-Marquardt on the encoder and probe readings
//! (output error: the whole axis simulated from the command).
//!
//! The fit is local, so it starts from a grid: command delays of 1-6 ticks (a late setpoint
//! takes 4-6; a survivor at 6 steps further while the fit improves) times servo
//! bandwidths of 30-300 Hz (controller gains of a well-damped PID at that bandwidth), the
//! servo and the effect fitted together on the encoder, the starts thinned by successive
//! halving; then the mode from a grid of frequencies on the probe; then everything on both.
//! Each group is simulated over a few periods of its steady sine, not the whole group: the
//! same fits from a fifth of the simulated ticks.
//! The encoder ripple's phase and amplitudes enter each stage by linear least squares
//! (`ripple_linear`): over a travel of several pitches a local fit of the phase has a
//! minimum every turn.
//! The simulation here is f64 (the firmware's is f32); both simulate the whole axis with the
//! same laws and share the discretisation ([`zoh`]).
//!
//! The simulation is nearly all of the fit's time, so it is written by hand as a measured hot
//! loop: the Jacobian's and the ripple's simulations run four candidates side by side, as
//! branch-free steps over the lanes that compile to vector instructions (AVX2 where the CPU
//! has it), each lane with a lone simulation's operations in the same order, so the lanes give
//! a lone simulation's bits and the identification about half the time.

mod candidate;
mod sample;
mod simulate;
mod slot_fit;

use std::f64::consts::PI;

use sts_dataset::Dataset;
use sts_twin_core::axis::{AxisParams, MAX_CMD_DELAY_TICKS};
use sts_twin_core::TICK_S;

use sts_numerics::lm::rms;
use sts_numerics::lsq::{solve, Stats};

use crate::FitError;
use candidate::{Candidate, Slot, MODE, MODE2, RIPPLE_SHAPE, SERVO, SLOTS};
use sample::{Fit, Sample};
use slot_fit::levenberg_marquardt;

/// Which nonlinear effects the axis carries.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct AxisEffects {
    /// Coulomb friction with a Stribeck peak.
    pub friction: bool,
    /// Dahl presliding hysteresis.
    pub hysteresis: bool,
    /// Encoder interpolation error, with a first estimate of its pitch, um.
    pub ripple_pitch_um: Option<f64>,
    /// A second structural mode between slide and TCP.
    pub second_mode: bool,
    /// Where the command's own phasors put a mode inside the band (frequency Hz, damping
    /// ratio), one more start of the second mode's search: its grid's starts a factor of two
    /// apart miss a lightly damped mode between the test's frequencies.
    pub second_mode_start: Option<(f64, f64)>,
}

/// The command delays of the starts' grid, 1 tick to this; a survivor at the top steps on
/// towards [`MAX_CMD_DELAY_TICKS`]. A late setpoint adds up to 4 ticks to the machine's own
/// delay; a grid that stops short of it bends the servo's gains instead.
const GRID_TOP_DELAY_TICKS: usize = 6;

/// The share of the Coulomb level the sharp split ([`identify`]) gives the Dahl force.
const SHARP_SHARE: f64 = 0.7;
/// The Dahl force's presliding distance in the sharp split, m.
const SHARP_PRESLIDING_M: f64 = 1e-9;

/// The ripple's amplitudes and phase for the candidate's servo, by linear least squares:
/// the interpolation error moves the readings nearly linearly in `a cos(phase)`,
/// `a sin(phase)` and the second harmonic's two parts (the position it is read at differs
/// from the command by nanometres), so four unit-ripple simulations give the regressors.
/// The phase of a ripple over many pitches has a minimum every turn; this lands in the right
/// one, which a local fit from a guessed phase often does not.
fn ripple_linear(c: &Candidate, sample: &Sample, what: Fit) -> Candidate {
    let with = |amp: f64, phase: f64, second: f64| {
        let mut out = *c;
        out.v[Slot::RippleAmp as usize] = amp;
        out.v[Slot::RipplePhase as usize] = phase;
        out.v[Slot::Ripple2 as usize] = second;
        out
    };
    let unit_nm = 10.0;
    let units =
        [(0.0, 0.0, 0.0), (unit_nm, 0.0, 0.0), (unit_nm, PI / 2.0, 0.0), (0.0, 0.0, unit_nm), (0.0, PI / 4.0, unit_nm)];
    let mut runs = sample.residuals_of(&units.map(|(a, ph, a2)| with(a, ph, a2)), what).into_iter();
    let r0 = runs.next().unwrap_or_default();
    let columns: Vec<Vec<f64>> =
        runs.map(|rs| rs.iter().zip(&r0).map(|(r, r0)| (r0 - r) / unit_nm).collect()).collect();
    let b = solve(&[&Stats::from_columns(&columns, &r0)]);
    if b.iter().any(|x| !x.is_finite()) {
        return *c;
    }
    let phase = b[1].atan2(b[0]);
    // The model's second harmonic keeps twice the first's phase: its part along that.
    with(b[0].hypot(b[1]), phase, b[2] * (2.0 * phase).cos() + b[3] * (2.0 * phase).sin())
}

/// The identified axis and how well it reproduces the measurement.
#[derive(Clone, Debug)]
pub struct AxisFit {
    /// The firmware's parameters.
    pub params: AxisParams,
    /// RMS of the encoder reading minus the simulated one, over the fit's samples, nm.
    pub encoder_rms_nm: f64,
    /// RMS of the probe reading minus the simulated TCP, nm.
    pub tcp_rms_nm: f64,
}

/// Identifies the axis with `effects` from `dataset` (8 kHz samples, with encoder and probe).
pub fn identify(dataset: &Dataset, effects: AxisEffects) -> Result<AxisFit, FitError> {
    if (dataset.manifest.sample_rate_hz - 1.0 / TICK_S).abs() > 1e-6 {
        return Err(FitError::AxisSampleRate { sample_rate_hz: dataset.manifest.sample_rate_hz });
    }
    let n = dataset.groups.len();
    if n == 0 {
        return Err(FitError::NoGroups);
    }
    // About a dozen groups over the whole grid for the searches, more for the final fit.
    let coarse = Sample::new(dataset, n.div_ceil(12), 4, 2.0, 0.5);
    let fine = Sample::new(dataset, n.div_ceil(32), 2, 3.0, 1.0);

    let mut base = [0.0; SLOTS];
    let set = |v: &mut [f64; SLOTS], s: Slot, x: f64| v[s as usize] = x;
    set(&mut base, Slot::Tau, 1e-4);
    set(&mut base, Slot::Viscous, 1.0);
    set(&mut base, Slot::Gain, 1.0);
    set(&mut base, Slot::RippleAmp, 10.0);
    set(&mut base, Slot::ModeHz, 100.0);
    set(&mut base, Slot::Zeta, 0.2);
    set(&mut base, Slot::Zeta2, 0.05);
    set(&mut base, Slot::Gain2, 0.1);
    set(&mut base, Slot::Mode2Hz, 200.0);
    set(&mut base, Slot::Coulomb, 0.05);
    set(&mut base, Slot::Static, 0.08);
    set(&mut base, Slot::Stribeck, 1e-3);
    set(&mut base, Slot::Smooth, 1e-5);
    set(&mut base, Slot::DahlForce, 0.05);
    set(&mut base, Slot::DahlStiffness, 1e5);
    set(&mut base, Slot::RipplePitch, effects.ripple_pitch_um.unwrap_or(1.0));
    let ripple = effects.ripple_pitch_um.is_some();

    // Servo and effect from a grid of starts, on the encoder (the probe's mode comes later).
    let mut starts = Vec::new();
    for delay in 1..=GRID_TOP_DELAY_TICKS {
        for bandwidth_hz in [30.0, 55.0, 100.0, 180.0, 300.0] {
            let w: f64 = 2.0 * PI * bandwidth_hz;
            let mut v = base;
            set(&mut v, Slot::Kp, w * w);
            set(&mut v, Slot::Ki, w * w * w / 10.0);
            set(&mut v, Slot::Kd, 1.4 * w);
            starts.push(Candidate { v, delay, effects });
        }
    }
    let (encoder_slots, probe_slots) = starts[0].effect_slots();
    // Servo and effect together: the servo alone, fitted first, bends to the effect's part of
    // the encoder error and ends in another minimum (kp twice the true one on a weak friction).
    let servo_and_effect: Vec<Slot> = SERVO.iter().chain(&encoder_slots).copied().collect();
    let free: Vec<Slot> =
        if ripple { servo_and_effect.iter().chain(&RIPPLE_SHAPE).copied().collect() } else { servo_and_effect.clone() };
    // Successive halving: every start a few steps, the best few further, the best to the end.
    // Most starts stall in a minimum of their own or crawl along a valley of the servo's
    // nearly interchangeable gains; the start in the right valley is among the best early.
    let mut pool: Vec<(Candidate, f64)> = starts
        .iter()
        .map(|&start| {
            // The ripple shows in the reading where the loop cannot follow it (fast groups):
            // its phase and amplitudes for the start's servo, then both.
            let start = if ripple { ripple_linear(&start, &coarse, Fit::Encoder) } else { start };
            levenberg_marquardt(start, &free, &coarse, Fit::Encoder, 12)
        })
        .collect();
    // The ripple's encoder fit has minima of nearly equal depth (the servo's gains traded
    // against the ripple's phase); the probe tells them apart, so two go on to the mode.
    let survivors = if ripple { 2 } else { 1 };
    for (keep, iterations) in [(3, 30), (survivors, 100)] {
        // Stable sort: the first of equals (the grid's order) is kept.
        pool.sort_by(|a, b| a.1.total_cmp(&b.1));
        pool.truncate(keep);
        pool =
            pool.into_iter().map(|(c, _)| levenberg_marquardt(c, &free, &coarse, Fit::Encoder, iterations)).collect();
    }
    // A late setpoint (a trajectory or command path some ticks behind) puts the whole
    // response later than the grid's top delay: from a survivor there, the delay steps up
    // while the encoder fits better, as far as the firmware takes.
    for entry in pool.iter_mut().filter(|(c, _)| c.delay == GRID_TOP_DELAY_TICKS) {
        while entry.0.delay < usize::from(MAX_CMD_DELAY_TICKS) {
            let mut later = entry.0;
            later.delay += 1;
            let fitted = levenberg_marquardt(later, &free, &coarse, Fit::Encoder, 30);
            if fitted.1 >= entry.1 {
                break;
            }
            *entry = fitted;
        }
    }
    if effects.friction {
        // The Stribeck velocity from a grid too, from the best servo: a local fit from one
        // guess can trade the Stribeck peak for a friction that rises with velocity (static
        // below Coulomb, Stribeck velocity 18x the true one on a suite draw), which fits
        // the encoder almost as well and the fast groups' probe reading 2x worse.
        let best = *pool.first().ok_or(FitError::NoStart)?;
        let restarts = [3e-5, 1e-4, 3e-4, 3e-3].map(|stribeck_mps| {
            let mut c = best.0;
            let (coulomb, stat) = (c.v[Slot::Coulomb as usize], c.v[Slot::Static as usize]);
            if stat < coulomb {
                // A friction rising with velocity: its low-speed level is the static one.
                c.v[Slot::Coulomb as usize] = 0.6 * stat;
            } else {
                c.v[Slot::Static as usize] = stat.max(1.5 * coulomb);
            }
            c.v[Slot::Stribeck as usize] = stribeck_mps;
            levenberg_marquardt(c, &free, &coarse, Fit::Encoder, 45)
        });
        // The first of equals is kept: the grid's best wins a tie.
        pool = vec![std::iter::once(best).chain(restarts).min_by(|a, b| a.1.total_cmp(&b.1)).unwrap_or(best)];
    }

    // The mode (and the ripple) on the probe, from a grid of frequencies.
    let mut tcp_free: Vec<Slot> = MODE.to_vec();
    tcp_free.extend(&probe_slots);
    let mut mode_best: Option<(Candidate, f64)> = None;
    for &(best, _) in &pool {
        for mode_hz in [40.0, 90.0, 200.0, 500.0] {
            let mut c = best;
            c.v[Slot::ModeHz as usize] = mode_hz;
            let (mut m, _) = levenberg_marquardt(c, &MODE, &coarse, Fit::Tcp, 15);
            if ripple {
                // On the probe, where the slow groups carry the ripple whole.
                m = ripple_linear(&m, &coarse, Fit::Tcp);
            }
            let fitted = levenberg_marquardt(m, &tcp_free, &coarse, Fit::Tcp, 20);
            if mode_best.as_ref().is_none_or(|b| fitted.1 < b.1) {
                mode_best = Some(fitted);
            }
        }
    }
    let (mut c, mut tcp_rms) = mode_best.ok_or(FitError::NoModeStart)?;

    if effects.second_mode {
        // The second mode from a grid of frequencies too, on what the first leaves on the
        // probe, then both modes together: the first alone settles between the two.
        let one_mode = c;
        let grid = [15.0, 30.0, 60.0, 120.0, 200.0, 330.0, 550.0].map(|hz| (hz, None));
        for (mode2_hz, zeta2) in grid.into_iter().chain(effects.second_mode_start.map(|(hz, zeta)| (hz, Some(zeta)))) {
            let mut start = one_mode;
            start.v[Slot::Mode2Hz as usize] = mode2_hz;
            if let Some(zeta) = zeta2 {
                start.v[Slot::Zeta2 as usize] = zeta;
            }
            let (m, _) = levenberg_marquardt(start, &MODE2, &coarse, Fit::Tcp, 15);
            let both: Vec<Slot> = MODE.iter().chain(&MODE2).chain(&probe_slots).copied().collect();
            let fitted = levenberg_marquardt(m, &both, &coarse, Fit::Tcp, 20);
            // A tie keeps the earlier: on an axis with one mode the second stays small.
            if fitted.1 < tcp_rms {
                (c, tcp_rms) = fitted;
            }
        }
    }

    // Everything on both readings.
    let mut all: Vec<Slot> = SERVO.iter().chain(&MODE).copied().collect();
    if effects.second_mode {
        all.extend(MODE2);
    }
    all.extend(encoder_slots.iter().chain(&probe_slots));
    let (mut c, cost) = levenberg_marquardt(c, &all, &fine, Fit::Both, 30);
    if effects.friction && effects.hysteresis {
        // A sharp Coulomb step, sharper than the friction law's smoothed sign, is carried by
        // the Dahl force with a presliding distance of a nanometre beside it. The fit reaches
        // that split from some starts and from others leaves the Dahl force unused or
        // wandering off into a spring of a metre's presliding: once more from the split, the
        // lower cost kept (BENCHMARKS.md, "Friction, hysteresis and ripple at low speed").
        let mut split = c;
        let (coulomb, stat) = (c.get(Slot::Coulomb), c.get(Slot::Static));
        split.set_within(Slot::DahlForce, SHARP_SHARE * coulomb);
        split.set_within(Slot::DahlStiffness, SHARP_SHARE * coulomb / SHARP_PRESLIDING_M);
        split.set_within(Slot::Coulomb, (1.0 - SHARP_SHARE) * coulomb);
        split.set_within(Slot::Static, stat - SHARP_SHARE * coulomb);
        let split = levenberg_marquardt(split, &all, &fine, Fit::Both, 30);
        if split.1 < cost {
            c = split.0;
        }
    }
    // Reported over the whole of the fine sample's groups.
    let whole = Sample::new(dataset, n.div_ceil(32), 2, f64::INFINITY, f64::INFINITY);
    let encoder_rms_nm = rms(&whole.residuals(&c, Fit::Encoder)) * 1e3;
    let tcp_rms_nm = rms(&whole.residuals(&c, Fit::Tcp)) * 1e3;
    let params = c.params();
    params.check().map_err(|error| FitError::AxisUnusable { error, params: Box::new(params) })?;
    Ok(AxisFit { params, encoder_rms_nm, tcp_rms_nm })
}

#[cfg(test)]
mod tests {
    use super::simulate::discretise;
    use super::*;
    use sts_dataset::{GroupData, GroupInfo, Manifest};
    use sts_twin_core::SERVO_RATE_HZ;

    /// Two groups of a sine command at the servo rate (readings zero: the residuals are then
    /// minus the simulated readings).
    fn dataset() -> Dataset {
        let groups: Vec<GroupData> = [(10.0, 3.0), (40.0, 8.0)]
            .iter()
            .map(|&(freq_hz, amp_um)| {
                let mut g = GroupData::with_len(6000);
                for (k, z) in g.z_cmd_um.iter_mut().enumerate() {
                    *z = amp_um * (2.0 * PI * freq_hz * k as f64 * TICK_S).sin();
                }
                g
            })
            .collect();
        let info = |i: usize, freq_hz: f64| GroupInfo::new(&format!("g{i}.csv"), freq_hz, 1.0, 0.0);
        Dataset { manifest: Manifest::new(f64::from(SERVO_RATE_HZ), "", vec![info(0, 10.0), info(1, 40.0)]), groups }
    }

    /// Five axes with friction, hysteresis, ripple and a second mode, each a little different.
    fn candidates() -> Vec<Candidate> {
        let effects = AxisEffects {
            friction: true,
            hysteresis: true,
            ripple_pitch_um: Some(4.0),
            second_mode: true,
            second_mode_start: None,
        };
        (0..5)
            .map(|i| {
                let w = 2.0 * PI * (60.0 + 25.0 * i as f64);
                let mut v = [0.0; SLOTS];
                for (slot, x) in [
                    (Slot::Kp, w * w),
                    (Slot::Ki, w * w * w / 10.0),
                    (Slot::Kd, 1.4 * w),
                    (Slot::Vff, 5.0),
                    (Slot::Aff, 0.1),
                    (Slot::Viscous, 2.0),
                    (Slot::Tau, 1e-4),
                    (Slot::ModeHz, 120.0 + 10.0 * i as f64),
                    (Slot::Zeta, 0.1),
                    (Slot::Gain, 0.5),
                    (Slot::Coulomb, 0.05 * (1.0 + i as f64)),
                    (Slot::Static, 0.09),
                    (Slot::Stribeck, 1e-4),
                    (Slot::Smooth, 1e-5),
                    (Slot::DahlForce, 0.04),
                    (Slot::DahlStiffness, 1e5),
                    (Slot::RippleAmp, 20.0),
                    (Slot::RipplePhase, 0.3 * i as f64),
                    (Slot::Ripple2, 5.0),
                    (Slot::RipplePitch, 4.0),
                    (Slot::Mode2Hz, 210.0 - 15.0 * i as f64),
                    (Slot::Zeta2, 0.04),
                    (Slot::Gain2, 0.3),
                ] {
                    v[slot as usize] = x;
                }
                Candidate { v, delay: 2, effects }
            })
            .collect()
    }

    #[test]
    fn lanes_and_instruction_sets_give_the_lone_simulations_bits() {
        let data = dataset();
        let sample = Sample::new(&data, 1, 3, 4.0, 0.3);
        let cs = candidates();
        let together = sample.residuals_of(&cs, Fit::Both);
        for (c, lanes) in cs.iter().zip(&together) {
            let discrete = discretise(c);
            // One at a time, without vector instructions beyond the baseline.
            let alone: Vec<f64> = (0..sample.groups.len())
                .flat_map(|g| {
                    let lone = (std::slice::from_ref(c), std::slice::from_ref(&discrete));
                    sample.group_residuals_generic(lone, g, Fit::Both)
                })
                .flatten()
                .collect();
            assert!(alone.iter().any(|r| *r != 0.0));
            assert_eq!(lanes.len(), alone.len());
            for (a, b) in lanes.iter().zip(&alone) {
                assert_eq!(a.to_bits(), b.to_bits());
            }
        }
    }
}
