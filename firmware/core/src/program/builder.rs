//! A builder that writes bytecode, so that hosts and tests never hand-assemble bytes.

use super::{op, Program, ProgramError, TickTerm};

/// Writes a [`Program`] one operation at a time; [`finish`](Self::finish) validates it.
///
/// Capacity overflows (too much code, too many constants or terms) are remembered and
/// reported by `finish` as a validation error rather than panicking.
#[derive(Clone, Debug)]
pub struct ProgramBuilder {
    program: Program,
    overflowed: bool,
}

impl Default for ProgramBuilder {
    fn default() -> Self {
        Self::new()
    }
}

impl ProgramBuilder {
    /// A builder for an empty program with id 0.
    pub const fn new() -> Self {
        Self { program: Program::empty(0), overflowed: false }
    }

    /// Sets the program id reported in status.
    pub fn id(&mut self, id: u32) -> &mut Self {
        self.program.id = id;
        self
    }

    fn emit(&mut self, bytes: &[u8]) -> &mut Self {
        if self.program.code.extend_from_slice(bytes).is_err() {
            self.overflowed = true;
        }
        self
    }

    /// Pushes a constant (re-using an identical one already in the table).
    pub fn constant(&mut self, value: f32) -> &mut Self {
        let existing = self.program.consts.iter().position(|c| c.to_bits() == value.to_bits());
        let index = match existing {
            Some(index) => index,
            None => {
                if self.program.consts.push(value).is_err() {
                    self.overflowed = true;
                    return self;
                }
                self.program.consts.len() - 1
            }
        };
        self.emit(&[op::CONST, index as u8])
    }

    /// Pushes feature `index` (0-based: 0 is f1).
    pub fn feature(&mut self, index: u8) -> &mut Self {
        self.emit(&[op::FEATURE, index])
    }

    /// Pushes register `register`.
    pub fn register(&mut self, register: u8) -> &mut Self {
        self.emit(&[op::REG, register])
    }

    /// Pops into register `register`.
    pub fn store(&mut self, register: u8) -> &mut Self {
        self.emit(&[op::STORE, register])
    }

    /// Emits an operation without operand (one of the binary or unary opcodes of [`op`]).
    pub fn operation(&mut self, opcode: u8) -> &mut Self {
        self.emit(&[opcode])
    }

    /// a + b.
    pub fn add(&mut self) -> &mut Self {
        self.operation(op::ADD)
    }
    /// a - b.
    pub fn sub(&mut self) -> &mut Self {
        self.operation(op::SUB)
    }
    /// a * b.
    pub fn mul(&mut self) -> &mut Self {
        self.operation(op::MUL)
    }
    /// a / b.
    pub fn div(&mut self) -> &mut Self {
        self.operation(op::DIV)
    }
    /// |a|^b.
    pub fn pow(&mut self) -> &mut Self {
        self.operation(op::POW)
    }
    /// -a.
    pub fn neg(&mut self) -> &mut Self {
        self.operation(op::NEG)
    }
    /// |a|.
    pub fn abs(&mut self) -> &mut Self {
        self.operation(op::ABS)
    }
    /// sqrt(|a|).
    pub fn sqrt(&mut self) -> &mut Self {
        self.operation(op::SQRT)
    }
    /// e^a.
    pub fn exp(&mut self) -> &mut Self {
        self.operation(op::EXP)
    }
    /// ln|a|.
    pub fn log(&mut self) -> &mut Self {
        self.operation(op::LOG)
    }
    /// tanh(a).
    pub fn tanh(&mut self) -> &mut Self {
        self.operation(op::TANH)
    }
    /// sin(a).
    pub fn sin(&mut self) -> &mut Self {
        self.operation(op::SIN)
    }
    /// cos(a).
    pub fn cos(&mut self) -> &mut Self {
        self.operation(op::COS)
    }

    /// Adds a per-tick term.
    pub fn term(&mut self, term: TickTerm) -> &mut Self {
        if self.program.terms.push(term).is_err() {
            self.overflowed = true;
        }
        self
    }

    /// Validates and returns the program.
    pub fn finish(&self) -> Result<Program, ProgramError> {
        if self.overflowed {
            return Err(ProgramError::TooLarge);
        }
        self.program.validate()?;
        Ok(self.program.clone())
    }
}
