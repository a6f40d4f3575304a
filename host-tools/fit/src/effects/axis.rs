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

use std::f64::consts::PI;

use rayon::prelude::*;
use sts_dataset::Dataset;
use sts_twin_core::axis::discretise::{zoh, Continuous, STATES};
use sts_twin_core::axis::{AxisParams, Friction, Hysteresis, Ripple, StructuralMode, MAX_CMD_DELAY_TICKS};

use sts_numerics::lm::{self, rms, Settings};
use sts_numerics::lsq::{solve, Stats};

use crate::FitError;
use sts_twin_core::{SERVO_RATE_HZ, TICK_S};

/// Servo tick, s (the dataset's rate is checked to be 8 kHz by the caller).
/// Implicitness of the friction step, as in the firmware.
const THETA: f64 = 0.5;

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

/// Parameter slots of the fit. Positive quantities are fitted on a log scale, signed ones
/// additively on a typical scale.
#[derive(Clone, Copy)]
enum Slot {
    Kp,
    Ki,
    Kd,
    Vff,
    Aff,
    Viscous,
    Tau,
    ModeHz,
    Zeta,
    Gain,
    Coulomb,
    Static,
    Stribeck,
    Smooth,
    DahlForce,
    DahlStiffness,
    RippleAmp,
    RipplePhase,
    Ripple2,
    RipplePitch,
    Mode2Hz,
    Zeta2,
    Gain2,
}
const SLOTS: usize = 23;

impl Slot {
    /// The range the firmware accepts (`AxisParams::check`), kept inside by the fit.
    fn bounds(self) -> (f64, f64) {
        match self {
            Slot::Kp => (1.0, 1e9),
            Slot::Ki => (1e-6, 1e12),
            Slot::Kd => (1e-6, 1e6),
            Slot::Vff => (-1e6, 1e6),
            Slot::Aff => (-10.0, 10.0),
            Slot::Viscous => (1e-6, 1e6),
            Slot::Tau => (1e-6, 0.1),
            Slot::ModeHz | Slot::Mode2Hz => (1.0, 3000.0),
            Slot::Zeta | Slot::Zeta2 => (0.001, 10.0),
            Slot::Gain | Slot::Gain2 => (-100.0, 100.0),
            Slot::Coulomb | Slot::Static | Slot::DahlForce => (1e-6, 1e3),
            Slot::Stribeck => (1e-7, 1.0),
            Slot::Smooth => (1e-8, 1.0),
            Slot::DahlStiffness => (1.0, 1e10),
            Slot::RippleAmp | Slot::Ripple2 => (-1e4, 1e4),
            Slot::RipplePhase => (-1e3, 1e3),
            Slot::RipplePitch => (0.01, 1e6),
        }
    }

    /// `Some(scale)` for an additive parameter, `None` for a log-scale one.
    fn additive(self) -> Option<f64> {
        match self {
            Slot::Vff => Some(10.0),
            Slot::Aff => Some(0.3),
            Slot::Gain | Slot::Gain2 => Some(1.0),
            Slot::RippleAmp | Slot::Ripple2 => Some(20.0),
            Slot::RipplePhase => Some(1.0),
            _ => None,
        }
    }
}

/// The command delays of the starts' grid, 1 tick to this; a survivor at the top steps on
/// towards [`MAX_CMD_DELAY_TICKS`]. A late setpoint adds up to 4 ticks to the machine's own
/// delay; a grid that stops short of it bends the servo's gains instead.
const GRID_TOP_DELAY_TICKS: usize = 6;

/// A candidate axis: the parameter vector and the command delay.
#[derive(Clone, Copy, Debug)]
struct Candidate {
    v: [f64; SLOTS],
    delay: usize,
    effects: AxisEffects,
}

impl Candidate {
    fn get(&self, s: Slot) -> f64 {
        self.v[s as usize]
    }

    /// The firmware's parameters.
    fn params(&self) -> AxisParams {
        let g = |s| self.get(s) as f32;
        let mut p = AxisParams {
            cmd_delay_ticks: self.delay as u8,
            kp_per_s2: g(Slot::Kp),
            ki_per_s3: g(Slot::Ki),
            kd_per_s: g(Slot::Kd),
            vff_per_s: g(Slot::Vff),
            aff: g(Slot::Aff),
            viscous_per_s: g(Slot::Viscous),
            current_tau_s: g(Slot::Tau),
            mode_freq_hz: g(Slot::ModeHz),
            mode_damping: g(Slot::Zeta),
            mode_tcp_gain: g(Slot::Gain),
            friction: None,
            hysteresis: None,
            ripple: None,
            second_mode: None,
        };
        if self.effects.second_mode {
            p.second_mode =
                Some(StructuralMode { freq_hz: g(Slot::Mode2Hz), damping: g(Slot::Zeta2), tcp_gain: g(Slot::Gain2) });
        }
        if self.effects.friction {
            p.friction = Some(Friction {
                coulomb_mps2: g(Slot::Coulomb),
                static_mps2: g(Slot::Static),
                stribeck_mps: g(Slot::Stribeck),
                smooth_mps: g(Slot::Smooth),
            });
        }
        if self.effects.hysteresis {
            p.hysteresis =
                Some(Hysteresis { force_mps2: g(Slot::DahlForce), stiffness_per_s2: g(Slot::DahlStiffness) });
        }
        if self.effects.ripple_pitch_um.is_some() {
            // Negative amplitude: the same sine half a turn on.
            let (mut amp, mut phase) = (self.get(Slot::RippleAmp), self.get(Slot::RipplePhase));
            if amp < 0.0 {
                amp = -amp;
                phase += PI;
            }
            p.ripple = Some(Ripple {
                amp_nm: amp as f32,
                harmonic2_nm: g(Slot::Ripple2),
                turns_per_nm: (4_294_967_296.0 / (self.get(Slot::RipplePitch) * 1000.0)).round() as u32,
                phase_turns: ((phase / (2.0 * PI)).rem_euclid(1.0) * 4_294_967_296.0) as u64 as u32,
            });
        }
        p
    }

    /// The slots of the effects that show in the encoder reading (friction and hysteresis
    /// move the slide against the loop) and those fitted on the probe (the loop follows
    /// the encoder's error, so at low speed it moves the slide, not the reading; the start
    /// search adds the ripple's shape on the encoder too, where fast groups show it).
    fn effect_slots(&self) -> (Vec<Slot>, Vec<Slot>) {
        let mut encoder = Vec::new();
        if self.effects.friction {
            encoder.extend([Slot::Coulomb, Slot::Static, Slot::Stribeck, Slot::Smooth]);
        }
        if self.effects.hysteresis {
            encoder.extend([Slot::DahlForce, Slot::DahlStiffness]);
        }
        let probe = if self.effects.ripple_pitch_um.is_some() {
            vec![Slot::RippleAmp, Slot::RipplePhase, Slot::Ripple2, Slot::RipplePitch]
        } else {
            Vec::new()
        };
        (encoder, probe)
    }
}

const SERVO: [Slot; 7] = [Slot::Kp, Slot::Ki, Slot::Kd, Slot::Vff, Slot::Aff, Slot::Viscous, Slot::Tau];
const MODE: [Slot; 3] = [Slot::ModeHz, Slot::Zeta, Slot::Gain];
const MODE2: [Slot; 3] = [Slot::Mode2Hz, Slot::Zeta2, Slot::Gain2];
/// The ripple's amplitudes and phase (its pitch comes from a search, refined last).
const RIPPLE_SHAPE: [Slot; 3] = [Slot::RippleAmp, Slot::RipplePhase, Slot::Ripple2];

/// The transition and input matrices of the tick (`phi`, `gamma` of [`zoh`]), and the second
/// mode's rows of both (zero without one).
type Discrete = ([[f64; STATES]; STATES], [[f64; 2]; STATES], SecondMode);

/// The second mode's rows of `phi` over `[x, v, f, q2, q2']` and of `gamma`.
type SecondMode = ([[f64; STATES]; 2], [[f64; 2]; 2]);

/// A candidate's linear part over one tick.
fn discretise(c: &Candidate) -> Discrete {
    let continuous = Continuous {
        viscous_per_s: c.get(Slot::Viscous),
        current_tau_s: c.get(Slot::Tau),
        mode_rad_per_s: 2.0 * PI * c.get(Slot::ModeHz),
        mode_damping: c.get(Slot::Zeta),
        mode_tcp_gain: c.get(Slot::Gain),
    };
    let (phi, gamma) = zoh(&continuous, TICK_S);
    let mut second: SecondMode = ([[0.0; STATES]; 2], [[0.0; 2]; 2]);
    if c.effects.second_mode {
        // The modes do not act back on the slide: the second's rows are the first's with
        // the second in its place (as the firmware derives them).
        let (phi2, gamma2) = zoh(
            &Continuous {
                mode_rad_per_s: 2.0 * PI * c.get(Slot::Mode2Hz),
                mode_damping: c.get(Slot::Zeta2),
                mode_tcp_gain: c.get(Slot::Gain2),
                ..continuous
            },
            TICK_S,
        );
        second = ([phi2[3], phi2[4]], [gamma2[3], gamma2[4]]);
    }
    (phi, gamma, second)
}

/// Candidates simulated side by side over one command. The axis's recursion is one chain
/// of dependent operations per tick (divisions among them), so a lone simulation waits on
/// latencies; the lanes are written as loops over the lanes of each step, without branches,
/// which the compiler turns into vector instructions. Each lane does the operations of a lone
/// simulation in the same order: the same bits as one at a time.
const LANES: usize = 4;

/// Candidates simulated together, with their linear parts.
type Chunk<'a> = (&'a [Candidate], &'a [Discrete]);

/// One `f64` per lane.
type Lanes<const N: usize> = [f64; N];

/// Lane-wise `f(a[l])`.
#[inline(always)]
fn map<const N: usize>(a: &Lanes<N>, f: impl Fn(f64) -> f64) -> Lanes<N> {
    let mut out = [0.0; N];
    for l in 0..N {
        out[l] = f(a[l]);
    }
    out
}

/// Lane-wise `f(a[l], b[l])`.
#[inline(always)]
fn zip<const N: usize>(a: &Lanes<N>, b: &Lanes<N>, f: impl Fn(f64, f64) -> f64) -> Lanes<N> {
    let mut out = [0.0; N];
    for l in 0..N {
        out[l] = f(a[l], b[l]);
    }
    out
}

/// The whole axis over a command (um), for each of `lanes` (candidates with the same command
/// delay and effects) with its linear part `discrete`: `emit(k, encoder, tcp)` with each
/// lane's encoder reading and TCP at tick `k`, um, for every tick of `ticks` (from the
/// command's start, where the slide rests).
#[inline(always)]
fn simulate<const N: usize>(
    lanes: [&Candidate; N],
    discrete: [&Discrete; N],
    cmd_um: &[f64],
    ticks: std::ops::Range<usize>,
    mut emit: impl FnMut(usize, &Lanes<N>, &Lanes<N>),
) {
    let Some(first) = lanes.first() else { return };
    let (delay, effects) = (first.delay, first.effects);
    debug_assert!(lanes.iter().all(|c| c.delay == delay && c.effects == effects));
    let per_lane = |f: &dyn Fn(&Candidate) -> f64| -> Lanes<N> { std::array::from_fn(|l| f(lanes[l])) };
    let kp = per_lane(&|c| c.get(Slot::Kp));
    let ki_t = per_lane(&|c| c.get(Slot::Ki) * TICK_S);
    let kd_t = per_lane(&|c| c.get(Slot::Kd) / TICK_S);
    let vff_t = per_lane(&|c| c.get(Slot::Vff) / TICK_S);
    let aff_t2 = per_lane(&|c| c.get(Slot::Aff) / (TICK_S * TICK_S));
    let (fc, fs) = (per_lane(&|c| c.get(Slot::Coulomb)), per_lane(&|c| c.get(Slot::Static)));
    let (vs, sm) = (per_lane(&|c| c.get(Slot::Stribeck)), per_lane(&|c| c.get(Slot::Smooth)));
    let (hf, hs) = (per_lane(&|c| c.get(Slot::DahlForce)), per_lane(&|c| c.get(Slot::DahlStiffness)));
    let ra = per_lane(&|c| c.get(Slot::RippleAmp) * 1e-9);
    let rph = per_lane(&|c| c.get(Slot::RipplePhase));
    let r2 = per_lane(&|c| c.get(Slot::Ripple2) * 1e-9);
    let pitch_m = per_lane(&|c| c.get(Slot::RipplePitch) * 1e-6);
    // The matrices lane-minor, so that each of their entries is one vector.
    let phi: [[Lanes<N>; STATES]; STATES] =
        std::array::from_fn(|i| std::array::from_fn(|j| std::array::from_fn(|l| discrete[l].0[i][j])));
    let gamma: [[Lanes<N>; 2]; STATES] =
        std::array::from_fn(|i| std::array::from_fn(|j| std::array::from_fn(|l| discrete[l].1[i][j])));
    let phi2: [[Lanes<N>; STATES]; 2] =
        std::array::from_fn(|i| std::array::from_fn(|j| std::array::from_fn(|l| discrete[l].2 .0[i][j])));
    let gamma2: [[Lanes<N>; 2]; 2] =
        std::array::from_fn(|i| std::array::from_fn(|j| std::array::from_fn(|l| discrete[l].2 .1[i][j])));
    let second_mode = effects.second_mode;
    // The second mode's displacement and rate.
    let mut q2 = [[0.0f64; N]; 2];
    let ripple = effects.ripple_pitch_um.is_some();
    let mut s = [[0.0f64; N]; STATES];
    let (mut integral, mut e_prev, mut u_prev, mut dahl) = ([0.0; N], [0.0; N], [0.0; N], [0.0; N]);
    // Relative to the first command, where the slide rests at the start.
    let r0 = cmd_um.first().copied().unwrap_or(0.0) * 1e-6;
    let mut r_prev = [0.0f64; 2];
    for k in 0..ticks.end.min(cmd_um.len()) {
        let mut reading = s[0];
        if ripple {
            for l in 0..N {
                let theta = 2.0 * PI * (s[0][l] + r0) / pitch_m[l] + rph[l];
                // The vectorised sine: libm's scalar one would dominate a three-effect fit.
                let (sin, cos) = sts_symreg::fastmath::sin_cos(theta);
                reading[l] += ra[l] * sin + r2[l] * (2.0 * sin * cos);
            }
        }
        if k >= ticks.start {
            let enc = map(&reading, |x| (x + r0) * 1e6);
            let tcp = if second_mode {
                let modal = zip(&s[3], &q2[0], |m, m2| m + m2);
                zip(&s[0], &modal, |x, m| (x + m + r0) * 1e6)
            } else {
                zip(&s[0], &s[3], |x, m| (x + m + r0) * 1e6)
            };
            emit(k, &enc, &tcp);
        }
        let r = if k >= delay { cmd_um[k - delay] * 1e-6 - r0 } else { 0.0 };
        let dr = r - r_prev[0];
        let ddr = dr - (r_prev[0] - r_prev[1]);
        r_prev = [r, r_prev[0]];
        let mut u = [0.0; N];
        for l in 0..N {
            let e = r - reading[l];
            integral[l] += ki_t[l] * e;
            u[l] = kp[l] * e + integral[l] + kd_t[l] * (e - e_prev[l]) + vff_t[l] * dr + aff_t2[l] * ddr;
            e_prev[l] = e;
        }
        let mut free = [[0.0; N]; STATES];
        for i in 0..STATES {
            for l in 0..N {
                let mut acc = gamma[i][0][l] * u_prev[l];
                for j in 0..STATES {
                    acc += phi[i][j][l] * s[j][l];
                }
                free[i][l] = acc;
            }
        }
        // The second mode over the tick, before its inputs are overwritten (its force term is
        // added below, with the first mode's).
        let mut free2 = [[0.0; N]; 2];
        if second_mode {
            for i in 0..2 {
                for l in 0..N {
                    let own = [s[0][l], s[1][l], s[2][l], q2[0][l], q2[1][l]];
                    let mut acc = gamma2[i][0][l] * u_prev[l];
                    for j in 0..STATES {
                        acc += phi2[i][j][l] * own[j];
                    }
                    free2[i][l] = acc;
                }
            }
        }
        u_prev = u;
        let mut force = map(&dahl, |d| -d);
        if effects.friction {
            let v = s[1];
            let z = zip(&v, &vs, |v, vs| v / vs);
            // The firmware's table (linear interpolation of exp(-x), 0 from x = 16 on).
            let ex = map(&z, |z| f64::from(sts_twin_core::axis::math::exp_neg((z * z) as f32)));
            let y = zip(&v, &sm, |v, sm| v / sm);
            let mut th = [0.0; N];
            let mut th_slope = [0.0; N];
            for l in 0..N {
                let y = y[l];
                // The firmware's smoothed sign (a Pade form of tanh, saturating at |y| = 3),
                // both sides computed and one kept: no branch.
                let pade = y * (27.0 + y * y) / (27.0 + 9.0 * y * y);
                let pade_slope = ((9.0 - y * y) / (9.0 + 3.0 * y * y)).powi(2);
                let saturated = y.abs() >= 3.0;
                th[l] = if saturated { y.signum() } else { pade };
                th_slope[l] = if saturated { 0.0 } else { pade_slope };
            }
            for l in 0..N {
                let (fc, fs, vs, sm, v, z, ex) = (fc[l], fs[l], vs[l], sm[l], v[l], z[l], ex[l]);
                let level = fc + (fs - fc) * ex;
                let f0 = -level * th[l];
                let slope = -((fs - fc) * ex * (-2.0 * z / vs) * th[l] + level * th_slope[l] / sm);
                let g = gamma[1][1][l];
                let v_next = (free[1][l] + g * (f0 - slope * THETA * v)) / (1.0 - g * slope * THETA);
                force[l] += f0 + slope * THETA * (v_next - v);
            }
        }
        let x_before = s[0];
        for i in 0..STATES {
            for l in 0..N {
                s[i][l] = free[i][l] + gamma[i][1][l] * force[l];
            }
        }
        if second_mode {
            for i in 0..2 {
                for l in 0..N {
                    q2[i][l] = free2[i][l] + gamma2[i][1][l] * force[l];
                }
            }
        }
        if effects.hysteresis {
            for l in 0..N {
                let moved = s[0][l] - x_before[l];
                dahl[l] += hs[l] * moved * (1.0 - dahl[l] / hf[l] * moved.signum());
                dahl[l] = dahl[l].clamp(-hf[l], hf[l]);
            }
        }
    }
}

/// What the fit compares.
#[derive(Clone, Copy, PartialEq)]
enum Fit {
    Encoder,
    Tcp,
    Both,
}

/// Groups and samples the fit reads: in each of `groups`, every `stride`-th sample of a
/// window from the group's 1/12th on (the start's transient left out), the window lasting
/// `periods` of the command or `min_s`, whichever is longer, or to the group's end. In a
/// steady sine every period repeats the last, so a few of them carry what the whole group
/// does; the axis is simulated only to the window's end.
struct Sample<'a> {
    dataset: &'a Dataset,
    groups: Vec<usize>,
    stride: usize,
    /// Each of `groups`' first and end sample.
    windows: Vec<(usize, usize)>,
}

impl<'a> Sample<'a> {
    fn new(dataset: &'a Dataset, group_step: usize, stride: usize, periods: f64, min_s: f64) -> Self {
        let groups: Vec<usize> = (0..dataset.groups.len()).step_by(group_step.max(1)).collect();
        let windows = groups
            .iter()
            .map(|&gi| {
                let len = dataset.groups[gi].len();
                let freq_hz = dataset.manifest.groups[gi].freq_hz;
                let window_s = if freq_hz > 0.0 { (periods / freq_hz).max(min_s) } else { f64::INFINITY };
                let first = len / 12;
                let end = (first as f64 + window_s * f64::from(SERVO_RATE_HZ)).min(len as f64) as usize;
                (first, end.max(first))
            })
            .collect();
        Sample { dataset, groups, stride, windows }
    }

    fn residuals(&self, c: &Candidate, what: Fit) -> Vec<f64> {
        self.residuals_of(std::slice::from_ref(c), what).pop().unwrap_or_default()
    }

    /// [`Self::residuals`] of each candidate (all with the same command delay and effects),
    /// simulated [`LANES`] at a time, the groups in parallel.
    fn residuals_of(&self, cs: &[Candidate], what: Fit) -> Vec<Vec<f64>> {
        let discrete: Vec<Discrete> = cs.iter().map(discretise).collect();
        let tasks: Vec<(usize, usize)> =
            (0..cs.len()).step_by(LANES).flat_map(|c0| (0..self.groups.len()).map(move |g| (c0, g))).collect();
        let parts: Vec<Vec<Vec<f64>>> = tasks
            .par_iter()
            .map(|&(c0, g)| {
                let c1 = (c0 + LANES).min(cs.len());
                self.group_residuals((&cs[c0..c1], &discrete[c0..c1]), g, what)
            })
            .collect();
        let mut out: Vec<Vec<f64>> = vec![Vec::new(); cs.len()];
        for (&(c0, _), part) in tasks.iter().zip(parts) {
            for (lane, r) in part.into_iter().enumerate() {
                out[c0 + lane].extend(r);
            }
        }
        out
    }

    /// The residuals of up to [`LANES`] candidates (with their linear parts) on the sample's
    /// `index`-th group.
    fn group_residuals(&self, chunk: Chunk, index: usize, what: Fit) -> Vec<Vec<f64>> {
        #[cfg(target_arch = "x86_64")]
        {
            if std::arch::is_x86_feature_detected!("avx2") {
                // SAFETY: the CPU supports AVX2 (checked just above).
                return unsafe { self.group_residuals_avx2(chunk, index, what) };
            }
        }
        self.group_residuals_generic(chunk, index, what)
    }

    /// [`Self::group_residuals`] compiled for AVX2 (4 lanes a vector instead of SSE2's 2; no
    /// FMA, and Rust never contracts `a * b + c`: the same bits).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn group_residuals_avx2(&self, chunk: Chunk, index: usize, what: Fit) -> Vec<Vec<f64>> {
        self.group_residuals_generic(chunk, index, what)
    }

    /// The body of [`Self::group_residuals`], for every instruction set.
    #[inline(always)]
    fn group_residuals_generic(&self, chunk: Chunk, index: usize, what: Fit) -> Vec<Vec<f64>> {
        #[inline(always)]
        fn lanes<const N: usize>(sample: &Sample, (cs, discrete): Chunk, index: usize, what: Fit) -> Vec<Vec<f64>> {
            let g = &sample.dataset.groups[sample.groups[index]];
            let (first, end) = sample.windows[index];
            let mut out = vec![Vec::new(); N];
            let mut next = first;
            simulate::<N>(
                std::array::from_fn(|l| &cs[l]),
                std::array::from_fn(|l| &discrete[l]),
                &g.z_cmd_um,
                first..end,
                |k, enc, tcp| {
                    if k != next {
                        return;
                    }
                    next += sample.stride;
                    for (l, r) in out.iter_mut().enumerate() {
                        if what != Fit::Tcp {
                            r.push(g.z_enc_um[k] - enc[l]);
                        }
                        if what != Fit::Encoder {
                            r.push(g.z_tcp_um[k] - tcp[l]);
                        }
                    }
                },
            );
            out
        }
        match chunk.0.len() {
            1 => lanes::<1>(self, chunk, index, what),
            2 => lanes::<2>(self, chunk, index, what),
            3 => lanes::<3>(self, chunk, index, what),
            _ => lanes::<LANES>(self, chunk, index, what),
        }
    }
}

/// The damping of the axis's fits: from a moderate start, never below 1e-7 (the servo's gains
/// are nearly interchangeable along a valley, where an undamped step overshoots), stopping where
/// a step gains less than 0.01%.
const AXIS_LM: Settings =
    Settings { iterations: 0, tries: 8, damping_start: 1e-2, damping_min: 1e-7, min_relative_gain: 1e-4 };

/// Levenberg-Marquardt ([`sts_numerics::lm`]) over `free` slots, at most `iterations`.
fn levenberg_marquardt(
    start: Candidate,
    free: &[Slot],
    sample: &Sample,
    what: Fit,
    iterations: usize,
) -> (Candidate, f64) {
    lm::minimize(&mut SlotFit { free, sample, what }, start, &Settings { iterations, ..AXIS_LM })
}

/// The fit of a candidate's `free` slots to the sample's readings: a Jacobian by forward
/// differences (the probes simulated side by side), each slot moved on its own scale and
/// kept within its bounds.
struct SlotFit<'s, 'a> {
    free: &'s [Slot],
    sample: &'s Sample<'a>,
    what: Fit,
}

/// The forward difference's step, in each slot's scale.
const PROBE_STEP: f64 = 1e-5;

impl lm::Problem for SlotFit<'_, '_> {
    type Point = Candidate;

    fn residuals(&mut self, c: &Candidate) -> Option<Vec<f64>> {
        Some(self.sample.residuals(c, self.what))
    }

    fn jacobian(&mut self, c: &Candidate, r: &[f64]) -> Option<Vec<Vec<f64>>> {
        let probes: Vec<Candidate> = self.free.iter().map(|&slot| moved(c, slot, PROBE_STEP)).collect();
        Some(
            self.sample
                .residuals_of(&probes, self.what)
                .into_iter()
                .map(|rs| rs.iter().zip(r).map(|(a, b)| (a - b) / PROBE_STEP).collect())
                .collect(),
        )
    }

    fn moved(&self, c: &Candidate, step: &[f64]) -> Option<Candidate> {
        Some(self.free.iter().zip(step).fold(*c, |trial, (&slot, &s)| moved(&trial, slot, s)))
    }
}

/// `c` with `slot` moved by `step` in its scale (additive, or a factor `exp(step)` of at most
/// `exp(0.7)`), kept within its bounds.
fn moved(c: &Candidate, slot: Slot, step: f64) -> Candidate {
    let mut out = *c;
    let x = &mut out.v[slot as usize];
    match slot.additive() {
        Some(scale) => *x += step * scale,
        None => *x *= step.clamp(-0.7, 0.7).exp(),
    }
    let (lo, hi) = match (slot, c.effects.ripple_pitch_um) {
        // Near the pitch measured from the data: at twice it, the second harmonic alone
        // fits the same ripple.
        (Slot::RipplePitch, Some(pitch_um)) => (pitch_um / 1.05, pitch_um * 1.05),
        _ => slot.bounds(),
    };
    *x = x.clamp(lo, hi);
    out
}

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
    let (c, _) = levenberg_marquardt(c, &all, &fine, Fit::Both, 30);
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
    use super::*;
    use sts_dataset::{GroupData, GroupInfo, Manifest};

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
