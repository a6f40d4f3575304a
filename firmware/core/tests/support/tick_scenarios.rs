//! The servo tick's test scenarios, shared by the golden hashes (`tick_golden`) and the check
//! against the f64 reference (`tick_reference`): the input stream and the programs of the
//! twin's runs, and the random terms, model updates and per-tick inputs that drive the
//! synthesiser directly. Each run hands every tick (and, for the synthesiser, every call)
//! to a closure, so that both tests see the same runs.

use sts_twin_core::bus::{InputSlot, OutputSlot, IN_FLAG_PHASE_VALID};
use sts_twin_core::features::FeatureConfig;
use sts_twin_core::feedforward::FeedforwardParams;
use sts_twin_core::program::{
    paper_program, ModelOutput, Program, ProgramBuilder, TermInput, TickTerm, LAGUERRE_STAGES, REG_AMP_UM,
    REG_PHASE_DEG,
};
use sts_twin_core::servo::ServoConfig;
use sts_twin_core::synth::TickInput;
use sts_twin_core::twin::Twin;
use sts_twin_core::wire::{Request, Response};

/// FNV-1a, 64 bits.
pub struct Hash(pub u64);

impl Hash {
    pub fn new() -> Self {
        Self(0xcbf2_9ce4_8422_2325)
    }

    pub fn add(&mut self, value: i64) {
        for byte in value.to_le_bytes() {
            self.0 = (self.0 ^ u64::from(byte)).wrapping_mul(0x0000_0100_0000_01b3);
        }
    }
}

pub fn xorshift(seed: &mut u64) -> u64 {
    *seed ^= *seed << 13;
    *seed ^= *seed >> 7;
    *seed ^= *seed << 17;
    *seed
}

/// A 40 Hz motion whose amplitude changes, with pseudo-noise, and a command position that
/// also jumps now and then (a new cut).
pub fn input(k: u32) -> InputSlot {
    let t = k as f64 / 8000.0;
    let amp = 4000.0 + 2000.0 * (2.0 * std::f64::consts::PI * 0.3 * t).sin();
    let phase = 2.0 * std::f64::consts::PI * 40.0 * t;
    let noise = ((k.wrapping_mul(2_654_435_761) >> 16) % 9) as f64 - 4.0;
    let jump = if (k / 3000) % 2 == 1 { 40_000 } else { 0 };
    InputSlot {
        tick: k,
        acc_code: (-amp * phase.sin() + noise).round() as i16,
        flags: IN_FLAG_PHASE_VALID,
        cmd_phase_turns: ((40.0 * t).fract() * 4_294_967_296.0) as u64 as u32,
        cmd_pos_nm: (3000.0 * phase.sin()) as i32 + jump,
        // The hashes date from before the bus carried the other axes (the servo passed zero).
        x_acc_um_per_s2: 0,
        spindle_turns: 0,
    }
}

pub fn laguerre(input: TermInput, pole: f64, scale: i32) -> TickTerm {
    let mut gains_pm = [0i32; LAGUERRE_STAGES];
    for (i, gain) in gains_pm.iter_mut().enumerate() {
        *gain = scale / (i as i32 + 1) * if i % 2 == 0 { 1 } else { -1 };
    }
    TickTerm::Laguerre { input, pole_q30: (pole * (1u64 << 30) as f64).round() as i32, gains_pm }
}

/// RMS-driven amplitude and a frequency-driven phase, with harmonic coefficients in
/// registers 2..8 (also driven by the features).
pub fn program(id: u32, terms: &[TickTerm]) -> Program {
    let mut b = ProgramBuilder::new();
    b.id(id).constant(2.0).feature(4).mul().store(REG_AMP_UM);
    b.constant(-0.2).feature(0).mul().store(REG_PHASE_DEG);
    b.constant(0.4).feature(4).mul().store(2).constant(25.0).feature(9).mul().store(3);
    b.constant(0.15).feature(3).mul().store(4).constant(-70.0).store(5);
    b.constant(0.05).feature(1).mul().store(6).constant(130.0).feature(6).add().store(7);
    for term in terms {
        b.term(*term);
    }
    b.finish().expect("a valid program")
}

pub fn harmonic(order: u8, amp_reg: u8) -> TickTerm {
    TickTerm::Harmonic { order, amp_reg, phase_reg: amp_reg + 1 }
}

/// The programs of the twin's runs, in order: harmonics alone, a velocity-sign bank with a
/// drift, a harmonic beside a position-sine bank and a drift, two harmonics, and the paper's
/// program with a Dahl bank and a drift (each within the tick's budget).
pub fn programs() -> Vec<Program> {
    let drift = TickTerm::Drift { offset_pm: 300_000, decay_pm: -450_000, tau_ticks: 9000 };
    let velocity = laguerre(TermInput::VelocitySign { smooth_nm_per_4_ticks: 300 }, 0.93, 150_000);
    let dahl = laguerre(TermInput::Dahl { inv_x0_q30: (1 << 30) / 2000 }, 0.93, 120_000);
    let sine = laguerre(TermInput::PositionSine { turns_per_nm: 4_294_967, phase_turns: 7 << 28 }, 0.9, 90_000);
    let mut harmonics = vec![];
    for (i, order) in (2..10).enumerate() {
        harmonics.push(harmonic(order, 2 + 2 * (i as u8 % 3)));
    }
    vec![
        program(11, &harmonics),
        program(12, &[velocity, drift]),
        // Kernels beside one harmonic (two would be over the tick's budget).
        program(13, &[harmonic(3, 2), sine, drift]),
        program(14, &[harmonic(3, 2), harmonic(2, 4)]),
        {
            let mut paper = paper_program();
            paper.terms.push(dahl).unwrap();
            paper.terms.push(drift).unwrap();
            paper
        },
    ]
}

/// The feedforward parameters of the twin's runs: a short enable ramp and a slew limit that
/// the 40 Hz correction reaches.
pub fn twin_params() -> FeedforwardParams {
    FeedforwardParams { enable_ramp_ticks: 400, slew_v_per_tick: 0.05, ..FeedforwardParams::default() }
}

/// The requests of a run that changes programs: [`programs`] in turn, each for a sixth of
/// `ticks`, then none (cleared).
pub fn switching_requests(ticks: u32) -> impl Fn(u32) -> Option<Request> {
    let programs = programs();
    let change_every = ticks / (programs.len() as u32 + 1);
    move |k| {
        (k % change_every == 0).then(|| match programs.get((k / change_every) as usize) {
            Some(program) => Request::UploadProgram { program: program.clone(), activate: true },
            None => Request::ClearProgram,
        })
    }
}

/// The requests of a run with `program` uploaded at the start and never switched.
pub fn one_program_requests(program: &Program) -> impl Fn(u32) -> Option<Request> + '_ {
    move |k| (k == 0).then(|| Request::UploadProgram { program: program.clone(), activate: true })
}

/// Runs the twin for `ticks` ticks under `window_samples` and `params`, handling the request
/// `request_at(k)` before tick `k`, and hands each tick's output to `each_tick` with the twin
/// after it. Returns the hash of every output.
pub fn twin_run(
    window_samples: u32,
    ticks: u32,
    params: FeedforwardParams,
    request_at: impl Fn(u32) -> Option<Request>,
    mut each_tick: impl FnMut(u32, &Twin, &OutputSlot),
) -> u64 {
    let mut twin =
        Box::new(Twin::boot(FeatureConfig { window_samples, ..FeatureConfig::DEFAULT }, ServoConfig::default(), &[]));
    assert_eq!(twin.handle(Request::SetParams(params)), Response::Ack);
    // The stream is open loop (the accelerometer does not see the DAC): no machine for the
    // supervisor to judge, and the pinned outputs are the pipeline's without it.
    let off = sts_twin_core::supervisor::SupervisorParams { active: false, ..Default::default() };
    assert_eq!(twin.handle(Request::SetSupervisor(off)), Response::Ack);
    assert_eq!(twin.handle(Request::SetEnabled(true)), Response::Ack);
    let mut hash = Hash::new();
    let mut predicting = 0u32;
    for k in 0..ticks {
        if let Some(request) = request_at(k) {
            assert_eq!(twin.handle(request), Response::Ack);
        }
        let out = twin.tick(Some(&input(k)));
        hash.add(i64::from(out.dac_code));
        hash.add(i64::from(out.de_pred_pm));
        hash.add(i64::from(out.flags));
        predicting += u32::from(out.de_pred_pm != 0);
        each_tick(k, &twin, &out);
    }
    // The run exercises what it should: predictions most of the time, many model updates.
    assert!(predicting > ticks / 2, "{predicting} ticks with a prediction");
    assert!(twin.servo().counters().model_updates > 100, "{:?}", twin.servo().counters());
    hash.0
}

/// A random term of any kind the synthesiser runs without a model of its own (poles inside
/// and beyond the narrow range, inputs on every path).
pub fn random_term(seed: &mut u64) -> TickTerm {
    let r = xorshift(seed);
    match r % 6 {
        0 | 1 => TickTerm::Harmonic {
            order: 1 + (r >> 8) as u8 % 15,
            amp_reg: 2 + 2 * ((r >> 16) % 3) as u8,
            phase_reg: 3 + 2 * ((r >> 20) % 3) as u8,
        },
        2 => TickTerm::Drift {
            offset_pm: (r >> 8) as i32 % 2_000_000,
            decay_pm: (r >> 24) as i32 % 3_000_000,
            tau_ticks: 256 + (r >> 40) as u32 % 100_000,
        },
        3 => TickTerm::AxisCoupling {
            x_gain_pm_per_mps2: (r >> 8) as i32,
            spindle_amp_pm: (r >> 20) as i32 % 1_000_000,
            spindle_phase_turns: (r >> 32) as u32,
        },
        _ => {
            let input = match (r >> 8) % 4 {
                0 => TermInput::VelocitySign { smooth_nm_per_4_ticks: 1 + (r >> 12) as i32 % 300 },
                1 => TermInput::VelocitySign { smooth_nm_per_4_ticks: 1 + ((r >> 12) as i32 & i32::MAX) },
                2 => TermInput::Dahl { inv_x0_q30: 1 + ((r >> 16) as i32 & 0x7fff_ffff) % (1 << 24) },
                _ => TermInput::PositionSine { turns_per_nm: 1 + (r >> 16) as u32, phase_turns: (r >> 32) as u32 },
            };
            let pole = [0.3, 0.93, 0.99, 0.9949, 0.9951, 0.999, 0.99999][(r >> 40) as usize % 7];
            let scale = [1, 1_000, 150_000, i32::MAX / 9][(r >> 44) as usize % 4];
            laguerre(input, pole, scale)
        }
    }
}

/// One call on the synthesiser in a run that drives it directly.
#[derive(Clone, Debug)]
pub enum SynthStep {
    /// A model update: `Synth::update` of `output` and `terms` after setting the ramp length.
    Update { output: ModelOutput, terms: Vec<TickTerm>, ramp_ticks: u32 },
    /// `Synth::set_time_ticks`.
    SetTime(u64),
    /// `Synth::restart_kernels`.
    Restart,
    /// `Synth::next_input`: one tick.
    Tick(TickInput),
}

/// The calls of a run of `ticks` ticks that drives the synthesiser directly, handed to
/// `each` in order: random model updates (new random terms each time, or always
/// `fixed_terms`) with random ramp lengths, machine-time jumps, restarts, and per-tick inputs
/// with X acceleration, spindle angle and position jumps.
pub fn synth_steps(seed: u64, ticks: u32, fixed_terms: Option<&[TickTerm]>, mut each: impl FnMut(SynthStep)) {
    let mut seed = seed;
    let mut pos: i64 = 0;
    let mut theta = 0u32;
    for _ in 0..ticks {
        let r = xorshift(&mut seed);
        if r.is_multiple_of(97) {
            let terms: Vec<TickTerm> = match fixed_terms {
                Some(terms) => terms.to_vec(),
                None => {
                    let count = (xorshift(&mut seed) % 9) as usize;
                    (0..count).map(|_| random_term(&mut seed)).collect()
                }
            };
            let mut output = ModelOutput::default();
            for register in output.registers.iter_mut() {
                *register = (xorshift(&mut seed) % 4000) as f32 * 1e-3 - 1.0;
            }
            output.registers[1] = (xorshift(&mut seed) % 720) as f32 - 360.0;
            let ramp_ticks = [0, 1, 7, 80, 80][(xorshift(&mut seed) % 5) as usize];
            each(SynthStep::Update { output, terms, ramp_ticks });
        }
        if r.is_multiple_of(1009) {
            each(SynthStep::SetTime(xorshift(&mut seed) % 100_000_000));
        }
        if r.is_multiple_of(1013) {
            each(SynthStep::Restart);
        }
        pos += match (r >> 12) % 50 {
            0 => (xorshift(&mut seed) % 2_000_001) as i64 - 1_000_000,
            1 => 0,
            _ => ((r >> 20) % 801) as i64 - 400,
        };
        pos = pos.clamp(i32::MIN as i64, i32::MAX as i64);
        theta = theta.wrapping_add(5_368_709 + (r >> 40) as u32 % 1000);
        let x_acc = match (r >> 30) % 8 {
            0 => i32::MAX,
            1 => i32::MIN,
            2 => 0,
            _ => (r >> 32) as i32 % 10_000_000,
        };
        each(SynthStep::Tick(TickInput {
            cmd_phase_turns: theta,
            cmd_pos_nm: pos as i32,
            x_acc_um_per_s2: x_acc,
            spindle_turns: (r >> 8) as u32,
        }));
    }
}

/// The terms of a run without a program switch: `term_count` random ones, drawn from `seed`;
/// returns them and the seed to drive the run with.
pub fn fixed_random_terms(seed: u64, term_count: usize) -> (Vec<TickTerm>, u64) {
    let mut seed = seed;
    let terms = (0..term_count).map(|_| random_term(&mut seed)).collect();
    (terms, seed)
}

/// Ticks of each run that drives the synthesiser directly.
pub const SYNTH_TICKS: u32 = 60_000;
/// Seeds of the runs with new random terms at every model update.
pub const SYNTH_SEEDS: [u64; 2] = [0x5eed_0001, 0x5eed_0002];
/// Seeds and term counts of the runs without a program switch.
pub const SYNTH_ONE_PROGRAM_RUNS: [(u64, usize); 4] =
    [(0x5eed_0003, 8), (0x5eed_0004, 8), (0x5eed_0005, 3), (0x5eed_0006, 5)];

/// The twin's feature windows: model updates every 112 ticks (the synthesiser's ramps settle
/// in between) and every 48 (they never do).
pub const TWIN_WINDOWS: [u32; 2] = [2000, 800];
/// Ticks of the twin's runs with program switches, and of those with one program.
pub const TWIN_TICKS: u32 = 24_000;
pub const TWIN_ONE_PROGRAM_TICKS: u32 = 16_000;
