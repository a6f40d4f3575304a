//! The twin program: the amplitude model, the phase model and any extra error terms, as a
//! compact bytecode for a small stack machine.
//!
//! A [`Program`] is what the host's `fit` produces and uploads, and what the firmware
//! evaluates at the model-update rate on the current [`features`](crate::features). It is
//! serialised with postcard (see `docs/wire-spec.md`). Nothing in a program is trusted: a
//! program must pass [`Program::validate`] before it is used, and a program that fails keeps
//! the previous one in force.
//!
//! # The machine
//! The bytecode ([`Program::code`]) is a sequence of one-byte opcodes ([`op`]), some with a
//! one-byte operand. It pushes f32 values on a stack of at most [`MAX_STACK`] entries and
//! stores results into [`REGISTER_COUNT`] output registers. Register [`REG_AMP_UM`] holds the
//! predicted dynamic-error amplitude in micrometres and [`REG_PHASE_DEG`] its phase in degrees
//! relative to the command phase; both must be stored by every program. The other registers
//! are free for the coefficients of [`TickTerm`]s, the per-tick error terms that the servo
//! interrupt adds on top of the fundamental (physical-effect terms).
//!
//! Operator semantics match the host's symbolic regression exactly and are total where
//! possible: `pow(a, b) = |a|^b`, `sqrt(a) = sqrt(|a|)`, `log(a) = ln|a|`; any non-finite
//! intermediate makes the evaluation fail (the firmware then holds its last good output).
//!
//! ```
//! use sts_twin_core::program::{Program, ProgramBuilder, REG_AMP_UM, REG_PHASE_DEG};
//! // amp = 2 * f5 (RMS), phase = -3 degrees
//! let mut b = ProgramBuilder::new();
//! b.constant(2.0).feature(4).mul().store(REG_AMP_UM);
//! b.constant(-3.0).store(REG_PHASE_DEG);
//! let program = b.finish().unwrap();
//! let mut features = [0.0f32; 12];
//! features[4] = 0.5;
//! let out = program.evaluate(&features).unwrap();
//! assert_eq!(out.amp_um(), 1.0);
//! assert_eq!(out.phase_deg(), -3.0);
//! ```

mod builder;
mod builtin;
mod eval;
mod term;
mod validate;

pub use builder::ProgramBuilder;
pub use builtin::{paper_program, PAPER_PROGRAM_ID};
pub use eval::{EvalError, ModelOutput};
pub use term::{
    laguerre_stages_are_narrow, resonance_params_ok, tick_cost, TermInput, TickTerm, LAGUERRE_STAGES,
    MAX_HARMONIC_ORDER, NARROW_POLE_MAX_Q30, RESONANCE_DAMPING_RANGE, RESONANCE_FREQ_RANGE_HZ, RESONANCE_GAIN_MAX,
    TICK_BUDGET_INSTRUCTIONS, VELOCITY_SMOOTH_32_BIT_LIMIT,
};
pub use validate::{terms_tick_cost, ProgramError};

use heapless::Vec;
use serde::{Deserialize, Serialize};

/// The program format version this library reads and writes.
pub const PROGRAM_VERSION: u16 = 2;
/// Most bytes of bytecode in a program.
pub const MAX_CODE_BYTES: usize = 256;
/// Most constants in a program.
pub const MAX_CONSTS: usize = 48;
/// Most per-tick terms in a program.
pub const MAX_TERMS: usize = 8;
/// Deepest stack a program may use.
pub const MAX_STACK: usize = 16;
/// Number of output registers.
pub const REGISTER_COUNT: usize = 8;
/// Register holding the dynamic-error amplitude, micrometres.
pub const REG_AMP_UM: u8 = 0;
/// Register holding the dynamic-error phase relative to the command phase, degrees.
pub const REG_PHASE_DEG: u8 = 1;
/// Number of features a program may read (the paper's Table 1).
pub const FEATURE_INPUTS: usize = 12;

/// The opcodes of the bytecode. Operands follow their opcode as one byte.
pub mod op {
    /// Push constant `consts[operand]`.
    pub const CONST: u8 = 0x01;
    /// Push feature `operand` (0-based: 0 is f1, the signal frequency).
    pub const FEATURE: u8 = 0x02;
    /// Push register `operand` (must have been stored earlier in the same program).
    pub const REG: u8 = 0x03;
    /// Pop into register `operand`.
    pub const STORE: u8 = 0x04;
    /// a + b.
    pub const ADD: u8 = 0x10;
    /// a - b.
    pub const SUB: u8 = 0x11;
    /// a * b.
    pub const MUL: u8 = 0x12;
    /// a / b.
    pub const DIV: u8 = 0x13;
    /// |a|^b.
    pub const POW: u8 = 0x14;
    /// -a.
    pub const NEG: u8 = 0x20;
    /// |a|.
    pub const ABS: u8 = 0x21;
    /// sqrt(|a|).
    pub const SQRT: u8 = 0x22;
    /// e^a.
    pub const EXP: u8 = 0x23;
    /// ln|a|.
    pub const LOG: u8 = 0x24;
    /// tanh(a).
    pub const TANH: u8 = 0x25;
    /// sin(a), a in radians.
    pub const SIN: u8 = 0x26;
    /// cos(a), a in radians.
    pub const COS: u8 = 0x27;

    /// Whether `code` takes a one-byte operand.
    pub const fn has_operand(code: u8) -> bool {
        matches!(code, CONST | FEATURE | REG | STORE)
    }

    /// Stack effect of `code`: (values popped, values pushed), or `None` if unknown.
    pub const fn stack_effect(code: u8) -> Option<(u8, u8)> {
        match code {
            CONST | FEATURE | REG => Some((0, 1)),
            STORE => Some((1, 0)),
            ADD | SUB | MUL | DIV | POW => Some((2, 1)),
            NEG | ABS | SQRT | EXP | LOG | TANH | SIN | COS => Some((1, 1)),
            _ => None,
        }
    }

    /// The mnemonic of `code`, for listings and error messages.
    pub const fn name(code: u8) -> &'static str {
        match code {
            CONST => "const",
            FEATURE => "feature",
            REG => "reg",
            STORE => "store",
            ADD => "add",
            SUB => "sub",
            MUL => "mul",
            DIV => "div",
            POW => "pow",
            NEG => "neg",
            ABS => "abs",
            SQRT => "sqrt",
            EXP => "exp",
            LOG => "log",
            TANH => "tanh",
            SIN => "sin",
            COS => "cos",
            _ => "unknown",
        }
    }
}

/// A twin program as it travels and as it is stored. See the [module docs](self).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Program {
    /// Format version; must equal [`PROGRAM_VERSION`].
    pub version: u16,
    /// An identifier chosen by the host (e.g. a hash of the model file), reported in status.
    pub id: u32,
    /// The bytecode.
    pub code: Vec<u8, MAX_CODE_BYTES>,
    /// Constants referenced by `CONST` operands.
    pub consts: Vec<f32, MAX_CONSTS>,
    /// Per-tick error terms added to the fundamental by the servo interrupt.
    pub terms: Vec<TickTerm, MAX_TERMS>,
}

impl Program {
    /// An empty program of the current version (not valid until it stores the outputs).
    pub const fn empty(id: u32) -> Self {
        Self { version: PROGRAM_VERSION, id, code: Vec::new(), consts: Vec::new(), terms: Vec::new() }
    }
}
