//! Arbitrary bytes as a postcard program: decoding, validation and (for valid programs)
//! evaluation on arbitrary features must never panic; a valid program never produces a
//! non-finite output register.
#![no_main]
use libfuzzer_sys::fuzz_target;
use sts_twin_core::program::Program;

fuzz_target!(|data: &[u8]| {
    let (features_bytes, program_bytes) = data.split_at(data.len().min(48));
    let mut features = [0.0f32; 12];
    for (i, chunk) in features_bytes.chunks_exact(4).enumerate() {
        features[i] = f32::from_le_bytes([chunk[0], chunk[1], chunk[2], chunk[3]]);
    }
    let Ok(program) = postcard::from_bytes::<Program>(program_bytes) else { return };
    let valid = program.validate().is_ok();
    match program.evaluate(&features) {
        Ok(output) if valid => assert!(output.registers.iter().all(|r| r.is_finite())),
        _ => {}
    }
});
