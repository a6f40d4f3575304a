//! A machine that is not our emulator: a two-mass Z slide under a cascaded servo (P position
//! loop, PI velocity loop on a filtered encoder difference, partial velocity feedforward),
//! with LuGre friction, a lightly damped tool-post mode (a modal mass on the carrier) and a
//! late setpoint as options, written here from textbook equations and nothing of `sts-emulator`
//! or of the twin's own axis model (which is a PID with its friction a static map). Its
//! measurements are written as a lab would export them: CSV files by hand, columns in another
//! order, CRLF line ends, other decimals, no ADC scale in the manifest. It also steps one
//! servo tick at a time as an [`sts_rig::Plant`] ([`Foreign::plant`]), so that the rig's
//! calibration and loop run on it as on the emulator.

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
        let grid_hz = RATE_HZ * SUBSTEPS as f64;
        let record_every = (grid_hz / self.record_hz).round() as usize;
        assert!((grid_hz / record_every as f64 - self.record_hz).abs() < 1e-9, "record_hz must divide {grid_hz} Hz");
        // At rest before the start (a late setpoint reaches back there).
        let command = |t: f64| if t < 0.0 { 0.0 } else { amp_um * 1e-6 * (2.0 * PI * freq_hz * t).sin() };
        let records = (duration_s * self.record_hz).round() as usize;
        // The sensors' noise has a density: per sample it grows with the recorder's bandwidth
        // (the noise figures are per sample at the servo's 8 kHz).
        let noise_scale = (self.record_hz / RATE_HZ).sqrt();
        let mut run = Running::new(self, seed);
        let mut out: [Vec<f64>; 4] = Default::default();
        for i in 0..records * record_every {
            if i % record_every == 0 {
                let t = run.t_s();
                out[0].push(command(t) * 1e6);
                out[1].push(run.encoder_um());
                out[2].push(run.probe_um(noise_scale * self.probe_noise_um));
                out[3].push(run.acc_mps2(noise_scale * self.acc_noise_mps2));
            }
            if i % SUBSTEPS == 0 {
                run.control(command(run.t_s() - self.setpoint_delay_s));
            }
            run.integrate();
        }
        out
    }

    /// The machine on a rig ([`sts_rig::Plant`]), from rest: its controller's analogue input
    /// adds `um_per_v` micrometres of position command per volt, and its accelerometer
    /// reads in codes of `acc_mps2_per_lsb`.
    pub fn plant(&self, seed: u64, um_per_v: f64, acc_mps2_per_lsb: f64) -> ForeignPlant<'_> {
        let late_ticks = (self.setpoint_delay_s * RATE_HZ).round() as usize;
        ForeignPlant {
            run: Running::new(self, seed),
            um_per_v,
            acc_mps2_per_lsb,
            sent_um: std::collections::VecDeque::from(vec![0.0; late_ticks]),
        }
    }

    /// Measures the grid into `dir` as a lab would export it ([`write_dataset`]).
    pub fn measure(&self, dir: &Path, freqs_hz: &[f64], amps_um: &[f64], duration_s: f64, seed: u64) {
        let groups = freqs_hz.iter().flat_map(|f| amps_um.iter().map(move |a| (*f, *a)));
        write_dataset(dir, self.record_hz, "foreign two-mass slide, cascaded servo (test)", groups, |i, f, a| {
            self.run(f, a, duration_s, seed * 1000 + i as u64)
        });
    }
}

/// One run of the machine from rest: the slide's state, the controller's and the sensors'
/// noise, advanced one integration substep (`1 / (RATE_HZ * SUBSTEPS)`) at a time. The
/// controller acts on the first substep of each servo tick.
struct Running<'m> {
    machine: &'m Foreign,
    s: State,
    noise: Noise,
    /// Substeps so far.
    i: usize,
    enc_prev: f64,
    vel_est: f64,
    integral: f64,
    cmd_prev: f64,
    /// Force commands on their way to the current loop, oldest first.
    pending: Vec<f64>,
    /// The velocity filter's coefficient per servo tick.
    alpha: f64,
}

impl<'m> Running<'m> {
    fn new(machine: &'m Foreign, seed: u64) -> Self {
        let ts = 1.0 / RATE_HZ;
        Self {
            machine,
            s: State::default(),
            noise: Noise::new(seed),
            i: 0,
            enc_prev: 0.0,
            vel_est: 0.0,
            integral: 0.0,
            cmd_prev: 0.0,
            pending: vec![0.0; machine.delay_ticks.max(1)],
            alpha: 1.0 - (-2.0 * PI * machine.vel_filter_hz * ts).exp(),
        }
    }

    /// Time of the next substep, s.
    fn t_s(&self) -> f64 {
        self.i as f64 * (1.0 / RATE_HZ / SUBSTEPS as f64)
    }

    fn encoder_m(&self, x: f64) -> f64 {
        let um = self.machine.encoder_um;
        (x / (um * 1e-6)).round() * um * 1e-6
    }

    /// The encoder's reading, um.
    fn encoder_um(&self) -> f64 {
        self.encoder_m(self.s.x1) * 1e6
    }

    /// The tool's true position, m.
    fn tool_m(&self) -> f64 {
        self.s.x2 + self.machine.mode_share() * self.s.r
    }

    /// The probe's reading with `noise_um` RMS of noise, um.
    fn probe_um(&mut self, noise_um: f64) -> f64 {
        self.machine.probe_gain * self.tool_m() * 1e6 + noise_um * self.noise.gaussian()
    }

    /// The accelerometer at the tool with `noise_mps2` RMS of noise, m/s^2.
    fn acc_mps2(&mut self, noise_mps2: f64) -> f64 {
        let d = self.machine.derivative(&self.s, self.pending[0]);
        d.v2 + self.machine.mode_share() * d.vr + noise_mps2 * self.noise.gaussian()
    }

    /// The controller at a servo tick, with the position command `cmd` (m) as it reaches it:
    /// velocity from the encoder's difference, filtered, a P position loop with velocity
    /// feedforward and a PI velocity loop; its force command joins the queue.
    fn control(&mut self, cmd: f64) {
        let m = self.machine;
        let ts = 1.0 / RATE_HZ;
        let enc = self.encoder_m(self.s.x1);
        self.vel_est += self.alpha * ((enc - self.enc_prev) / ts - self.vel_est);
        self.enc_prev = enc;
        let vel_cmd = m.kpp_per_s * (cmd - enc) + m.vff * (cmd - self.cmd_prev) / ts;
        self.cmd_prev = cmd;
        self.integral += (vel_cmd - self.vel_est) * ts;
        let force_cmd = m.kvp_ns_per_m * (vel_cmd - self.vel_est) + m.kvi_n_per_m * self.integral;
        self.pending.rotate_left(1);
        *self.pending.last_mut().unwrap() = force_cmd;
    }

    /// One integration substep with the oldest force command.
    fn integrate(&mut self) {
        self.s = self.machine.rk4(&self.s, self.pending[0], 1.0 / RATE_HZ / SUBSTEPS as f64);
        self.i += 1;
    }
}

/// [`Foreign`] on a rig, one servo tick per [`sts_rig::Plant::step`] ([`Foreign::plant`]).
/// The command of each tick is held over the tick (a late setpoint arrives whole ticks late);
/// the controller reads its analogue input exactly and adds `um_per_v` per volt of it to the
/// command while enabled. Its "pulses" are that addition in whole nanometres. The probe reads
/// with its noise and scale, the accelerometer with its noise.
pub struct ForeignPlant<'m> {
    run: Running<'m>,
    um_per_v: f64,
    acc_mps2_per_lsb: f64,
    /// The commands sent and not yet arrived, um.
    sent_um: std::collections::VecDeque<f64>,
}

impl sts_rig::Plant for ForeignPlant<'_> {
    fn step(&mut self, input: &sts_rig::PlantInput) -> sts_rig::PlantReading {
        let run = &mut self.run;
        let machine = run.machine;
        let time_s = run.t_s();
        let z_enc_um = run.encoder_um();
        let z_tcp_true_um = run.tool_m() * 1e6;
        let z_tcp_um = run.probe_um(machine.probe_noise_um);
        self.sent_um.push_back(input.z_cmd_um);
        let cmd_um = self.sent_um.pop_front().unwrap_or(input.z_cmd_um);
        let analogue_um = if input.analog_enabled { input.analog_in_v * self.um_per_v } else { 0.0 };
        run.control((cmd_um + analogue_um) * 1e-6);
        let acc_mps2 = run.acc_mps2(machine.acc_noise_mps2);
        for _ in 0..SUBSTEPS {
            run.integrate();
        }
        sts_rig::PlantReading {
            time_s,
            z_enc_um,
            z_tcp_um,
            z_tcp_true_um,
            acc_code: sts_analysis::features::acc_code(acc_mps2, self.acc_mps2_per_lsb),
            ain_read_v: input.analog_in_v,
            ain_pulses: (input.analog_in_v * self.um_per_v * 1e3).round() as i64,
        }
    }
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
