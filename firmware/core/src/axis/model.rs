//! The coefficients of an activated axis twin and its per-tick state.

use super::discretise::{zoh, Continuous};
use super::math::{exp_neg, tanh};
use super::{AxisError, AxisParams, MAX_CMD_DELAY_TICKS};
use crate::synth::sin_q31;

/// Servo tick, s.
const TICK_S: f64 = 1.0 / 8000.0;
/// Implicitness of the friction step (0.5: the force at the tick's mean velocity).
const THETA: f32 = 0.5;
/// A deviation beyond this is a diverging (unstable) model: the state is reset, m.
const DIVERGED_M: f32 = 1e-3;
/// Command positions kept: the delay plus the two differences the feedforward takes.
const HISTORY: usize = MAX_CMD_DELAY_TICKS as usize + 3;

/// Single-precision coefficients of an axis twin, computed once when a program is
/// activated (the discretisation runs in f64; on the firmware in software, some 10^5
/// instructions at low priority).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AxisModel {
    delay: usize,
    // Controller per kg: kp, ki T, kd / T, vff / T, aff / T^2.
    kp: f32,
    ki_t: f32,
    kd_t: f32,
    vff_t: f32,
    aff_t2: f32,
    // Slide rows of the transition (x has a unit diagonal) and their input columns [u, F].
    p01: f32,
    p02: f32,
    p11: f32,
    p12: f32,
    p22: f32,
    gu: [f32; 5],
    gf: [f32; 5],
    // Mode rows: [v, f, q, q'] (the position does not drive them).
    p3: [f32; 4],
    p4: [f32; 4],
    friction: Option<FrictionCoef>,
    hysteresis: Option<(f32, f32)>,
    ripple: Option<(f32, f32, u32, u32)>,
}

#[derive(Clone, Copy, Debug, PartialEq)]
struct FrictionCoef {
    coulomb: f32,
    stribeck_excess: f32,
    inv_stribeck: f32,
    inv_smooth: f32,
}

/// The running state of an axis twin: the linear axis relative to the command and the
/// nonlinear one's deviation from it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AxisState {
    history: [i32; HISTORY],
    newest: usize,
    primed: bool,
    dr_prev_m: f32,
    // Linear axis: command minus position (m), velocity, force per kg, integral, last error,
    // force command of the last tick.
    w: f32,
    v: f32,
    f: f32,
    integral: f32,
    e_prev: f32,
    u_prev: f32,
    // Deviation of the nonlinear axis: x, v, f, q, q', its controller's integral, last
    // error and last force command, and the Dahl force.
    dev: [f32; 5],
    d_integral: f32,
    d_e_prev: f32,
    d_u_prev: f32,
    dahl: f32,
    /// Times the deviation diverged and was reset.
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
        integral: 0.0,
        e_prev: 0.0,
        u_prev: 0.0,
        dev: [0.0; 5],
        d_integral: 0.0,
        d_e_prev: 0.0,
        d_u_prev: 0.0,
        dahl: 0.0,
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
        let c = |x: f64| x as f32;
        let friction = p.friction.map(|f| FrictionCoef {
            coulomb: f.coulomb_mps2,
            stribeck_excess: f.static_mps2 - f.coulomb_mps2,
            inv_stribeck: 1.0 / f.stribeck_mps,
            inv_smooth: 1.0 / f.smooth_mps,
        });
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
            gu: [c(gamma[0][0]), c(gamma[1][0]), c(gamma[2][0]), c(gamma[3][0]), c(gamma[4][0])],
            gf: [c(gamma[0][1]), c(gamma[1][1]), c(gamma[2][1]), c(gamma[3][1]), c(gamma[4][1])],
            p3: [c(phi[3][1]), c(phi[3][2]), c(phi[3][3]), c(phi[3][4])],
            p4: [c(phi[4][1]), c(phi[4][2]), c(phi[4][3]), c(phi[4][4])],
            friction,
            hysteresis: p.hysteresis.map(|h| (h.stiffness_per_s2, 1.0 / h.force_mps2)),
            ripple: p.ripple.map(|r| (r.amp_nm * 1e-9, r.harmonic2_nm * 1e-9, r.turns_per_nm, r.phase_turns)),
        })
    }

    /// One servo tick with the command position `cmd_pos_nm`: the deviation of the TCP
    /// this tick (before the tick's motion), picometres.
    pub fn step(&self, st: &mut AxisState, cmd_pos_nm: i32) -> i64 {
        if !st.primed {
            st.history = [cmd_pos_nm; HISTORY];
            st.primed = true;
        }
        st.newest = if st.newest + 1 == HISTORY { 0 } else { st.newest + 1 };
        st.history[st.newest] = cmd_pos_nm;
        let at = |back: usize| st.history[(st.newest + HISTORY - back) % HISTORY];
        let r_nm = at(self.delay);
        let dr_m = r_nm.wrapping_sub(at(self.delay + 1)) as f32 * 1e-9;
        let ddr_m = dr_m - st.dr_prev_m;
        st.dr_prev_m = dr_m;

        // The linear axis's controller.
        st.w += dr_m;
        let e = st.w;
        st.integral += self.ki_t * e;
        let u = self.kp * e + st.integral + self.kd_t * (e - st.e_prev) + self.vff_t * dr_m + self.aff_t2 * ddr_m;
        st.e_prev = e;

        // The nonlinear axis's controller sees its own position and the encoder's error.
        let [dx, dv, df, dq, dqd] = st.dev;
        let mut de = -dx;
        if let Some((a1, a2, turns_per_nm, phase)) = self.ripple {
            let behind_nm = ((st.w - dx) * 1e9) as i32;
            let theta = (r_nm.wrapping_sub(behind_nm) as u32).wrapping_mul(turns_per_nm).wrapping_add(phase);
            let q31 = 1.0 / 2_147_483_648.0f32;
            de -= a1 * (sin_q31(theta) as f32 * q31) + a2 * (sin_q31(theta.wrapping_mul(2)) as f32 * q31);
        }
        st.d_integral += self.ki_t * de;
        let du = self.kp * de + st.d_integral + self.kd_t * (de - st.d_e_prev);
        st.d_e_prev = de;
        let out_pm = ((dx + dq) * 1e12) as i64;

        // Advance the linear axis over the tick with last tick's force command.
        let (v, f, u_prev) = (st.v, st.f, st.u_prev);
        let step_x = self.p01 * v + self.p02 * f + self.gu[0] * u_prev;
        let v_next = self.p11 * v + self.p12 * f + self.gu[1] * u_prev;
        st.f = self.p22 * f + self.gu[2] * u_prev;
        st.v = v_next;
        st.w -= step_x;
        st.u_prev = u;

        // The nonlinear force, friction linearly implicit in the next velocity.
        let du_prev = st.d_u_prev;
        let dv_free = self.p11 * dv + self.p12 * df + self.gu[1] * du_prev;
        let mut force = -st.dahl;
        if let Some(fr) = &self.friction {
            let v_abs = v + dv;
            let z = v_abs * fr.inv_stribeck;
            let ex = exp_neg(z * z);
            let level = fr.coulomb + fr.stribeck_excess * ex;
            let th = tanh(v_abs * fr.inv_smooth);
            let f0 = -level * th;
            let slope = -(fr.stribeck_excess * ex * (-2.0 * z * fr.inv_stribeck) * th + level * (1.0 - th * th) * fr.inv_smooth);
            let g = self.gf[1];
            let v_abs_next = (v_next + dv_free + g * (f0 - slope * THETA * v_abs)) / (1.0 - g * slope * THETA);
            force += f0 + slope * THETA * (v_abs_next - v_abs);
        }
        let dx_next = dx + self.p01 * dv + self.p02 * df + self.gu[0] * du_prev + self.gf[0] * force;
        st.dev = [
            dx_next,
            dv_free + self.gf[1] * force,
            self.p22 * df + self.gu[2] * du_prev,
            self.p3[0] * dv + self.p3[1] * df + self.p3[2] * dq + self.p3[3] * dqd + self.gu[3] * du_prev + self.gf[3] * force,
            self.p4[0] * dv + self.p4[1] * df + self.p4[2] * dq + self.p4[3] * dqd + self.gu[4] * du_prev + self.gf[4] * force,
        ];
        st.d_u_prev = du;
        if let Some((stiffness, inv_force)) = self.hysteresis {
            let moved = step_x + (dx_next - dx);
            let sign = if moved > 0.0 { 1.0 } else if moved < 0.0 { -1.0 } else { 0.0 };
            let h = st.dahl + stiffness * moved * (1.0 - st.dahl * inv_force * sign);
            let limit = 1.0 / inv_force;
            st.dahl = if h > limit { limit } else if h < -limit { -limit } else { h };
        }
        // NaN compares false: a non-finite state is diverged too.
        let bounded = |x: f32| x > -DIVERGED_M && x < DIVERGED_M;
        let healthy = bounded(st.dev[0]) && bounded(st.dev[3]) && bounded(st.w) && st.dev.iter().all(|x| x.is_finite()) && st.dahl.is_finite();
        if !healthy {
            let resets = st.resets.saturating_add(1);
            let (history, newest) = (st.history, st.newest);
            *st = AxisState { history, newest, primed: true, resets, ..AxisState::INITIAL };
            return 0;
        }
        out_pm
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::axis::{Friction, Hysteresis, Ripple};

    /// The default emulated machine's axis, per kg of its 45 kg slide.
    fn machine() -> AxisParams {
        let m = 45.0;
        AxisParams {
            cmd_delay_ticks: 2,
            kp_per_s2: 10.551e6 / m,
            ki_per_s3: 900.18e6 / m,
            kd_per_s: 0.017826e6 / m,
            vff_per_s: 450.0 / m,
            aff: 13.5 / m,
            viscous_per_s: 300.0 / m,
            current_tau_s: 80e-6,
            mode_freq_hz: 89.554,
            mode_damping: 0.28,
            mode_tcp_gain: 2.3662,
            friction: None,
            hysteresis: None,
            ripple: None,
        }
    }

    /// A 40 Hz, 10 um sine command, nm.
    fn command(k: u32) -> i32 {
        (10_000.0 * libm::sin(2.0 * core::f64::consts::PI * 40.0 * k as f64 / 8000.0)) as i32
    }

    fn run(params: &AxisParams, ticks: u32) -> (heapless::Vec<i64, 16_000>, AxisState) {
        let model = AxisModel::new(params).expect("valid");
        let mut st = AxisState::INITIAL;
        let mut out = heapless::Vec::new();
        for k in 0..ticks {
            out.push(model.step(&mut st, command(k))).unwrap();
        }
        (out, st)
    }

    #[test]
    fn without_effects_there_is_no_deviation() {
        let (out, st) = run(&machine(), 8000);
        assert!(out.iter().all(|&pm| pm == 0));
        assert_eq!(st.resets, 0);
    }

    #[test]
    fn friction_deviation_is_periodic_and_mirrored_each_half_period() {
        let params = AxisParams { friction: Some(Friction { coulomb_mps2: 3.0 / 45.0, static_mps2: 4.5 / 45.0, stribeck_mps: 2e-4, smooth_mps: 1e-5 }), ..machine() };
        let (out, st) = run(&params, 16_000);
        assert_eq!(st.resets, 0);
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
            AxisParams { hysteresis: Some(Hysteresis { force_mps2: 2.5 / 45.0, stiffness_per_s2: 3e6 / 45.0 }), ..machine() },
            AxisParams { ripple: Some(Ripple { amp_nm: 50.0, harmonic2_nm: 8.0, turns_per_nm: 810_000, phase_turns: 1 << 29 }), ..machine() },
        ] {
            let (out, st) = run(&params, 8000);
            assert_eq!(st.resets, 0);
            let peak = out.iter().map(|x| x.abs()).max().unwrap();
            assert!((10_000..2_000_000).contains(&peak), "peak {peak} pm");
        }
    }

    #[test]
    fn an_unstable_model_is_reset_not_output() {
        // A derivative gain far beyond what the tick can carry makes the loop diverge.
        let params = AxisParams { kd_per_s: 9e5, friction: Some(Friction { coulomb_mps2: 0.1, static_mps2: 0.1, stribeck_mps: 1e-4, smooth_mps: 1e-5 }), ..machine() };
        let (out, st) = run(&params, 8000);
        assert!(st.resets > 0);
        assert!(out.iter().all(|pm| pm.abs() <= 1_000_000_000), "never beyond the divergence limit");
    }

    #[test]
    fn out_of_range_parameters_name_their_field() {
        let bad = AxisParams { current_tau_s: f32::NAN, ..machine() };
        assert_eq!(AxisModel::new(&bad), Err(AxisError::OutOfRange("current_tau_s")));
        let bad = AxisParams { friction: Some(Friction { coulomb_mps2: 0.1, static_mps2: 0.1, stribeck_mps: 0.0, smooth_mps: 1e-5 }), ..machine() };
        assert_eq!(AxisModel::new(&bad), Err(AxisError::OutOfRange("friction.stribeck_mps")));
        let bad = AxisParams { cmd_delay_ticks: MAX_CMD_DELAY_TICKS + 1, ..machine() };
        assert_eq!(AxisModel::new(&bad), Err(AxisError::OutOfRange("cmd_delay_ticks")));
    }
}
