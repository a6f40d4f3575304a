//! Any byte stream into both frame decoders: they must never panic, and every frame they
//! accept must re-encode to a frame that decodes to the same message.
#![no_main]
use libfuzzer_sys::fuzz_target;
use sts_twin_core::wire::{encode_frame, FrameDecoder, Request, Response, MAX_ENCODED_FRAME};

fuzz_target!(|data: &[u8]| {
    let mut requests = FrameDecoder::<Request>::new();
    let mut responses = FrameDecoder::<Response>::new();
    for &byte in data {
        if let Some(Ok(envelope)) = requests.push(byte) {
            let mut out = [0u8; MAX_ENCODED_FRAME];
            let len = encode_frame(envelope.seq, &envelope.body, &mut out).expect("a decoded request re-encodes");
            let mut again = FrameDecoder::<Request>::new();
            let decoded = out[..len].iter().find_map(|&b| again.push(b)).expect("one frame");
            assert_eq!(decoded.expect("re-encoded frame decodes").body, envelope.body);
        }
        let _ = responses.push(byte);
    }
});
