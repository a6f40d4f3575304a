//! Streaming accelerometer features (placeholder; being written).
