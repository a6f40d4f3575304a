//! Exported Rust and C source computes the same values as the engine (compiled and run
//! with the system's `cc` and `rustc`).
use std::process::Command;
use sts_symreg::{BinaryOp, Expr, FloatType, UnaryOp};

fn sample() -> Expr {
    // 1.95 - 1.23*tanh(-0.0441*f + 0.122*s + 1.08) + sqrt(|log(s)|)*|f/s|^0.78 - sin(exp(-s))
    let t = Expr::binary(
        BinaryOp::Sub,
        Expr::Const(1.95),
        Expr::binary(
            BinaryOp::Mul,
            Expr::Const(1.23),
            Expr::unary(
                UnaryOp::Tanh,
                Expr::binary(
                    BinaryOp::Add,
                    Expr::binary(
                        BinaryOp::Add,
                        Expr::binary(BinaryOp::Mul, Expr::Const(-0.0441), Expr::Var(0)),
                        Expr::binary(BinaryOp::Mul, Expr::Const(0.122), Expr::Var(1)),
                    ),
                    Expr::Const(1.08),
                ),
            ),
        ),
    );
    let p = Expr::binary(
        BinaryOp::Mul,
        Expr::unary(UnaryOp::Sqrt, Expr::unary(UnaryOp::Log, Expr::Var(1))),
        Expr::binary(BinaryOp::Pow, Expr::binary(BinaryOp::Div, Expr::Var(0), Expr::Var(1)), Expr::Const(0.78)),
    );
    let s = Expr::unary(
        UnaryOp::Sin,
        Expr::unary(UnaryOp::Exp, Expr::binary(BinaryOp::Sub, Expr::Const(0.0), Expr::Var(1))),
    );
    Expr::binary(BinaryOp::Sub, Expr::binary(BinaryOp::Add, t, p), Expr::unary(UnaryOp::Abs, s))
}

const ROWS: [[f64; 2]; 4] = [[5.0, 1.5], [12.5, 0.3], [40.0, 9.0], [7.0, 2.0]];

fn dir() -> std::path::PathBuf {
    let d = std::env::temp_dir().join(format!("sts-symreg-export-{}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn check_output(stdout: &[u8], e: &Expr, tol: f64) {
    let text = String::from_utf8_lossy(stdout);
    let values: Vec<f64> = text.split_whitespace().map(|v| v.parse().unwrap()).collect();
    assert_eq!(values.len(), ROWS.len(), "{text}");
    for (row, v) in ROWS.iter().zip(values) {
        let want = e.eval_row(row);
        assert!((v - want).abs() <= tol * (1.0 + want.abs()), "row {row:?}: exported {v}, engine {want}");
    }
}

#[test]
fn c_export_matches_the_engine() {
    let e = sample();
    let d = dir();
    for (float, ty, fmt, tol) in [(FloatType::F64, "double", "%.17g", 1e-12), (FloatType::F32, "float", "%.9g", 1e-5)] {
        let mut src = e.to_c("model", &["freq_hz", "shape"], float);
        src.push_str("#include <stdio.h>\nint main(void) {\n");
        for r in ROWS {
            src.push_str(&format!(
                "    {{ const {ty} x[2] = {{ {:?}, {:?} }}; printf(\"{fmt}\\n\", (double)model(x)); }}\n",
                r[0], r[1]
            ));
        }
        src.push_str("    return 0;\n}\n");
        let c = d.join(format!("model_{ty}.c"));
        let bin = d.join(format!("model_{ty}"));
        std::fs::write(&c, &src).unwrap();
        let st = Command::new("cc")
            .arg("-std=c99")
            .arg("-Wall")
            .arg("-Werror")
            .arg(&c)
            .arg("-lm")
            .arg("-o")
            .arg(&bin)
            .status();
        let st = st.expect("a C compiler (cc) is needed for this test");
        assert!(st.success(), "cc failed on:\n{src}");
        let out = Command::new(&bin).output().unwrap();
        check_output(&out.stdout, &e, tol);
    }
}

#[test]
fn rust_export_matches_the_engine() {
    let e = sample();
    let d = dir();
    for (float, ty, tol) in [(FloatType::F64, "f64", 1e-12), (FloatType::F32, "f32", 1e-5)] {
        let mut src = String::from("#![deny(warnings)]\n");
        src.push_str(&e.to_rust("model", &["freq_hz", "shape"], float));
        src.push_str("fn main() {\n");
        for r in ROWS {
            src.push_str(&format!("    println!(\"{{:?}}\", model(&[{:?}_{ty}, {:?}_{ty}]) as f64);\n", r[0], r[1]));
        }
        src.push_str("}\n");
        let rs = d.join(format!("model_{ty}.rs"));
        let bin = d.join(format!("model_rs_{ty}"));
        std::fs::write(&rs, &src).unwrap();
        let rustc = std::env::var("RUSTC").unwrap_or_else(|_| "rustc".into());
        let st = Command::new(rustc).arg("--edition=2021").arg("-O").arg(&rs).arg("-o").arg(&bin).status().unwrap();
        assert!(st.success(), "rustc failed on:\n{src}");
        let out = Command::new(&bin).output().unwrap();
        check_output(&out.stdout, &e, tol);
    }
}

#[test]
fn infix_is_what_sympy_would_read() {
    // The printed form spells out the firmware's semantics.
    let text = sample().to_infix(&["f", "s"]);
    assert_eq!(
        text,
        "1.95-1.23*tanh((-0.0441)*f+0.122*s+1.08)+sqrt(abs(log(abs(s))))*abs(f/s)**0.78-abs(sin(exp(0.0-s)))"
    );
}
