//! A machine that is not our emulator: a two-mass Z slide under a cascaded servo (P position
//! loop, PI velocity loop on a filtered encoder difference, partial velocity feedforward),
//! with LuGre friction, a lightly damped tool-post mode (a modal mass on the carrier) and a
//! late setpoint as options, written here from textbook equations and nothing of `sts-emulator`
//! or of the twin's own axis model (which is a PID with its friction a static map). Its
//! measurements are written as a lab would export them: CSV files by hand, columns in another
//! order, CRLF line ends, other decimals, no ADC scale in the manifest.

use std::f64::consts::PI;
use std::fmt::Write as _;
use std::path::Path;

pub mod ball_screw;

/// Servo rate, Hz (the firmware's, so that the twin can run on the board).
pub const RATE_HZ: f64 = 8000.0;
/// Integration steps per servo tick (a 160 kHz grid, on which 8, 10, 16 and 20 kHz recorders
/// sample).
const SUBSTEPS: usize = 20;

/// LuGre friction on the slide (Canudas de Wit et al. 1995): bristles of stiffness `sigma0`
/// and damping `sigma1`, a Stribeck curve `g(v)` and viscous `sigma2`.
#[derive(Clone, Copy, Debug)]
pub struct Lugre {
    pub coulomb_n: f64,
    pub static_n: f64,
    pub stribeck_mps: f64,
    pub sigma0_n_per_m: f64,
    pub sigma1_ns_per_m: f64,
}

/// A lightly damped mode of the tool post inside the test band: a modal mass on a spring
/// and damper riding on the tool carrier (`m r'' + c r' + k r = -m x2''`, `r` its motion
/// against the carrier), reacting on the carrier; the tool tip and the accelerometer see
/// `share` of it (their mode-shape value relative to the modal mass's).
#[derive(Clone, Copy, Debug)]
pub struct ToolMode {
    pub freq_hz: f64,
    pub damping: f64,
    pub modal_kg: f64,
    pub share: f64,
}

/// The foreign machine's parameters.
#[derive(Clone, Copy, Debug)]
pub struct Foreign {
    /// Slide (motor, encoder) and tool-carrier masses, kg, their coupling, N/m and N s/m.
    pub slide_kg: f64,
    pub carrier_kg: f64,
    pub coupling_n_per_m: f64,
    pub coupling_ns_per_m: f64,
    /// Bearing drag on the slide, N s/m.
    pub drag_ns_per_m: f64,
    /// Position loop gain, 1/s; velocity loop P (N s/m) and I (N/m); feedforward fraction.
    pub kpp_per_s: f64,
    pub kvp_ns_per_m: f64,
    pub kvi_n_per_m: f64,
    pub vff: f64,
    /// Velocity estimate's low-pass corner, Hz; current loop time constant, s.
    pub vel_filter_hz: f64,
    pub current_tau_s: f64,
    /// Ticks between reading the encoder and the force command taking effect.
    pub delay_ticks: usize,
    /// Encoder resolution, um; probe and accelerometer noise (RMS per sample at 8 kHz), um
    /// and m/s^2.
    pub encoder_um: f64,
    pub probe_noise_um: f64,
    pub acc_noise_mps2: f64,
    /// The probe's scale (1: calibrated).
    pub probe_gain: f64,
    /// The recorder's rate, Hz (the servo's or another).
    pub record_hz: f64,
    pub friction: Option<Lugre>,
    /// A mode of the tool post, if any.
    pub tool_mode: Option<ToolMode>,
    /// How late the position command reaches the controller (an interpolator or bus ahead
    /// of the loop), s; the recorded command is the one sent.
    pub setpoint_delay_s: f64,
}

impl Default for Foreign {
    fn default() -> Self {
        let slide_kg = 14.0;
        let carrier_kg = 2.5;
        let total = slide_kg + carrier_kg;
        let kvp = total * 2.0 * PI * 120.0;
        Self {
            slide_kg,
            carrier_kg,
            coupling_n_per_m: 5.0e6,
            coupling_ns_per_m: 260.0,
            drag_ns_per_m: 30.0,
            kpp_per_s: 2.0 * PI * 30.0,
            kvp_ns_per_m: kvp,
            kvi_n_per_m: kvp * 2.0 * PI * 15.0,
            vff: 0.6,
            vel_filter_hz: 1500.0,
            current_tau_s: 80e-6,
            delay_ticks: 1,
            encoder_um: 0.002,
            probe_noise_um: 0.004,
            acc_noise_mps2: 0.003,
            probe_gain: 1.0,
            record_hz: RATE_HZ,
            friction: None,
            tool_mode: None,
            setpoint_delay_s: 0.0,
        }
    }
}

/// Continuous state: slide and carrier position (m) and velocity, motor force (N), bristle
/// deflection (m), the tool mode's motion against the carrier (m) and its velocity.
#[derive(Clone, Copy, Default)]
struct State {
    x1: f64,
    v1: f64,
    x2: f64,
    v2: f64,
    force: f64,
    z: f64,
    r: f64,
    vr: f64,
}

impl Foreign {
    fn friction_n(&self, s: &State) -> (f64, f64) {
        match self.friction {
            None => (0.0, 0.0),
            Some(f) => {
                let g = f.coulomb_n + (f.static_n - f.coulomb_n) * (-(s.v1 / f.stribeck_mps).powi(2)).exp();
                let dz = s.v1 - f.sigma0_n_per_m * s.v1.abs() * s.z / g;
                (f.sigma0_n_per_m * s.z + f.sigma1_ns_per_m * dz, dz)
            }
        }
    }

    fn derivative(&self, s: &State, force_cmd: f64) -> State {
        let (friction, dz) = self.friction_n(s);
        let spring = self.coupling_n_per_m * (s.x2 - s.x1) + self.coupling_ns_per_m * (s.v2 - s.v1);
        // The tool mode's spring and damper pull the carrier as they push the modal mass.
        let (mode_n, stiffness, damping, modal_kg) = match self.tool_mode {
            Some(m) => {
                let w = 2.0 * PI * m.freq_hz;
                let (k, c) = (m.modal_kg * w * w, 2.0 * m.damping * m.modal_kg * w);
                (k * s.r + c * s.vr, k, c, m.modal_kg)
            }
            None => (0.0, 0.0, 0.0, 1.0),
        };
        let a2 = (-spring + mode_n) / self.carrier_kg;
        State {
            x1: s.v1,
            v1: (s.force - friction - self.drag_ns_per_m * s.v1 + spring) / self.slide_kg,
            x2: s.v2,
            v2: a2,
            force: (force_cmd - s.force) / self.current_tau_s,
            z: dz,
            r: s.vr,
            vr: if self.tool_mode.is_some() { -(stiffness * s.r + damping * s.vr) / modal_kg - a2 } else { 0.0 },
        }
    }

    /// The share of the tool mode that the tool tip and the accelerometer see.
    fn mode_share(&self) -> f64 {
        self.tool_mode.map_or(0.0, |m| m.share)
    }

    fn rk4(&self, s: &State, force_cmd: f64, dt: f64) -> State {
        let add = |a: &State, b: &State, h: f64| State {
            x1: a.x1 + h * b.x1,
            v1: a.v1 + h * b.v1,
            x2: a.x2 + h * b.x2,
            v2: a.v2 + h * b.v2,
            force: a.force + h * b.force,
            z: a.z + h * b.z,
            r: a.r + h * b.r,
            vr: a.vr + h * b.vr,
        };
        let k1 = self.derivative(s, force_cmd);
        let k2 = self.derivative(&add(s, &k1, dt / 2.0), force_cmd);
        let k3 = self.derivative(&add(s, &k2, dt / 2.0), force_cmd);
        let k4 = self.derivative(&add(s, &k3, dt), force_cmd);
        let mut out = *s;
        for (o, (a, (b, (c, d)))) in [
            (&mut out.x1, (k1.x1, (k2.x1, (k3.x1, k4.x1)))),
            (&mut out.v1, (k1.v1, (k2.v1, (k3.v1, k4.v1)))),
            (&mut out.x2, (k1.x2, (k2.x2, (k3.x2, k4.x2)))),
            (&mut out.v2, (k1.v2, (k2.v2, (k3.v2, k4.v2)))),
            (&mut out.force, (k1.force, (k2.force, (k3.force, k4.force)))),
            (&mut out.z, (k1.z, (k2.z, (k3.z, k4.z)))),
            (&mut out.r, (k1.r, (k2.r, (k3.r, k4.r)))),
            (&mut out.vr, (k1.vr, (k2.vr, (k3.vr, k4.vr)))),
        ] {
            *o += dt / 6.0 * (a + 2.0 * b + 2.0 * c + d);
        }
        out
    }

    /// One group: the command `amp_um sin(2 pi freq_hz t)` for `duration_s` from rest,
    /// recorded at `record_hz`. Columns: command, encoder, probe, accelerometer.
    pub fn run(&self, freq_hz: f64, amp_um: f64, duration_s: f64, seed: u64) -> [Vec<f64>; 4] {
        self.simulate(freq_hz, amp_um, duration_s, seed, None)
    }

    /// [`Self::run`] with a co-processor on the controller's analogue input: at every servo
    /// tick `analogue` gets the tick's [`ServoReading`] and returns the input, in micrometres
    /// of position command, that the controller adds to the command from the next tick on.
    /// The recorded probe column is the true tool position (no probe noise): the error a cut
    /// leaves.
    pub fn run_with_analogue(
        &self,
        freq_hz: f64,
        amp_um: f64,
        duration_s: f64,
        seed: u64,
        analogue: &mut dyn FnMut(&ServoReading) -> f64,
    ) -> [Vec<f64>; 4] {
        self.simulate(freq_hz, amp_um, duration_s, seed, Some(analogue))
    }

    fn simulate(
        &self,
        freq_hz: f64,
        amp_um: f64,
        duration_s: f64,
        seed: u64,
        mut analogue: Option<&mut dyn FnMut(&ServoReading) -> f64>,
    ) -> [Vec<f64>; 4] {
        let grid_hz = RATE_HZ * SUBSTEPS as f64;
        let record_every = (grid_hz / self.record_hz).round() as usize;
        assert!((grid_hz / record_every as f64 - self.record_hz).abs() < 1e-9, "record_hz must divide {grid_hz} Hz");
        let ts = 1.0 / RATE_HZ;
        let dt = ts / SUBSTEPS as f64;
        let mut noise = Noise::new(seed);
        let mut s = State::default();
        let mut out: [Vec<f64>; 4] = Default::default();
        let (mut enc_prev, mut vel_est, mut integral, mut cmd_prev) = (0.0, 0.0, 0.0, 0.0);
        let mut pending = vec![0.0; self.delay_ticks.max(1)];
        let alpha = 1.0 - (-2.0 * PI * self.vel_filter_hz * ts).exp();
        // At rest before the start (a late setpoint reaches back there).
        let command = |t: f64| if t < 0.0 { 0.0 } else { amp_um * 1e-6 * (2.0 * PI * freq_hz * t).sin() };
        let encoder = |x: f64| (x / (self.encoder_um * 1e-6)).round() * self.encoder_um * 1e-6;
        let records = (duration_s * self.record_hz).round() as usize;
        // The sensors' noise has a density: per sample it grows with the recorder's bandwidth
        // (the noise figures are per sample at the servo's 8 kHz).
        let noise_scale = (self.record_hz / RATE_HZ).sqrt();
        let probe_noise_um = if analogue.is_some() { 0.0 } else { self.probe_noise_um };
        let mut analogue_um = 0.0;
        for i in 0..records * record_every {
            let t = i as f64 * dt;
            if i % record_every == 0 {
                out[0].push(command(t) * 1e6);
                out[1].push(encoder(s.x1) * 1e6);
                let tool_m = s.x2 + self.mode_share() * s.r;
                out[2].push(self.probe_gain * tool_m * 1e6 + noise_scale * probe_noise_um * noise.gaussian());
                let d = self.derivative(&s, pending[0]);
                let tool_mps2 = d.v2 + self.mode_share() * d.vr;
                out[3].push(tool_mps2 + noise_scale * self.acc_noise_mps2 * noise.gaussian());
            }
            if i % SUBSTEPS == 0 {
                // The controller: velocity from the encoder's difference, filtered.
                let (cmd, enc) = (command(t - self.setpoint_delay_s) + analogue_um * 1e-6, encoder(s.x1));
                vel_est += alpha * ((enc - enc_prev) / ts - vel_est);
                enc_prev = enc;
                let vel_cmd = self.kpp_per_s * (cmd - enc) + self.vff * (cmd - cmd_prev) / ts;
                cmd_prev = cmd;
                integral += (vel_cmd - vel_est) * ts;
                let force_cmd = self.kvp_ns_per_m * (vel_cmd - vel_est) + self.kvi_n_per_m * integral;
                pending.rotate_left(1);
                *pending.last_mut().unwrap() = force_cmd;
                if let Some(analogue) = analogue.as_mut() {
                    let d = self.derivative(&s, pending[0]);
                    let tick = i / SUBSTEPS;
                    analogue_um = analogue(&ServoReading {
                        tick,
                        acc_mps2: d.v2 + self.mode_share() * d.vr + self.acc_noise_mps2 * noise.gaussian(),
                        next_t_s: (tick + 1) as f64 / RATE_HZ,
                        next_cmd_um: command((tick + 1) as f64 / RATE_HZ) * 1e6,
                    });
                }
            }
            s = self.rk4(&s, pending[0], dt);
        }
        out
    }

    /// Measures the grid into `dir` as a lab would export it ([`write_dataset`]).
    pub fn measure(&self, dir: &Path, freqs_hz: &[f64], amps_um: &[f64], duration_s: f64, seed: u64) {
        let groups = freqs_hz.iter().flat_map(|f| amps_um.iter().map(move |a| (*f, *a)));
        write_dataset(dir, self.record_hz, "foreign two-mass slide, cascaded servo (test)", groups, |i, f, a| {
            self.run(f, a, duration_s, seed * 1000 + i as u64)
        });
    }
}

/// What the co-processor reads at a servo tick of [`Foreign::run_with_analogue`]: the
/// accelerometer now, and the command the controller is sent at the next tick.
pub struct ServoReading {
    pub tick: usize,
    pub acc_mps2: f64,
    pub next_t_s: f64,
    pub next_cmd_um: f64,
}

/// Writes groups as a lab would export them: one CSV file per group by hand (columns in
/// another order than the tools', CRLF line ends, other decimals), groups 1.5 s apart on
/// machine time (the operator's pauses), no ADC scale in the manifest. `run(i, freq_hz,
/// amp_um)` records group `i`: command, encoder, probe and accelerometer at `record_hz`.
pub fn write_dataset(
    dir: &Path,
    record_hz: f64,
    description: &str,
    groups: impl Iterator<Item = (f64, f64)>,
    run: impl Fn(usize, f64, f64) -> [Vec<f64>; 4],
) {
    std::fs::create_dir_all(dir).unwrap();
    let mut manifest_groups = Vec::new();
    let mut start_s = 0.0;
    for (i, (f, a)) in groups.enumerate() {
        let [cmd, enc, tcp, acc] = run(i, f, a);
        let mut csv = String::from("t_s,acc_mps2,z_cmd_um,z_tcp_um,z_enc_um\r\n");
        for k in 0..cmd.len() {
            writeln!(csv, "{:.8},{:.6},{:.6},{:.6},{:.4}\r", k as f64 / record_hz, acc[k], cmd[k], tcp[k], enc[k])
                .unwrap();
        }
        let file = format!("run-{f}hz-{a}um.csv");
        std::fs::write(dir.join(&file), csv).unwrap();
        manifest_groups.push(serde_json::json!({"file": file, "freq_hz": f, "amp_um": a, "start_s": start_s}));
        start_s += cmd.len() as f64 / record_hz + 1.5;
    }
    let manifest = serde_json::json!({
        "format": "sts-twin-dataset/1",
        "sample_rate_hz": record_hz,
        "description": description,
        "groups": manifest_groups,
    });
    std::fs::write(dir.join("manifest.json"), serde_json::to_string_pretty(&manifest).unwrap()).unwrap();
}

/// Gaussian noise (xorshift64* and Box-Muller): the foreign machine owes nothing to the
/// emulator's random streams.
struct Noise(u64);

impl Noise {
    fn new(seed: u64) -> Self {
        Self(seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1)
    }
    fn uniform(&mut self) -> f64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        ((self.0.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 11) as f64 + 0.5) / (1u64 << 53) as f64
    }
    fn gaussian(&mut self) -> f64 {
        (-2.0 * self.uniform().ln()).sqrt() * (2.0 * PI * self.uniform()).cos()
    }
}
