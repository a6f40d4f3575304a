//! Single-owner bundle of state, rings and scratch, for the host and for tests.

use super::{FeatureConfig, FeatureError, FeatureState, Features, Scratch, SpectralRings};

/// State, rings and scratch in one value: `push` codes, read [`Features`] any time.
///
/// `WINDOW_BLOCKS`, `RING_BLOCKS` and `FFT_HALF` as for [`FeatureState`], [`SpectralRings`]
/// and [`Scratch`]; use [`DefaultFeatureExtractor`](super::DefaultFeatureExtractor) for
/// 40,000 samples. Memory: about 145 KB for the default.
#[derive(Debug)]
pub struct FeatureExtractor<const WINDOW_BLOCKS: usize, const RING_BLOCKS: usize, const FFT_HALF: usize> {
    state: FeatureState<WINDOW_BLOCKS>,
    rings: SpectralRings<RING_BLOCKS>,
    scratch: Scratch<FFT_HALF>,
}

impl<const WINDOW_BLOCKS: usize, const RING_BLOCKS: usize, const FFT_HALF: usize>
    FeatureExtractor<WINDOW_BLOCKS, RING_BLOCKS, FFT_HALF>
{
    const SCRATCH_OK: () = assert!(
        WINDOW_BLOCKS.next_power_of_two() <= 2 * FFT_HALF,
        "FFT_HALF too small for WINDOW_BLOCKS: need 2 * FFT_HALF >= next_pow2(WINDOW_BLOCKS)"
    );

    /// A fresh extractor; fails if `cfg` is invalid for the capacity.
    pub fn new(cfg: FeatureConfig) -> Result<Self, FeatureError> {
        #[allow(clippy::let_unit_value)]
        let () = Self::SCRATCH_OK;
        cfg.validate(FeatureState::<WINDOW_BLOCKS>::CAPACITY_SAMPLES)?;
        if cfg.fft_len() / 2 > FFT_HALF {
            return Err(FeatureError::ScratchTooSmall { needed_half_len: (cfg.fft_len() / 2) as u32 });
        }
        Ok(Self { state: FeatureState::new(cfg)?, rings: SpectralRings::new(), scratch: Scratch::new() })
    }

    /// The configuration in force.
    pub fn config(&self) -> &FeatureConfig {
        self.state.config()
    }

    /// Switches to `cfg` and empties the window; on error nothing changes.
    pub fn reconfigure(&mut self, cfg: FeatureConfig) -> Result<(), FeatureError> {
        cfg.validate(FeatureState::<WINDOW_BLOCKS>::CAPACITY_SAMPLES)?;
        if cfg.fft_len() / 2 > FFT_HALF {
            return Err(FeatureError::ScratchTooSmall { needed_half_len: (cfg.fft_len() / 2) as u32 });
        }
        self.state.reconfigure(cfg)
    }

    /// Adds one ADC code.
    #[inline]
    pub fn push(&mut self, code: i16) {
        self.state.push(&self.rings, code);
    }

    /// Adds ADC codes in order.
    pub fn push_slice(&mut self, codes: &[i16]) {
        for &c in codes {
            self.state.push(&self.rings, c);
        }
    }

    /// The features of the current window.
    pub fn features(&mut self) -> Features {
        let capture = self.state.capture(&self.rings);
        // Neither error can occur: `push` cannot run during this `&mut self` call, and the
        // scratch size was checked by `new`/`reconfigure`.
        self.rings.finish(&capture, &mut self.scratch).unwrap_or_default()
    }

    /// The interrupt-owned part, for tests and split use.
    pub fn state(&self) -> &FeatureState<WINDOW_BLOCKS> {
        &self.state
    }

    /// The shared rings, for tests and split use.
    pub fn rings(&self) -> &SpectralRings<RING_BLOCKS> {
        &self.rings
    }
}
