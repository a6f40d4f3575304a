//! The shared part: decimated and block-extreme rings of atomics, and the read-time `finish`.

use super::moments::{time_domain, Extremes};
use super::spectrum::{fft_bfp, lower_median, real_spectrum_powers, refine_peak, Hann, MAX_FFT_LEN};
use super::{
    Capture, FeatureError, Features, BLOCK_SAMPLES, DISTINCT_POWER_GAIN, FEATURE_COUNT, MAX_WINDOW_SAMPLES,
    MEAN_FREQ_HZ, NOISE_FLOOR_FACTOR, SIGNAL_FREQ_HZ, TOTAL_POWER_M2PS4,
};
use core::sync::atomic::{fence, AtomicI32, AtomicU32, Ordering};

/// Rings shared between the interrupt (writer) and the feature reader, one slot per block:
/// the block's sum of 16 codes (the decimated sample, times 16), its packed min/max, and the
/// command position handed in with its last sample (for the supervisor's view of the
/// motion).
///
/// All fields are atomics, so the rings are `Sync`, need no `unsafe` and can live in a
/// `static`. `RING_BLOCKS` must be at least the state's `WINDOW_BLOCKS + MARGIN_BLOCKS`
/// (checked at compile time by `push`). Memory: `12 * RING_BLOCKS + 4` bytes.
#[derive(Debug)]
pub struct SpectralRings<const RING_BLOCKS: usize> {
    /// Blocks whose write has started (wrapping); stored before the slot is written.
    claimed: AtomicU32,
    /// Sum of the block's 16 codes (|sum| <= 2^19), and the command position handed in with
    /// its last sample, nm (side by side: the block end stores both from one address).
    block_sum_cmd: [[AtomicI32; 2]; RING_BLOCKS],
    /// Block maximum (high 16 bits) and minimum (low 16 bits) codes.
    block_extremes: [AtomicU32; RING_BLOCKS],
}

impl<const RING_BLOCKS: usize> Default for SpectralRings<RING_BLOCKS> {
    fn default() -> Self {
        Self::new()
    }
}

/// Scratch memory for [`SpectralRings::finish`]: a complex FFT of up to `FFT_HALF` points
/// (real FFT length `2 * FFT_HALF`, a power of two, at most 4,096). Memory: `16 * FFT_HALF`
/// bytes. It holds no state between calls.
#[derive(Clone, Debug)]
pub struct Scratch<const FFT_HALF: usize> {
    /// Complex FFT buffer, `[re, im]` pairs.
    z: [[i32; 2]; FFT_HALF],
    /// Block sums (two per word) before the FFT, bin powers after it.
    power: [u64; FFT_HALF],
}

impl<const FFT_HALF: usize> Default for Scratch<FFT_HALF> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const FFT_HALF: usize> Scratch<FFT_HALF> {
    const SIZE_OK: () = assert!(
        FFT_HALF.is_power_of_two() && FFT_HALF >= 4 && FFT_HALF <= MAX_FFT_LEN / 2,
        "FFT_HALF must be a power of two within 4..=2048"
    );

    /// Zeroed scratch.
    pub const fn new() -> Self {
        #[allow(clippy::let_unit_value)]
        let () = Self::SIZE_OK;
        Self { z: [[0; 2]; FFT_HALF], power: [0; FFT_HALF] }
    }
}

impl<const RING_BLOCKS: usize> SpectralRings<RING_BLOCKS> {
    /// Empty rings.
    pub const fn new() -> Self {
        Self {
            claimed: AtomicU32::new(0),
            block_sum_cmd: [const { [AtomicI32::new(0), AtomicI32::new(0)] }; RING_BLOCKS],
            block_extremes: [const { AtomicU32::new(0) }; RING_BLOCKS],
        }
    }

    /// Writes block number `index` to `slot` (interrupt side).
    #[inline]
    pub(crate) fn publish(&self, slot: usize, index: u32, sum: i32, max: i16, min: i16, cmd_nm: i32) {
        let (Some([sum_slot, cmd_slot]), Some(ext_slot)) =
            (self.block_sum_cmd.get(slot), self.block_extremes.get(slot))
        else {
            return;
        };
        // Claim first: a reader that sees the new slot contents after its acquire fence
        // is then guaranteed to see the claim (fence-fence synchronisation).
        self.claimed.store(index.wrapping_add(1), Ordering::Relaxed);
        fence(Ordering::Release);
        sum_slot.store(sum, Ordering::Relaxed);
        cmd_slot.store(cmd_nm, Ordering::Relaxed);
        ext_slot.store(((max as u16 as u32) << 16) | min as u16 as u32, Ordering::Relaxed);
    }

    /// Hands the window's complete blocks of `capture` to `visit`, oldest first, as (index,
    /// block sum, packed extremes, command position handed in with the block's last sample),
    /// and returns how many there were; [`FeatureError::Torn`]
    /// when `push` overwrote any of them during the reading (the visited values are then
    /// not to be used), [`FeatureError::InvalidCapture`] for a capture from larger rings.
    pub fn visit_window(
        &self,
        capture: &Capture,
        mut visit: impl FnMut(usize, i32, u32, i32),
    ) -> Result<usize, FeatureError> {
        let nd = (capture.blocks as usize).min(capture.cfg.window_blocks());
        if nd > RING_BLOCKS || capture.ring_slot as usize >= RING_BLOCKS.max(1) {
            return Err(FeatureError::InvalidCapture);
        }
        let mut slot = (capture.ring_slot as usize + RING_BLOCKS - nd) % RING_BLOCKS.max(1);
        for j in 0..nd {
            visit(
                j,
                self.block_sum_cmd[slot][0].load(Ordering::Relaxed),
                self.block_extremes[slot].load(Ordering::Relaxed),
                self.block_sum_cmd[slot][1].load(Ordering::Relaxed),
            );
            slot += 1;
            if slot == RING_BLOCKS {
                slot = 0;
            }
        }
        fence(Ordering::Acquire);
        let claimed = self.claimed.load(Ordering::Relaxed);
        if nd > 0 && claimed.wrapping_sub(capture.blocks_written) > (RING_BLOCKS - nd) as u32 {
            return Err(FeatureError::Torn);
        }
        Ok(nd)
    }

    /// Computes the features of `capture`. Reads only the ring slots of the blocks the
    /// capture covers, so `push` may continue meanwhile for up to
    /// `RING_BLOCKS - window blocks` blocks (at least [`MARGIN_BLOCKS`](super::MARGIN_BLOCKS));
    /// beyond that the result is [`FeatureError::Torn`]. Also fails with
    /// [`FeatureError::ScratchTooSmall`] if `scratch` cannot hold the configured FFT, and
    /// with a configuration error or [`FeatureError::InvalidCapture`] for a hand-made,
    /// inconsistent capture. Never panics.
    pub fn finish<const FFT_HALF: usize>(
        &self,
        capture: &Capture,
        scratch: &mut Scratch<FFT_HALF>,
    ) -> Result<Features, FeatureError> {
        let cfg = &capture.cfg;
        // Captures made by `FeatureState::capture` always pass; hand-made ones must not
        // make the arithmetic below overflow or produce non-finite values.
        cfg.validate(MAX_WINDOW_SAMPLES)?;
        if capture.samples > cfg.window_samples
            || capture.blocks as usize > cfg.window_blocks()
            || capture.partial_len as usize >= BLOCK_SAMPLES
        {
            return Err(FeatureError::InvalidCapture);
        }
        let fft_len = cfg.fft_len();
        let half = fft_len / 2;
        if half > FFT_HALF || fft_len > MAX_FFT_LEN {
            return Err(FeatureError::ScratchTooSmall { needed_half_len: half as u32 });
        }
        // Gather the window's blocks, oldest first: extremes into max/min, block sums packed
        // two per u64 into scratch.power (2 * FFT_HALF >= FFT length >= nd slots).
        let mut max = if capture.partial_len > 0 { capture.partial_max } else { i16::MIN };
        let mut min = if capture.partial_len > 0 { capture.partial_min } else { i16::MAX };
        let nd = self.visit_window(capture, |j, sum, ext, _| {
            let (bmax, bmin) = ((ext >> 16) as u16 as i16, ext as u16 as i16);
            max = max.max(bmax);
            min = min.min(bmin);
            set_block_sum(&mut scratch.power, j, sum);
        })?;

        let mut out = [0.0f32; FEATURE_COUNT];
        let extremes = if nd > 0 || capture.partial_len > 0 { Some(Extremes { max, min }) } else { None };
        time_domain(capture, extremes, &mut out);
        spectral(capture, nd, scratch, &mut out);
        Ok(Features::from_array(out, capture.samples))
    }
}

/// Stores block sum `j` in the packed scratch (two i32 per u64).
#[inline]
fn set_block_sum(packed: &mut [u64], j: usize, sum: i32) {
    if let Some(word) = packed.get_mut(j / 2) {
        let shift = 32 * (j % 2);
        *word = (*word & !(0xffff_ffffu64 << shift)) | ((sum as u32 as u64) << shift);
    }
}

/// Block sum `j` from the packed scratch.
#[inline]
fn block_sum(packed: &[u64], j: usize) -> i64 {
    packed.get(j / 2).map_or(0, |word| (word >> (32 * (j % 2))) as u32 as i32 as i64)
}

/// Spectral features (f1, f11, f12) from the `nd` block sums packed in `scratch.power`.
fn spectral<const FFT_HALF: usize>(
    cap: &Capture,
    nd: usize,
    scratch: &mut Scratch<FFT_HALF>,
    out: &mut [f32; FEATURE_COUNT],
) {
    let cfg = &cap.cfg;
    let nd = nd.min(FFT_HALF * 2);
    if nd < 2 {
        return;
    }
    let Scratch { z, power } = scratch;
    // f12: variance of the decimated signal (block mean = sum / 16), exact in i128.
    let mut sum = 0i64;
    let mut sum_sq = 0i64; // <= 2^38 * 2^12
    let (mut y_max, mut y_min) = (i64::MIN, i64::MAX);
    for j in 0..nd {
        let v = block_sum(power, j);
        sum += v;
        sum_sq += v * v;
        y_max = y_max.max(v);
        y_min = y_min.min(v);
    }
    let c2 = nd as i128 * sum_sq as i128 - sum as i128 * sum as i128;
    let scale = cfg.acc_mps2_per_lsb;
    out[TOTAL_POWER_M2PS4] = (c2 as f32 / ((nd * nd) as f32) / 256.0) * (scale * scale);
    if nd < 4 || c2 == 0 {
        return;
    }

    // Mean removal, exact: z_j = nd * y_j - sum, |z| <= 2^32; normalised to 30 bits (exact
    // for small signals, rounded for large ones), times the Q30 Hann weight, rounded to 29
    // bits. Even/odd samples are packed as one complex sequence, zero-padded.
    let z_max = (nd as i64 * y_max - sum).max(sum - nd as i64 * y_min) as u64;
    let bits = 64 - z_max.leading_zeros();
    let (right, left) = if bits > 30 { (bits - 30, 0) } else { (0, 30 - bits) };
    let normalised = |j: usize| -> i32 {
        let z = nd as i64 * block_sum(power, j) - sum;
        if right > 0 {
            ((z + (1 << (right - 1))) >> right) as i32
        } else {
            (z as i32) << left
        }
    };
    let fft_len = cfg.fft_len();
    let half = fft_len / 2;
    let mut hann = Hann::new(nd);
    let mut windowed = |j: usize| -> i32 {
        match hann.next() {
            Some(w) if j < nd => ((normalised(j) as i64 * w as i64 + (1 << 30)) >> 31) as i32,
            _ => 0,
        }
    };
    let z = &mut z[..half];
    for (m, zm) in z.iter_mut().enumerate() {
        let even = windowed(2 * m);
        *zm = [even, windowed(2 * m + 1)];
    }
    fft_bfp(z);

    // Bin powers k = 1 ..= half into power[k - 1]; the peak is the first maximum.
    let power = &mut power[..half];
    let p0 = real_spectrum_powers(z, power);
    let mut peak_k = 1;
    let mut peak_p = 0u64;
    for (i, &p) in power.iter().enumerate() {
        if p > peak_p {
            peak_p = p;
            peak_k = i + 1;
        }
    }
    let below = if peak_k == 1 { p0 } else { power[peak_k - 2] };
    let above = if peak_k == half { power[half - 2] } else { power[peak_k] };
    let bin_hz = cfg.bin_hz();
    out[SIGNAL_FREQ_HZ] = refine_peak(peak_k, below, peak_p, above) * bin_hz;

    // The FFT buffer is free now: keep the powers in order there (low and high halves)
    // while selecting the median in place.
    for (p, zk) in power.iter().zip(z.iter_mut()) {
        *zk = [*p as u32 as i32, (*p >> 32) as u32 as i32];
    }
    let median = lower_median(power);
    // Sums in u64: powers reduced to 40 bits relative to the peak (weights k w <= 2^12,
    // at most 2^11 bins: < 2^63).
    let reduce = (64 - peak_p.leading_zeros()).saturating_sub(40);
    let floor = ((median as u128 * NOISE_FLOOR_FACTOR as u128) >> reduce).min(u64::MAX as u128) as u64;
    let (mut num_excess, mut den_excess, mut num_plain, mut den_plain) = (0u64, 0u64, 0u64, 0u64);
    let mut k = 0u64;
    for zk in z.iter() {
        k += 1;
        let p = ((zk[1] as u32 as u64) << 32 | zk[0] as u32 as u64) >> reduce;
        let w = if k == half as u64 { 1 } else { 2 };
        let excess = w * p.saturating_sub(floor);
        num_excess += k * excess;
        den_excess += excess;
        num_plain += k * w * p;
        den_plain += w * p;
    }
    let bins = if den_plain == 0 {
        0.0
    } else {
        let plain = num_plain as f32 / den_plain as f32;
        let distinct = if den_excess > 0 { num_excess as f32 / den_excess as f32 } else { 0.0 };
        let alpha = ((den_excess as f32 / den_plain as f32) * DISTINCT_POWER_GAIN).min(1.0);
        alpha * distinct + (1.0 - alpha) * plain
    };
    out[MEAN_FREQ_HZ] = bins * bin_hz;
}
