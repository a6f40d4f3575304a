//! The analogue path's response: DAC -> motion controller -> servo loop -> TCP.
//!
//! The feedforward asks for a displacement `u`, but the machine moves the tool by `H(f) u`,
//! where `H` is the response of the path from the co-processor's DAC to the tool centre
//! point relative to its static gain `K_dv`. `sts-twin calibrate` measures `|H|` and
//! `arg H` (a sine through the analogue input at each frequency, the capacitance probe at the
//! TCP) and the co-processor holds them as a table of at most [`PATH_POINTS`] points,
//! linearly interpolated. Two corrections use it:
//!
//! - The formulas predict the error's phase relative to the *command*, so a lag of the path
//!   shifts their correction by the same lag: every model update's phase is reduced by
//!   `arg H(f)` at the command frequency ([`AnaloguePath::phase_deg_at`]). Their amplitude
//!   needs no correction: the accelerometer sees the compensated motion, and at the fixed
//!   point the formulas' amplitude is the one required. Below the first point the phase goes
//!   linearly to zero at 0 Hz (a causal path has no phase at DC), above the last it holds.
//! - The axis twin learns its correction through its *own* simulated path `G(f)`, from the
//!   command alone, so any difference between `G` and the machine's `H` lands in the cut
//!   whole (1 deg of phase at 40 Hz leaves 1.7% of the error). Its correction is therefore
//!   multiplied by `G(f) / H(f)` ([`AnaloguePath::response_at`]), gain and phase, at each
//!   harmonic the table covers; beyond the last point nothing is known and nothing changes.
//!   `G` is then simulated as `H` was measured, with the slide at rest and a sine of the
//!   table's amplitude [`AnaloguePath::amp_um`], effects included: friction bends a sine's
//!   response at rest (at 40 Hz, 3 N / 4.5 N Coulomb / static: -8.7 deg with 8 um against
//!   -5.9 deg without friction), and the twin's friction must bend it alike, or the ratio
//!   would carry that bend into a cut where the slide moves.
//!
//! An empty table is no correction (the paper's Eq. 5 as written). A point's gain of 0 means
//! "not measured": that correction then takes the phase only.
//!
//! ```
//! use sts_twin_core::analogue_path::AnaloguePath;
//! let path = AnaloguePath::from_points(&[(20.0, -1.0), (40.0, -6.0)]).unwrap();
//! assert_eq!(path.phase_deg_at(30.0), -3.5);
//! assert_eq!(path.phase_deg_at(10.0), -0.5);
//! assert_eq!(path.phase_deg_at(80.0), -6.0);
//! assert!(AnaloguePath::from_points(&[(40.0, 0.0), (20.0, 0.0)]).is_err());
//! let measured = AnaloguePath::from_responses(8.0, &[(20.0, 1.2, -1.0), (40.0, 2.0, -6.0)]).unwrap();
//! assert_eq!(measured.response_at(30.0), Some((Some(1.6), -3.5)));
//! assert_eq!(measured.response_at(10.0), Some((Some(1.1), -0.5)));
//! assert_eq!(measured.response_at(41.0), None);
//! ```

use serde::{Deserialize, Serialize};

/// Most points in an [`AnaloguePath`] table (calibration measures 5 to 100 Hz in ten).
pub const PATH_POINTS: usize = 10;

/// Largest sine amplitude a table may say it was measured with, um.
pub const PATH_MAX_AMP_UM: f32 = 1000.0;

/// Largest gain a table may hold (`|H|` relative to `K_dv`): a path amplifying a hundred
/// times is a broken measurement, not a machine.
pub const PATH_MAX_GAIN: f32 = 100.0;

/// Highest frequency a table may name, Hz (half the 8 kHz servo rate).
pub const PATH_MAX_FREQ_HZ: f32 = 4000.0;

/// The analogue path's response `H(f)` at up to [`PATH_POINTS`] frequencies. See the
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
    /// `|H|` at each frequency, relative to `K_dv`, in [0, [`PATH_MAX_GAIN`]]; 0 is not
    /// measured.
    pub gain: [f32; PATH_POINTS],
    /// Amplitude of the sine `H` was measured with, um, in [0, [`PATH_MAX_AMP_UM`]]; 0 is not
    /// stated (the axis twin's response is then simulated with its own amplitude).
    pub amp_um: f32,
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
    /// A gain is not finite or not in [0, [`PATH_MAX_GAIN`]].
    Gain,
    /// The amplitude is not finite or not in [0, [`PATH_MAX_AMP_UM`]].
    Amplitude,
}

impl core::fmt::Display for PathError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            Self::TooManyPoints => "an analogue-path table has at most 10 points",
            Self::Frequency => "analogue-path frequencies must be finite, in (0, 4000] Hz and strictly increasing",
            Self::Phase => "analogue-path phases must be finite and within +-180 degrees",
            Self::Gain => "analogue-path gains must be finite and within [0, 100] (0: not measured)",
            Self::Amplitude => "the analogue path's sine amplitude must be finite and within [0, 1000] um",
        })
    }
}

impl core::error::Error for PathError {}

impl AnaloguePath {
    /// No correction.
    pub const NONE: Self = Self {
        count: 0,
        freq_hz: [0.0; PATH_POINTS],
        phase_deg: [0.0; PATH_POINTS],
        gain: [0.0; PATH_POINTS],
        amp_um: 0.0,
    };

    /// A table of phases only from `(freq_hz, phase_deg)` points (gains not measured),
    /// validated.
    pub fn from_points(points: &[(f32, f32)]) -> Result<Self, PathError> {
        Self::from_triples(0.0, points.len(), points.iter().map(|&(freq_hz, phase_deg)| (freq_hz, 0.0, phase_deg)))
    }

    /// A table from `(freq_hz, gain, phase_deg)` points measured with a sine of `amp_um`,
    /// validated.
    pub fn from_responses(amp_um: f32, points: &[(f32, f32, f32)]) -> Result<Self, PathError> {
        Self::from_triples(amp_um, points.len(), points.iter().copied())
    }

    /// A table of `len` `(freq_hz, gain, phase_deg)` points, validated.
    fn from_triples(amp_um: f32, len: usize, points: impl Iterator<Item = (f32, f32, f32)>) -> Result<Self, PathError> {
        if len > PATH_POINTS {
            return Err(PathError::TooManyPoints);
        }
        let mut path = Self { count: len as u8, amp_um, ..Self::NONE };
        for (i, (freq_hz, gain, phase_deg)) in points.enumerate() {
            path.freq_hz[i] = freq_hz;
            path.gain[i] = gain;
            path.phase_deg[i] = phase_deg;
        }
        path.validate()?;
        Ok(path)
    }

    /// The points in use, `(freq_hz, gain, phase_deg)` (a gain of 0: not measured).
    pub fn points(&self) -> impl Iterator<Item = (f32, f32, f32)> + '_ {
        let n = usize::from(self.count).min(PATH_POINTS);
        (0..n).map(|i| (self.freq_hz[i], self.gain[i], self.phase_deg[i]))
    }

    /// Checks the table; only valid tables are ever used.
    pub fn validate(&self) -> Result<(), PathError> {
        if usize::from(self.count) > PATH_POINTS {
            return Err(PathError::TooManyPoints);
        }
        let mut previous = 0.0f32;
        for (freq_hz, _, phase_deg) in self.points() {
            if !(freq_hz.is_finite() && freq_hz > previous && freq_hz <= PATH_MAX_FREQ_HZ) {
                return Err(PathError::Frequency);
            }
            if !(phase_deg.is_finite() && phase_deg.abs() <= 180.0) {
                return Err(PathError::Phase);
            }
            previous = freq_hz;
        }
        let n = usize::from(self.count);
        if !self.gain[..n].iter().all(|g| g.is_finite() && (0.0..=PATH_MAX_GAIN).contains(g)) {
            return Err(PathError::Gain);
        }
        if !(self.amp_um.is_finite() && (0.0..=PATH_MAX_AMP_UM).contains(&self.amp_um)) {
            return Err(PathError::Amplitude);
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
        for (f1, _, p1) in self.points() {
            if freq_hz <= f1 {
                return p0 + (p1 - p0) * (freq_hz - f0) / (f1 - f0);
            }
            (f0, p0) = (f1, p1);
        }
        p0
    }

    /// `(|H|, arg H)` at `freq_hz` (gain relative to `K_dv`, phase in degrees), linearly
    /// interpolated, from `(1, 0)` at 0 Hz below the first point; `None` beyond the last point
    /// or for an empty table or a frequency that is not a positive finite number. The gain is
    /// `None` where a point it comes from was not measured.
    pub fn response_at(&self, freq_hz: f32) -> Option<(Option<f32>, f32)> {
        if !(freq_hz.is_finite() && freq_hz > 0.0) {
            return None;
        }
        let (mut f0, mut g0, mut p0) = (0.0f32, 1.0f32, 0.0f32);
        for (f1, g1, p1) in self.points() {
            if freq_hz <= f1 {
                let x = (freq_hz - f0) / (f1 - f0);
                let gain = (g0 > 0.0 && g1 > 0.0).then_some(g0 + (g1 - g0) * x);
                return Some((gain, p0 + (p1 - p0) * x));
            }
            (f0, g0, p0) = (f1, g1, p1);
        }
        None
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
    fn the_response_is_known_up_to_the_last_point_and_its_gain_only_where_measured() {
        let path =
            AnaloguePath::from_responses(8.0, &[(10.0, 1.5, 1.0), (20.0, 2.0, -1.0), (40.0, 3.0, -9.0)]).unwrap();
        assert_eq!(path.response_at(5.0), Some((Some(1.25), 0.5)));
        assert_eq!(path.response_at(30.0), Some((Some(2.5), -5.0)));
        assert_eq!(path.response_at(40.0), Some((Some(3.0), -9.0)));
        for beyond in [40.5, 400.0, 0.0, -3.0, f32::NAN] {
            assert_eq!(path.response_at(beyond), None, "{beyond}");
        }
        let mut partly = path;
        partly.gain[1] = 0.0;
        assert_eq!(partly.response_at(15.0), Some((None, 0.0)));
        assert_eq!(partly.response_at(5.0), Some((Some(1.25), 0.5)));
        assert_eq!(AnaloguePath::from_points(&[(40.0, -6.0)]).unwrap().response_at(20.0), Some((None, -3.0)));
        assert_eq!(AnaloguePath::NONE.response_at(20.0), None);
    }

    #[test]
    fn bad_tables_are_rejected_with_the_reason() {
        assert_eq!(AnaloguePath::from_points(&[(1.0, 0.0); 11]), Err(PathError::TooManyPoints));
        assert_eq!(AnaloguePath::from_responses(8.0, &[(10.0, -0.1, 0.0)]), Err(PathError::Gain));
        assert_eq!(AnaloguePath::from_responses(8.0, &[(10.0, f32::NAN, 0.0)]), Err(PathError::Gain));
        assert_eq!(AnaloguePath::from_responses(8.0, &[(10.0, 101.0, 0.0)]), Err(PathError::Gain));
        assert_eq!(AnaloguePath::from_responses(-1.0, &[(10.0, 1.0, 0.0)]), Err(PathError::Amplitude));
        assert_eq!(AnaloguePath::from_responses(f32::NAN, &[(10.0, 1.0, 0.0)]), Err(PathError::Amplitude));
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
