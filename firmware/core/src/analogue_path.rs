//! The analogue path's phase response: DAC -> motion controller -> servo loop -> TCP.
//!
//! The feedforward asks for a displacement `u`, but the machine moves the tool by `H(f) u`,
//! where `H` is the response of the path from the co-processor's DAC to the tool centre
//! point relative to its static gain `K_dv`. The twin predicts the error's phase relative to
//! the *command*, so a phase lag of the path shifts the correction by the same lag. The
//! synthesiser therefore subtracts `arg H(f)` at the command frequency `f` from every model
//! update's phase (the amplitude needs no such correction: the accelerometer sees the
//! compensated motion, and at the fixed point the twin's amplitude is the one required).
//!
//! `arg H` is measured by `sts-twin calibrate` (a sine through the analogue input at each
//! frequency, the capacitance probe at the TCP) and held as a table of at most
//! [`PATH_POINTS`] points, linearly interpolated; below the first point the phase goes
//! linearly to zero at 0 Hz (a causal path has no phase at DC), above the last it holds. An
//! empty table is no correction (the paper's Eq. 5 as written).
//!
//! ```
//! use sts_twin_core::analogue_path::AnaloguePath;
//! let path = AnaloguePath::from_points(&[(20.0, -1.0), (40.0, -6.0)]).unwrap();
//! assert_eq!(path.phase_deg_at(30.0), -3.5);
//! assert_eq!(path.phase_deg_at(10.0), -0.5);
//! assert_eq!(path.phase_deg_at(80.0), -6.0);
//! assert!(AnaloguePath::from_points(&[(40.0, 0.0), (20.0, 0.0)]).is_err());
//! ```

use serde::{Deserialize, Serialize};

/// Most points in an [`AnaloguePath`] table.
pub const PATH_POINTS: usize = 8;

/// Highest frequency a table may name, Hz (half the 8 kHz servo rate).
pub const PATH_MAX_FREQ_HZ: f32 = 4000.0;

/// The analogue path's phase `arg H(f)` at up to [`PATH_POINTS`] frequencies. See the
/// [module docs](self).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct AnaloguePath {
    /// Points in use (the first `count` of each array).
    pub count: u8,
    /// Frequencies, Hz, strictly increasing, in (0, [`PATH_MAX_FREQ_HZ`]].
    pub freq_hz: [f32; PATH_POINTS],
    /// `arg H` at each frequency, degrees, within +-180 (a lag is negative).
    pub phase_deg: [f32; PATH_POINTS],
}

/// Why an analogue-path table was rejected.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum PathError {
    /// More than [`PATH_POINTS`] points.
    TooManyPoints,
    /// A frequency is not finite, not in (0, [`PATH_MAX_FREQ_HZ`]], or not above the one before.
    Frequency,
    /// A phase is not finite or not within +-180 degrees.
    Phase,
}

impl core::fmt::Display for PathError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            Self::TooManyPoints => "an analogue-path table has at most 8 points",
            Self::Frequency => "analogue-path frequencies must be finite, in (0, 4000] Hz and strictly increasing",
            Self::Phase => "analogue-path phases must be finite and within +-180 degrees",
        })
    }
}

impl core::error::Error for PathError {}

impl AnaloguePath {
    /// No correction.
    pub const NONE: Self = Self { count: 0, freq_hz: [0.0; PATH_POINTS], phase_deg: [0.0; PATH_POINTS] };

    /// A table from `(freq_hz, phase_deg)` points, validated.
    pub fn from_points(points: &[(f32, f32)]) -> Result<Self, PathError> {
        if points.len() > PATH_POINTS {
            return Err(PathError::TooManyPoints);
        }
        let mut path = Self { count: points.len() as u8, ..Self::NONE };
        for (i, &(freq_hz, phase_deg)) in points.iter().enumerate() {
            path.freq_hz[i] = freq_hz;
            path.phase_deg[i] = phase_deg;
        }
        path.validate()?;
        Ok(path)
    }

    /// The points in use, `(freq_hz, phase_deg)`.
    pub fn points(&self) -> impl Iterator<Item = (f32, f32)> + '_ {
        let n = usize::from(self.count).min(PATH_POINTS);
        self.freq_hz[..n].iter().copied().zip(self.phase_deg[..n].iter().copied())
    }

    /// Checks the table; only valid tables are ever used.
    pub fn validate(&self) -> Result<(), PathError> {
        if usize::from(self.count) > PATH_POINTS {
            return Err(PathError::TooManyPoints);
        }
        let mut previous = 0.0f32;
        for (freq_hz, phase_deg) in self.points() {
            if !(freq_hz.is_finite() && freq_hz > previous && freq_hz <= PATH_MAX_FREQ_HZ) {
                return Err(PathError::Frequency);
            }
            if !(phase_deg.is_finite() && phase_deg.abs() <= 180.0) {
                return Err(PathError::Phase);
            }
            previous = freq_hz;
        }
        Ok(())
    }

    /// `arg H` at `freq_hz`, degrees (0 for an empty table or a frequency that is not a
    /// positive finite number).
    pub fn phase_deg_at(&self, freq_hz: f32) -> f32 {
        if !(freq_hz.is_finite() && freq_hz > 0.0) {
            return 0.0;
        }
        let (mut f0, mut p0) = (0.0f32, 0.0f32);
        for (f1, p1) in self.points() {
            if freq_hz <= f1 {
                return p0 + (p1 - p0) * (freq_hz - f0) / (f1 - f0);
            }
            (f0, p0) = (f1, p1);
        }
        p0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn interpolates_between_points_goes_to_zero_at_dc_and_holds_beyond() {
        let path = AnaloguePath::from_points(&[(10.0, 1.0), (20.0, -1.0), (40.0, -9.0)]).unwrap();
        assert_eq!(path.phase_deg_at(5.0), 0.5);
        assert_eq!(path.phase_deg_at(10.0), 1.0);
        assert_eq!(path.phase_deg_at(15.0), 0.0);
        assert_eq!(path.phase_deg_at(30.0), -5.0);
        assert_eq!(path.phase_deg_at(400.0), -9.0);
        for bad in [0.0, -3.0, f32::NAN, f32::INFINITY] {
            assert_eq!(path.phase_deg_at(bad), 0.0);
        }
        assert_eq!(AnaloguePath::NONE.phase_deg_at(40.0), 0.0);
    }

    #[test]
    fn bad_tables_are_rejected_with_the_reason() {
        assert_eq!(AnaloguePath::from_points(&[(1.0, 0.0); 9]), Err(PathError::TooManyPoints));
        assert_eq!(AnaloguePath::from_points(&[(0.0, 0.0)]), Err(PathError::Frequency));
        assert_eq!(AnaloguePath::from_points(&[(5000.0, 0.0)]), Err(PathError::Frequency));
        assert_eq!(AnaloguePath::from_points(&[(10.0, 0.0), (10.0, 0.0)]), Err(PathError::Frequency));
        assert_eq!(AnaloguePath::from_points(&[(f32::NAN, 0.0)]), Err(PathError::Frequency));
        assert_eq!(AnaloguePath::from_points(&[(10.0, 181.0)]), Err(PathError::Phase));
        assert_eq!(AnaloguePath::from_points(&[(10.0, f32::NAN)]), Err(PathError::Phase));
        let raw = AnaloguePath { count: 200, ..AnaloguePath::NONE };
        assert_eq!(raw.validate(), Err(PathError::TooManyPoints));
        // Points beyond `count` are ignored, whatever they hold.
        let mut tail = AnaloguePath::from_points(&[(10.0, -1.0)]).unwrap();
        tail.freq_hz[5] = f32::NAN;
        assert_eq!(tail.validate(), Ok(()));
    }
}
