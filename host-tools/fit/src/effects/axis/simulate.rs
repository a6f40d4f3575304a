//! The whole axis simulated from the command, several candidates side by side: the hot loop of
//! the identification.

use std::f64::consts::PI;

use sts_twin_core::axis::discretise::{zoh, Continuous, STATES};
use sts_twin_core::TICK_S;

use super::candidate::{Candidate, Slot};

/// Implicitness of the friction step, as in the firmware.
const THETA: f64 = 0.5;

/// The transition and input matrices of the tick (`phi`, `gamma` of [`zoh`]), and the second
/// mode's rows of both (zero without one).
pub(super) type Discrete = ([[f64; STATES]; STATES], [[f64; 2]; STATES], SecondMode);

/// The second mode's rows of `phi` over `[x, v, f, q2, q2']` and of `gamma`.
pub(super) type SecondMode = ([[f64; STATES]; 2], [[f64; 2]; 2]);

/// A candidate's linear part over one tick.
pub(super) fn discretise(c: &Candidate) -> Discrete {
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
/// simulation in the same order: the same bits as one at a time. Eight lanes: two AVX2
/// vectors, whose chains of operations overlap where one vector's would wait.
pub(super) const LANES: usize = 8;

/// Candidates simulated together, with their linear parts.
pub(super) type Chunk<'a> = (&'a [Candidate], &'a [Discrete]);

/// One `f64` per lane.
pub(super) type Lanes<const N: usize> = [f64; N];

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
pub(super) fn simulate<const N: usize>(
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
