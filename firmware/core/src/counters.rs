//! Event counters of the firmware.

use serde::{Deserialize, Serialize};

/// Event counters. Every fault the firmware sees is counted here.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Counters {
    /// Servo ticks processed.
    pub ticks: u64,
    /// Ticks whose input arrived late or never (the output was held).
    pub bus_underruns: u32,
    /// Ticks that started before the previous one finished.
    pub bus_overruns: u32,
    /// Ticks whose DAC target was clamped at full scale.
    pub dac_saturations: u32,
    /// Ticks on which the output moved at the slew limit.
    pub slew_limited_ticks: u32,
    /// Control frames dropped (stuffing, CRC, decode, length).
    pub frame_errors: u32,
    /// Uploaded programs rejected by validation.
    pub rejected_programs: u32,
    /// Parameter sets rejected.
    pub rejected_params: u32,
    /// Model evaluations that failed (non-finite values, torn feature snapshot).
    pub model_faults: u32,
    /// Model results that arrived after their due tick.
    pub model_late: u32,
    /// Model updates made.
    pub model_updates: u32,
    /// Episodes of a stuck or dead accelerometer.
    pub input_stuck: u32,
    /// Episodes of accelerometer saturation.
    pub input_saturated: u32,
    /// Times the servo entered the degraded state.
    pub degraded_entries: u32,
    /// Config store reads or writes that failed.
    pub config_store_errors: u32,
    /// Feature settings rejected (`SetFeatureConfig` with a zero or too long window).
    pub rejected_feature_configs: u32,
    /// Servo-axis twin states reset to rest after diverging (a model whose loop is unstable
    /// on this motion; the term restarts, its output never leaves the bound).
    pub axis_resets: u32,
    /// Times the supervisor switched compensation off (not helping, or running away).
    pub supervisor_trips: u32,
}

impl Counters {
    /// Sum of the fault counters (wrapping): underruns, overruns, DAC saturations, frame
    /// errors, rejected programs and parameters, model faults, axis twin resets, stuck and
    /// saturated inputs, config store errors, supervisor trips. Every output slot reports it.
    pub fn fault_sum(&self) -> u32 {
        self.bus_underruns
            .wrapping_add(self.bus_overruns)
            .wrapping_add(self.dac_saturations)
            .wrapping_add(self.frame_errors)
            .wrapping_add(self.rejected_programs)
            .wrapping_add(self.rejected_params)
            .wrapping_add(self.rejected_feature_configs)
            .wrapping_add(self.model_faults)
            .wrapping_add(self.axis_resets)
            .wrapping_add(self.input_stuck)
            .wrapping_add(self.input_saturated)
            .wrapping_add(self.config_store_errors)
            .wrapping_add(self.supervisor_trips)
    }
}
