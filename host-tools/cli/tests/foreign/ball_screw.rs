//! A second machine that is not our emulator, of another structure than [`super::Foreign`]:
//! a ball-screw drive in three masses (the motor's rotor as seen through the screw's lead, the
//! table on the screw's nut, a tool holder on the table), the encoder on the motor (a
//! semi-closed loop: the screw's and the holder's compliance lie between it and the tool),
//! one discrete PID on position with acceleration feedforward, a sample of computation delay
//! and a second-order current loop, sharp Coulomb friction on the table's guides and the
//! motor's bearings (a tanh law about 1 um/s wide), and a piezo accelerometer on the table
//! (no DC: a first-order high-pass; a first-order low-pass), not on the tool. Written from
//! textbook equations, nothing of `sts-emulator` or of the twin's axis model.

use std::f64::consts::PI;
use std::path::Path;

use super::{write_dataset, Noise, RATE_HZ};

/// Integration steps per servo tick: the sharpest friction law (5 N over 1 um/s on 25 kg,
/// a time constant of 5 us) stays inside RK4's stable step.
const SUBSTEPS: usize = 20;

/// Coulomb friction, `F tanh(v / width)`, on the table's guides and the motor's bearings.
#[derive(Clone, Copy, Debug)]
pub struct Coulomb {
    pub guide_n: f64,
    pub bearing_n: f64,
    pub width_mps: f64,
}

/// The ball-screw machine's parameters.
#[derive(Clone, Copy, Debug)]
pub struct BallScrew {
    /// The rotor's inertia as a mass at the table (`J (2 pi / lead)^2`), the table's and the
    /// tool holder's, kg.
    pub motor_kg: f64,
    pub table_kg: f64,
    pub holder_kg: f64,
    /// The screw and nut's axial stiffness, N/m, and damping, N s/m.
    pub screw_n_per_m: f64,
    pub screw_ns_per_m: f64,
    /// The tool holder's mode on the table: frequency, Hz, and damping ratio.
    pub holder_hz: f64,
    pub holder_damping: f64,
    /// Viscous drag of the guides, N s/m.
    pub guide_ns_per_m: f64,
    /// PID on the motor encoder's position: N/m, N/(m s), N s/m; the derivative's low-pass
    /// corner, Hz; acceleration feedforward, kg.
    pub kp_n_per_m: f64,
    pub ki_n_per_m_s: f64,
    pub kd_ns_per_m: f64,
    pub derivative_hz: f64,
    pub acc_ff_kg: f64,
    /// The current loop's natural frequency, Hz, and damping ratio.
    pub current_hz: f64,
    pub current_damping: f64,
    /// Ticks between reading the encoder and the force command taking effect.
    pub delay_ticks: usize,
    /// Encoder resolution, um; probe and accelerometer noise (RMS per sample), um and m/s^2.
    pub encoder_um: f64,
    pub probe_noise_um: f64,
    pub acc_noise_mps2: f64,
    /// The accelerometer's high-pass (piezo) and low-pass corners, Hz.
    pub acc_highpass_hz: f64,
    pub acc_lowpass_hz: f64,
    pub friction: Option<Coulomb>,
}

impl Default for BallScrew {
    fn default() -> Self {
        let total_kg = 18.0 + 25.0 + 1.5;
        let wc = 2.0 * PI * 70.0;
        Self {
            motor_kg: 18.0,
            table_kg: 25.0,
            holder_kg: 1.5,
            screw_n_per_m: 1.5e8,
            screw_ns_per_m: 4000.0,
            holder_hz: 220.0,
            holder_damping: 0.03,
            guide_ns_per_m: 60.0,
            kp_n_per_m: total_kg * wc * wc / 2.0,
            ki_n_per_m_s: total_kg * wc * wc * wc / 20.0,
            kd_ns_per_m: total_kg * wc * 1.2,
            derivative_hz: 1200.0,
            acc_ff_kg: 0.9 * total_kg,
            current_hz: 2000.0,
            current_damping: 0.7,
            delay_ticks: 1,
            encoder_um: 0.001,
            probe_noise_um: 0.004,
            acc_noise_mps2: 0.003,
            acc_highpass_hz: 0.2,
            acc_lowpass_hz: 3000.0,
            friction: None,
        }
    }
}

/// Continuous state: motor, table and tool positions (m) and velocities, the motor force (N)
/// and its rate.
#[derive(Clone, Copy, Default)]
struct State {
    x: [f64; 3],
    v: [f64; 3],
    force: f64,
    force_rate: f64,
}

impl BallScrew {
    /// The accelerations of the three masses and the force's second derivative under
    /// `force_cmd`.
    fn derivative(&self, s: &State, force_cmd: f64) -> State {
        let coulomb = |f: f64, v: f64| self.friction.map_or(0.0, |c| f * (v / c.width_mps).tanh());
        let (bearing, guide) = match self.friction {
            Some(c) => (coulomb(c.bearing_n, s.v[0]), coulomb(c.guide_n, s.v[1])),
            None => (0.0, 0.0),
        };
        let screw = self.screw_n_per_m * (s.x[1] - s.x[0]) + self.screw_ns_per_m * (s.v[1] - s.v[0]);
        let w = 2.0 * PI * self.holder_hz;
        let holder = self.holder_kg * w * w * (s.x[2] - s.x[1])
            + 2.0 * self.holder_damping * self.holder_kg * w * (s.v[2] - s.v[1]);
        let wi = 2.0 * PI * self.current_hz;
        State {
            x: s.v,
            v: [
                (s.force - bearing + screw) / self.motor_kg,
                (-screw - guide - self.guide_ns_per_m * s.v[1] + holder) / self.table_kg,
                -holder / self.holder_kg,
            ],
            force: s.force_rate,
            force_rate: wi * wi * (force_cmd - s.force) - 2.0 * self.current_damping * wi * s.force_rate,
        }
    }

    fn rk4(&self, s: &State, force_cmd: f64, dt: f64) -> State {
        let add = |a: &State, b: &State, h: f64| State {
            x: std::array::from_fn(|i| a.x[i] + h * b.x[i]),
            v: std::array::from_fn(|i| a.v[i] + h * b.v[i]),
            force: a.force + h * b.force,
            force_rate: a.force_rate + h * b.force_rate,
        };
        let k1 = self.derivative(s, force_cmd);
        let k2 = self.derivative(&add(s, &k1, dt / 2.0), force_cmd);
        let k3 = self.derivative(&add(s, &k2, dt / 2.0), force_cmd);
        let k4 = self.derivative(&add(s, &k3, dt), force_cmd);
        let sum = add(&add(&k1, &k4, 1.0), &add(&k2, &k3, 1.0), 2.0);
        add(s, &sum, dt / 6.0)
    }

    /// One group: the command `amp_um sin(2 pi freq_hz t)` for `duration_s` from rest at the
    /// servo's rate. Columns: command, encoder, probe, accelerometer.
    pub fn run(&self, freq_hz: f64, amp_um: f64, duration_s: f64, seed: u64) -> [Vec<f64>; 4] {
        let ts = 1.0 / RATE_HZ;
        let dt = ts / SUBSTEPS as f64;
        let mut noise = Noise::new(seed);
        let mut s = State::default();
        let mut out: [Vec<f64>; 4] = Default::default();
        let command = |k: i64| if k < 0 { 0.0 } else { amp_um * 1e-6 * (2.0 * PI * freq_hz * k as f64 * ts).sin() };
        let encoder = |x: f64| (x / (self.encoder_um * 1e-6)).round() * self.encoder_um * 1e-6;
        let (mut integral, mut derivative, mut error_prev) = (0.0, 0.0, 0.0);
        let alpha = 1.0 - (-2.0 * PI * self.derivative_hz * ts).exp();
        let mut pending = vec![0.0; self.delay_ticks.max(1)];
        // The accelerometer's filters, each first order at the servo's rate.
        let (mut hp_in, mut hp_out, mut lp_out) = (0.0, 0.0, 0.0);
        let hp = 1.0 / (1.0 + 2.0 * PI * self.acc_highpass_hz * ts);
        let lp = 1.0 - (-2.0 * PI * self.acc_lowpass_hz * ts).exp();
        let ticks = (duration_s * RATE_HZ).round() as i64;
        for k in 0..ticks {
            // Sampled at the tick: the sensors, then the controller.
            let table_mps2 = self.derivative(&s, pending[0]).v[1];
            hp_out = hp * (hp_out + table_mps2 - hp_in);
            hp_in = table_mps2;
            lp_out += lp * (hp_out - lp_out);
            let cmd = command(k);
            let enc = encoder(s.x[0]);
            out[0].push(cmd * 1e6);
            out[1].push(enc * 1e6);
            out[2].push(s.x[2] * 1e6 + self.probe_noise_um * noise.gaussian());
            out[3].push(lp_out + self.acc_noise_mps2 * noise.gaussian());
            let error = cmd - enc;
            integral += error * ts;
            derivative += alpha * ((error - error_prev) / ts - derivative);
            error_prev = error;
            let acc_cmd = (command(k + 1) - 2.0 * cmd + command(k - 1)) / (ts * ts);
            let force_cmd = self.kp_n_per_m * error
                + self.ki_n_per_m_s * integral
                + self.kd_ns_per_m * derivative
                + self.acc_ff_kg * acc_cmd;
            pending.rotate_left(1);
            *pending.last_mut().unwrap() = force_cmd;
            for _ in 0..SUBSTEPS {
                s = self.rk4(&s, pending[0], dt);
            }
        }
        out
    }

    /// Measures the grid into `dir` as the lab's recorder exports it ([`write_dataset`]).
    pub fn measure(&self, dir: &Path, freqs_hz: &[f64], amps_um: &[f64], duration_s: f64, seed: u64) {
        let groups = freqs_hz.iter().flat_map(|f| amps_um.iter().map(move |a| (*f, *a)));
        write_dataset(
            dir,
            RATE_HZ,
            "foreign ball-screw drive, PID with a sample of delay (test)",
            groups,
            |i, f, a| self.run(f, a, duration_s, seed * 1000 + i as u64),
        );
    }
}
