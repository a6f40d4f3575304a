//! The twin program (placeholder; being written).
