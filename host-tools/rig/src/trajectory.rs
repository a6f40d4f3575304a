//! Commanded motions: the measurement test's sinusoids and the STS bicuspid cut (Eq. 6).

use std::f64::consts::PI;

use sts_model::replay::turns_u32;

/// The command at one instant.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct TrajectoryPoint {
    /// Z command, um.
    pub z_cmd_um: f64,
    /// X slide position, mm.
    pub x_mm: f64,
    /// Spindle angle, degrees.
    pub spindle_deg: f64,
    /// Phase of the Z motion's fundamental, u32 turns (2^32 = one turn).
    pub phase_turns: u32,
}

/// A commanded motion sampled at the servo rate.
pub trait Trajectory {
    /// The command at machine time `t_s` from the trajectory's start.
    fn at(&self, t_s: f64) -> TrajectoryPoint;
    /// The servo rate, Hz.
    fn sample_rate_hz(&self) -> f64;
    /// Duration, s.
    fn duration_s(&self) -> f64;
}

/// `z = amp sin(2 pi f t)` for a duration, X and spindle at rest.
#[derive(Clone, Copy, Debug)]
pub struct Sinusoid {
    /// Frequency, Hz.
    pub freq_hz: f64,
    /// Amplitude, um.
    pub amp_um: f64,
    /// Duration, s.
    pub duration_s: f64,
    /// Servo rate, Hz.
    pub sample_rate_hz: f64,
}

impl Trajectory for Sinusoid {
    fn at(&self, t_s: f64) -> TrajectoryPoint {
        let turns = self.freq_hz * t_s;
        TrajectoryPoint {
            z_cmd_um: self.amp_um * (2.0 * PI * turns).sin(),
            x_mm: 0.0,
            spindle_deg: 0.0,
            phase_turns: turns_u32(turns),
        }
    }
    fn sample_rate_hz(&self) -> f64 {
        self.sample_rate_hz
    }
    fn duration_s(&self) -> f64 {
        self.duration_s
    }
}

/// The paper's STS cut of the bicuspid surface `z = 0.006 x sin(2C) - 0.006 x` (Eq. 6, x and
/// z in mm), facing from `x = r_start_mm` to the centre with a constant feed per revolution.
/// The spindle turns at `freq_hz / 2` rev/s so that the Z motion's frequency is `freq_hz`.
#[derive(Clone, Copy, Debug)]
pub struct Bicuspid {
    /// Z operational frequency, Hz.
    pub freq_hz: f64,
    /// Starting radius, mm.
    pub r_start_mm: f64,
    /// X feed per spindle revolution, um.
    pub feed_um_per_rev: f64,
    /// Servo rate, Hz.
    pub sample_rate_hz: f64,
}

impl Bicuspid {
    /// Spindle speed, rev/s.
    pub fn spindle_rev_per_s(&self) -> f64 {
        self.freq_hz / 2.0
    }

    /// Speed of the X slide towards the centre, mm/s.
    pub fn feed_mm_per_s(&self) -> f64 {
        self.spindle_rev_per_s() * self.feed_um_per_rev * 1e-3
    }

    /// The design surface height at radius `x_mm` and spindle angle `c_deg`, um.
    pub fn design_z_um(x_mm: f64, c_deg: f64) -> f64 {
        1e3 * (0.006 * x_mm * (2.0 * c_deg.to_radians()).sin() - 0.006 * x_mm)
    }
}

impl Trajectory for Bicuspid {
    fn at(&self, t_s: f64) -> TrajectoryPoint {
        let revs = self.spindle_rev_per_s() * t_s;
        let x_mm = (self.r_start_mm - revs * self.feed_um_per_rev * 1e-3).max(0.0);
        let c_deg = 360.0 * revs.fract();
        TrajectoryPoint {
            z_cmd_um: Self::design_z_um(x_mm, c_deg),
            x_mm,
            spindle_deg: c_deg,
            phase_turns: turns_u32(2.0 * revs),
        }
    }
    fn sample_rate_hz(&self) -> f64 {
        self.sample_rate_hz
    }
    fn duration_s(&self) -> f64 {
        self.r_start_mm * 1e3 / self.feed_um_per_rev / self.spindle_rev_per_s()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_bicuspid_has_the_papers_amplitude_and_frequency() {
        let cut = Bicuspid { freq_hz: 40.0, r_start_mm: 0.5, feed_um_per_rev: 5.0, sample_rate_hz: 8000.0 };
        // At r = 0.5 mm the surface spans 0 .. -6 um: amplitude 3 um about -3 um.
        let z: Vec<f64> = (0..200).map(|k| cut.at(k as f64 / 8000.0).z_cmd_um).collect();
        let max = z.iter().cloned().fold(f64::MIN, f64::max);
        let min = z.iter().cloned().fold(f64::MAX, f64::min);
        assert!((max - 0.0).abs() < 0.05 && (min + 6.0).abs() < 0.05, "{min} {max}");
        // 40 Hz: the phase makes one turn in 25 ms.
        assert_eq!(cut.at(0.0).phase_turns, 0);
        assert!(cut.at(0.025).phase_turns < 1 << 20 || cut.at(0.025).phase_turns > u32::MAX - (1 << 20));
        assert!((cut.duration_s() - 5.0).abs() < 1e-9);
    }
}
