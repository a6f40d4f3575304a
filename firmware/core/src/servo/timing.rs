//! When model updates happen: the interval between model requests and the latency from a
//! request to its result, for the feature window in force.

use super::ServoConfig;

/// Ticks to the first model request: one interval, shifted by half a feature block so that
/// requests (and the model results applied `model_latency_ticks` later, when that is a whole
/// number of blocks) never fall on the tick that closes a 16-sample feature block, the most
/// expensive tick of the feature update.
pub(super) fn first_request_countdown(timing: &ModelTiming) -> u32 {
    timing.interval_ticks.saturating_add((crate::features::BLOCK_SAMPLES / 2) as u32)
}

/// When model updates happen, for a feature window: the interval is the window over
/// [`ServoConfig::model_updates_per_window`], within the configured bounds, and the latency
/// half of it (at most [`ServoConfig::model_latency_ticks`]), both in whole 16-sample blocks
/// so that requests and results avoid the block ends.
///
/// Why frequent updates for short windows: the accelerometer sees the compensated motion,
/// so the twin's amplitude closes a loop through the machine, and a cut whose amplitude
/// changes (the bicuspid's shrinks with the radius) is followed with this loop's delay
/// (measured at 40 Hz with a 0.1 s window: 800/400 ticks left a 0.65 deg phase error,
/// 96/48 ticks 0.30 deg, 48/16 ticks 0.29 deg; the window itself is the larger delay). A long window gains nothing from frequent updates and its
/// feature computation costs more, so its interval stays long.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ModelTiming {
    /// Ticks between model requests.
    pub interval_ticks: u32,
    /// Ticks from a request to its result taking effect.
    pub latency_ticks: u32,
}

impl ModelTiming {
    /// The timing for `window_samples` under `config`.
    pub fn new(config: &ServoConfig, window_samples: u32) -> Self {
        let block = crate::features::BLOCK_SAMPLES as u32;
        let whole_blocks = |ticks: u32| (ticks / block).max(1) * block;
        let longest = config.model_interval_ticks.max(1);
        let shortest = config.min_model_interval_ticks.clamp(1, longest);
        let per_window = window_samples / config.model_updates_per_window.max(1);
        let interval_ticks = whole_blocks(per_window.clamp(shortest, longest));
        let latency_ticks = whole_blocks(interval_ticks / 2).min(config.model_latency_ticks);
        Self { interval_ticks, latency_ticks }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn model_timing_follows_the_window_within_bounds_in_whole_blocks() {
        let config = ServoConfig::default();
        assert_eq!(ModelTiming::new(&config, 40_000), ModelTiming { interval_ticks: 800, latency_ticks: 400 });
        assert_eq!(ModelTiming::new(&config, 2_000), ModelTiming { interval_ticks: 112, latency_ticks: 48 });
        assert_eq!(ModelTiming::new(&config, 800), ModelTiming { interval_ticks: 48, latency_ticks: 16 });
        assert_eq!(ModelTiming::new(&config, 16), ModelTiming { interval_ticks: 48, latency_ticks: 16 });
        let odd =
            ServoConfig { model_interval_ticks: 7, min_model_interval_ticks: 0, model_updates_per_window: 0, ..config };
        let timing = ModelTiming::new(&odd, 40_000);
        assert!(timing.interval_ticks >= 1 && timing.latency_ticks >= 1);
    }
}
