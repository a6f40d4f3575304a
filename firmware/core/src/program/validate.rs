//! Validation of a [`Program`]: everything the evaluator relies on is checked here once, so
//! that evaluation itself cannot index out of bounds or overflow its stack.

use super::{op, Program, TickTerm, FEATURE_INPUTS, MAX_STACK, PROGRAM_VERSION, REGISTER_COUNT, REG_AMP_UM, REG_PHASE_DEG};

/// Why a program was rejected. Byte positions are offsets into [`Program::code`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ProgramError {
    /// The version is not [`PROGRAM_VERSION`].
    BadVersion {
        /// The version found.
        found: u16,
    },
    /// The code is empty.
    Empty,
    /// An opcode this library does not know.
    UnknownOpcode {
        /// Byte position of the opcode.
        at: u16,
        /// The opcode.
        opcode: u8,
    },
    /// An opcode that needs an operand ends the code.
    MissingOperand {
        /// Byte position of the opcode.
        at: u16,
    },
    /// An operation pops more values than the stack holds.
    StackUnderflow {
        /// Byte position of the opcode.
        at: u16,
    },
    /// The stack would exceed [`MAX_STACK`].
    StackOverflow {
        /// Byte position of the opcode.
        at: u16,
    },
    /// Values are left on the stack at the end.
    UnconsumedValues {
        /// How many.
        count: u8,
    },
    /// A `FEATURE` operand is not below [`FEATURE_INPUTS`].
    UnknownFeature {
        /// Byte position of the opcode.
        at: u16,
        /// The feature index.
        index: u8,
    },
    /// A `CONST` operand is past the constant table.
    UnknownConstant {
        /// Byte position of the opcode.
        at: u16,
        /// The constant index.
        index: u8,
    },
    /// A constant is NaN or infinite.
    NonFiniteConstant {
        /// The constant index.
        index: u8,
    },
    /// A register operand is not below [`REGISTER_COUNT`].
    UnknownRegister {
        /// Byte position of the opcode.
        at: u16,
        /// The register.
        register: u8,
    },
    /// A register is read before any instruction stored it.
    RegisterReadBeforeWrite {
        /// Byte position of the opcode.
        at: u16,
        /// The register.
        register: u8,
    },
    /// The program never stores a required output register.
    MissingOutput {
        /// The register.
        register: u8,
    },
    /// The program does not fit the capacity limits (code, constants or terms).
    TooLarge,
    /// A tick term is malformed.
    BadTerm {
        /// Index of the term.
        index: u8,
    },
}

impl core::fmt::Display for ProgramError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match *self {
            Self::BadVersion { found } => write!(f, "program version {found}, expected {PROGRAM_VERSION}"),
            Self::Empty => write!(f, "program has no code"),
            Self::UnknownOpcode { at, opcode } => write!(f, "unknown opcode 0x{opcode:02x} at byte {at}"),
            Self::MissingOperand { at } => write!(f, "opcode at byte {at} lacks its operand"),
            Self::StackUnderflow { at } => write!(f, "stack underflow at byte {at}"),
            Self::StackOverflow { at } => write!(f, "stack deeper than {MAX_STACK} at byte {at}"),
            Self::UnconsumedValues { count } => write!(f, "{count} value(s) left on the stack at the end"),
            Self::UnknownFeature { at, index } => write!(f, "feature index {index} at byte {at} is not below {FEATURE_INPUTS}"),
            Self::UnknownConstant { at, index } => write!(f, "constant index {index} at byte {at} is past the constant table"),
            Self::NonFiniteConstant { index } => write!(f, "constant {index} is not finite"),
            Self::UnknownRegister { at, register } => write!(f, "register {register} at byte {at} is not below {REGISTER_COUNT}"),
            Self::RegisterReadBeforeWrite { at, register } => write!(f, "register {register} read at byte {at} before it is stored"),
            Self::MissingOutput { register } => write!(f, "program never stores output register {register}"),
            Self::TooLarge => write!(f, "program exceeds the code, constant or term capacity"),
            Self::BadTerm { index } => write!(f, "tick term {index} is malformed"),
        }
    }
}

impl Program {
    /// Checks everything the evaluator relies on. A program that passes can be evaluated on
    /// any features without panicking.
    pub fn validate(&self) -> Result<(), ProgramError> {
        if self.version != PROGRAM_VERSION {
            return Err(ProgramError::BadVersion { found: self.version });
        }
        if self.code.is_empty() {
            return Err(ProgramError::Empty);
        }
        for (index, value) in self.consts.iter().enumerate() {
            if !value.is_finite() {
                return Err(ProgramError::NonFiniteConstant { index: index as u8 });
            }
        }
        let written = self.check_code()?;
        for register in [REG_AMP_UM, REG_PHASE_DEG] {
            if written & (1 << register) == 0 {
                return Err(ProgramError::MissingOutput { register });
            }
        }
        for (index, term) in self.terms.iter().enumerate() {
            if !term.is_valid(written) {
                return Err(ProgramError::BadTerm { index: index as u8 });
            }
        }
        Ok(())
    }

    /// Walks the code once, simulating the stack depth; returns the set of stored registers.
    fn check_code(&self) -> Result<u16, ProgramError> {
        let code = &self.code;
        let mut depth: usize = 0;
        let mut written: u16 = 0;
        let mut pc = 0usize;
        while pc < code.len() {
            let at = pc as u16;
            let opcode = code[pc];
            let Some((pops, pushes)) = op::stack_effect(opcode) else {
                return Err(ProgramError::UnknownOpcode { at, opcode });
            };
            let operand = if op::has_operand(opcode) {
                pc += 1;
                match code.get(pc) {
                    Some(&value) => value,
                    None => return Err(ProgramError::MissingOperand { at }),
                }
            } else {
                0
            };
            match opcode {
                op::CONST if operand as usize >= self.consts.len() => {
                    return Err(ProgramError::UnknownConstant { at, index: operand })
                }
                op::FEATURE if operand as usize >= FEATURE_INPUTS => {
                    return Err(ProgramError::UnknownFeature { at, index: operand })
                }
                op::REG | op::STORE if operand as usize >= REGISTER_COUNT => {
                    return Err(ProgramError::UnknownRegister { at, register: operand })
                }
                op::REG if written & (1 << operand) == 0 => {
                    return Err(ProgramError::RegisterReadBeforeWrite { at, register: operand })
                }
                _ => {}
            }
            if depth < pops as usize {
                return Err(ProgramError::StackUnderflow { at });
            }
            depth = depth - pops as usize + pushes as usize;
            if depth > MAX_STACK {
                return Err(ProgramError::StackOverflow { at });
            }
            if opcode == op::STORE {
                written |= 1 << operand;
            }
            pc += 1;
        }
        if depth != 0 {
            return Err(ProgramError::UnconsumedValues { count: depth as u8 });
        }
        Ok(written)
    }
}

/// Whether a term's register references are valid given the set of stored registers.
pub(super) fn register_ok(register: u8, written: u16) -> bool {
    (register as usize) < REGISTER_COUNT && written & (1 << register) != 0
}

impl TickTerm {
    fn is_valid(&self, written: u16) -> bool {
        self.check(written)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::program::ProgramBuilder;

    fn minimal() -> ProgramBuilder {
        let mut b = ProgramBuilder::new();
        b.constant(1.0).store(REG_AMP_UM).constant(0.0).store(REG_PHASE_DEG);
        b
    }

    fn raw(code: &[u8], consts: &[f32]) -> Program {
        let mut p = Program::empty(0);
        p.code.extend_from_slice(code).unwrap();
        p.consts.extend_from_slice(consts).unwrap();
        p
    }

    #[test]
    fn a_minimal_program_is_valid() {
        assert_eq!(minimal().finish().map(|_| ()), Ok(()));
    }

    #[test]
    fn each_malformation_gets_its_own_error() {
        let store_both = [op::CONST, 0, op::STORE, 0, op::CONST, 0, op::STORE, 1];
        let mut p = raw(&store_both, &[1.0]);
        p.version = 9;
        assert_eq!(p.validate(), Err(ProgramError::BadVersion { found: 9 }));
        assert_eq!(raw(&[], &[]).validate(), Err(ProgramError::Empty));
        assert_eq!(raw(&[0x7f], &[]).validate(), Err(ProgramError::UnknownOpcode { at: 0, opcode: 0x7f }));
        assert_eq!(raw(&[op::CONST], &[1.0]).validate(), Err(ProgramError::MissingOperand { at: 0 }));
        assert_eq!(raw(&[op::ADD], &[]).validate(), Err(ProgramError::StackUnderflow { at: 0 }));
        let deep: [u8; 34] = core::array::from_fn(|i| if i % 2 == 0 { op::CONST } else { 0 });
        assert_eq!(raw(&deep, &[1.0]).validate(), Err(ProgramError::StackOverflow { at: 32 }));
        assert_eq!(raw(&[op::CONST, 0], &[1.0]).validate(), Err(ProgramError::UnconsumedValues { count: 1 }));
        assert_eq!(raw(&[op::FEATURE, 12], &[]).validate(), Err(ProgramError::UnknownFeature { at: 0, index: 12 }));
        assert_eq!(raw(&[op::CONST, 1], &[1.0]).validate(), Err(ProgramError::UnknownConstant { at: 0, index: 1 }));
        assert_eq!(raw(&store_both, &[f32::NAN]).validate(), Err(ProgramError::NonFiniteConstant { index: 0 }));
        assert_eq!(raw(&[op::CONST, 0, op::STORE, 8], &[1.0]).validate(), Err(ProgramError::UnknownRegister { at: 2, register: 8 }));
        assert_eq!(raw(&[op::REG, 3, op::STORE, 0], &[]).validate(), Err(ProgramError::RegisterReadBeforeWrite { at: 0, register: 3 }));
        assert_eq!(raw(&[op::CONST, 0, op::STORE, 0], &[1.0]).validate(), Err(ProgramError::MissingOutput { register: 1 }));
    }

    #[test]
    fn a_term_must_reference_stored_registers() {
        let mut b = minimal();
        b.term(TickTerm::Harmonic { order: 3, amp_reg: 5, phase_reg: REG_PHASE_DEG });
        assert_eq!(b.finish().map(|_| ()), Err(ProgramError::BadTerm { index: 0 }));
    }
}
