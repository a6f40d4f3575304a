//! The wire protocol (placeholder; being written).
