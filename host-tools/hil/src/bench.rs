//! Benchmarks of the firmware under QEMU: guest instructions per servo tick and HIL
//! throughput. Both drive the real ELF; `sts-twin hil bench` prints them.

use std::time::Instant;

use sts_twin_core::bus::{InputSlot, IN_FLAG_PHASE_VALID};

use sts_twin_board::qemu::QemuBoard;

use super::{Hil, HilConfig, HilError};

/// The `-icount` shift the instruction benchmark runs at: one instruction is 64 ns of guest
/// time, and one timer count 40 ns (the MPS2 boards' 25 MHz timer: 0.625 instructions) or
/// 1 ns (the RISC-V board's RTC).
pub const INSTRUCTION_BENCH_SHIFT: u32 = 6;

/// A deterministic test stream: a 1 kHz-ish accelerometer tone with pseudo-random noise and
/// a command phase turning at 10 Hz (8 kHz ticks).
pub fn bench_inputs(ticks: u32) -> Vec<InputSlot> {
    let mut noise: u32 = 0x2545_F491;
    (0..ticks)
        .map(|k| {
            noise ^= noise << 13;
            noise ^= noise >> 17;
            noise ^= noise << 5;
            let tone = (8000.0 * (k as f64 * std::f64::consts::TAU / 8.0).sin()) as i32;
            let acc = tone + (noise % 2001) as i32 - 1000;
            InputSlot {
                tick: k,
                acc_code: acc as i16,
                flags: IN_FLAG_PHASE_VALID,
                cmd_phase_turns: k.wrapping_mul(5_368_709), // 2^32 * 10 Hz / 8 kHz
                cmd_pos_nm: (k as i32 % 4000) * 250,
                ..Default::default()
            }
        })
        .collect()
}

/// Guest instructions of the servo tick, measured with the guest's own timer under
/// `-icount` (one instruction = 2^shift ns of guest time exactly).
#[derive(Clone, Debug, PartialEq)]
pub struct InstructionReport {
    /// The ELF measured.
    pub elf: String,
    /// The board it ran on.
    pub board: QemuBoard,
    /// Ticks measured.
    pub ticks: u32,
    /// The `-icount` shift used.
    pub icount_shift: u32,
    /// Median instructions from input arrival to handler end.
    pub busy_median: f64,
    /// Mean of the same.
    pub busy_mean: f64,
    /// 99th percentile of the same.
    pub busy_p99: f64,
    /// Largest of the same (worst case over the run).
    pub busy_max: f64,
    /// Median instructions from input arrival to the very end of the handler (publishing
    /// the counters and diagnostics included).
    pub handler_median: f64,
    /// Largest of the same.
    pub handler_max: f64,
    /// Largest instructions from the tick edge to the start of the input wait (entry).
    pub entry_max: f64,
    /// Instructions of one evaluation of the built-in paper program (Eqs. 2-3), measured by
    /// the firmware at boot.
    pub paper_eval: f64,
    /// Underruns and overruns seen (should be 0).
    pub underruns: u32,
    /// Overruns seen.
    pub overruns: u32,
}

impl std::fmt::Display for InstructionReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(
            f,
            "servo tick on {} ({}), guest instructions ({} ticks, -icount shift={}):",
            self.board.qemu_machine(),
            self.board.core(),
            self.ticks,
            self.icount_shift
        )?;
        writeln!(
            f,
            "  input arrival -> output written (app + bus): median {:.0}, mean {:.1}, p99 {:.0}, worst {:.0}",
            self.busy_median, self.busy_mean, self.busy_p99, self.busy_max
        )?;
        writeln!(
            f,
            "  input arrival -> handler end (+ counters, diagnostics): median {:.0}, worst {:.0}",
            self.handler_median, self.handler_max
        )?;
        writeln!(f, "  tick edge -> input wait (entry): worst {:.0}", self.entry_max)?;
        writeln!(
            f,
            "  whole servo handler excluding the wait: typical {:.0}, worst {:.0}",
            self.typical_per_tick(),
            self.worst_per_tick()
        )?;
        writeln!(f, "one model evaluation (the paper's Eqs. 2-3, measured at boot): {:.0}", self.paper_eval)?;
        write!(f, "  underruns {}, overruns {}", self.underruns, self.overruns)
    }
}

impl InstructionReport {
    /// Instructions of a typical servo tick: entry plus the median handler after the wait.
    pub fn typical_per_tick(&self) -> f64 {
        self.entry_max + self.handler_median
    }

    /// Instructions of the worst servo tick seen: entry plus the largest handler.
    pub fn worst_per_tick(&self) -> f64 {
        self.entry_max + self.handler_max
    }
}

/// Runs `ticks` lockstep ticks of [`bench_inputs`] at [`INSTRUCTION_BENCH_SHIFT`] and reads
/// the firmware's per-tick timer measurement after each.
pub fn bench_instructions(config: HilConfig, ticks: u32) -> Result<InstructionReport, HilError> {
    bench_instructions_prepared(config, ticks, |_| Ok(()))
}

/// [`bench_instructions`] with `prepare` run on the booted firmware first (e.g. to upload a
/// twin program so that the model path and the per-tick terms are measured too).
pub fn bench_instructions_prepared(
    mut config: HilConfig,
    ticks: u32,
    prepare: impl FnOnce(&mut Hil) -> Result<(), HilError>,
) -> Result<InstructionReport, HilError> {
    config.icount_shift = INSTRUCTION_BENCH_SHIFT;
    let board = config.board;
    let mut hil = Hil::start(config)?;
    prepare(&mut hil)?;
    let per_count = f64::from(board.count_ns()) / f64::from(1u32 << INSTRUCTION_BENCH_SHIFT);
    let mut busy: Vec<u32> = Vec::with_capacity(ticks as usize);
    let mut handler: Vec<u32> = Vec::with_capacity(ticks as usize);
    for (k, input) in bench_inputs(ticks).into_iter().enumerate() {
        hil.step(input)?;
        let diag = hil.diagnostics();
        busy.push(diag.busy_last_counts);
        // Published one tick late: after tick k it describes tick k - 1.
        if k > 0 {
            handler.push(diag.handler_last_counts);
        }
    }
    let diag = hil.diagnostics();
    let counters = hil.counters();
    let elf = hil.elf().display().to_string();
    hil.shutdown()?;
    busy.sort_unstable();
    handler.sort_unstable();
    let quantile = |v: &[u32], q: f64| {
        v.get(((v.len().max(1) - 1) as f64 * q).round() as usize).map_or(0.0, |&c| f64::from(c) * per_count)
    };
    let at = |q: f64| quantile(&busy, q);
    Ok(InstructionReport {
        elf,
        board,
        ticks,
        icount_shift: INSTRUCTION_BENCH_SHIFT,
        busy_median: at(0.5),
        busy_mean: busy.iter().map(|&b| f64::from(b)).sum::<f64>() / busy.len().max(1) as f64 * per_count,
        busy_p99: at(0.99),
        busy_max: f64::from(diag.busy_max_counts) * per_count,
        handler_median: quantile(&handler, 0.5),
        handler_max: f64::from(diag.handler_max_counts) * per_count,
        entry_max: f64::from(diag.entry_max_counts) * per_count,
        paper_eval: f64::from(diag.paper_eval_counts) * per_count,
        underruns: counters.underruns,
        overruns: counters.overruns,
    })
}

/// HIL throughput: simulated seconds (8,000 ticks each) per wall-clock second.
#[derive(Clone, Debug, PartialEq)]
pub struct ThroughputReport {
    /// Ticks per run.
    pub ticks: u32,
    /// Lockstep ([`Hil::step`]) ticks per wall second.
    pub lockstep_ticks_per_s: f64,
    /// Pipelined ([`Hil::run_open_loop`]) ticks per wall second.
    pub open_loop_ticks_per_s: f64,
    /// Underruns over both runs (should be 0).
    pub underruns: u32,
}

impl ThroughputReport {
    /// Lockstep simulated seconds per wall second.
    pub fn lockstep_sim_per_wall(&self) -> f64 {
        self.lockstep_ticks_per_s / f64::from(sts_twin_core::SERVO_RATE_HZ)
    }

    /// Open-loop simulated seconds per wall second.
    pub fn open_loop_sim_per_wall(&self) -> f64 {
        self.open_loop_ticks_per_s / f64::from(sts_twin_core::SERVO_RATE_HZ)
    }
}

impl std::fmt::Display for ThroughputReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(f, "HIL throughput ({} ticks each):", self.ticks)?;
        writeln!(
            f,
            "  lockstep:  {:>9.0} ticks/s = {:.2} simulated s per wall s",
            self.lockstep_ticks_per_s,
            self.lockstep_sim_per_wall()
        )?;
        writeln!(
            f,
            "  open loop: {:>9.0} ticks/s = {:.2} simulated s per wall s",
            self.open_loop_ticks_per_s,
            self.open_loop_sim_per_wall()
        )?;
        write!(f, "  underruns {}", self.underruns)
    }
}

/// Boots the firmware, then times `ticks` lockstep ticks and `ticks` open-loop ticks.
pub fn bench_throughput(config: HilConfig, ticks: u32) -> Result<ThroughputReport, HilError> {
    let mut hil = Hil::start(config)?;
    let inputs = bench_inputs(ticks);
    // Warm up QEMU's translation cache.
    for input in &inputs[..(ticks as usize).min(1000)] {
        hil.step(*input)?;
    }
    let t0 = Instant::now();
    for input in &inputs {
        hil.step(*input)?;
    }
    let lockstep = t0.elapsed().as_secs_f64();
    let t0 = Instant::now();
    let outputs = hil.run_open_loop(&inputs)?;
    let open_loop = t0.elapsed().as_secs_f64();
    debug_assert_eq!(outputs.len(), inputs.len());
    let underruns = hil.counters().underruns;
    hil.shutdown()?;
    Ok(ThroughputReport {
        ticks,
        lockstep_ticks_per_s: f64::from(ticks) / lockstep,
        open_loop_ticks_per_s: f64::from(ticks) / open_loop,
        underruns,
    })
}
