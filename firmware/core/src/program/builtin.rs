//! The paper's model (Eqs. 2 and 3), the built-in default program.

use super::{Program, ProgramBuilder, REG_AMP_UM, REG_PHASE_DEG};

/// Id of the built-in paper program.
pub const PAPER_PROGRAM_ID: u32 = 0x5041_5045;

/// The paper's twin: amplitude `49.67 * f8 * |f3 / f5|^0.78` (Eqs. 2 and 4) and phase
/// `1.95 - 1.23 * tanh(-0.0441 * f1 + 0.122 * f10 + 1.08)` degrees (Eq. 3).
///
/// It was fitted on the authors' machine and accelerometer; on another machine it is a
/// starting point, not a calibrated model.
pub fn paper_program() -> Program {
    let mut b = ProgramBuilder::new();
    b.id(PAPER_PROGRAM_ID);
    // f8 is index 7, f3 index 2, f5 index 4.
    b.constant(49.67).feature(7).mul().feature(2).feature(4).div().constant(0.78).pow().mul().store(REG_AMP_UM);
    // f1 is index 0, f10 index 9.
    b.constant(1.95).constant(1.23);
    b.constant(-0.0441).feature(0).mul().constant(0.122).feature(9).mul().add().constant(1.08).add().tanh();
    b.mul().sub().store(REG_PHASE_DEG);
    match b.finish() {
        Ok(program) => program,
        // The builder input above is fixed; validation can only fail if this file is edited wrongly.
        Err(_) => unreachable!("the built-in paper program is valid"),
    }
}
