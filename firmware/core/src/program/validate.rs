//! Validation of a [`Program`]: everything the evaluator relies on is checked here once, so
//! that evaluation itself cannot index out of bounds or overflow its stack.

use super::term::{tick_cost, TICK_BUDGET_INSTRUCTIONS};
use super::{
    op, Program, TickTerm, FEATURE_INPUTS, MAX_STACK, PROGRAM_VERSION, REGISTER_COUNT, REG_AMP_UM, REG_PHASE_DEG,
};

/// Why a program was rejected. Byte positions are offsets into [`Program::code`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
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
    /// The per-tick terms would make the servo tick longer than its budget
    /// ([`Program::tick_cost`] against [`TICK_BUDGET_INSTRUCTIONS`]).
    TickBudget {
        /// The tick's instructions with these terms, at worst.
        cost: u16,
        /// The budget.
        budget: u16,
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
            Self::UnknownFeature { at, index } => {
                write!(f, "feature index {index} at byte {at} is not below {FEATURE_INPUTS}")
            }
            Self::UnknownConstant { at, index } => {
                write!(f, "constant index {index} at byte {at} is past the constant table")
            }
            Self::NonFiniteConstant { index } => write!(f, "constant {index} is not finite"),
            Self::UnknownRegister { at, register } => {
                write!(f, "register {register} at byte {at} is not below {REGISTER_COUNT}")
            }
            Self::RegisterReadBeforeWrite { at, register } => {
                write!(f, "register {register} read at byte {at} before it is stored")
            }
            Self::MissingOutput { register } => write!(f, "program never stores output register {register}"),
            Self::TooLarge => write!(f, "program exceeds the code, constant or term capacity"),
            Self::BadTerm { index } => write!(f, "tick term {index} is malformed"),
            Self::TickBudget { cost, budget } => {
                write!(f, "the per-tick terms would take the servo tick to about {cost} instructions, over its budget of {budget}")
            }
        }
    }
}

impl core::error::Error for ProgramError {}

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
        let has_axis = self.terms.iter().any(|t| matches!(t, TickTerm::Axis(_)));
        let mut axis_orders = 0u32;
        for (index, term) in self.terms.iter().enumerate() {
            // An axis twin's harmonic needs the twin, and a slot to itself.
            let axis_harmonic_ok = match *term {
                TickTerm::AxisHarmonic { order } => {
                    let bit = 1u32 << (order & 31);
                    let fresh = axis_orders & bit == 0;
                    axis_orders |= bit;
                    has_axis && fresh && axis_orders.count_ones() as usize <= crate::axis::compensate::MAX_HIGHER_ORDERS
                }
                _ => true,
            };
            if !(axis_harmonic_ok && term.is_valid(written)) {
                return Err(ProgramError::BadTerm { index: index as u8 });
            }
        }
        let cost = self.tick_cost();
        if cost > TICK_BUDGET_INSTRUCTIONS {
            return Err(ProgramError::TickBudget {
                cost: cost.min(u32::from(u16::MAX)) as u16,
                budget: TICK_BUDGET_INSTRUCTIONS as u16,
            });
        }
        Ok(())
    }

    /// The servo tick's instructions at worst with this program's per-tick terms
    /// ([`tick_cost`]): [`tick_cost::FIXED`], [`tick_cost::KERNELS`] if it has kernel
    /// terms, and each term's [`TickTerm::tick_cost`].
    pub fn tick_cost(&self) -> u32 {
        terms_tick_cost(&self.terms)
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

impl TickTerm {
    fn is_valid(&self, written: u16) -> bool {
        self.check(written)
    }
}

/// The servo tick's instructions at worst with per-tick terms `terms` ([`Program::tick_cost`]
/// of a program holding them): for a caller that weighs terms before it builds the program.
pub fn terms_tick_cost(terms: &[TickTerm]) -> u32 {
    let with_kernels = terms.iter().any(TickTerm::is_kernel);
    let kernels = if with_kernels { tick_cost::KERNELS } else { 0 };
    tick_cost::FIXED + kernels + terms.iter().map(|term| term.tick_cost(with_kernels)).sum::<u32>()
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
        assert_eq!(
            raw(&[op::CONST, 0, op::STORE, 8], &[1.0]).validate(),
            Err(ProgramError::UnknownRegister { at: 2, register: 8 })
        );
        assert_eq!(
            raw(&[op::REG, 3, op::STORE, 0], &[]).validate(),
            Err(ProgramError::RegisterReadBeforeWrite { at: 0, register: 3 })
        );
        assert_eq!(
            raw(&[op::CONST, 0, op::STORE, 0], &[1.0]).validate(),
            Err(ProgramError::MissingOutput { register: 1 })
        );
    }

    fn laguerre(input: super::super::TermInput, pole: f64) -> TickTerm {
        let gains_pm = [180_000, -95_000, 61_000, -40_000, 22_000, -15_000, 9_000, -4_000];
        TickTerm::Laguerre { input, pole_q30: (pole * (1u64 << 30) as f64) as i32, gains_pm }
    }

    fn with_terms(terms: &[TickTerm]) -> Program {
        let mut b = minimal();
        b.constant(0.3).store(2).constant(10.0).store(3);
        let mut program = b.finish().unwrap();
        for term in terms {
            program.terms.push(*term).unwrap();
        }
        program
    }

    #[test]
    fn the_tick_budget_takes_the_programs_of_fit_and_rejects_more() {
        use super::super::TermInput;
        let harmonic = |order| TickTerm::Harmonic { order, amp_reg: 2, phase_reg: 3 };
        let velocity = laguerre(TermInput::VelocitySign { smooth_nm_per_4_ticks: 300 }, 0.93);
        let dahl = laguerre(TermInput::Dahl { inv_x0_q30: 1 << 20 }, 0.93);
        let sine = laguerre(TermInput::PositionSine { turns_per_nm: 4295, phase_turns: 0 }, 0.93);
        let cosine = laguerre(TermInput::PositionSine { turns_per_nm: 4295, phase_turns: 1 << 30 }, 0.93);
        let drift = TickTerm::Drift { offset_pm: 1, decay_pm: 1, tau_ticks: 8000 };
        let coupling = TickTerm::AxisCoupling { x_gain_pm_per_mps2: 1, spindle_amp_pm: 1, spindle_phase_turns: 0 };
        let axis = |friction: bool, hysteresis: bool, ripple: bool| {
            TickTerm::Axis(crate::axis::AxisParams {
                friction: friction.then_some(crate::axis::Friction {
                    coulomb_mps2: 0.07,
                    static_mps2: 0.1,
                    stribeck_mps: 2e-4,
                    smooth_mps: 1e-5,
                }),
                hysteresis: hysteresis.then_some(crate::axis::Hysteresis { force_mps2: 0.05, stiffness_per_s2: 6e4 }),
                ripple: ripple.then_some(crate::axis::Ripple {
                    amp_nm: 50.0,
                    harmonic2_nm: 8.0,
                    turns_per_nm: 810_000,
                    phase_turns: 0,
                }),
                ..crate::axis::default_machine()
            })
        };
        // Accepted: eight harmonics, the terms of each `fit --effect` (the axis twin with
        // friction, hysteresis or encoder error, or all three, which the servo synthesises as
        // a harmonic; drift; coupling), one bank with a drift, a velocity bank with a coupling
        // (a late setpoint beside it), the axis twin with a coupling, and with a drift too.
        let eight: std::vec::Vec<TickTerm> = (2..10).map(harmonic).collect();
        let fitted =
            [axis(true, false, false), axis(false, true, false), axis(false, false, true), axis(true, true, true)];
        for terms in [
            &eight[..],
            &fitted[..1],
            &fitted[1..2],
            &fitted[2..3],
            &fitted[3..],
            &[velocity],
            &[dahl],
            &[drift],
            &[coupling],
            &[velocity, drift],
            &[dahl, drift],
            &[fitted[0], coupling],
            &[velocity, coupling],
            &[fitted[3], drift, coupling],
        ] {
            let program = with_terms(terms);
            assert_eq!(program.validate(), Ok(()), "{terms:?}: {}", program.tick_cost());
        }
        // Just over: two velocity-sign banks, the ripple's two position banks (802 measured
        // since the supervisor's command store; `fit` makes the axis twin for a ripple), a bank
        // with a drift and a coupling, the Dahl bank with a coupling.
        for terms in [&[velocity, velocity][..], &[sine, cosine], &[velocity, drift, coupling], &[dahl, coupling]] {
            assert!(matches!(with_terms(terms).validate(), Err(ProgramError::TickBudget { .. })), "{terms:?}");
        }
        // Rejected, with the cost: three banks with a drift and a coupling, a bank whose pole
        // needs 64-bit stages.
        let three = with_terms(&[velocity, dahl, sine, drift, coupling]);
        let cost = three.tick_cost();
        assert_eq!(cost, 534 + 42 + 145 + 162 + 119 + 53 + 65);
        assert_eq!(three.validate(), Err(ProgramError::TickBudget { cost: cost as u16, budget: 800 }));
        let slow_pole = with_terms(&[laguerre(TermInput::PositionSine { turns_per_nm: 4295, phase_turns: 0 }, 0.999)]);
        assert!(matches!(slow_pole.validate(), Err(ProgramError::TickBudget { .. })));
        // The paper program alone costs the fixed part.
        assert_eq!(crate::program::paper_program().tick_cost(), tick_cost::FIXED);
    }

    #[test]
    fn an_axis_harmonic_needs_the_axis_twin_and_an_order_of_its_own() {
        let axis = TickTerm::Axis(crate::axis::default_machine());
        let harmonic = |order| TickTerm::AxisHarmonic { order };
        let with = |terms: &[TickTerm]| {
            let mut b = minimal();
            for t in terms {
                b.term(*t);
            }
            b.finish().map(|_| ())
        };
        assert_eq!(with(&[axis, harmonic(5), harmonic(7), harmonic(2)]), Ok(()));
        // Six higher orders beside the twin fit the budget (534 + 46 + 6 x 26 = 736).
        let six: Vec<TickTerm> = core::iter::once(axis).chain([5, 7, 9, 11, 13, 15].map(harmonic)).collect();
        assert_eq!(with(&six), Ok(()));
        assert_eq!(with(&[harmonic(5), axis]), Ok(()), "before the twin in the program");
        assert_eq!(with(&[harmonic(5)]), Err(ProgramError::BadTerm { index: 0 }), "no axis twin");
        assert_eq!(with(&[axis, harmonic(5), harmonic(5)]), Err(ProgramError::BadTerm { index: 2 }), "twice");
        assert_eq!(with(&[axis, harmonic(3)]), Err(ProgramError::BadTerm { index: 1 }), "the twin's own slot's");
        assert_eq!(with(&[axis, harmonic(1)]), Err(ProgramError::BadTerm { index: 1 }), "the fundamental");
        assert_eq!(with(&[axis, harmonic(16)]), Err(ProgramError::BadTerm { index: 1 }), "beyond the highest order");
        let seven: Vec<TickTerm> = core::iter::once(axis).chain([2, 4, 5, 6, 7, 8, 9].map(harmonic)).collect();
        assert_eq!(with(&seven), Err(ProgramError::BadTerm { index: 7 }), "more than the compensator learns");
    }

    #[test]
    fn a_term_must_reference_stored_registers() {
        let mut b = minimal();
        b.term(TickTerm::Harmonic { order: 3, amp_reg: 5, phase_reg: REG_PHASE_DEG });
        assert_eq!(b.finish().map(|_| ()), Err(ProgramError::BadTerm { index: 0 }));
    }
}
