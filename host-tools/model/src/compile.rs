//! Compiling fitted expressions into the firmware's twin program.

use sts_symreg::{BinaryOp, Expr, PostfixNode, UnaryOp};
use sts_twin_core::program::{Program, ProgramBuilder, ProgramError, REG_AMP_UM, REG_PHASE_DEG};
use sts_twin_core::wire::frame_crc32;

/// Appends the code of `expr`, storing its value into `register`. Variables are feature
/// indices; constants become f32.
pub fn expr_to_code(builder: &mut ProgramBuilder, expr: &Expr, register: u8) {
    for node in expr.postfix() {
        match node {
            PostfixNode::Const(value) => builder.constant(value as f32),
            PostfixNode::Var(index) => builder.feature(index.min(255) as u8),
            PostfixNode::Unary(op) => match op {
                UnaryOp::Abs => builder.abs(),
                UnaryOp::Sqrt => builder.sqrt(),
                UnaryOp::Exp => builder.exp(),
                UnaryOp::Log => builder.log(),
                UnaryOp::Tanh => builder.tanh(),
                UnaryOp::Sin => builder.sin(),
            },
            PostfixNode::Binary(op) => match op {
                BinaryOp::Add => builder.add(),
                BinaryOp::Sub => builder.sub(),
                BinaryOp::Mul => builder.mul(),
                BinaryOp::Div => builder.div(),
                BinaryOp::Pow => builder.pow(),
            },
        };
    }
    builder.store(register);
}

/// The firmware program of an amplitude and a phase formula. Its id is the CRC-32 of its
/// postcard bytes with id 0, so the same formulas always give the same id.
pub fn compile_program(amplitude: &Expr, phase: &Expr) -> Result<Program, ProgramError> {
    let mut builder = ProgramBuilder::new();
    expr_to_code(&mut builder, amplitude, REG_AMP_UM);
    expr_to_code(&mut builder, phase, REG_PHASE_DEG);
    let mut program = builder.finish()?;
    let mut buf = [0u8; 1024];
    if let Ok(bytes) = postcard::to_slice(&program, &mut buf) {
        program.id = frame_crc32(bytes);
    }
    Ok(program)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_compiled_program_evaluates_like_the_expression() {
        // amp = 2.5 * f1 * |f2 / f3|^0.78 ; phase = 1.95 - 1.23 * tanh(-0.0441 * f1 + 1.08)
        let amp = Expr::binary(
            BinaryOp::Mul,
            Expr::binary(BinaryOp::Mul, Expr::Const(2.5), Expr::Var(0)),
            Expr::binary(BinaryOp::Pow, Expr::binary(BinaryOp::Div, Expr::Var(1), Expr::Var(2)), Expr::Const(0.78)),
        );
        let phase = Expr::binary(
            BinaryOp::Sub,
            Expr::Const(1.95),
            Expr::binary(
                BinaryOp::Mul,
                Expr::Const(1.23),
                Expr::unary(
                    UnaryOp::Tanh,
                    Expr::binary(
                        BinaryOp::Add,
                        Expr::binary(BinaryOp::Mul, Expr::Const(-0.0441), Expr::Var(0)),
                        Expr::Const(1.08),
                    ),
                ),
            ),
        );
        let program = compile_program(&amp, &phase).unwrap();
        let mut features = [0.0f32; 12];
        features[0] = 30.0;
        features[1] = -0.4;
        features[2] = 0.9;
        let out = program.evaluate(&features).unwrap();
        let row: Vec<f64> = features.iter().map(|&v| f64::from(v)).collect();
        assert!((f64::from(out.amp_um()) - amp.eval_row(&row)).abs() < 1e-5 * amp.eval_row(&row).abs());
        assert!((f64::from(out.phase_deg()) - phase.eval_row(&row)).abs() < 1e-5);
        assert_eq!(compile_program(&amp, &phase).unwrap().id, program.id);
    }
}
