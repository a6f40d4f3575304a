//! The emulated machine, stepped at the 8 kHz servo rate.
//!
//! Each [`Machine::step`] at tick k (time `t_k = k / 8000 s`): the sensors are sampled at
//! `t_k`, the controller reads its analogue input and computes the force command from the
//! encoder, then the plant is integrated to `t_{k+1}` in `substeps` exact zero-order-hold
//! sub-steps (the nonlinear effect forces held over each sub-step). The returned
//! [`StepOutput`] holds the sensor readings at `t_k`, the same instant as the step's command.

// Small dense matrix-vector products read clearest with indices.
#![allow(clippy::needless_range_loop)]

use crate::effects::{check_unique, EffectError, EffectSpec};
use crate::linalg::{discretize, NU, NX};
use crate::params::{ParamsError, PlantParams};
use crate::G_MPS2;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::f64::consts::PI;
use sts_model::Effect;
use sts_twin_core::{SERVO_RATE_HZ, TICK_S};

const HISTORY: usize = 128;

/// A discretised linear step: state transition and input matrices.
type Discrete = ([[f64; NX]; NX], [[f64; NU]; NX]);

/// Why a machine could not be built.
#[derive(Debug, thiserror::Error)]
pub enum MachineError {
    /// Bad plant parameters.
    #[error(transparent)]
    Params(#[from] ParamsError),
    /// Bad effect list.
    #[error(transparent)]
    Effect(#[from] EffectError),
}

/// What drives the machine during one tick.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct StepInput {
    /// Z position command from the trajectory, um.
    pub z_cmd_um: f64,
    /// X slide position, mm (axis coupling uses its acceleration).
    pub x_mm: f64,
    /// Spindle angle, degrees.
    pub spindle_deg: f64,
    /// Voltage at the controller's analogue input (from the co-processor's DAC), V.
    pub analog_in_v: f64,
    /// Whether the controller adds the analogue input's motion pulses to the position command
    /// (the A3200's analogue feedforward switched on). The input is read either way.
    pub analog_enabled: bool,
}

/// The sensor readings at the step's instant and what the controller sees.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct StepOutput {
    /// Machine time of this sample, s.
    pub time_s: f64,
    /// Encoder reading, um.
    pub z_enc_um: f64,
    /// Capacitance probe reading of the TCP, um.
    pub z_tcp_um: f64,
    /// True TCP position (no probe noise or scale error), um.
    pub z_tcp_true_um: f64,
    /// Accelerometer: `acc_code * acc_mps2_per_lsb`, m/s^2.
    pub acc_mps2: f64,
    /// Accelerometer ADC code.
    pub acc_code: i16,
    /// Whether the accelerometer ADC clipped at this sample.
    pub acc_saturated: bool,
    /// The controller's reading of its analogue input (offset included, quantised), V.
    pub ain_read_v: f64,
    /// Motion pulses the controller makes of it (`round(ain_read_v * K_vc)`), added to the
    /// command only when `analog_enabled`.
    pub ain_pulses: i64,
    /// Position command the servo loop used (delayed trajectory plus pulses), um.
    pub z_servo_cmd_um: f64,
    /// Motor force, N.
    pub force_n: f64,
    /// X slide acceleration (from the X positions given), m/s^2.
    pub x_acc_mps2: f64,
    /// Machine temperature sensor, C.
    pub temp_c: f64,
}

/// Options beyond the plant and the effects.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MachineOptions {
    /// Seed of every random process (noise, ambient wander).
    pub seed: u64,
    /// Machine time at the first step, s (thermal processes depend on it).
    pub start_s: f64,
    /// Noise stream: machines with the same seed and different streams get independent noise
    /// but the same slow ambient wander.
    pub stream: u64,
}

#[derive(Debug, Clone)]
struct Friction {
    coulomb_n: f64,
    static_n: f64,
    stribeck_mps: f64,
    smooth_mps: f64,
}

#[derive(Debug, Clone)]
struct Hysteresis {
    force_n: f64,
    stiffness_n_per_m: f64,
    state_n: f64,
}

#[derive(Debug, Clone, Default)]
struct Effects {
    friction: Option<Friction>,
    hysteresis: Option<Hysteresis>,
    thermal: Option<(f64, f64, f64)>,
    ripple: Option<(f64, f64, f64, f64)>,
    coupling: Option<(f64, f64, f64)>,
    acc_gain: f64,
    probe_gain: f64,
}

/// The emulated Z axis with its controller, structure and sensors.
#[derive(Debug, Clone)]
pub struct Machine {
    params: PlantParams,
    substeps: usize,
    phi: [[f64; NX]; NX],
    gamma: [[f64; NU]; NX],
    // Linear-only fast path: the tick split where the delayed force command changes.
    split_substep: usize,
    seg: [Discrete; 2],
    nonlinear: bool,
    slow_temp: (u64, f64, f64),
    state: [f64; NX],
    // Modal accelerations: q'' = acc_row . state + acc_dist * F_dist.
    mode_acc_row: [[f64; NX]; 2],
    mode_acc_dist: [f64; 2],
    mode_tcp: [f64; 2],
    mode_acc_shape: [f64; 2],
    tick: u64,
    start_s: f64,
    output_delay_substeps: usize,
    /// Extra delay of the position command ahead of the loop (`setpoint-delay`), ticks.
    setpoint_delay_ticks: f64,
    force_history: [f64; HISTORY],
    cmd_history: [f64; HISTORY],
    servo_cmd_prev: [f64; 2],
    error_prev_um: f64,
    integral_um_s: f64,
    x_prev_mm: [f64; 2],
    x_primed: bool,
    acc_hp: (f64, f64, f64),
    acc_lp: [f64; 4],
    acc_lp_coef: [f64; 5],
    acc_noise_sigma: f64,
    effects: Effects,
    wander_phase: [f64; 3],
    rng: ChaCha8Rng,
    spare_normal: Option<f64>,
}

/// Round to nearest (ties to even) without a libm call; exact for |x| < 2^51.
#[inline]
fn round_fast(x: f64) -> f64 {
    const MAGIC: f64 = 6_755_399_441_055_744.0; // 1.5 * 2^52
    if x.abs() < 2_251_799_813_685_248.0 {
        (x + MAGIC) - MAGIC
    } else {
        x.round()
    }
}

fn splitmix(mut x: u64) -> u64 {
    x = x.wrapping_add(0x9E37_79B9_7F4A_7C15);
    x = (x ^ (x >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    x = (x ^ (x >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    x ^ (x >> 31)
}

/// What the sensors read at one tick ([`Machine::sense`]).
struct Sensed {
    z_enc_um: f64,
    z_tcp_um: f64,
    z_tcp_true_um: f64,
    acc_mps2: f64,
    acc_code: i16,
    acc_saturated: bool,
    x_acc_mps2: f64,
    temp_c: f64,
}

/// What the controller read and commanded at one tick ([`Machine::control`]).
struct Control {
    ain_read_v: f64,
    ain_pulses: i64,
    /// The position command after the analogue input's pulses, um.
    r_um: f64,
}

impl Machine {
    /// A machine at rest at position zero, machine time zero.
    pub fn new(params: &PlantParams, effects: &[EffectSpec], seed: u64) -> Result<Self, MachineError> {
        Self::with_options(params, effects, MachineOptions { seed, start_s: 0.0, stream: 0 })
    }

    /// A machine at rest at position zero, at machine time `options.start_s`.
    pub fn with_options(
        params: &PlantParams,
        effects: &[EffectSpec],
        options: MachineOptions,
    ) -> Result<Self, MachineError> {
        params.validate()?;
        check_unique(effects)?;
        let p = params;
        let mut fx = Effects { acc_gain: 1.0, probe_gain: 1.0, ..Effects::default() };
        let mut extra_mode: Option<(f64, f64, f64, f64)> = None;
        let mut extra_delay_us = 0.0;
        let mut setpoint_delay_ticks = 0.0;
        for e in effects {
            match e.kind() {
                Effect::CoulombFriction => {
                    fx.friction = Some(Friction {
                        coulomb_n: e.get("coulomb_n"),
                        static_n: e.get("static_n"),
                        stribeck_mps: e.get("stribeck_mps"),
                        smooth_mps: e.get("smooth_mps"),
                    })
                }
                Effect::PreslidingHysteresis => {
                    fx.hysteresis = Some(Hysteresis {
                        force_n: e.get("force_n"),
                        stiffness_n_per_m: e.get("stiffness_n_per_um") * 1e6,
                        state_n: 0.0,
                    })
                }
                Effect::StructuralMode => {
                    extra_mode = Some((e.get("freq_hz"), e.get("damping"), e.get("tcp_gain"), e.get("acc_shape")))
                }
                Effect::LoopDelay => extra_delay_us = e.get("delay_us"),
                Effect::SetpointDelay => setpoint_delay_ticks = e.get("delay_us") * 1e-6 / TICK_S,
                Effect::ThermalDrift => fx.thermal = Some((e.get("rise_k"), e.get("tau_s"), e.get("um_per_k"))),
                Effect::ForceRipple => {
                    fx.ripple = Some((
                        e.get("amp_nm"),
                        e.get("period_um"),
                        e.get("harmonic2_nm"),
                        e.get("phase_deg").to_radians(),
                    ))
                }
                Effect::AxisCoupling => {
                    fx.coupling =
                        Some((e.get("x_um_per_mps2"), e.get("spindle_um"), e.get("spindle_phase_deg").to_radians()))
                }
                Effect::SensorGain => {
                    fx.acc_gain = e.get("acc_gain");
                    fx.probe_gain = e.get("probe_gain");
                }
            }
        }

        // Sub-steps: as configured, more when a stiff friction law needs them for stability
        // of the explicit friction force (h < M v_smooth / F_static).
        let mut substeps = p.servo.substeps as usize;
        if let Some(f) = &fx.friction {
            let peak = f.static_n.max(f.coulomb_n).max(1e-9);
            let h_max = p.slide.mass_kg * f.smooth_mps / peak;
            substeps = substeps.max((TICK_S / h_max).ceil() as usize).min(256);
        }
        let h_s = TICK_S / substeps as f64;

        let m = p.slide.mass_kg;
        let c = p.slide.viscous_n_s_per_m;
        let tau = p.slide.current_loop_tau_us * 1e-6;
        let mut a = [[0.0; NX]; NX];
        let mut b = [[0.0; NU]; NX];
        a[0][1] = 1.0;
        a[1][1] = -c / m;
        a[1][2] = 1.0 / m;
        b[1][1] = 1.0 / m;
        a[2][2] = -1.0 / tau;
        b[2][0] = 1.0 / tau;
        let s = &p.structure;
        let modes = [Some((s.mode_freq_hz, s.mode_damping, s.mode_tcp_gain, s.acc_mode_shape)), extra_mode];
        let mut mode_acc_row = [[0.0; NX]; 2];
        let mut mode_acc_dist = [0.0; 2];
        let mut mode_tcp = [0.0; 2];
        let mut mode_acc_shape = [0.0; 2];
        for (i, mode) in modes.iter().enumerate() {
            let Some((freq_hz, zeta, gain, shape)) = *mode else { continue };
            let w = 2.0 * PI * freq_hz;
            let (qi, qd) = (3 + 2 * i, 4 + 2 * i);
            a[qi][qd] = 1.0;
            // q'' + 2 zeta w q' + w^2 q = -gain * (slide acceleration)
            let mut row = [0.0; NX];
            row[qi] = -w * w;
            row[qd] = -2.0 * zeta * w;
            row[1] = gain * c / m;
            row[2] = -gain / m;
            a[qd] = row;
            b[qd][1] = -gain / m;
            mode_acc_row[i] = row;
            mode_acc_dist[i] = -gain / m;
            mode_tcp[i] = 1.0;
            mode_acc_shape[i] = shape;
        }
        let (phi, gamma) = discretize(&a, &b, h_s);

        let total_delay_s = (p.servo.compute_delay_us + extra_delay_us) * 1e-6;
        let output_delay_substeps = (total_delay_s / h_s).round() as usize;
        let split_substep = output_delay_substeps % substeps;
        let first = if split_substep == 0 { substeps } else { split_substep };
        let seg = [discretize(&a, &b, first as f64 * h_s), discretize(&a, &b, (substeps - split_substep) as f64 * h_s)];
        let nonlinear = fx.friction.is_some() || fx.hysteresis.is_some();

        // Accelerometer filters at the 8 kHz sample rate (bilinear, low-pass prewarped).
        let hp_a = 1.0 / (1.0 + 2.0 * PI * p.accelerometer.highpass_hz * TICK_S);
        let k = (PI * p.accelerometer.lowpass_hz * TICK_S).tan();
        let norm = 1.0 / (1.0 + std::f64::consts::SQRT_2 * k + k * k);
        let b0 = k * k * norm;
        let lp = [b0, 2.0 * b0, b0, 2.0 * (k * k - 1.0) * norm, (1.0 - std::f64::consts::SQRT_2 * k + k * k) * norm];
        let acc_noise_sigma =
            p.accelerometer.noise_ug_per_rthz * 1e-6 * G_MPS2 * (f64::from(SERVO_RATE_HZ) / 2.0).sqrt();

        let mut wander_rng = ChaCha8Rng::seed_from_u64(splitmix(options.seed));
        let mut wander_phase = [0.0; 3];
        for ph in wander_phase.iter_mut() {
            *ph = 2.0 * PI * (wander_rng.next_u64() >> 11) as f64 / (1u64 << 53) as f64;
        }
        let rng = ChaCha8Rng::seed_from_u64(splitmix(options.seed ^ splitmix(options.stream.wrapping_add(1))));

        Ok(Self {
            params: params.clone(),
            substeps,
            phi,
            gamma,
            split_substep,
            seg,
            nonlinear,
            slow_temp: (u64::MAX, 0.0, 0.0),
            state: [0.0; NX],
            mode_acc_row,
            mode_acc_dist,
            mode_tcp,
            mode_acc_shape,
            tick: 0,
            start_s: options.start_s,
            output_delay_substeps,
            setpoint_delay_ticks,
            force_history: [0.0; HISTORY],
            cmd_history: [0.0; HISTORY],
            servo_cmd_prev: [0.0; 2],
            error_prev_um: 0.0,
            integral_um_s: 0.0,
            x_prev_mm: [0.0; 2],
            x_primed: false,
            acc_hp: (hp_a, 0.0, 0.0),
            acc_lp: [0.0; 4],
            acc_lp_coef: lp,
            acc_noise_sigma,
            effects: fx,
            wander_phase,
            rng,
            spare_normal: None,
        })
    }

    /// Machine time of the next step's sample, s.
    pub fn time_s(&self) -> f64 {
        self.start_s + self.tick as f64 * TICK_S
    }

    /// The plant parameters.
    pub fn params(&self) -> &PlantParams {
        &self.params
    }

    /// Accelerometer ADC scale, m/s^2 per LSB.
    pub fn acc_mps2_per_lsb(&self) -> f64 {
        self.params.acc_mps2_per_lsb()
    }

    /// Integration sub-steps per tick actually used (more than configured when friction
    /// needs them).
    pub fn substeps(&self) -> usize {
        self.substeps
    }

    /// Sets the X positions of the two ticks before the next one, so that the X acceleration
    /// is right from the first step (otherwise the first X position is taken as at rest).
    pub fn prime_x(&mut self, x_mm_two_before: f64, x_mm_one_before: f64) {
        self.x_prev_mm = [x_mm_one_before, x_mm_two_before];
        self.x_primed = true;
    }

    fn normal(&mut self) -> f64 {
        if let Some(v) = self.spare_normal.take() {
            return v;
        }
        loop {
            let u = 2.0 * ((self.rng.next_u64() >> 11) as f64 / (1u64 << 53) as f64) - 1.0;
            let v = 2.0 * ((self.rng.next_u64() >> 11) as f64 / (1u64 << 53) as f64) - 1.0;
            let s = u * u + v * v;
            if s > 0.0 && s < 1.0 {
                let f = (-2.0 * s.ln() / s).sqrt();
                self.spare_normal = Some(v * f);
                return u * f;
            }
        }
    }

    /// Disturbance force on the slide from the nonlinear effects at the current state, N.
    #[inline]
    fn disturbance_n(&self, velocity_mps: f64) -> f64 {
        let mut f = 0.0;
        if let Some(fr) = &self.effects.friction {
            let stribeck =
                fr.coulomb_n + (fr.static_n - fr.coulomb_n) * (-(velocity_mps / fr.stribeck_mps).powi(2)).exp();
            f -= stribeck * (velocity_mps / fr.smooth_mps).tanh();
        }
        if let Some(h) = &self.effects.hysteresis {
            f -= h.state_n;
        }
        f
    }

    /// Ambient temperature wander plus the thermal-drift effect's rise at machine time `t`.
    fn temperature_c(&self, t: f64) -> (f64, f64) {
        let th = &self.params.thermal;
        let w = &self.wander_phase;
        let wander = th.wander_mk
            * 1e-3
            * (0.5 * (2.0 * PI * t / 1100.0 + w[0]).sin()
                + 0.3 * (2.0 * PI * t / 370.0 + w[1]).sin()
                + 0.2 * (2.0 * PI * t / 2900.0 + w[2]).sin());
        let rise = match self.effects.thermal {
            Some((rise_k, tau_s, _)) => rise_k * (1.0 - (-t / tau_s).exp()),
            None => 0.0,
        };
        (th.ambient_c + wander + rise, rise)
    }

    /// One servo tick: sample the sensors, run the controller, integrate the plant.
    pub fn step(&mut self, input: &StepInput) -> StepOutput {
        let time_s = self.time_s();
        let sensed = self.sense(input, time_s);
        let control = self.control(input, sensed.z_enc_um);
        let force_n = self.state[2];
        self.integrate_plant();
        self.tick += 1;
        StepOutput {
            time_s,
            z_enc_um: sensed.z_enc_um,
            z_tcp_um: sensed.z_tcp_um,
            z_tcp_true_um: sensed.z_tcp_true_um,
            acc_mps2: sensed.acc_mps2,
            acc_code: sensed.acc_code,
            acc_saturated: sensed.acc_saturated,
            ain_read_v: control.ain_read_v,
            ain_pulses: control.ain_pulses,
            z_servo_cmd_um: control.r_um,
            force_n,
            x_acc_mps2: sensed.x_acc_mps2,
            temp_c: sensed.temp_c,
        }
    }

    /// The sensors at this tick: the encoder, the probe on the tool, the accelerometer's
    /// chain to its ADC code, the temperature, and the X slide's acceleration.
    fn sense(&mut self, input: &StepInput, time_s: f64) -> Sensed {
        let noise_probe = self.normal();
        let noise_acc = self.normal();
        let noise_temp = self.normal();
        let p = &self.params;
        let x_m = self.state[0];
        let v = self.state[1];

        // X slide acceleration from the given positions.
        if !self.x_primed {
            self.x_prev_mm = [input.x_mm, input.x_mm];
            self.x_primed = true;
        }
        let x_acc_mps2 = (input.x_mm - 2.0 * self.x_prev_mm[0] + self.x_prev_mm[1]) * 1e-3 / (TICK_S * TICK_S);
        self.x_prev_mm = [input.x_mm, self.x_prev_mm[0]];

        // Accelerations at this instant.
        let f_dist = self.disturbance_n(v);
        let slide_acc = (self.state[2] + f_dist - p.slide.viscous_n_s_per_m * v) / p.slide.mass_kg;
        let mut modal_disp = 0.0;
        let mut acc_true = slide_acc;
        for i in 0..2 {
            if self.mode_tcp[i] == 0.0 {
                continue;
            }
            let row = &self.mode_acc_row[i];
            let mut qdd = self.mode_acc_dist[i] * f_dist;
            for j in 0..NX {
                qdd += row[j] * self.state[j];
            }
            acc_true += self.mode_acc_shape[i] * qdd;
            modal_disp += self.state[3 + 2 * i];
        }

        // Encoder (with the interpolation error of force-ripple).
        let mut enc_pos_um = x_m * 1e6;
        if let Some((amp_nm, period_um, h2_nm, phase)) = self.effects.ripple {
            let arg = 2.0 * PI * enc_pos_um / period_um + phase;
            enc_pos_um += 1e-3 * (amp_nm * arg.sin() + h2_nm * (2.0 * arg).sin());
        }
        let res_um = p.encoder.resolution_nm * 1e-3;
        let z_enc_um = round_fast(enc_pos_um / res_um) * res_um;

        // TCP: slide + modes + tool-side effects; then the probe.
        // Slow thermal processes: evaluated every 64 ticks (8 ms), held in between.
        let block = self.tick / 64;
        if self.slow_temp.0 != block {
            let (temp, rise) = self.temperature_c(time_s);
            self.slow_temp = (block, temp, rise);
        }
        let p = &self.params;
        let (temp_true_c, rise_k) = (self.slow_temp.1, self.slow_temp.2);
        let mut z_tcp_true_um = (x_m + modal_disp) * 1e6;
        if let Some((_, _, um_per_k)) = self.effects.thermal {
            z_tcp_true_um += um_per_k * rise_k;
        }
        if let Some((um_per_mps2, spindle_um, spindle_phase)) = self.effects.coupling {
            z_tcp_true_um +=
                um_per_mps2 * x_acc_mps2 + spindle_um * (input.spindle_deg.to_radians() + spindle_phase).sin();
        }
        let probe_noise = noise_probe * p.probe.noise_rms_nm * 1e-3;
        let z_tcp_um = self.effects.probe_gain * z_tcp_true_um + probe_noise;

        // Accelerometer chain: gain, noise, high-pass, anti-alias low-pass, 16-bit ADC.
        let acc_noise = noise_acc * self.acc_noise_sigma;
        let raw = self.effects.acc_gain * acc_true + acc_noise;
        let (hp_a, hp_x, hp_y) = self.acc_hp;
        let hp = hp_a * (hp_y + raw - hp_x);
        self.acc_hp = (hp_a, raw, hp);
        let [b0, b1, b2, a1, a2] = self.acc_lp_coef;
        let [x1, x2, y1, y2] = self.acc_lp;
        let lp = b0 * hp + b1 * x1 + b2 * x2 - a1 * y1 - a2 * y2;
        self.acc_lp = [hp, x1, lp, y1];
        let lsb = p.acc_mps2_per_lsb();
        let code_f = round_fast(lp / lsb);
        let acc_saturated = !(-32768.0..=32767.0).contains(&code_f);
        let acc_code = code_f.clamp(-32768.0, 32767.0) as i16;
        let acc_mps2 = acc_code as f64 * lsb;

        let temp_c = temp_true_c + noise_temp * p.thermal.sensor_noise_mk * 1e-3;
        Sensed { z_enc_um, z_tcp_um, z_tcp_true_um, acc_mps2, acc_code, acc_saturated, x_acc_mps2, temp_c }
    }

    /// The motion controller at this tick: the analogue input read and turned into motion
    /// pulses, added to the delayed trajectory, and the PID with feedforward on the encoder's
    /// error; its force command goes into the history the plant reads, delayed.
    fn control(&mut self, input: &StepInput, z_enc_um: f64) -> Control {
        let p = &self.params;
        let itf = &p.interface;
        let ain_lsb = 2.0 * itf.adc_range_v / (1u64 << itf.adc_bits) as f64;
        let ain_v = (input.analog_in_v + itf.offset_v).clamp(-itf.adc_range_v, itf.adc_range_v - ain_lsb);
        let ain_read_v = round_fast(ain_v / ain_lsb) * ain_lsb;
        let ain_pulses = round_fast(ain_read_v * itf.kvc_pulses_per_v) as i64;
        let slot = (self.tick as usize) % HISTORY;
        self.cmd_history[slot] = input.z_cmd_um;
        let delay = p.servo.command_delay_ticks as u64;
        let at = |ticks_back: u64| {
            if self.tick >= ticks_back {
                self.cmd_history[((self.tick - ticks_back) as usize) % HISTORY]
            } else {
                0.0
            }
        };
        let delayed_cmd = if self.setpoint_delay_ticks > 0.0 {
            // Between the two ticks around the late instant (the command is smooth).
            let whole = self.setpoint_delay_ticks.floor();
            let frac = self.setpoint_delay_ticks - whole;
            let back = delay + whole as u64;
            at(back) * (1.0 - frac) + at(back + 1) * frac
        } else {
            at(delay)
        };
        let added_pulses = if input.analog_enabled { ain_pulses } else { 0 };
        let r_um = delayed_cmd + added_pulses as f64 * itf.pulse_nm * 1e-3;
        let s = &p.servo;
        let e_um = r_um - z_enc_um;
        self.integral_um_s += e_um * TICK_S;
        let vel_cmd = (r_um - self.servo_cmd_prev[0]) * 1e-6 / TICK_S;
        let acc_cmd = (r_um - 2.0 * self.servo_cmd_prev[0] + self.servo_cmd_prev[1]) * 1e-6 / (TICK_S * TICK_S);
        self.servo_cmd_prev = [r_um, self.servo_cmd_prev[0]];
        let mut u = s.kp_n_per_um * e_um
            + s.ki_n_per_um_s * self.integral_um_s
            + s.kd_n_s_per_um * (e_um - self.error_prev_um) / TICK_S
            + s.vff_n_s_per_m * vel_cmd
            + s.aff_kg * acc_cmd;
        self.error_prev_um = e_um;
        let limit = p.slide.force_limit_n;
        if u.abs() > limit {
            u = u.clamp(-limit, limit);
            // Conditional integration: no wind-up while saturated.
            self.integral_um_s -= e_um * TICK_S;
        }
        self.force_history[slot] = u;
        Control { ain_read_v, ain_pulses, r_um }
    }

    /// The plant over one tick, driven by the force command delayed by the computation (and
    /// loop) delay. Linear plant: exact in at most two segments; with nonlinear forces:
    /// sub-steps.
    fn integrate_plant(&mut self) {
        let n = self.substeps as u64;
        let d = self.output_delay_substeps as u64;
        let command_at = |i: u64, tick: u64, history: &[f64; HISTORY]| -> f64 {
            if i >= d {
                let m = (i - d) / n;
                if tick - m < HISTORY as u64 {
                    return history[(m as usize) % HISTORY];
                }
            }
            0.0
        };
        if !self.nonlinear {
            let split = self.split_substep as u64;
            let segments: &[(u64, usize)] = if split == 0 { &[(0, 0)] } else { &[(0, 0), (split, 1)] };
            for &(j0, which) in segments {
                let f_cmd = command_at(self.tick * n + j0, self.tick, &self.force_history);
                let (phi, gamma) = &self.seg[which];
                let mut next = [0.0; NX];
                for (r, out) in next.iter_mut().enumerate() {
                    let mut acc = gamma[r][0] * f_cmd;
                    for c in 0..NX {
                        acc += phi[r][c] * self.state[c];
                    }
                    *out = acc;
                }
                self.state = next;
            }
        }
        for j in 0..if self.nonlinear { n } else { 0 } {
            let f_cmd = command_at(self.tick * n + j, self.tick, &self.force_history);
            let x_before = self.state[0];
            let f_dist = self.disturbance_n(self.state[1]);
            let mut next = [0.0; NX];
            for (r, out) in next.iter_mut().enumerate() {
                let phi = &self.phi[r];
                let mut acc = self.gamma[r][0] * f_cmd + self.gamma[r][1] * f_dist;
                for c in 0..NX {
                    acc += phi[c] * self.state[c];
                }
                *out = acc;
            }
            self.state = next;
            if let Some(h) = &mut self.effects.hysteresis {
                // Dahl: dF = sigma dx (1 - F/Fc sgn(dx)).
                let dx = self.state[0] - x_before;
                let ratio = h.state_n / h.force_n.max(1e-12);
                h.state_n += h.stiffness_n_per_m * dx * (1.0 - ratio * dx.signum());
                h.state_n = h.state_n.clamp(-h.force_n, h.force_n);
            }
        }
    }
}
