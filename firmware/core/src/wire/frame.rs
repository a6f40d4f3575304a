//! COBS framing with a CRC-32 and a non-panicking streaming decoder.

use core::marker::PhantomData;

use crc::{Crc, CRC_32_ISO_HDLC};
use serde::{de::DeserializeOwned, Serialize};

use super::Envelope;

/// Largest postcard payload of a frame (before CRC and stuffing), bytes.
pub const MAX_FRAME_PAYLOAD: usize = 600;
/// Largest encoded frame on the wire, including the COBS overhead and the 0x00 delimiter.
pub const MAX_ENCODED_FRAME: usize = MAX_FRAME_PAYLOAD + 4 + (MAX_FRAME_PAYLOAD + 4) / 254 + 2;

/// The CRC used by every frame and by the persistent config store.
const CRC32: Crc<u32> = Crc::<u32>::new(&CRC_32_ISO_HDLC);

/// CRC-32/ISO-HDLC of `bytes`: the checksum of frames and of the config record.
pub fn frame_crc32(bytes: &[u8]) -> u32 {
    CRC32.checksum(bytes)
}

/// Why a frame was dropped (or could not be encoded).
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum FrameError {
    /// More bytes than [`MAX_ENCODED_FRAME`] arrived before a delimiter.
    TooLong,
    /// The COBS stuffing is invalid.
    Stuffing,
    /// Fewer bytes than a CRC.
    TooShort,
    /// The CRC does not match.
    Crc,
    /// The payload is not a valid message (unknown variant, bad length, trailing bytes).
    Decode,
    /// The message does not fit the output buffer (encoding only).
    BufferTooSmall,
}

impl core::fmt::Display for FrameError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            Self::TooLong => "frame longer than the maximum",
            Self::Stuffing => "invalid COBS stuffing",
            Self::TooShort => "frame shorter than its CRC",
            Self::Crc => "CRC mismatch",
            Self::Decode => "payload is not a valid message",
            Self::BufferTooSmall => "message does not fit the buffer",
        })
    }
}

impl core::error::Error for FrameError {}

/// Encodes `body` with sequence number `seq` into `out` as one complete frame including the
/// trailing 0x00; returns the number of bytes written.
pub fn encode_frame<T: Serialize>(seq: u16, body: &T, out: &mut [u8]) -> Result<usize, FrameError> {
    let mut raw = [0u8; MAX_FRAME_PAYLOAD + 4];
    let envelope = Envelope { seq, body };
    let used =
        postcard::to_slice(&envelope, &mut raw[..MAX_FRAME_PAYLOAD]).map_err(|_| FrameError::BufferTooSmall)?.len();
    let crc = CRC32.checksum(&raw[..used]);
    raw[used..used + 4].copy_from_slice(&crc.to_le_bytes());
    let stuffed = cobs::try_encode(&raw[..used + 4], out).map_err(|_| FrameError::BufferTooSmall)?;
    let delimiter = out.get_mut(stuffed).ok_or(FrameError::BufferTooSmall)?;
    *delimiter = 0;
    Ok(stuffed + 1)
}

/// A streaming frame decoder for messages of type `T`. Feed it bytes with
/// [`push`](Self::push); it answers at every delimiter.
pub struct FrameDecoder<T> {
    buf: [u8; MAX_ENCODED_FRAME],
    len: usize,
    /// Set after an over-long frame: drop bytes until the next delimiter.
    discarding: bool,
    _message: PhantomData<fn() -> T>,
}

impl<T: DeserializeOwned> Default for FrameDecoder<T> {
    fn default() -> Self {
        Self::new()
    }
}

impl<T: DeserializeOwned> FrameDecoder<T> {
    /// An empty decoder.
    pub const fn new() -> Self {
        Self { buf: [0; MAX_ENCODED_FRAME], len: 0, discarding: false, _message: PhantomData }
    }

    /// Takes one byte. Returns `None` in the middle of a frame, and at a delimiter the
    /// decoded message or why the frame was dropped. Empty frames (repeated delimiters) are
    /// skipped silently, so a sender may start with a 0x00 to resynchronise.
    pub fn push(&mut self, byte: u8) -> Option<Result<Envelope<T>, FrameError>> {
        if byte != 0 {
            if self.discarding {
                return None;
            }
            if self.len == self.buf.len() {
                self.discarding = true;
                self.len = 0;
                return Some(Err(FrameError::TooLong));
            }
            self.buf[self.len] = byte;
            self.len += 1;
            return None;
        }
        let len = core::mem::replace(&mut self.len, 0);
        if core::mem::replace(&mut self.discarding, false) || len == 0 {
            return None;
        }
        Some(decode(&mut self.buf[..len]))
    }

    /// Drops any partial frame.
    pub fn reset(&mut self) {
        self.len = 0;
        self.discarding = false;
    }
}

fn decode<T: DeserializeOwned>(stuffed: &mut [u8]) -> Result<Envelope<T>, FrameError> {
    let len = cobs::decode_in_place(stuffed).map_err(|_| FrameError::Stuffing)?;
    let frame = stuffed.get(..len).ok_or(FrameError::Stuffing)?;
    if frame.len() < 4 {
        return Err(FrameError::TooShort);
    }
    let (payload, crc_bytes) = frame.split_at(frame.len() - 4);
    let crc = u32::from_le_bytes([crc_bytes[0], crc_bytes[1], crc_bytes[2], crc_bytes[3]]);
    if CRC32.checksum(payload) != crc {
        return Err(FrameError::Crc);
    }
    match postcard::take_from_bytes::<Envelope<T>>(payload) {
        Ok((envelope, [])) => Ok(envelope),
        _ => Err(FrameError::Decode),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::program::paper_program;
    use crate::wire::{Request, Response};

    fn frames<T: DeserializeOwned>(bytes: &[u8]) -> heapless::Vec<Result<Envelope<T>, FrameError>, 16> {
        let mut decoder = FrameDecoder::<T>::new();
        let mut out = heapless::Vec::new();
        for &b in bytes {
            if let Some(frame) = decoder.push(b) {
                let _ = out.push(frame);
            }
        }
        out
    }

    #[test]
    fn the_crc_is_crc32_iso_hdlc_and_the_frame_limit_is_as_specified() {
        assert_eq!(frame_crc32(b"123456789"), 0xCBF4_3926);
        assert_eq!(MAX_ENCODED_FRAME, 608);
    }

    #[test]
    fn the_largest_message_fits_a_frame() {
        let mut program = paper_program();
        while program.code.push(crate::program::op::NEG).is_ok() {}
        while program.consts.push(1.0).is_ok() {}
        let body = Request::UploadProgram { program, activate: true };
        let mut out = [0u8; MAX_ENCODED_FRAME];
        let len = encode_frame(1, &body, &mut out).unwrap();
        let got = frames::<Request>(&out[..len]);
        assert_eq!(got.len(), 1);
        assert_eq!(got[0].as_ref().unwrap().body, body);
    }

    #[test]
    fn corruption_is_detected_and_the_stream_recovers() {
        let mut out = [0u8; MAX_ENCODED_FRAME];
        let len = encode_frame(3, &Response::Pong { nonce: 9, protocol_version: 2 }, &mut out).unwrap();
        let mut stream: heapless::Vec<u8, 256> = heapless::Vec::new();
        // A frame with one flipped bit, a truncated frame, then a good one.
        let mut bad = out;
        bad[2] ^= 0x10;
        stream.extend_from_slice(&bad[..len]).unwrap();
        stream.extend_from_slice(&out[..len / 2]).unwrap();
        stream.push(0).unwrap();
        stream.extend_from_slice(&out[..len]).unwrap();
        let got = frames::<Response>(&stream);
        assert_eq!(got.len(), 3);
        assert!(got[0].is_err());
        assert!(got[1].is_err());
        assert_eq!(got[2].as_ref().unwrap().body, Response::Pong { nonce: 9, protocol_version: 2 });
    }

    #[test]
    fn an_overlong_frame_is_dropped_once() {
        let mut stream = [0x55u8; MAX_ENCODED_FRAME + 10];
        stream[MAX_ENCODED_FRAME + 9] = 0;
        let got = frames::<Response>(&stream);
        assert_eq!(got.as_slice(), &[Err(FrameError::TooLong)]);
    }
}
