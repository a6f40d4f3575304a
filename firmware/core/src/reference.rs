//! f64 references (placeholder).
