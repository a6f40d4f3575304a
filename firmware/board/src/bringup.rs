//! The bring-up application: small, deterministic, and exercising every path of the
//! platform (tick, model work at a fixed latency, control link, config store), so the
//! platform can be tested before the real servo is plugged in. It builds on the host too,
//! which gives the tests a bit-exact reference.
//!
//! Per tick `k` with input `x`:
//! - every [`BLOCK_TICKS`] ticks the tick hands the block's accelerometer sum to the
//!   background ([`BackgroundApp::model_work`] computes the block mean), and
//!   [`MODEL_LATENCY_TICKS`] ticks into the next block takes the result up (or counts it
//!   late in `fault_count`);
//! - `dac_code = sat16(x.acc_code * gain / 256 + (x.cmd_phase_turns >> 22) + model)`,
//!   `de_pred_pm = model * 1000`, `flags` = [`OUT_FLAG_MODEL_ACTIVE`] once a model value
//!   was taken up, [`OUT_FLAG_SATURATED`] when clamped.
//!
//! Control bytes (a bring-up protocol, not the real wire protocol):
//! - `'G' lo hi`: set the gain (`i16` LE, 256 = 1.0) from the next tick on; reply `'g' lo hi`.
//! - `'?'`: status; reply `'s'` then `u32` LE: ticks, underruns, overruns, model runs,
//!   then `i16` LE gain (19 bytes).
//! - `'W'`: store the gain in the config store; reply `'w'` and 1 (ok) or 0.
//! - `'P'`: panic (tests the panic path). `'F'`: fault (reads an unmapped address).
//! - any other byte is echoed back unchanged.

use core::sync::atomic::Ordering;

use sts_twin_core::bus::{InputSlot, OutputSlot, OUT_FLAG_MODEL_ACTIVE, OUT_FLAG_SATURATED};

use crate::servo::{BackgroundApp, BackgroundCtx, ServoApp, TickOutcome};
use crate::sync::SharedCell;

/// Ticks per model block.
pub const BLOCK_TICKS: u32 = 64;
/// Ticks after a block's end at which the tick takes up that block's model result.
pub const MODEL_LATENCY_TICKS: u32 = 8;
/// Gain at boot when nothing is stored (1.0).
pub const DEFAULT_GAIN: i16 = 256;

/// State shared by the two halves.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct BringUpShared {
    /// A gain set by control, for the tick to take up.
    pub pending_gain: Option<i16>,
    /// The gain in use (for status).
    pub gain: i16,
    /// The last block handed to the background: (block index, accelerometer sum).
    pub request: Option<(u32, i64)>,
    /// The last result: (block index, model value).
    pub result: Option<(u32, i32)>,
}

impl BringUpShared {
    /// The state at boot.
    pub const fn new() -> Self {
        Self { pending_gain: None, gain: DEFAULT_GAIN, request: None, result: None }
    }
}

/// The tick half.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct BringUpServo {
    gain: i16,
    block_sum: i64,
    model: Option<i32>,
    late: u32,
}

impl BringUpServo {
    /// The state at boot.
    pub const fn new() -> Self {
        Self { gain: DEFAULT_GAIN, block_sum: 0, model: None, late: 0 }
    }
}

impl Default for BringUpServo {
    fn default() -> Self {
        Self::new()
    }
}

impl ServoApp for BringUpServo {
    type Shared = BringUpShared;

    fn tick(&mut self, input: &InputSlot, shared: &SharedCell<BringUpShared>) -> TickOutcome {
        let k = input.tick;
        let phase_in_block = k % BLOCK_TICKS;
        let block = k / BLOCK_TICKS;
        let take_result = phase_in_block == MODEL_LATENCY_TICKS && block > 0;
        let (gain, result) = shared.with(|s| {
            if let Some(g) = s.pending_gain.take() {
                s.gain = g;
            }
            (s.gain, if take_result { s.result } else { None })
        });
        self.gain = gain;
        if take_result {
            match result {
                Some((b, value)) if b == block - 1 => self.model = Some(value),
                _ => self.late = self.late.wrapping_add(1),
            }
        }
        self.block_sum += i64::from(input.acc_code);
        let mut request_model_work = false;
        if phase_in_block == BLOCK_TICKS - 1 {
            let sum = self.block_sum;
            self.block_sum = 0;
            shared.with(|s| s.request = Some((block, sum)));
            request_model_work = true;
        }
        let model = self.model.unwrap_or(0);
        let wide = i64::from(input.acc_code) * i64::from(self.gain) / 256
            + i64::from(input.cmd_phase_turns >> 22)
            + i64::from(model);
        let dac_code = wide.clamp(i64::from(i16::MIN), i64::from(i16::MAX)) as i16;
        let mut flags = 0;
        if self.model.is_some() {
            flags |= OUT_FLAG_MODEL_ACTIVE;
        }
        if i64::from(dac_code) != wide {
            flags |= OUT_FLAG_SATURATED;
        }
        TickOutcome {
            output: OutputSlot {
                tick: k,
                dac_code,
                flags,
                de_pred_pm: model.wrapping_mul(1000),
                fault_count: self.late,
            },
            request_model_work,
        }
    }
}

/// Parser state of the bring-up control protocol.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
enum Rx {
    #[default]
    Idle,
    Gain0,
    Gain1(u8),
}

/// The background half.
#[derive(Debug, Default)]
pub struct BringUpBackground {
    rx: Rx,
}

impl BringUpBackground {
    /// The state at boot.
    pub const fn new() -> Self {
        Self { rx: Rx::Idle }
    }

    /// The model work on one block: the mean accelerometer code of the block.
    pub fn model(sum: i64) -> i32 {
        (sum / i64::from(BLOCK_TICKS)) as i32
    }

    fn reply(ctx: &mut BackgroundCtx<'_, BringUpShared>, bytes: &[u8]) {
        let mut done = 0;
        // The link queue holds far more than a reply; a full queue drops the rest.
        while done < bytes.len() {
            let n = ctx.link.write(&bytes[done..]);
            if n == 0 {
                break;
            }
            done += n;
        }
    }
}

impl BackgroundApp for BringUpBackground {
    type Shared = BringUpShared;

    fn on_boot(&mut self, ctx: &mut BackgroundCtx<'_, BringUpShared>) {
        let mut blob = [0u8; 3];
        if let Ok(3) = ctx.config.read(&mut blob)
            && blob[0] == b'G'
        {
            let gain = i16::from_le_bytes([blob[1], blob[2]]);
            ctx.shared.with(|s| {
                s.gain = gain;
                s.pending_gain = Some(gain);
            });
        }
    }

    fn model_work(&mut self, ctx: &mut BackgroundCtx<'_, BringUpShared>) {
        if let Some((block, sum)) = ctx.shared.with(|s| s.request.take()) {
            let value = Self::model(sum);
            ctx.shared.with(|s| s.result = Some((block, value)));
        }
    }

    fn on_control_bytes(&mut self, rx: &[u8], ctx: &mut BackgroundCtx<'_, BringUpShared>) {
        for &b in rx {
            self.rx = match (self.rx, b) {
                (Rx::Gain0, lo) => Rx::Gain1(lo),
                (Rx::Gain1(lo), hi) => {
                    let gain = i16::from_le_bytes([lo, hi]);
                    ctx.shared.with(|s| s.pending_gain = Some(gain));
                    Self::reply(ctx, &[b'g', lo, hi]);
                    Rx::Idle
                }
                (Rx::Idle, b'G') => Rx::Gain0,
                (Rx::Idle, b'?') => {
                    let c = ctx.counters;
                    let gain = ctx.shared.with(|s| s.pending_gain.unwrap_or(s.gain));
                    let mut msg = [0u8; 19];
                    msg[0] = b's';
                    for (i, v) in [&c.ticks, &c.underruns, &c.overruns, &c.model_runs].iter().enumerate() {
                        msg[1 + 4 * i..5 + 4 * i].copy_from_slice(&v.load(Ordering::Relaxed).to_le_bytes());
                    }
                    msg[17..19].copy_from_slice(&gain.to_le_bytes());
                    Self::reply(ctx, &msg);
                    Rx::Idle
                }
                (Rx::Idle, b'W') => {
                    let gain = ctx.shared.with(|s| s.pending_gain.unwrap_or(s.gain)).to_le_bytes();
                    let ok = ctx.config.write(&[b'G', gain[0], gain[1]]).is_ok();
                    Self::reply(ctx, &[b'w', u8::from(ok)]);
                    Rx::Idle
                }
                (Rx::Idle, b'P') => panic!("panic requested over the control link"),
                (Rx::Idle, b'F') => {
                    // SAFETY: deliberately faults: nothing is mapped at this address.
                    let v = unsafe { core::ptr::read_volatile(0xF000_0000 as *const u32) };
                    Self::reply(ctx, &v.to_le_bytes());
                    Rx::Idle
                }
                (Rx::Idle, other) => {
                    Self::reply(ctx, &[other]);
                    Rx::Idle
                }
            };
        }
    }
}

/// Host-side reference of the bring-up application: the outputs the firmware must
/// produce for `inputs` (ticks `0..`), with `gain` in force from tick 0.
pub fn reference_outputs(inputs: &[InputSlot], gain: i16) -> impl Iterator<Item = OutputSlot> + '_ {
    let shared = SharedCell::new(BringUpShared { pending_gain: Some(gain), ..BringUpShared::new() });
    let mut servo = BringUpServo::new();
    inputs.iter().enumerate().map(move |(k, input)| {
        let mut input = *input;
        input.tick = k as u32;
        let outcome = servo.tick(&input, &shared);
        if outcome.request_model_work {
            // The background always finishes within the latency on a healthy platform.
            shared.with(|s| {
                if let Some((block, sum)) = s.request.take() {
                    s.result = Some((block, BringUpBackground::model(sum)));
                }
            });
        }
        outcome.output
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn model_result_is_taken_up_at_a_fixed_tick() {
        let inputs: Vec<InputSlot> =
            (0..200).map(|k| InputSlot { acc_code: 100 + (k % 7) as i16, ..Default::default() }).collect();
        let out: Vec<OutputSlot> = reference_outputs(&inputs, 256).collect();
        let first_active = out.iter().position(|o| o.flags & OUT_FLAG_MODEL_ACTIVE != 0).unwrap();
        assert_eq!(first_active as u32, BLOCK_TICKS + MODEL_LATENCY_TICKS);
        assert_eq!(out[first_active].de_pred_pm, BringUpBackground::model((0..64).map(|k| 100 + k % 7).sum()) * 1000);
        assert!(out.iter().all(|o| o.fault_count == 0));
        // The gain scales the accelerometer term.
        let half: Vec<OutputSlot> = reference_outputs(&inputs, 128).collect();
        assert_eq!(half[0].dac_code, 50);
        assert_eq!(out[0].dac_code, 100);
    }

    #[test]
    fn saturates_at_full_scale() {
        let inputs = [InputSlot { acc_code: i16::MAX, cmd_phase_turns: u32::MAX, ..Default::default() }];
        let out: Vec<OutputSlot> = reference_outputs(&inputs, 512).collect();
        assert_eq!(out[0].dac_code, i16::MAX);
        assert_ne!(out[0].flags & OUT_FLAG_SATURATED, 0);
    }
}
