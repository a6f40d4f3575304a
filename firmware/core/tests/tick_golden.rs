//! The servo tick's outputs pinned bit for bit: a hash of every DAC code and prediction of
//! long runs with every kind of per-tick term (five programs within the tick budget: harmonics,
//! Laguerre banks on each input, a drift, a servo-axis twin), program changes and both update
//! schedules (ramps that settle between model results and ramps that never do), and of the
//! synthesiser driven directly with random terms (64-bit Laguerre stages, divisions, couplings)
//! and the inputs the bus does not carry yet. Any change of output, however small, fails here.
//!
//! The runs without a program switch (each program alone, the synthesiser with fixed terms)
//! and those with switches are pinned apart, so that a change of the switching behaviour
//! leaves the first ones standing. A hash is pinned again only with a change of behaviour on
//! purpose, whose commit says what changed and why (`git log -- firmware/core/tests/tick_golden.rs`);
//! a change of speed alone must leave every hash as it is. What the hashes cannot say, that the
//! outputs are right, other tests check against plain computations: `synth::kernel`'s unit
//! tests hold each fast kernel to its plain 64-bit form (the velocity sign without a 64-bit
//! division exactly, the coupling's product within its bound), and the HIL tests hold the
//! firmware's DAC codes to the host core's.

use sts_twin_core::bus::{InputSlot, IN_FLAG_PHASE_VALID};
use sts_twin_core::features::FeatureConfig;
use sts_twin_core::feedforward::FeedforwardParams;
use sts_twin_core::program::{
    paper_program, Program, ProgramBuilder, TermInput, TickTerm, LAGUERRE_STAGES, REG_AMP_UM, REG_PHASE_DEG,
};
use sts_twin_core::servo::ServoConfig;
use sts_twin_core::synth::{Synth, TickInput};
use sts_twin_core::twin::Twin;
use sts_twin_core::wire::{Request, Response};

/// FNV-1a, 64 bits.
struct Hash(u64);

impl Hash {
    fn new() -> Self {
        Self(0xcbf2_9ce4_8422_2325)
    }

    fn add(&mut self, value: i64) {
        for byte in value.to_le_bytes() {
            self.0 = (self.0 ^ u64::from(byte)).wrapping_mul(0x0000_0100_0000_01b3);
        }
    }
}

fn xorshift(seed: &mut u64) -> u64 {
    *seed ^= *seed << 13;
    *seed ^= *seed >> 7;
    *seed ^= *seed << 17;
    *seed
}

/// A 40 Hz motion whose amplitude changes, with pseudo-noise, and a command position that
/// also jumps now and then (a new cut).
fn input(k: u32) -> InputSlot {
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

fn laguerre(input: TermInput, pole: f64, scale: i32) -> TickTerm {
    let mut gains_pm = [0i32; LAGUERRE_STAGES];
    for (i, gain) in gains_pm.iter_mut().enumerate() {
        *gain = scale / (i as i32 + 1) * if i % 2 == 0 { 1 } else { -1 };
    }
    TickTerm::Laguerre { input, pole_q30: (pole * (1u64 << 30) as f64).round() as i32, gains_pm }
}

/// RMS-driven amplitude and a frequency-driven phase, with harmonic coefficients in
/// registers 2..8 (also driven by the features).
fn program(id: u32, terms: &[TickTerm]) -> Program {
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

fn harmonic(order: u8, amp_reg: u8) -> TickTerm {
    TickTerm::Harmonic { order, amp_reg, phase_reg: amp_reg + 1 }
}

/// The programs of the run, in order.
fn programs() -> Vec<Program> {
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

/// Runs the twin for `ticks` ticks under `window_samples`, changing programs on the way,
/// and hashes every output.
fn twin_hash(window_samples: u32, ticks: u32) -> u64 {
    let programs = programs();
    let change_every = ticks / (programs.len() as u32 + 1);
    twin_run(window_samples, ticks, |k| {
        (k % change_every == 0).then(|| match programs.get((k / change_every) as usize) {
            Some(program) => Request::UploadProgram { program: program.clone(), activate: true },
            None => Request::ClearProgram,
        })
    })
}

/// Runs the twin for `ticks` ticks under `window_samples` with `program` uploaded at the
/// start and never switched, and hashes every output.
fn twin_hash_one_program(window_samples: u32, ticks: u32, program: &Program) -> u64 {
    twin_run(window_samples, ticks, |k| {
        (k == 0).then(|| Request::UploadProgram { program: program.clone(), activate: true })
    })
}

/// Runs the twin for `ticks` ticks under `window_samples`, handling the request
/// `request_at(k)` before tick `k`, and hashes every output.
fn twin_run(window_samples: u32, ticks: u32, request_at: impl Fn(u32) -> Option<Request>) -> u64 {
    let mut twin =
        Box::new(Twin::boot(FeatureConfig { window_samples, ..FeatureConfig::DEFAULT }, ServoConfig::default(), &[]));
    let params = FeedforwardParams { enable_ramp_ticks: 400, slew_v_per_tick: 0.05, ..FeedforwardParams::default() };
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
    }
    // The run exercises what it should: predictions most of the time, many model updates.
    assert!(predicting > ticks / 2, "{predicting} ticks with a prediction");
    assert!(twin.servo().counters().model_updates > 100, "{:?}", twin.servo().counters());
    hash.0
}

#[test]
fn the_twins_outputs_are_those_pinned_ramps_settling_between_updates() {
    assert_eq!(twin_hash(2000, 24_000), 1_172_237_732_981_430_062, "window 2000");
}

#[test]
fn the_twins_outputs_are_those_pinned_ramps_never_settling() {
    assert_eq!(twin_hash(800, 24_000), 18_048_703_951_985_695_510, "window 800");
}

/// Each program of the run alone, never switched, under both schedules: a program switch may
/// change the outputs of the ticks after it, a run without one must not change at all.
#[test]
fn the_twins_outputs_without_a_program_switch_are_those_pinned() {
    let pinned: [[u64; 2]; 5] = [
        [9_100_906_065_443_868_003, 9_571_390_674_043_219_037],
        [4_715_860_211_714_405_979, 3_838_874_250_454_834_930],
        [9_679_915_960_794_309_429, 8_331_655_143_772_813_187],
        [14_419_431_135_460_686_159, 16_391_232_033_328_672_457],
        [13_188_647_319_128_626_359, 2_583_491_077_265_107_475],
    ];
    let mut got = vec![];
    for program in programs().iter() {
        got.push([2000, 800].map(|window| twin_hash_one_program(window, 16_000, program)));
    }
    assert_eq!(got, pinned);
}

/// A random term of any kind (poles inside and beyond the narrow range, inputs on every path).
fn random_term(seed: &mut u64) -> TickTerm {
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

/// Drives the synthesiser directly: random programs, ramp lengths, machine-time jumps,
/// restarts, and per-tick inputs with X acceleration, spindle angle and position jumps.
fn synth_hash(seed: u64, ticks: u32) -> u64 {
    synth_run(seed, ticks, None)
}

/// [`synth_hash`] with the `term_count` random terms drawn once: model updates without a
/// program switch.
fn synth_hash_one_program(seed: u64, ticks: u32, term_count: usize) -> u64 {
    let mut seed = seed;
    let terms: Vec<TickTerm> = (0..term_count).map(|_| random_term(&mut seed)).collect();
    synth_run(seed, ticks, Some(&terms))
}

/// [`synth_hash`], with new random terms at every model update or always `fixed_terms`.
fn synth_run(seed: u64, ticks: u32, fixed_terms: Option<&[TickTerm]>) -> u64 {
    let mut seed = seed;
    let mut synth = Synth::new(80);
    let mut hash = Hash::new();
    let mut pos: i64 = 0;
    let mut theta = 0u32;
    for k in 0..ticks {
        let r = xorshift(&mut seed);
        if r % 97 == 0 {
            let terms: Vec<TickTerm> = match fixed_terms {
                Some(terms) => terms.to_vec(),
                None => {
                    let count = (xorshift(&mut seed) % 9) as usize;
                    (0..count).map(|_| random_term(&mut seed)).collect()
                }
            };
            let mut output = sts_twin_core::program::ModelOutput::default();
            for register in output.registers.iter_mut() {
                *register = (xorshift(&mut seed) % 4000) as f32 * 1e-3 - 1.0;
            }
            output.registers[1] = (xorshift(&mut seed) % 720) as f32 - 360.0;
            synth.ramp_ticks = [0, 1, 7, 80, 80][(xorshift(&mut seed) % 5) as usize];
            synth.update(&output, &terms);
        }
        if r % 1009 == 0 {
            synth.set_time_ticks(xorshift(&mut seed) % 100_000_000);
        }
        if r % 1013 == 0 {
            synth.restart_kernels();
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
        let tick_input = TickInput {
            cmd_phase_turns: theta,
            cmd_pos_nm: pos as i32,
            x_acc_um_per_s2: x_acc,
            spindle_turns: (r >> 8) as u32,
        };
        hash.add(i64::from(synth.next_input(&tick_input)));
        let _ = k;
    }
    hash.0
}

#[test]
fn the_synthesisers_outputs_are_those_pinned() {
    assert_eq!(synth_hash(0x5eed_0001, 60_000), 17_174_907_237_876_833_646, "seed 1");
    assert_eq!(synth_hash(0x5eed_0002, 60_000), 12_700_657_915_622_410_726, "seed 2");
}

#[test]
fn the_synthesisers_outputs_without_a_program_switch_are_those_pinned() {
    let got = [(0x5eed_0003, 8), (0x5eed_0004, 8), (0x5eed_0005, 3), (0x5eed_0006, 5)]
        .map(|(seed, count)| synth_hash_one_program(seed, 60_000, count));
    assert_eq!(
        got,
        [7_066_689_386_559_545_409, 983_777_811_597_032_170, 13_924_118_992_660_030_052, 5_816_555_242_102_462_526]
    );
}
