//! The control protocol between host and firmware: postcard messages in COBS frames with a
//! CRC-32, over the UART control channel.
//!
//! A frame on the wire is `COBS(postcard(Envelope) ++ crc32_le) ++ 0x00`, where the CRC is
//! CRC-32/ISO-HDLC over the postcard bytes. The full byte-level specification is in
//! `docs/wire-spec.md`. The decoder ([`FrameDecoder`]) takes bytes one at a time, never
//! panics and never allocates: a frame that is too long, badly stuffed, fails its CRC or
//! does not decode is counted by the caller and dropped, and decoding resumes at the next
//! `0x00`.
//!
//! ```
//! use sts_twin_core::wire::{encode_frame, FrameDecoder, Request, MAX_ENCODED_FRAME};
//! let mut bytes = [0u8; MAX_ENCODED_FRAME];
//! let len = encode_frame(7, &Request::Ping { nonce: 42 }, &mut bytes).unwrap();
//! let mut decoder = FrameDecoder::<Request>::new();
//! let mut got = None;
//! for &b in &bytes[..len] {
//!     if let Some(frame) = decoder.push(b) {
//!         got = Some(frame.unwrap());
//!     }
//! }
//! let envelope = got.unwrap();
//! assert_eq!(envelope.seq, 7);
//! assert_eq!(envelope.body, Request::Ping { nonce: 42 });
//! ```

mod frame;
mod message;

/// The control protocol's version (docs/wire-spec.md). A host refuses to talk to a firmware
/// whose [`Response::Pong`] carries another.
pub const PROTOCOL_VERSION: u16 = 3;

pub use frame::{encode_frame, frame_crc32, FrameDecoder, FrameError, MAX_ENCODED_FRAME, MAX_FRAME_PAYLOAD};
pub use message::{ConfigSource, Envelope, Rejection, Request, Response, Status};
