//! The coefficients of an activated axis twin and its per-tick state.

use super::discretise::{zoh, Continuous};
use super::{AxisError, AxisParams, MAX_CMD_DELAY_TICKS};
use crate::math::{exp_neg, sin_turns, smooth_sign};

use crate::TICK_S;
/// Implicitness of the friction step (0.5: the force at the tick's mean velocity).
const THETA: f32 = 0.5;
/// A following error beyond this is a diverging (unstable) model: the state is reset, m.
const DIVERGED_M: f32 = 1e-3;
/// Command positions kept (a power of two at least the delay plus the two differences the
/// feedforward takes, so the ring index is a mask).
const HISTORY: usize = 16;
const _: () = assert!(HISTORY >= MAX_CMD_DELAY_TICKS as usize + 3 && HISTORY.is_power_of_two());

/// Single-precision coefficients of an axis twin, computed once when a program is
/// activated (the discretisation runs in f64; on the firmware in software, at low priority).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AxisModel {
    delay: usize,
    // Controller per kg: kp, ki T, kd / T, vff / T, aff / T^2.
    kp: f32,
    ki_t: f32,
    kd_t: f32,
    vff_t: f32,
    aff_t2: f32,
    // Slide rows of the transition (x has a unit diagonal and drives nothing) and the
    // input columns [u, F] of every row.
    p01: f32,
    p02: f32,
    p11: f32,
    p12: f32,
    p22: f32,
    gu: [f32; 3],
    gf: [f32; 3],
    mode: ModeRows,
    // The second mode's (zero and skipped when the axis has one mode).
    second_mode: bool,
    mode2: ModeRows,
    // The effects' coefficients (zero when absent) and which are present: `step` runs one
    // of eight instances without the absent ones' branches.
    effects: u8,
    friction: FrictionCoef,
    /// Dahl stiffness, 1 / limit force, limit force.
    hysteresis: (f32, f32, f32),
    /// First and second harmonic (m), turns per nm, phase.
    ripple: (f32, f32, u32, u32),
}

/// A structural mode's rows of the transition over `[v, f, q, q']` and its input columns
/// `[u, F]`, for `q` and `q'`.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
struct ModeRows {
    rows: [[f32; 4]; 2],
    gu: [f32; 2],
    gf: [f32; 2],
}

impl ModeRows {
    /// Rows 3 and 4 of a discretised axis (`zoh`), whose mode they are.
    fn of(phi: &[[f64; 5]; 5], gamma: &[[f64; 2]; 5]) -> Self {
        let c = |x: f64| x as f32;
        let row = |i: usize| [c(phi[i][1]), c(phi[i][2]), c(phi[i][3]), c(phi[i][4])];
        Self { rows: [row(3), row(4)], gu: [c(gamma[3][0]), c(gamma[4][0])], gf: [c(gamma[3][1]), c(gamma[4][1])] }
    }

    /// The mode's `(q, q')` after the tick from `(q, q')`, the slide's velocity and motor
    /// force before it, last tick's force command and the nonlinear force.
    #[inline(always)]
    fn step(&self, (v, f): (f32, f32), (q, qd): (f32, f32), u_prev: f32, force: f32) -> (f32, f32) {
        let [r, rd] = &self.rows;
        (
            r[0] * v + r[1] * f + r[2] * q + r[3] * qd + self.gu[0] * u_prev + self.gf[0] * force,
            rd[0] * v + rd[1] * f + rd[2] * q + rd[3] * qd + self.gu[1] * u_prev + self.gf[1] * force,
        )
    }
}

const FRICTION: u8 = 1;
const HYSTERESIS: u8 = 2;
const RIPPLE: u8 = 4;

#[derive(Clone, Copy, Debug, PartialEq, Default)]
struct FrictionCoef {
    coulomb: f32,
    stribeck_excess: f32,
    inv_stribeck: f32,
    inv_smooth: f32,
    /// `THETA / v_smooth`.
    inv_smooth_theta: f32,
    /// `-2 THETA (Fs - Fc) / vs`: the Stribeck term's slope factor.
    stribeck_slope_theta: f32,
}

/// The running state of an axis twin, relative to the command so that single precision
/// resolves picometres at any absolute position.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AxisState {
    history: [i32; HISTORY],
    newest: usize,
    primed: bool,
    dr_prev_m: f32,
    /// Delayed command minus slide position, m.
    w: f32,
    /// Slide velocity, m/s; motor force per kg, m/s^2; modal displacement, m, and rate.
    v: f32,
    f: f32,
    q: f32,
    qd: f32,
    /// The second mode's displacement, m, and rate (zero with one mode).
    q2: f32,
    qd2: f32,
    integral: f32,
    e_prev: f32,
    u_prev: f32,
    dahl: f32,
    /// The displacement added to the delayed command last tick (the analogue input's), nm.
    added_prev_nm: i32,
    /// Times the state diverged and was reset.
    pub resets: u32,
}

impl AxisState {
    /// At rest, before the first command.
    pub const INITIAL: Self = Self {
        history: [0; HISTORY],
        newest: 0,
        primed: false,
        dr_prev_m: 0.0,
        w: 0.0,
        v: 0.0,
        f: 0.0,
        q: 0.0,
        qd: 0.0,
        q2: 0.0,
        qd2: 0.0,
        integral: 0.0,
        e_prev: 0.0,
        u_prev: 0.0,
        dahl: 0.0,
        added_prev_nm: 0,
        resets: 0,
    };
}

impl AxisModel {
    /// Checks the parameters and discretises the model.
    pub fn new(params: &AxisParams) -> Result<Self, AxisError> {
        params.check()?;
        let p = params;
        let continuous = Continuous {
            viscous_per_s: p.viscous_per_s as f64,
            current_tau_s: p.current_tau_s as f64,
            mode_rad_per_s: 2.0 * core::f64::consts::PI * p.mode_freq_hz as f64,
            mode_damping: p.mode_damping as f64,
            mode_tcp_gain: p.mode_tcp_gain as f64,
        };
        let (phi, gamma) = zoh(&continuous, TICK_S);
        // The modes do not act back on the slide: the second mode's rows are the mode rows of
        // the same axis discretised with the second mode in the first's place.
        let mode2 = p.second_mode.map_or(ModeRows::default(), |m| {
            let (phi2, gamma2) = zoh(
                &Continuous {
                    mode_rad_per_s: 2.0 * core::f64::consts::PI * m.freq_hz as f64,
                    mode_damping: m.damping as f64,
                    mode_tcp_gain: m.tcp_gain as f64,
                    ..continuous
                },
                TICK_S,
            );
            ModeRows::of(&phi2, &gamma2)
        });
        let c = |x: f64| x as f32;
        let friction = p.friction.map_or(FrictionCoef::default(), |f| FrictionCoef {
            coulomb: f.coulomb_mps2,
            stribeck_excess: f.static_mps2 - f.coulomb_mps2,
            inv_stribeck: 1.0 / f.stribeck_mps,
            inv_smooth: 1.0 / f.smooth_mps,
            inv_smooth_theta: THETA / f.smooth_mps,
            stribeck_slope_theta: -2.0 * THETA * (f.static_mps2 - f.coulomb_mps2) / f.stribeck_mps,
        });
        let effects = if p.friction.is_some() { FRICTION } else { 0 }
            | if p.hysteresis.is_some() { HYSTERESIS } else { 0 }
            | if p.ripple.is_some() { RIPPLE } else { 0 };
        Ok(Self {
            delay: p.cmd_delay_ticks as usize,
            kp: p.kp_per_s2,
            ki_t: c(p.ki_per_s3 as f64 * TICK_S),
            kd_t: c(p.kd_per_s as f64 / TICK_S),
            vff_t: c(p.vff_per_s as f64 / TICK_S),
            aff_t2: c(p.aff as f64 / (TICK_S * TICK_S)),
            p01: c(phi[0][1]),
            p02: c(phi[0][2]),
            p11: c(phi[1][1]),
            p12: c(phi[1][2]),
            p22: c(phi[2][2]),
            gu: [c(gamma[0][0]), c(gamma[1][0]), c(gamma[2][0])],
            gf: [c(gamma[0][1]), c(gamma[1][1]), c(gamma[2][1])],
            mode: ModeRows::of(&phi, &gamma),
            second_mode: p.second_mode.is_some(),
            mode2,
            effects,
            friction,
            hysteresis: p
                .hysteresis
                .map_or((0.0, 0.0, 0.0), |h| (h.stiffness_per_s2, 1.0 / h.force_mps2, h.force_mps2)),
            ripple: p
                .ripple
                .map_or((0.0, 0.0, 0, 0), |r| (r.amp_nm * 1e-9, r.harmonic2_nm * 1e-9, r.turns_per_nm, r.phase_turns)),
        })
    }

    /// Ticks the command is delayed before the servo loop (a correction is not).
    pub fn cmd_delay_ticks(&self) -> u32 {
        self.delay as u32
    }

    /// One servo tick with the command position `cmd_pos_nm`: the axis's dynamic error at
    /// the TCP this tick (TCP minus command, before the tick's motion), picometres. Out of
    /// line: inlined, its register use made the servo tick's other kernel terms dearer.
    #[inline(never)]
    pub fn step(&self, st: &mut AxisState, cmd_pos_nm: i32) -> i32 {
        self.dispatch(st, cmd_pos_nm, 0)
    }

    /// [`AxisModel::step`] with `added_nm` added to the delayed command, as the motion
    /// controller adds its analogue input's motion pulses: the axis under a correction.
    #[inline(never)]
    pub fn step_added(&self, st: &mut AxisState, cmd_pos_nm: i32, added_nm: i32) -> i32 {
        self.dispatch(st, cmd_pos_nm, added_nm)
    }

    /// The step specialised for the effects present (no per-tick tests of absent ones).
    #[inline(always)]
    fn dispatch(&self, st: &mut AxisState, cmd_pos_nm: i32, added_nm: i32) -> i32 {
        // One mode or two: an axis without a second mode runs the step it ran before it.
        if self.second_mode {
            self.dispatch_effects::<true>(st, cmd_pos_nm, added_nm)
        } else {
            self.dispatch_effects::<false>(st, cmd_pos_nm, added_nm)
        }
    }

    #[inline(always)]
    fn dispatch_effects<const M: bool>(&self, st: &mut AxisState, cmd_pos_nm: i32, added_nm: i32) -> i32 {
        match self.effects {
            0 => self.step_with::<false, false, false, M>(st, cmd_pos_nm, added_nm),
            FRICTION => self.step_with::<true, false, false, M>(st, cmd_pos_nm, added_nm),
            HYSTERESIS => self.step_with::<false, true, false, M>(st, cmd_pos_nm, added_nm),
            RIPPLE => self.step_with::<false, false, true, M>(st, cmd_pos_nm, added_nm),
            3 => self.step_with::<true, true, false, M>(st, cmd_pos_nm, added_nm),
            5 => self.step_with::<true, false, true, M>(st, cmd_pos_nm, added_nm),
            6 => self.step_with::<false, true, true, M>(st, cmd_pos_nm, added_nm),
            _ => self.step_with::<true, true, true, M>(st, cmd_pos_nm, added_nm),
        }
    }

    #[inline(always)]
    fn step_with<const F: bool, const H: bool, const R: bool, const M: bool>(
        &self,
        st: &mut AxisState,
        cmd_pos_nm: i32,
        added_nm: i32,
    ) -> i32 {
        if !st.primed {
            st.history = [cmd_pos_nm; HISTORY];
            st.added_prev_nm = added_nm;
            st.primed = true;
        }
        st.newest = (st.newest + 1) & (HISTORY - 1);
        st.history[st.newest] = cmd_pos_nm;
        let r_nm = st.history[(st.newest.wrapping_sub(self.delay)) & (HISTORY - 1)].wrapping_add(added_nm);
        let r_before_nm =
            st.history[(st.newest.wrapping_sub(self.delay + 1)) & (HISTORY - 1)].wrapping_add(st.added_prev_nm);
        st.added_prev_nm = added_nm;
        let dr_m = r_nm.wrapping_sub(r_before_nm) as f32 * 1e-9;
        let ddr_m = dr_m - st.dr_prev_m;
        st.dr_prev_m = dr_m;
        st.w += dr_m;

        // The controller on the encoder reading (with its interpolation error).
        let mut e = st.w;
        if R {
            let (a1, a2, turns_per_nm, phase) = self.ripple;
            let x_nm = r_nm.wrapping_sub((st.w * 1e9) as i32);
            let theta = (x_nm as u32).wrapping_mul(turns_per_nm).wrapping_add(phase);
            e -= a1 * sin_turns(theta) + a2 * sin_turns(theta.wrapping_mul(2));
        }
        st.integral += self.ki_t * e;
        let u = self.kp * e + st.integral + self.kd_t * (e - st.e_prev) + self.vff_t * dr_m + self.aff_t2 * ddr_m;
        st.e_prev = e;
        // TCP - command = (r - command) - (r - x) + q; the first part exact in nanometres.
        let lag_nm = r_nm.wrapping_sub(cmd_pos_nm);
        // The lag is a few ticks of command motion (far below 2 mm); |q - w| < 2 mm (the reset).
        let modal = if M { st.q + st.q2 } else { st.q };
        let out_pm = lag_nm.wrapping_mul(1000).wrapping_add(((modal - st.w) * 1e12) as i32);

        // Over the tick with last tick's force command; friction linearly implicit in the
        // next velocity, hysteresis from last tick's motion.
        let (v, f, u_prev) = (st.v, st.f, st.u_prev);
        let v_free = self.p11 * v + self.p12 * f + self.gu[1] * u_prev;
        let mut force = -st.dahl;
        if F {
            // F(v) = -(Fc + (Fs - Fc) exp(-(v/vs)^2)) s(v / v_smooth), s the smoothed sign;
            // applied as F(v) + F'(v) THETA (v_next - v), solved for v_next.
            let fr = &self.friction;
            let z = v * fr.inv_stribeck;
            let ex = exp_neg(z * z);
            let level = fr.coulomb + fr.stribeck_excess * ex;
            let (sign, sign_slope) = smooth_sign(v * fr.inv_smooth);
            let slope_theta = -(fr.stribeck_slope_theta * ex * z * sign + level * sign_slope * fr.inv_smooth_theta);
            let f0 = -level * sign;
            let g = self.gf[1];
            force += f0 + slope_theta * (v_free + g * f0 - v) / (1.0 - g * slope_theta);
        }
        let step_x = self.p01 * v + self.p02 * f + self.gu[0] * u_prev + self.gf[0] * force;
        (st.q, st.qd) = self.mode.step((v, f), (st.q, st.qd), u_prev, force);
        if M {
            (st.q2, st.qd2) = self.mode2.step((v, f), (st.q2, st.qd2), u_prev, force);
        }
        st.v = v_free + self.gf[1] * force;
        st.f = self.p22 * f + self.gu[2] * u_prev;
        st.w -= step_x;
        st.u_prev = u;
        if H {
            let (stiffness, inv_force, force_max) = self.hysteresis;
            let sign = if step_x > 0.0 {
                1.0
            } else if step_x < 0.0 {
                -1.0
            } else {
                0.0
            };
            let h = st.dahl + stiffness * step_x * (1.0 - st.dahl * inv_force * sign);
            st.dahl = if h > force_max {
                force_max
            } else if h < -force_max {
                -force_max
            } else {
                h
            };
        }
        // NaN compares false, and a non-finite velocity, force or rate reaches the
        // following error or the mode within a tick.
        let excursion = if M { st.w.abs() + st.q.abs() + st.q2.abs() } else { st.w.abs() + st.q.abs() };
        #[allow(clippy::neg_cmp_op_on_partial_ord)] // NaN must fail it too, in one comparison
        if !(excursion < DIVERGED_M) {
            self.reset(st);
        }
        out_pm
    }

    /// Back to rest at the current command (a diverging, unstable model).
    #[cold]
    fn reset(&self, st: &mut AxisState) {
        let resets = st.resets.saturating_add(1);
        let (history, newest, added_prev_nm) = (st.history, st.newest, st.added_prev_nm);
        *st = AxisState { history, newest, added_prev_nm, primed: true, resets, ..AxisState::INITIAL };
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::axis::{default_machine as machine, Friction, Hysteresis, Ripple};

    /// A 40 Hz, 10 um sine command, nm.
    fn command(k: u32) -> i32 {
        (10_000.0 * libm::sin(2.0 * core::f64::consts::PI * 40.0 * k as f64 / 8000.0)) as i32
    }

    fn run_scaled(params: &AxisParams, ticks: u32, scale: i32) -> (heapless::Vec<i64, 16_000>, AxisState) {
        let model = AxisModel::new(params).expect("valid");
        let mut st = AxisState::INITIAL;
        let mut out = heapless::Vec::new();
        for k in 0..ticks {
            out.push(i64::from(model.step(&mut st, scale * command(k)))).unwrap();
        }
        (out, st)
    }

    fn run(params: &AxisParams, ticks: u32) -> (heapless::Vec<i64, 16_000>, AxisState) {
        run_scaled(params, ticks, 1)
    }

    /// What the effect adds to the linear axis's error, picometres.
    fn effect_of(params: &AxisParams, ticks: u32) -> heapless::Vec<i64, 16_000> {
        let (with, st) = run(params, ticks);
        assert_eq!(st.resets, 0);
        let (without, _) = run(&machine(), ticks);
        with.iter().zip(&without).map(|(a, b)| a - b).collect()
    }

    #[test]
    fn the_linear_axis_lags_and_is_linear() {
        let (once, st) = run(&machine(), 8000);
        let (twice, _) = run_scaled(&machine(), 8000, 2);
        assert_eq!(st.resets, 0);
        // A 40 Hz, 10 um sine through a 2-tick delay and the servo: microns of error.
        let peak = once[4000..].iter().map(|x| x.abs()).max().unwrap();
        assert!((300_000..20_000_000).contains(&peak), "peak {peak} pm");
        // Linear: twice the command, twice the error (within the nanometre rounding of the
        // command and single precision).
        for k in 4000..8000 {
            assert!(
                (twice[k] - 2 * once[k]).abs() < 2_000 + peak / 10_000,
                "tick {k}: {} vs 2 x {}",
                twice[k],
                once[k]
            );
        }
    }

    #[test]
    fn friction_deviation_is_periodic_and_mirrored_each_half_period() {
        let params = AxisParams {
            friction: Some(Friction {
                coulomb_mps2: 3.0 / 45.0,
                static_mps2: 4.5 / 45.0,
                stribeck_mps: 2e-4,
                smooth_mps: 1e-5,
            }),
            ..machine()
        };
        let out = effect_of(&params, 16_000);
        // Steady state after 1 s: one period (200 ticks) later the same error within 1 nm.
        for k in 8000..15_800 {
            assert!((out[k] - out[k + 200]).abs() < 1000, "tick {k}: {} vs {}", out[k], out[k + 200]);
        }
        let peak = out[8000..].iter().map(|x| x.abs()).max().unwrap();
        assert!((100_000..5_000_000).contains(&peak), "peak {peak} pm");
        // Friction opposes the motion: half a period later (100 ticks), the deviation is mirrored.
        for k in 8000..8200 {
            assert!((out[k] + out[k + 100]).abs() < peak / 50, "tick {k}: {} vs {}", out[k], out[k + 100]);
        }
    }

    #[test]
    fn hysteresis_and_ripple_deviate_boundedly() {
        for params in [
            AxisParams {
                hysteresis: Some(Hysteresis { force_mps2: 2.5 / 45.0, stiffness_per_s2: 3e6 / 45.0 }),
                ..machine()
            },
            AxisParams {
                ripple: Some(Ripple { amp_nm: 50.0, harmonic2_nm: 8.0, turns_per_nm: 810_000, phase_turns: 1 << 29 }),
                ..machine()
            },
        ] {
            let out = effect_of(&params, 8000);
            let peak = out.iter().map(|x| x.abs()).max().unwrap();
            assert!((10_000..2_000_000).contains(&peak), "peak {peak} pm");
        }
    }

    #[test]
    fn a_second_mode_adds_what_it_would_add_in_the_first_modes_place() {
        use crate::axis::StructuralMode;
        let mode2 = StructuralMode { freq_hz: 210.0, damping: 0.03, tcp_gain: 0.9 };
        let friction =
            Some(Friction { coulomb_mps2: 3.0 / 45.0, static_mps2: 4.5 / 45.0, stribeck_mps: 2e-4, smooth_mps: 1e-5 });
        let base = AxisParams { friction, ..machine() };
        let (one, _) = run(&base, 8000);
        let (two, st) = run(&AxisParams { second_mode: Some(mode2), ..base }, 8000);
        assert_eq!(st.resets, 0);
        // The modes do not act back on the slide: the second one's share is what the same mode
        // adds in the first's place to an axis without a mode.
        let (alone, _) = run(&AxisParams { mode_tcp_gain: 0.0, ..base }, 8000);
        let (instead, _) =
            run(&AxisParams { mode_freq_hz: 210.0, mode_damping: 0.03, mode_tcp_gain: 0.9, ..base }, 8000);
        let share_peak = (4000..8000).map(|k| (two[k] - one[k]).abs()).max().unwrap();
        assert!(share_peak > 50_000, "the second mode shows: {share_peak} pm");
        for k in 4000..8000 {
            let expected = instead[k] - alone[k];
            assert!((two[k] - one[k] - expected).abs() < 200 + share_peak / 1000, "tick {k}");
        }
        // Without a second mode, not a bit changes.
        let (again, _) = run(&AxisParams { second_mode: None, ..base }, 8000);
        assert_eq!(one, again);
        let bad = AxisParams { second_mode: Some(StructuralMode { damping: 0.0, ..mode2 }), ..base };
        assert_eq!(AxisModel::new(&bad), Err(AxisError::OutOfRange("second_mode.damping")));
    }

    #[test]
    fn an_unstable_model_is_reset_not_output() {
        // A derivative gain far beyond what the tick can carry makes the loop diverge.
        let params = AxisParams {
            kd_per_s: 9e5,
            friction: Some(Friction { coulomb_mps2: 0.1, static_mps2: 0.1, stribeck_mps: 1e-4, smooth_mps: 1e-5 }),
            ..machine()
        };
        let (out, st) = run(&params, 8000);
        assert!(st.resets > 0);
        assert!(out.iter().all(|pm| pm.abs() <= 2_100_000_000), "never beyond the divergence limit");
    }

    #[test]
    fn out_of_range_parameters_name_their_field() {
        let bad = AxisParams { current_tau_s: f32::NAN, ..machine() };
        assert_eq!(AxisModel::new(&bad), Err(AxisError::OutOfRange("current_tau_s")));
        let bad = AxisParams {
            friction: Some(Friction { coulomb_mps2: 0.1, static_mps2: 0.1, stribeck_mps: 0.0, smooth_mps: 1e-5 }),
            ..machine()
        };
        assert_eq!(AxisModel::new(&bad), Err(AxisError::OutOfRange("friction.stribeck_mps")));
        let bad = AxisParams { cmd_delay_ticks: MAX_CMD_DELAY_TICKS + 1, ..machine() };
        assert_eq!(AxisModel::new(&bad), Err(AxisError::OutOfRange("cmd_delay_ticks")));
    }
}
