//! Plant parameters: the TOML plant file, its documented default, and validation.
//!
//! The default is shipped as `default-plant.toml` (embedded as [`DEFAULT_PLANT_TOML`]) and is
//! also [`PlantParams::default`]; a test keeps the two equal. A plant file may leave keys out
//! (they keep their defaults); unknown keys and bad values are errors naming the key.

use serde::Deserialize;

/// The default plant file's text (`host-tools/emulator/default-plant.toml`).
pub const DEFAULT_PLANT_TOML: &str = include_str!("../default-plant.toml");

/// Why a plant file was rejected.
#[derive(Debug, thiserror::Error)]
pub enum ParamsError {
    /// Not valid TOML, an unknown key or a value of the wrong type.
    #[error("plant file: {0}")]
    Toml(String),
    /// A value out of its range.
    #[error("plant file: `{key}` = {value}: {reason}")]
    OutOfRange {
        /// The key, as `section.name`.
        key: String,
        /// The value found.
        value: f64,
        /// The allowed range.
        reason: String,
    },
    /// The plant file could not be read.
    #[error("cannot read the plant file {path}")]
    Io {
        /// The file.
        path: String,
        /// The reason.
        source: std::io::Error,
    },
}

/// The Z slide and its drive.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SlideParams {
    /// Moving mass, kg.
    pub mass_kg: f64,
    /// Viscous drag (hydrostatic bearings, back-EMF), N s/m.
    pub viscous_n_s_per_m: f64,
    /// Motor force limit, N.
    pub force_limit_n: f64,
    /// Current-loop time constant, us.
    pub current_loop_tau_us: f64,
}

/// The A3200-like digital servo loop.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ServoParams {
    /// Proportional gain, N/um.
    pub kp_n_per_um: f64,
    /// Integral gain, N/(um s).
    pub ki_n_per_um_s: f64,
    /// Derivative gain, N s/um.
    pub kd_n_s_per_um: f64,
    /// Velocity feedforward, N s/m.
    pub vff_n_s_per_m: f64,
    /// Acceleration feedforward, kg.
    pub aff_kg: f64,
    /// Computation delay, us (0..=250).
    pub compute_delay_us: f64,
    /// Trajectory delay before the servo loop, ticks.
    pub command_delay_ticks: u32,
    /// Integration sub-steps per tick.
    pub substeps: u32,
}

/// The compliant path from the encoder to the TCP.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct StructureParams {
    /// Natural frequency of the mode, Hz.
    pub mode_freq_hz: f64,
    /// Damping ratio of the mode.
    pub mode_damping: f64,
    /// Modal displacement at the TCP per unit slide motion.
    pub mode_tcp_gain: f64,
    /// Modal displacement at the accelerometer relative to the TCP.
    pub acc_mode_shape: f64,
}

/// The accelerometer and its ADC.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct AccelerometerParams {
    /// Sensitivity, mV/g.
    pub sensitivity_mv_per_g: f64,
    /// High-pass corner, Hz.
    pub highpass_hz: f64,
    /// Anti-alias low-pass corner, Hz.
    pub lowpass_hz: f64,
    /// Noise density, ug/sqrt(Hz).
    pub noise_ug_per_rthz: f64,
    /// ADC input range, +-V.
    pub adc_range_v: f64,
}

/// The capacitance probe at the TCP.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ProbeParams {
    /// Noise, nm rms.
    pub noise_rms_nm: f64,
}

/// The linear encoder.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct EncoderParams {
    /// Resolution, nm.
    pub resolution_nm: f64,
}

/// The motion controller's analogue input.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct InterfaceParams {
    /// K_vc: motion pulses per volt.
    pub kvc_pulses_per_v: f64,
    /// Size of one motion pulse, nm.
    pub pulse_nm: f64,
    /// Input offset voltage added by the interface, V.
    pub offset_v: f64,
    /// ADC resolution of the analogue input, bits.
    pub adc_bits: u32,
    /// ADC input range, +-V.
    pub adc_range_v: f64,
}

/// The machine temperature sensor.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ThermalParams {
    /// Ambient temperature, C.
    pub ambient_c: f64,
    /// Peak slow wander of the ambient, mK.
    pub wander_mk: f64,
    /// Sensor noise, mK rms.
    pub sensor_noise_mk: f64,
}

/// Every parameter of the emulated machine (one TOML section per field).
#[derive(Debug, Clone, PartialEq, Default, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PlantParams {
    /// `[slide]`
    pub slide: SlideParams,
    /// `[servo]`
    pub servo: ServoParams,
    /// `[structure]`
    pub structure: StructureParams,
    /// `[accelerometer]`
    pub accelerometer: AccelerometerParams,
    /// `[probe]`
    pub probe: ProbeParams,
    /// `[encoder]`
    pub encoder: EncoderParams,
    /// `[interface]`
    pub interface: InterfaceParams,
    /// `[thermal]`
    pub thermal: ThermalParams,
}

impl Default for SlideParams {
    fn default() -> Self {
        Self { mass_kg: 45.0, viscous_n_s_per_m: 300.0, force_limit_n: 2000.0, current_loop_tau_us: 80.0 }
    }
}

impl Default for ServoParams {
    fn default() -> Self {
        Self {
            kp_n_per_um: 10.551,
            ki_n_per_um_s: 900.18,
            kd_n_s_per_um: 0.017826,
            vff_n_s_per_m: 450.0,
            aff_kg: 13.5,
            compute_delay_us: 125.0,
            command_delay_ticks: 2,
            substeps: 4,
        }
    }
}

impl Default for StructureParams {
    fn default() -> Self {
        Self { mode_freq_hz: 89.554, mode_damping: 0.28, mode_tcp_gain: 2.3662, acc_mode_shape: 0.8 }
    }
}

impl Default for AccelerometerParams {
    fn default() -> Self {
        Self {
            sensitivity_mv_per_g: 1000.0,
            highpass_hz: 0.5,
            lowpass_hz: 1000.0,
            noise_ug_per_rthz: 5.0,
            adc_range_v: 5.0,
        }
    }
}

impl Default for ProbeParams {
    fn default() -> Self {
        Self { noise_rms_nm: 5.0 }
    }
}

impl Default for EncoderParams {
    fn default() -> Self {
        Self { resolution_nm: 1.0 }
    }
}

impl Default for InterfaceParams {
    fn default() -> Self {
        Self { kvc_pulses_per_v: 2000.0, pulse_nm: 1.0, offset_v: 0.012, adc_bits: 16, adc_range_v: 10.0 }
    }
}

impl Default for ThermalParams {
    fn default() -> Self {
        Self { ambient_c: 20.0, wander_mk: 5.0, sensor_noise_mk: 1.0 }
    }
}

impl PlantParams {
    /// Parses and validates a plant file's text. Keys left out keep their defaults.
    pub fn from_toml_str(text: &str) -> Result<Self, ParamsError> {
        let params: PlantParams = toml::from_str(text).map_err(|e| ParamsError::Toml(e.to_string()))?;
        params.validate()?;
        Ok(params)
    }

    /// Reads, parses and validates a plant file.
    pub fn from_file(path: &std::path::Path) -> Result<Self, ParamsError> {
        let text = std::fs::read_to_string(path)
            .map_err(|source| ParamsError::Io { path: path.display().to_string(), source })?;
        Self::from_toml_str(&text).map_err(|e| match e {
            ParamsError::Toml(m) => ParamsError::Toml(format!("{}: {m}", path.display())),
            other => other,
        })
    }

    /// The accelerometer ADC scale, m/s^2 per LSB (16-bit, full scale = `adc_range_v`).
    pub fn acc_mps2_per_lsb(&self) -> f64 {
        let a = &self.accelerometer;
        a.adc_range_v / (a.sensitivity_mv_per_g * 1e-3) * crate::G_MPS2 / 32768.0
    }

    /// The accelerometer's full-scale range, +-m/s^2.
    pub fn acc_range_mps2(&self) -> f64 {
        self.acc_mps2_per_lsb() * 32768.0
    }

    /// Checks every value's range; the error names the key.
    pub fn validate(&self) -> Result<(), ParamsError> {
        let s = &self.slide;
        positive("slide.mass_kg", s.mass_kg)?;
        non_negative("slide.viscous_n_s_per_m", s.viscous_n_s_per_m)?;
        positive("slide.force_limit_n", s.force_limit_n)?;
        within("slide.current_loop_tau_us", s.current_loop_tau_us, 1.0, 10_000.0)?;
        let v = &self.servo;
        non_negative("servo.kp_n_per_um", v.kp_n_per_um)?;
        non_negative("servo.ki_n_per_um_s", v.ki_n_per_um_s)?;
        non_negative("servo.kd_n_s_per_um", v.kd_n_s_per_um)?;
        finite("servo.vff_n_s_per_m", v.vff_n_s_per_m)?;
        finite("servo.aff_kg", v.aff_kg)?;
        within("servo.compute_delay_us", v.compute_delay_us, 0.0, 250.0)?;
        within("servo.command_delay_ticks", v.command_delay_ticks as f64, 0.0, 64.0)?;
        within("servo.substeps", v.substeps as f64, 1.0, 64.0)?;
        let t = &self.structure;
        within("structure.mode_freq_hz", t.mode_freq_hz, 1.0, 2000.0)?;
        within_open_top("structure.mode_damping", t.mode_damping, 0.0, 1.0)?;
        non_negative("structure.mode_tcp_gain", t.mode_tcp_gain)?;
        within("structure.acc_mode_shape", t.acc_mode_shape, -2.0, 2.0)?;
        let a = &self.accelerometer;
        positive("accelerometer.sensitivity_mv_per_g", a.sensitivity_mv_per_g)?;
        within("accelerometer.highpass_hz", a.highpass_hz, 0.0, 100.0)?;
        within("accelerometer.lowpass_hz", a.lowpass_hz, 10.0, 3900.0)?;
        non_negative("accelerometer.noise_ug_per_rthz", a.noise_ug_per_rthz)?;
        positive("accelerometer.adc_range_v", a.adc_range_v)?;
        non_negative("probe.noise_rms_nm", self.probe.noise_rms_nm)?;
        positive("encoder.resolution_nm", self.encoder.resolution_nm)?;
        let i = &self.interface;
        positive("interface.kvc_pulses_per_v", i.kvc_pulses_per_v)?;
        positive("interface.pulse_nm", i.pulse_nm)?;
        within("interface.offset_v", i.offset_v, -1.0, 1.0)?;
        within("interface.adc_bits", i.adc_bits as f64, 8.0, 24.0)?;
        positive("interface.adc_range_v", i.adc_range_v)?;
        let h = &self.thermal;
        within("thermal.ambient_c", h.ambient_c, -50.0, 100.0)?;
        non_negative("thermal.wander_mk", h.wander_mk)?;
        non_negative("thermal.sensor_noise_mk", h.sensor_noise_mk)?;
        Ok(())
    }
}

fn finite(key: &str, value: f64) -> Result<(), ParamsError> {
    if value.is_finite() {
        Ok(())
    } else {
        Err(ParamsError::OutOfRange { key: key.into(), value, reason: "must be a finite number".into() })
    }
}

fn positive(key: &str, value: f64) -> Result<(), ParamsError> {
    if value.is_finite() && value > 0.0 {
        Ok(())
    } else {
        Err(ParamsError::OutOfRange { key: key.into(), value, reason: "must be positive".into() })
    }
}

fn non_negative(key: &str, value: f64) -> Result<(), ParamsError> {
    if value.is_finite() && value >= 0.0 {
        Ok(())
    } else {
        Err(ParamsError::OutOfRange { key: key.into(), value, reason: "must be zero or positive".into() })
    }
}

fn within(key: &str, value: f64, lo: f64, hi: f64) -> Result<(), ParamsError> {
    if value.is_finite() && value >= lo && value <= hi {
        Ok(())
    } else {
        Err(ParamsError::OutOfRange { key: key.into(), value, reason: format!("must be in [{lo}, {hi}]") })
    }
}

fn within_open_top(key: &str, value: f64, lo: f64, hi: f64) -> Result<(), ParamsError> {
    if value.is_finite() && value >= lo && value < hi {
        Ok(())
    } else {
        Err(ParamsError::OutOfRange { key: key.into(), value, reason: format!("must be in [{lo}, {hi})") })
    }
}
