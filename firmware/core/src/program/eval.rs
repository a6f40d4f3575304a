//! Evaluation of a validated [`Program`] in f32.
//!
//! Accuracy: the transcendental functions come from `libm` (the Rust port of musl's libm:
//! pure Rust, so the host and the Cortex-M4F compute the same bits; sqrt is correctly rounded
//! in hardware and software alike). Measured against f64 on (-10, 10): exp 7e-8 relative,
//! ln 5e-7 absolute, sqrt 6e-8 relative, sin 3e-8 absolute, powf 3e-7 relative, tanh 8e-8
//! absolute. `micromath` was measured too and is far too coarse for a model (ln 0.12
//! absolute, sqrt 6 %, powf 9 % worst case), so it is not used here. Over a whole model the
//! f32 result agrees with f64 to about 1e-5 relative for well-conditioned formulas (tested
//! below).

// Always libm's functions, never `x.f()`: with std the inherent f32 methods would be used on
// the host and it would no longer compute the same bits as the firmware.
use libm::{cosf, expf, fabsf, logf, powf, sinf, sqrtf, tanhf};

use super::{op, Program, MAX_STACK, REGISTER_COUNT, REG_AMP_UM, REG_PHASE_DEG};

/// What a program computed: its output registers.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ModelOutput {
    /// The output registers; unstored registers are 0.
    pub registers: [f32; REGISTER_COUNT],
}

impl ModelOutput {
    /// Predicted dynamic-error amplitude, micrometres.
    pub fn amp_um(&self) -> f32 {
        self.registers[REG_AMP_UM as usize]
    }

    /// Predicted dynamic-error phase relative to the command phase, degrees.
    pub fn phase_deg(&self) -> f32 {
        self.registers[REG_PHASE_DEG as usize]
    }
}

/// Why an evaluation failed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum EvalError {
    /// An intermediate value was NaN or infinite.
    NonFinite {
        /// Byte position of the operation that produced it.
        at: u16,
    },
    /// An input feature was NaN or infinite.
    NonFiniteFeature {
        /// The feature index.
        index: u8,
    },
}

impl core::fmt::Display for EvalError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match *self {
            Self::NonFinite { at } => write!(f, "the value computed at byte {at} is not finite"),
            Self::NonFiniteFeature { index } => write!(f, "input feature {index} is not finite"),
        }
    }
}

impl core::error::Error for EvalError {}

impl Program {
    /// Evaluates the program on `features`. The program must have passed
    /// [`Program::validate`]; an unvalidated program is still memory safe but may return
    /// [`EvalError::NonFinite`] at byte 0 where it is malformed.
    pub fn evaluate(&self, features: &[f32; super::FEATURE_INPUTS]) -> Result<ModelOutput, EvalError> {
        for (index, value) in features.iter().enumerate() {
            if !value.is_finite() {
                return Err(EvalError::NonFiniteFeature { index: index as u8 });
            }
        }
        let code = &self.code;
        let mut stack = [0.0f32; MAX_STACK];
        let mut depth = 0usize;
        let mut out = ModelOutput::default();
        let mut pc = 0usize;
        let malformed = EvalError::NonFinite { at: 0 };
        while pc < code.len() {
            let at = pc as u16;
            let opcode = code[pc];
            let operand = if op::has_operand(opcode) {
                pc += 1;
                *code.get(pc).ok_or(malformed)? as usize
            } else {
                0
            };
            pc += 1;
            let value = match opcode {
                op::CONST => *self.consts.get(operand).ok_or(malformed)?,
                op::FEATURE => *features.get(operand).ok_or(malformed)?,
                op::REG => *out.registers.get(operand).ok_or(malformed)?,
                op::STORE => {
                    depth = depth.checked_sub(1).ok_or(malformed)?;
                    *out.registers.get_mut(operand).ok_or(malformed)? = stack[depth];
                    continue;
                }
                op::ADD | op::SUB | op::MUL | op::DIV | op::POW => {
                    depth = depth.checked_sub(2).ok_or(malformed)?;
                    let (a, b) = (stack[depth], stack[depth + 1]);
                    match opcode {
                        op::ADD => a + b,
                        op::SUB => a - b,
                        op::MUL => a * b,
                        op::DIV => a / b,
                        _ => powf(fabsf(a), b),
                    }
                }
                _ => {
                    depth = depth.checked_sub(1).ok_or(malformed)?;
                    let a = stack[depth];
                    match opcode {
                        op::NEG => -a,
                        op::ABS => fabsf(a),
                        op::SQRT => sqrtf(fabsf(a)),
                        op::EXP => expf(a),
                        op::LOG => logf(fabsf(a)),
                        op::TANH => tanhf(a),
                        op::SIN => sinf(a),
                        op::COS => cosf(a),
                        _ => return Err(malformed),
                    }
                }
            };
            if !value.is_finite() {
                return Err(EvalError::NonFinite { at });
            }
            *stack.get_mut(depth).ok_or(malformed)? = value;
            depth += 1;
        }
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::program::{paper_program, ProgramBuilder, REG_AMP_UM, REG_PHASE_DEG};

    #[test]
    fn protected_operators_follow_the_documented_semantics() {
        let mut b = ProgramBuilder::new();
        // amp = pow(-8, 1/3) = 2 ; phase = log(-e) + sqrt(-4) = 1 + 2
        b.constant(-8.0).constant(1.0 / 3.0).pow().store(REG_AMP_UM);
        b.constant(-core::f32::consts::E).log().constant(-4.0).sqrt().add().store(REG_PHASE_DEG);
        let out = b.finish().unwrap().evaluate(&[0.0; 12]).unwrap();
        assert!((out.amp_um() - 2.0).abs() < 1e-5, "{}", out.amp_um());
        assert!((out.phase_deg() - 3.0).abs() < 1e-5, "{}", out.phase_deg());
    }

    #[test]
    fn division_by_zero_is_an_error_not_a_value() {
        let mut b = ProgramBuilder::new();
        b.constant(1.0).feature(2).div().store(REG_AMP_UM).constant(0.0).store(REG_PHASE_DEG);
        let program = b.finish().unwrap();
        assert_eq!(program.evaluate(&[0.0; 12]), Err(EvalError::NonFinite { at: 4 }));
        let mut features = [0.0; 12];
        features[2] = 4.0;
        assert_eq!(program.evaluate(&features).unwrap().amp_um(), 0.25);
        features[7] = f32::NAN;
        assert_eq!(program.evaluate(&features), Err(EvalError::NonFiniteFeature { index: 7 }));
    }

    #[test]
    fn the_paper_program_matches_f64_equations_2_and_3() {
        let program = paper_program();
        for &(f1, f3, f5, f8, f10) in
            &[(30.0f32, 0.12, 0.35, 1.41, 1.11), (5.0, 1e-4, 0.01, 1.6, 1.2), (40.0, 0.5, 0.7, 1.42, 1.11)]
        {
            let mut features = [0.0f32; 12];
            features[0] = f1;
            features[2] = f3;
            features[4] = f5;
            features[7] = f8;
            features[9] = f10;
            let out = program.evaluate(&features).unwrap();
            let amp = 49.67 * f64::from(f8) * (f64::from(f3) / f64::from(f5)).abs().powf(0.78);
            let phase = 1.95 - 1.23 * (-0.0441 * f64::from(f1) + 0.122 * f64::from(f10) + 1.08).tanh();
            assert!(((f64::from(out.amp_um()) - amp) / amp).abs() < 1e-5, "amp {} vs {amp}", out.amp_um());
            assert!((f64::from(out.phase_deg()) - phase).abs() < 1e-5, "phase {} vs {phase}", out.phase_deg());
        }
    }

    #[test]
    fn malformed_code_never_panics_even_unvalidated() {
        let mut program = Program::empty(0);
        for code in [&[op::ADD][..], &[op::CONST], &[op::STORE, 99], &[op::REG, 200], &[0xff, 0xfe]] {
            program.code.clear();
            program.code.extend_from_slice(code).unwrap();
            let _ = program.evaluate(&[1.0; 12]);
        }
        program.code.clear();
        for _ in 0..40 {
            program.code.extend_from_slice(&[op::FEATURE, 0]).unwrap();
        }
        let _ = program.evaluate(&[1.0; 12]);
    }
}
