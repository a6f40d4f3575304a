//! The interrupt-owned part: exact sliding sums, the raw ring and the block accumulator.

use super::{
    FeatureConfig, FeatureError, SpectralRings, BLOCK_SAMPLES, MARGIN_BLOCKS, MAX_WINDOW_BLOCKS, MAX_WINDOW_SAMPLES,
    MIN_WINDOW_BLOCKS,
};
use fixed::types::I24F8;

/// Interrupt-owned feature state for a window of up to `16 * WINDOW_BLOCKS` samples.
///
/// `WINDOW_BLOCKS` must be within [`MIN_WINDOW_BLOCKS`]..=[`MAX_WINDOW_BLOCKS`] (checked at
/// compile time). Memory: `36 * WINDOW_BLOCKS` bytes plus about 100.
///
/// `repr(C)`, the large rings last: the per-sample fields then sit at small offsets, which
/// a Cortex-M4 load or store reaches with one instruction (beyond 4 KB it takes three).
#[derive(Clone, Debug)]
#[repr(C)]
pub struct FeatureState<const WINDOW_BLOCKS: usize> {
    /// What a capture needs, contiguous (first, so also at small offsets).
    snap: FeatureSnapshot,
    /// Block slot of `raw` / `dc_ref` being written (0 .. window blocks).
    raw_block: u32,
    /// DC reference of the current block, and of the block leaving the window.
    dc_new: I24F8,
    dc_old: I24F8,
    /// Sum of the codes of the block being written so far (0 when it is empty).
    block_sum: i32,
    /// A block ended and the next one's DC reference is still to be set (by the next
    /// `push`, so that the block end's tick does not do it as well).
    dc_pending: bool,
    /// DC reference (Q24.8 codes) that each block of `raw` was accumulated with.
    dc_ref: [I24F8; WINDOW_BLOCKS],
    /// Raw codes of the window, oldest overwritten first. Only the first `filled` positions
    /// (in write order) hold codes of the current configuration: `reconfigure` leaves the
    /// rest as it was, and `push` ignores what it overwrites until the window is full.
    raw: [[i16; BLOCK_SAMPLES]; WINDOW_BLOCKS],
}

/// The part of [`FeatureState`] a [`Capture`] is made of, as it stands: copied by the
/// servo tick that requests a model update ([`FeatureSnapshot::copy_to`]), and turned into a
/// [`Capture`] at low priority ([`FeatureSnapshot::capture`]). In two parts of at most 64
/// bytes: a Cortex-M4 copies each with a few block moves (`ldm`/`stm`), where one copy of
/// the whole calls the library `memcpy` (about 90 instructions).
#[derive(Clone, Copy, Debug, PartialEq)]
#[repr(C)]
pub struct FeatureSnapshot {
    counts: SnapshotCounts,
    sums: SnapshotSums,
}

/// The 32-bit part of a [`FeatureSnapshot`].
#[derive(Clone, Copy, Debug, PartialEq)]
#[repr(C)]
struct SnapshotCounts {
    cfg: FeatureConfig,
    /// Samples in the window so far, saturating at the window length.
    filled: u32,
    /// Complete blocks in the window so far, saturating at the window length in blocks.
    blocks_filled: u32,
    /// Sample index within the block being written (0 .. 16).
    in_block: u32,
    /// Exact sliding sum of x over the window. It cannot overflow i32: at most
    /// 65,536 * 32,768 = 2^31 in magnitude, and -2^31 is the only extreme reached.
    s1: i32,
    /// Complete blocks ever written to the rings (wrapping), and the ring slot of the next.
    blocks_written: u32,
    ring_slot: u32,
    /// Largest and smallest code of the block being written so far (`i16::MIN`,
    /// `i16::MAX` when it is empty), kept per sample so that the block end and a capture
    /// need not scan the block.
    block_max: i16,
    block_min: i16,
}

/// The wide sums of a [`FeatureSnapshot`].
#[derive(Clone, Copy, Debug, PartialEq)]
#[repr(C)]
struct SnapshotSums {
    /// Exact sliding sums of x^2, x^3, x^4 over the window.
    s2: i64,
    s3: i64,
    s4: i128,
    /// Sliding sum of |256 x - d| (Q8 codes), at most 2^24 * 2^16 = 2^40.
    sum_abs_q8: i64,
}

const _: () = assert!(core::mem::size_of::<SnapshotCounts>() <= 64 && core::mem::size_of::<SnapshotSums>() <= 64);

impl FeatureSnapshot {
    /// An empty window of `cfg`.
    pub const fn empty(cfg: FeatureConfig) -> Self {
        Self {
            counts: SnapshotCounts {
                cfg,
                filled: 0,
                blocks_filled: 0,
                in_block: 0,
                s1: 0,
                blocks_written: 0,
                ring_slot: 0,
                block_max: i16::MIN,
                block_min: i16::MAX,
            },
            sums: SnapshotSums { s2: 0, s3: 0, s4: 0, sum_abs_q8: 0 },
        }
    }

    /// Copies `self` into `out`, part by part (see the type's docs).
    #[inline(always)]
    pub fn copy_to(&self, out: &mut Self) {
        out.counts = self.counts;
        out.sums = self.sums;
    }

    /// Samples in the window at the snapshot.
    pub const fn samples(&self) -> u32 {
        self.counts.filled
    }

    /// The capture this snapshot stands for.
    pub fn capture(&self) -> Capture {
        Capture {
            cfg: self.counts.cfg,
            samples: self.counts.filled,
            s1: self.counts.s1,
            s2: self.sums.s2,
            s3: self.sums.s3,
            s4: self.sums.s4,
            sum_abs_q8: self.sums.sum_abs_q8,
            blocks_written: self.counts.blocks_written,
            ring_slot: self.counts.ring_slot,
            blocks: self.counts.blocks_filled,
            partial_len: self.counts.in_block.min(BLOCK_SAMPLES as u32),
            partial_max: self.counts.block_max,
            partial_min: self.counts.block_min,
        }
    }
}

/// A snapshot of the interrupt-owned state, taken in O(1); [`SpectralRings::finish`] turns it
/// into [`Features`](super::Features).
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Capture {
    /// The configuration in force.
    pub cfg: FeatureConfig,
    /// Samples in the moment window, `min(pushed, window_samples)`.
    pub samples: u32,
    /// Sum of the codes in the window.
    pub s1: i32,
    /// Sum of squared codes.
    pub s2: i64,
    /// Sum of cubed codes.
    pub s3: i64,
    /// Sum of codes to the fourth power.
    pub s4: i128,
    /// Sum of `|256 x - d|` (codes/256).
    pub sum_abs_q8: i64,
    /// Complete blocks ever written to the rings (wrapping counter).
    pub blocks_written: u32,
    /// Ring slot the next block will be written to.
    pub ring_slot: u32,
    /// Complete blocks in the window, `min(blocks since configure, window blocks)`.
    pub blocks: u32,
    /// Samples in the current, incomplete block.
    pub partial_len: u32,
    /// Largest code of the current block (`i16::MIN` if it is empty).
    pub partial_max: i16,
    /// Smallest code of the current block (`i16::MAX` if it is empty).
    pub partial_min: i16,
}

impl<const WINDOW_BLOCKS: usize> FeatureState<WINDOW_BLOCKS> {
    const CAPACITY_OK: () = assert!(
        WINDOW_BLOCKS >= MIN_WINDOW_BLOCKS && WINDOW_BLOCKS <= MAX_WINDOW_BLOCKS,
        "WINDOW_BLOCKS must be within MIN_WINDOW_BLOCKS..=MAX_WINDOW_BLOCKS"
    );

    /// Capacity in samples.
    pub const CAPACITY_SAMPLES: usize = WINDOW_BLOCKS * BLOCK_SAMPLES;

    /// A fresh state; fails if `cfg` does not validate against the capacity.
    pub const fn new(cfg: FeatureConfig) -> Result<Self, FeatureError> {
        #[allow(clippy::let_unit_value)]
        let () = Self::CAPACITY_OK;
        if let Err(e) = cfg.validate(Self::CAPACITY_SAMPLES) {
            return Err(e);
        }
        Ok(Self {
            snap: FeatureSnapshot::empty(cfg),
            raw_block: 0,
            dc_new: I24F8::ZERO,
            dc_old: I24F8::ZERO,
            block_sum: 0,
            dc_pending: false,
            dc_ref: [I24F8::ZERO; WINDOW_BLOCKS],
            raw: [[0; BLOCK_SAMPLES]; WINDOW_BLOCKS],
        })
    }

    /// The configuration in force.
    pub const fn config(&self) -> &FeatureConfig {
        &self.snap.counts.cfg
    }

    /// Switches to `cfg` and empties the window, in O(1) (the raw codes are not cleared:
    /// `push` ignores the old ones until the window has filled again), so that it may run
    /// inside a short critical section. The ring write position continues, so the same
    /// [`SpectralRings`] stays valid. On error the old configuration and window stay in force.
    pub fn reconfigure(&mut self, cfg: FeatureConfig) -> Result<(), FeatureError> {
        cfg.validate(Self::CAPACITY_SAMPLES)?;
        // The ring positions continue.
        let empty = FeatureSnapshot::empty(cfg);
        self.snap = FeatureSnapshot {
            counts: SnapshotCounts {
                blocks_written: self.snap.counts.blocks_written,
                ring_slot: self.snap.counts.ring_slot,
                ..empty.counts
            },
            ..empty
        };
        self.raw_block = 0;
        self.dc_new = I24F8::ZERO;
        self.dc_old = I24F8::ZERO;
        self.block_sum = 0;
        self.dc_pending = false;
        Ok(())
    }

    /// Adds one ADC code: O(1), integer only, never panics or overflows.
    ///
    /// Every 16th call also writes one decimated sample and the block extremes to `rings`.
    #[inline]
    pub fn push<const RING_BLOCKS: usize>(&mut self, rings: &SpectralRings<RING_BLOCKS>, code: i16) {
        self.push_with_command(rings, code, 0);
    }

    /// [`push`](Self::push), with the command position handed in with this sample, nm: a
    /// block's last goes into `rings` with the block.
    #[inline]
    pub fn push_with_command<const RING_BLOCKS: usize>(
        &mut self,
        rings: &SpectralRings<RING_BLOCKS>,
        code: i16,
        cmd_nm: i32,
    ) {
        const { assert!(RING_BLOCKS >= WINDOW_BLOCKS + MARGIN_BLOCKS, "RING_BLOCKS too small") };
        if self.dc_pending {
            self.start_block_dc();
        }
        let in_block = (self.snap.counts.in_block as usize) % BLOCK_SAMPLES;
        let Some(block) = self.raw.get_mut(self.raw_block as usize) else {
            return; // unreachable: raw_block < window blocks <= WINDOW_BLOCKS
        };
        let old = block[in_block];
        block[in_block] = code;

        let x = code as i32;
        // Until the window is full the overwritten position holds no sample of it (written
        // before the last reconfiguration, or never).
        let full = self.snap.counts.filled >= self.snap.counts.cfg.window_samples;
        let (o, dc_old) = if full { (old as i32, self.dc_old) } else { (0, I24F8::ZERO) };
        self.block_sum += x;
        self.snap.counts.block_max = self.snap.counts.block_max.max(code);
        self.snap.counts.block_min = self.snap.counts.block_min.min(code);
        if self.snap.counts.filled == 0 {
            // No window mean yet: the first block is referenced to its first sample.
            self.dc_new = I24F8::from_bits(x << 8);
            if let Some(slot) = self.dc_ref.get_mut(self.raw_block as usize) {
                *slot = self.dc_new;
            }
        }
        let x2 = x * x; // <= 2^30
        let o2 = o * o;
        // True window sums always fit (see field docs), so the wrapping adds are exact.
        self.snap.counts.s1 = self.snap.counts.s1.wrapping_add(x - o);
        self.snap.sums.s2 += (x2 - o2) as i64;
        self.snap.sums.s3 += x2 as i64 * x as i64 - o2 as i64 * o as i64;
        let x4 = (x2 as u64) * (x2 as u64); // <= 2^60
        let o4 = (o2 as u64) * (o2 as u64);
        self.snap.sums.s4 += (x4 as i64 - o4 as i64) as i128;
        let a_new = (I24F8::from_bits(x << 8) - self.dc_new).abs().to_bits();
        let a_old = (I24F8::from_bits(o << 8) - dc_old).abs().to_bits();
        self.snap.sums.sum_abs_q8 += (a_new - a_old) as i64;

        if !full {
            self.snap.counts.filled += 1;
        }
        if in_block + 1 < BLOCK_SAMPLES {
            self.snap.counts.in_block = in_block as u32 + 1;
        } else {
            self.end_block(rings, cmd_nm);
        }
    }

    /// Block end: publish the block, advance the ring positions, set the next DC reference.
    #[inline(never)]
    fn end_block<const RING_BLOCKS: usize>(&mut self, rings: &SpectralRings<RING_BLOCKS>, cmd_nm: i32) {
        rings.publish(
            self.snap.counts.ring_slot as usize,
            self.snap.counts.blocks_written,
            self.block_sum,
            self.snap.counts.block_max,
            self.snap.counts.block_min,
            cmd_nm,
        );
        self.block_sum = 0;
        self.snap.counts.block_max = i16::MIN;
        self.snap.counts.block_min = i16::MAX;
        self.snap.counts.blocks_written = self.snap.counts.blocks_written.wrapping_add(1);
        self.snap.counts.ring_slot =
            if self.snap.counts.ring_slot as usize + 1 >= RING_BLOCKS { 0 } else { self.snap.counts.ring_slot + 1 };
        let window_blocks = self.snap.counts.cfg.window_blocks() as u32;
        if self.snap.counts.blocks_filled < window_blocks {
            self.snap.counts.blocks_filled += 1;
        }
        self.snap.counts.in_block = 0;
        self.raw_block = if self.raw_block + 1 >= window_blocks { 0 } else { self.raw_block + 1 };
        // The next block's DC reference: set by the next push, from the sums as they stand
        // now (nothing changes them before).
        self.dc_pending = true;
    }

    /// The start of a block: it overwrites the oldest one, so remember that one's DC
    /// reference, and set the new one to the window mean truncated to 1/256 LSB (two i32
    /// divisions, no i64). Out of line, on the tick after a block end.
    #[inline(never)]
    fn start_block_dc(&mut self) {
        self.dc_pending = false;
        // (At most the window, 65,536: the bound tells the compiler that the divisions
        // cannot overflow, so they need no checks.)
        let n = self.snap.counts.filled.clamp(1, MAX_WINDOW_SAMPLES as u32) as i32;
        let q = self.snap.counts.s1 / n;
        let r = self.snap.counts.s1 % n; // |r| < n <= 2^16, so r << 8 fits
        let dc = I24F8::from_bits((q << 8) + (r << 8) / n);
        if let Some(slot) = self.dc_ref.get_mut(self.raw_block as usize) {
            self.dc_old = *slot;
            *slot = dc;
        }
        self.dc_new = dc;
    }

    /// Takes a snapshot for [`SpectralRings::finish`]: O(1), a copy of a few fields.
    pub fn capture<const RING_BLOCKS: usize>(&self, _rings: &SpectralRings<RING_BLOCKS>) -> Capture {
        self.snap.capture()
    }

    /// Whether the last [`FeatureState::push`] did a block's extra work: closed a 16-sample
    /// block, or started the next one (its DC reference).
    #[inline(always)]
    pub fn last_push_was_busy(&self) -> bool {
        let counts = &self.snap.counts;
        (counts.in_block == 0 && counts.filled != 0) || (counts.in_block == 1 && counts.filled > 1)
    }

    /// Whether the next [`FeatureState::push`] will do a block's extra work (see
    /// [`FeatureState::last_push_was_busy`]).
    pub fn next_push_is_busy(&self) -> bool {
        self.next_push_ends_block() || self.dc_pending
    }

    /// Whether the next [`FeatureState::push`] will close a 16-sample block.
    pub fn next_push_ends_block(&self) -> bool {
        self.pushes_to_block_end() == 1
    }

    /// Pushes until the one that closes the current block (1 to 16).
    pub fn pushes_to_block_end(&self) -> u32 {
        BLOCK_SAMPLES as u32 - self.snap.counts.in_block.min(BLOCK_SAMPLES as u32 - 1)
    }

    /// What a capture is made of, to be copied (one block move) and turned into a
    /// [`Capture`] later ([`FeatureSnapshot::capture`]).
    #[inline(always)]
    pub fn snapshot(&self) -> &FeatureSnapshot {
        &self.snap
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::features::FeatureConfig;

    fn codes(seed: &mut u64, n: usize) -> impl Iterator<Item = i16> + '_ {
        (0..n).map(move |_| {
            *seed ^= *seed << 13;
            *seed ^= *seed >> 7;
            *seed ^= *seed << 17;
            (*seed >> 48) as i16
        })
    }

    /// The window restarts empty without clearing the raw ring: what `push` overwrites
    /// until the window is full again must not count.
    #[test]
    fn a_reconfigured_state_equals_a_fresh_one() {
        let cfg = |window_samples| FeatureConfig { window_samples, ..FeatureConfig::DEFAULT };
        let mut seed = 0x5eed_u64;
        for (before, after, pushed) in [(256u32, 128u32, 700usize), (128, 256, 1000), (512, 512, 333), (256, 256, 7)] {
            let rings = SpectralRings::<300>::new();
            let mut state = FeatureState::<32>::new(cfg(before)).unwrap();
            for code in codes(&mut seed, 1500) {
                state.push(&rings, code);
            }
            state.reconfigure(cfg(after)).unwrap();
            let fresh_rings = SpectralRings::<300>::new();
            let mut fresh = FeatureState::<32>::new(cfg(after)).unwrap();
            for code in codes(&mut seed, pushed) {
                state.push(&rings, code);
                fresh.push(&fresh_rings, code);
                let (a, b) = (state.capture(&rings), fresh.capture(&fresh_rings));
                assert_eq!(
                    Capture { blocks_written: 0, ring_slot: 0, ..a },
                    Capture { blocks_written: 0, ring_slot: 0, ..b }
                );
            }
        }
    }
}
