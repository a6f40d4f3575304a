//! Streaming accelerometer features (the 12 features of the paper's Table 1).
//!
//! One signed 16-bit ADC code arrives per servo tick (8 kHz by default); acceleration is
//! `code * acc_mps2_per_lsb`. The features describe a sliding window of the last
//! `window_samples` codes (default 40,000 = 5 s). Per-sample work is O(1), constant and
//! integer-only; the window-wide results are assembled at read time.
//!
//! # Split for interrupt use
//!
//! - [`FeatureState`] is owned by the 8 kHz interrupt. [`FeatureState::push`] updates exact
//!   integer sliding sums and, once per block of [`BLOCK_SAMPLES`] samples, writes one
//!   decimated sample and the block's extremes into the shared [`SpectralRings`].
//! - [`SpectralRings`] is made of atomics only (`const fn new`, `Sync`), so it can live in a
//!   `static` and be read by a lower-priority task while the interrupt keeps pushing.
//! - The reader takes a small [`Capture`] (O(1), e.g. inside a short critical section or by
//!   asking the interrupt to take it), then calls [`SpectralRings::finish`] outside any lock.
//!   The rings hold [`MARGIN_BLOCKS`] blocks more than the window (4,096 samples, 0.512 s at
//!   8 kHz), so `push` may run that long after the capture before it overwrites a slot
//!   `finish` reads; if it ran longer, `finish` notices it through the write counter and
//!   returns [`FeatureError::Torn`] instead of wrong values.
//! - [`FeatureExtractor`] bundles the three parts for single-threaded (host) use.
//!
//! # Feature definitions
//!
//! Let the window hold the last `n = min(pushed, window_samples)` codes `x_i`, let
//! `mean = (1/n) sum x_i` and all moments be central (so a DC offset of the accelerometer
//! does not change any feature). `s` is `acc_mps2_per_lsb`.
//!
//! | index | label | name | definition | unit |
//! |---|---|---|---|---|
//! | 0 | f1 | `signal_freq_hz` | dominant frequency: peak of the Hann-windowed, zero-padded power spectrum of the decimated window, refined by a parabola through the log power of the peak bin and its neighbours | Hz |
//! | 1 | f2 | `mean_abs_mps2` | `s * (1/n) sum abs(x_i - d_i)`, `d_i` the tracked DC reference (below) | m/s^2 |
//! | 2 | f3 | `variance_m2ps4` | `s^2 * (1/n) sum (x_i - mean)^2` (population variance) | (m/s^2)^2 |
//! | 3 | f4 | `peak_mps2` | `s * max abs(x_i - mean)` over the window extended back to a block boundary (below) | m/s^2 |
//! | 4 | f5 | `rms_mps2` | `sqrt(f3)`: RMS of the DC-removed signal | m/s^2 |
//! | 5 | f6 | `kurtosis` | `m4 / m2^2`, `mk = (1/n) sum (x_i - mean)^k` (Pearson, 3 for a Gaussian) | - |
//! | 6 | f7 | `skewness` | `m3 / m2^1.5` | - |
//! | 7 | f8 | `crest_factor` | `f4 / f5` | - |
//! | 8 | f9 | `impulse_factor` | `f4 / f2` | - |
//! | 9 | f10 | `shape_factor` | `f5 / f2` | - |
//! | 10 | f11 | `mean_freq_hz` | spectral centroid of the noise-floor-subtracted one-sided power spectrum (below) | Hz |
//! | 11 | f12 | `total_power_m2ps4` | integral of the (rectangular-window) periodogram of the decimated, mean-removed window over 0 < f <= fs/32, i.e. the variance of the decimated signal | (m/s^2)^2 |
//!
//! Details:
//!
//! - **Blocks and decimation.** Samples are grouped in blocks of [`BLOCK_SAMPLES`] = 16
//!   aligned to the first push after (re)configuration. Each complete block gives one
//!   decimated sample, the block mean (boxcar decimation by 16: 500 Hz at 8 kHz), and its
//!   minimum and maximum code. The window length must be a whole number of blocks.
//! - **Peak (f4)** is taken over the complete blocks that overlap the window plus the current
//!   partial block, so it may include up to 15 samples older than the window (granularity
//!   one block, 2 ms at 8 kHz); it never misses a sample of the window.
//! - **Mean absolute value (f2)** needs a DC reference that a sliding sum can subtract
//!   again: at the start of each block, `d` is set to the window mean at that moment,
//!   truncated toward zero to 1/256 LSB (for the first block after (re)configuration: its
//!   first code), and every sample of the block uses it. For a
//!   stationary DC offset `d` equals the window mean to within 1/256 LSB, so f2 is
//!   `mean abs(x - mean)`; when the mean drifts within the window f2 deviates by at most the
//!   drift of the block references. The f64 reference uses the same `d_i`.
//! - **Spectrum (f1, f11).** The last `nd = min(complete blocks, window_samples/16)`
//!   decimated samples, mean removed, times a periodic Hann window
//!   `w_j = 0.5 (1 - cos(2 pi j / nd))`, zero-padded to `M = max(8, next_pow2(window_samples/16))`
//!   points (4,096 by default: 0.122 Hz bins) and transformed; `P_k = |X_k|^2`,
//!   `k = 1 ..= M/2` (DC excluded). f1: first bin of largest `P_k`, refined by
//!   `delta = 0.5 (a - c) / (a - 2b + c)` with `a, b, c = log2 P` at `k-1, k, k+1`
//!   (`P_{M/2+1} = P_{M/2-1}`; powers floored at `2^-40` times the peak), `delta` clamped to
//!   +-0.5. f11: with one-sided weights `w_k = 2` (`w_{M/2} = 1`), the noise floor
//!   `T = 8 * median(P_1 ..= P_{M/2})` (lower median) and the excess
//!   `E_k = max(P_k - T, 0)`: the centroid of the excess `c_E = sum k w_k E_k / sum w_k E_k`,
//!   the plain centroid `c_P = sum k w_k P_k / sum w_k P_k`, the distinct-power fraction
//!   `rho = sum w_k E_k / sum w_k P_k`, `alpha = min(1, rho / 0.05)`, and
//!   `f11 = (alpha c_E + (1 - alpha) c_P) * bin width`. Subtracting the floor keeps
//!   broadband noise from pulling the centroid of a tone toward fs/64 (for white noise
//!   about 0.4% of the noise power stays above `T`); the blend, continuous in the input,
//!   makes a broadband spectrum (nothing distinct above the floor) report its plain
//!   centroid instead of the centroid of a few random noise peaks.
//! - **Degenerate windows** give defined, finite values: with `n < 2` all time-domain
//!   features are 0; a ratio whose denominator is 0 (silence, constant signal) is 0;
//!   skewness and kurtosis of a constant window are 0; with fewer than 4 decimated samples
//!   (or a constant decimated window) f1 and f11 are 0, with fewer than 2 f12 is 0.
//!
//! # Arithmetic and accuracy
//!
//! `push` keeps exact integer sums of `x, x^2, x^3, x^4` (i32, i64, i64, i128) and of
//! `abs(256 x - d)` (i64); none of them can overflow for any i16 sequence at the maximum
//! window of [`MAX_WINDOW_SAMPLES`]. At read time the central moments are formed exactly
//! in i128 (`n^2 m2 = n S2 - S1^2` etc.), so DC offsets cost no precision, and converted
//! to f32 once; the remaining f32 operations are IEEE `+ - * /` and [`sqrt_f32`], a
//! correctly rounded square root in integer arithmetic, so results are bit-identical on the
//! host and on Cortex-M4F. The spectrum uses a block-floating-point integer FFT with Q30
//! twiddles. Against the f64 reference (the tests' `support/reference.rs`), f2..f10 and f12 agree
//! to 2.3e-7 relative, f11 to 6e-6 and f1 to 1e-4 bins; for sinusoids of 1-100 Hz f1 is
//! within 0.005 Hz and f11 within 0.05 Hz down to 1e-4 m/s^2 under 5e-5 m/s^2 noise at
//! 1e-4 m/s^2 per LSB (see `docs/features.md`).
//!
//! # Memory
//!
//! `FeatureState<WB>`: `36 * WB` bytes plus about 100 (i16 raw ring of `16 WB` samples plus an i32
//! DC reference per block). `SpectralRings<RB>`: `8 * RB + 4` bytes. `Scratch<H>`:
//! `16 * H` bytes. Defaults (40,000 samples): 90 KB + 22 KB + 32 KB.
//!
//! # Example
//!
//! ```
//! use sts_twin_core::features::{FeatureConfig, FeatureExtractor, SIGNAL_FREQ_HZ};
//!
//! // A 1,024-sample window (64 blocks, 128 ms) with a 64-point FFT.
//! let cfg = FeatureConfig { window_samples: 1024, ..FeatureConfig::DEFAULT };
//! let mut fx = FeatureExtractor::<64, 320, 32>::new(cfg).unwrap();
//! for i in 0..2048 {
//!     let t = i as f32 / 8000.0;
//!     let phase = 2.0 * core::f32::consts::PI * 50.0 * t;
//!     // 0.5 m/s^2 at 50 Hz, 1e-4 m/s^2 per LSB.
//!     fx.push((5000.0 * micromath::F32Ext::sin(phase)) as i16);
//! }
//! let f = fx.features();
//! assert!((f.signal_freq_hz() - 50.0).abs() < 0.5);
//! assert_eq!(f.as_array()[SIGNAL_FREQ_HZ], f.signal_freq_hz());
//! assert!((f.rms_mps2() - 0.5 / core::f32::consts::SQRT_2).abs() < 0.01);
//! ```

mod extractor;
mod moments;
mod rings;
mod spectrum;
mod state;

pub use extractor::FeatureExtractor;
pub use moments::sqrt_f32;
pub use rings::{Scratch, SpectralRings};
pub use state::{Capture, FeatureSnapshot, FeatureState};

use core::fmt;

/// Samples per block: the decimation factor and the granularity of the peak window.
pub const BLOCK_SAMPLES: usize = 16;
/// Extra ring slots (in blocks) beyond the window: `push` may run this many blocks
/// (4,096 samples, 0.512 s at 8 kHz) after a [`Capture`] before `finish` must be done.
pub const MARGIN_BLOCKS: usize = 256;
/// Largest window, in blocks. Bounded so that the exact i128 central moments cannot
/// overflow and the FFT length stays within the built-in twiddle table.
pub const MAX_WINDOW_BLOCKS: usize = 4096;
/// Largest window in samples (65,536 = 8.19 s at 8 kHz).
pub const MAX_WINDOW_SAMPLES: usize = MAX_WINDOW_BLOCKS * BLOCK_SAMPLES;
/// Smallest window in blocks (8 blocks, 128 samples).
pub const MIN_WINDOW_BLOCKS: usize = 8;
/// Smallest window in samples.
pub const MIN_WINDOW_SAMPLES: usize = MIN_WINDOW_BLOCKS * BLOCK_SAMPLES;
/// The mean-frequency noise floor is this many times the median bin power.
pub const NOISE_FLOOR_FACTOR: u32 = 8;
/// Mean frequency blend: `alpha = min(1, DISTINCT_POWER_GAIN * rho)`, `rho` the fraction of
/// the power above the noise floor; full weight on the floor-subtracted centroid from 5%.
pub const DISTINCT_POWER_GAIN: f32 = 20.0;

/// Number of features.
pub const FEATURE_COUNT: usize = 12;
/// Index of f1, signal (dominant) frequency in Hz.
pub const SIGNAL_FREQ_HZ: usize = 0;
/// Index of f2, mean absolute value of the DC-removed signal in m/s^2.
pub const MEAN_ABS_MPS2: usize = 1;
/// Index of f3, variance in (m/s^2)^2.
pub const VARIANCE_M2PS4: usize = 2;
/// Index of f4, peak amplitude (about the mean) in m/s^2.
pub const PEAK_MPS2: usize = 3;
/// Index of f5, RMS of the DC-removed signal in m/s^2.
pub const RMS_MPS2: usize = 4;
/// Index of f6, kurtosis (Pearson, not excess).
pub const KURTOSIS: usize = 5;
/// Index of f7, skewness.
pub const SKEWNESS: usize = 6;
/// Index of f8, crest factor = peak / RMS.
pub const CREST_FACTOR: usize = 7;
/// Index of f9, impulse factor = peak / mean absolute value.
pub const IMPULSE_FACTOR: usize = 8;
/// Index of f10, shape factor = RMS / mean absolute value.
pub const SHAPE_FACTOR: usize = 9;
/// Index of f11, mean frequency (spectral centroid) in Hz.
pub const MEAN_FREQ_HZ: usize = 10;
/// Index of f12, total power of the decimated signal in (m/s^2)^2.
pub const TOTAL_POWER_M2PS4: usize = 11;

/// The paper's labels, by index.
pub const FEATURE_LABELS: [&str; FEATURE_COUNT] =
    ["f1", "f2", "f3", "f4", "f5", "f6", "f7", "f8", "f9", "f10", "f11", "f12"];
/// Descriptive names with units, by index.
pub const FEATURE_NAMES: [&str; FEATURE_COUNT] = [
    "signal_freq_hz",
    "mean_abs_mps2",
    "variance_m2ps4",
    "peak_mps2",
    "rms_mps2",
    "kurtosis",
    "skewness",
    "crest_factor",
    "impulse_factor",
    "shape_factor",
    "mean_freq_hz",
    "total_power_m2ps4",
];

/// The index of a feature given its label (`"f1"`..`"f12"`) or its name (`"rms_mps2"`).
pub fn feature_index(label_or_name: &str) -> Option<usize> {
    FEATURE_LABELS
        .iter()
        .position(|l| *l == label_or_name)
        .or_else(|| FEATURE_NAMES.iter().position(|n| *n == label_or_name))
}

/// Configuration of the feature extraction.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct FeatureConfig {
    /// Window length in samples: a multiple of [`BLOCK_SAMPLES`], at least
    /// [`MIN_WINDOW_SAMPLES`], at most the state's capacity.
    pub window_samples: u32,
    /// Accelerometer scale in m/s^2 per ADC LSB, in `[1e-9, 1e3]`.
    pub acc_mps2_per_lsb: f32,
    /// Sample rate of `push` in Hz, in `[1, 1e6]`.
    pub sample_rate_hz: f32,
}

impl FeatureConfig {
    /// 5 s at 8 kHz, 1e-4 m/s^2 per LSB (full scale +-3.28 m/s^2; a 1e-4 m/s^2 sinusoid is
    /// one LSB and is resolved in the spectrum with 0.3 LSB rms or more of noise as dither).
    pub const DEFAULT: Self =
        Self { window_samples: 40_000, acc_mps2_per_lsb: 1.0e-4, sample_rate_hz: crate::SERVO_RATE_HZ as f32 };

    /// Checks the configuration for a state holding `capacity_samples` samples.
    pub const fn validate(&self, capacity_samples: usize) -> Result<(), FeatureError> {
        let w = self.window_samples as usize;
        if w == 0 {
            return Err(FeatureError::WindowZero);
        }
        if w > capacity_samples || w > MAX_WINDOW_SAMPLES {
            let max = if capacity_samples < MAX_WINDOW_SAMPLES { capacity_samples } else { MAX_WINDOW_SAMPLES };
            return Err(FeatureError::WindowTooLong { window_samples: self.window_samples, max_samples: max as u32 });
        }
        if w < MIN_WINDOW_SAMPLES {
            return Err(FeatureError::WindowTooShort {
                window_samples: self.window_samples,
                min_samples: MIN_WINDOW_SAMPLES as u32,
            });
        }
        if !w.is_multiple_of(BLOCK_SAMPLES) {
            return Err(FeatureError::WindowNotWholeBlocks { window_samples: self.window_samples });
        }
        let s = self.acc_mps2_per_lsb;
        if !(s.is_finite() && s >= 1.0e-9 && s <= 1.0e3) {
            return Err(FeatureError::BadScale);
        }
        let fs = self.sample_rate_hz;
        if !(fs.is_finite() && fs >= 1.0 && fs <= 1.0e6) {
            return Err(FeatureError::BadSampleRate);
        }
        Ok(())
    }

    /// Window length in blocks.
    pub const fn window_blocks(&self) -> usize {
        self.window_samples as usize / BLOCK_SAMPLES
    }

    /// FFT length (real points) used for the spectral features.
    pub const fn fft_len(&self) -> usize {
        let m = self.window_blocks().next_power_of_two();
        if m < 8 {
            8
        } else {
            m
        }
    }

    /// Width of one FFT bin in Hz.
    pub fn bin_hz(&self) -> f32 {
        self.sample_rate_hz / ((BLOCK_SAMPLES * self.fft_len()) as f32)
    }
}

impl Default for FeatureConfig {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// Why a configuration was rejected or a read failed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum FeatureError {
    /// `window_samples` is 0.
    WindowZero,
    /// `window_samples` exceeds the capacity of the state (or [`MAX_WINDOW_SAMPLES`]).
    WindowTooLong {
        /// The requested window.
        window_samples: u32,
        /// The largest window allowed.
        max_samples: u32,
    },
    /// `window_samples` is below [`MIN_WINDOW_SAMPLES`].
    WindowTooShort {
        /// The requested window.
        window_samples: u32,
        /// The smallest window allowed.
        min_samples: u32,
    },
    /// `window_samples` is not a multiple of [`BLOCK_SAMPLES`].
    WindowNotWholeBlocks {
        /// The requested window.
        window_samples: u32,
    },
    /// `acc_mps2_per_lsb` is not finite or outside `[1e-9, 1e3]`.
    BadScale,
    /// `sample_rate_hz` is not finite or outside `[1, 1e6]`.
    BadSampleRate,
    /// The scratch buffer is too small for the configured FFT length.
    ScratchTooSmall {
        /// Complex FFT points needed (half the real FFT length).
        needed_half_len: u32,
    },
    /// A capture whose counts are inconsistent with its configuration (only possible for
    /// a hand-made [`Capture`]).
    InvalidCapture,
    /// `push` overwrote ring slots that `finish` was reading (the reader took longer than
    /// the margin); take a new capture and retry.
    Torn,
}

impl fmt::Display for FeatureError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::WindowZero => write!(f, "feature window_samples must not be 0"),
            Self::WindowTooLong { window_samples, max_samples } => {
                write!(f, "feature window_samples {window_samples} exceeds the capacity {max_samples}")
            }
            Self::WindowTooShort { window_samples, min_samples } => {
                write!(f, "feature window_samples {window_samples} is below the minimum {min_samples}")
            }
            Self::WindowNotWholeBlocks { window_samples } => {
                write!(f, "feature window_samples {window_samples} is not a multiple of {BLOCK_SAMPLES}")
            }
            Self::BadScale => write!(f, "acc_mps2_per_lsb must be finite and within [1e-9, 1e3]"),
            Self::BadSampleRate => write!(f, "sample_rate_hz must be finite and within [1, 1e6]"),
            Self::ScratchTooSmall { needed_half_len } => {
                write!(f, "feature scratch too small: {needed_half_len} complex FFT points needed")
            }
            Self::InvalidCapture => write!(f, "feature capture is inconsistent with its configuration"),
            Self::Torn => write!(f, "feature rings were overwritten during the read; retry"),
        }
    }
}

impl core::error::Error for FeatureError {}

/// The 12 features of one window, in SI units (see the module docs for definitions).
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Features {
    values: [f32; FEATURE_COUNT],
    window_samples_used: u32,
}

impl Features {
    /// Builds features from values by index (e.g. read back from a dataset).
    pub const fn from_array(values: [f32; FEATURE_COUNT], window_samples_used: u32) -> Self {
        Self { values, window_samples_used }
    }
    /// All values, indexed by [`SIGNAL_FREQ_HZ`] .. [`TOTAL_POWER_M2PS4`] (f1 at index 0).
    pub const fn as_array(&self) -> [f32; FEATURE_COUNT] {
        self.values
    }
    /// The value at `index` (0-based), or `None` past [`FEATURE_COUNT`].
    pub fn get(&self, index: usize) -> Option<f32> {
        self.values.get(index).copied()
    }
    /// Number of samples the time-domain features were computed over (`min(pushed, window)`).
    pub const fn window_samples_used(&self) -> u32 {
        self.window_samples_used
    }
    /// f1, dominant frequency in Hz.
    pub const fn signal_freq_hz(&self) -> f32 {
        self.values[SIGNAL_FREQ_HZ]
    }
    /// f2, mean absolute value of the DC-removed signal in m/s^2.
    pub const fn mean_abs_mps2(&self) -> f32 {
        self.values[MEAN_ABS_MPS2]
    }
    /// f3, variance in (m/s^2)^2.
    pub const fn variance_m2ps4(&self) -> f32 {
        self.values[VARIANCE_M2PS4]
    }
    /// f4, peak amplitude about the mean in m/s^2.
    pub const fn peak_mps2(&self) -> f32 {
        self.values[PEAK_MPS2]
    }
    /// f5, RMS of the DC-removed signal in m/s^2.
    pub const fn rms_mps2(&self) -> f32 {
        self.values[RMS_MPS2]
    }
    /// f6, kurtosis (Pearson: 3 for a Gaussian, 1.5 for a sinusoid).
    pub const fn kurtosis(&self) -> f32 {
        self.values[KURTOSIS]
    }
    /// f7, skewness.
    pub const fn skewness(&self) -> f32 {
        self.values[SKEWNESS]
    }
    /// f8, crest factor = peak / RMS.
    pub const fn crest_factor(&self) -> f32 {
        self.values[CREST_FACTOR]
    }
    /// f9, impulse factor = peak / mean absolute value.
    pub const fn impulse_factor(&self) -> f32 {
        self.values[IMPULSE_FACTOR]
    }
    /// f10, shape factor = RMS / mean absolute value.
    pub const fn shape_factor(&self) -> f32 {
        self.values[SHAPE_FACTOR]
    }
    /// f11, mean frequency (noise-floor-subtracted spectral centroid) in Hz.
    pub const fn mean_freq_hz(&self) -> f32 {
        self.values[MEAN_FREQ_HZ]
    }
    /// f12, total power of the decimated signal in (m/s^2)^2.
    pub const fn total_power_m2ps4(&self) -> f32 {
        self.values[TOTAL_POWER_M2PS4]
    }
}

/// Default capacity: 2,500 blocks = 40,000 samples (5 s at 8 kHz).
pub const DEFAULT_WINDOW_BLOCKS: usize = 2500;
/// Default ring length: window plus margin.
pub const DEFAULT_RING_BLOCKS: usize = DEFAULT_WINDOW_BLOCKS + MARGIN_BLOCKS;
/// Default scratch: 2,048 complex points = 4,096-point real FFT.
pub const DEFAULT_FFT_HALF: usize = 2048;

/// Interrupt-owned state for up to 40,000 samples.
pub type DefaultFeatureState = FeatureState<DEFAULT_WINDOW_BLOCKS>;
/// Shared rings matching [`DefaultFeatureState`].
pub type DefaultSpectralRings = SpectralRings<DEFAULT_RING_BLOCKS>;
/// Scratch matching [`DefaultFeatureState`].
pub type DefaultScratch = Scratch<DEFAULT_FFT_HALF>;
/// Host-side bundle for up to 40,000 samples.
pub type DefaultFeatureExtractor = FeatureExtractor<DEFAULT_WINDOW_BLOCKS, DEFAULT_RING_BLOCKS, DEFAULT_FFT_HALF>;
