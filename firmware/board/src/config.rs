//! A power-fail-safe [`ConfigStore`] over two slots of any erasable medium (PSRAM under
//! QEMU, flash sectors on a real board).
//!
//! Each slot holds one record: a 32-byte header, then the blob.
//!
//! | offset | field |
//! |---|---|
//! | 0 | magic `0x4353_5453` ("STSC") |
//! | 4 | generation (`u32`, wrapping, higher is newer) |
//! | 8 | blob length in bytes |
//! | 12 | CRC-32 (ISO-HDLC) over generation, length and blob |
//! | 16..32 | `0xFF` padding (a flash program unit) |
//! | 32.. | blob |
//!
//! A write goes to the slot not holding the newest record: erase, program the blob, then
//! program the header last. A write cut short leaves a slot without a valid header, and
//! the other slot (the previous blob) is read instead.

use crc::{Crc, CRC_32_ISO_HDLC};

use crate::{ConfigError, ConfigStore};

/// Header magic, "STSC".
pub const RECORD_MAGIC: u32 = 0x4353_5453;
/// Bytes of the record header (one program unit of the strictest medium, STM32H7 flash).
pub const HEADER_BYTES: usize = 32;

const CRC32: Crc<u32> = Crc::<u32>::new(&CRC_32_ISO_HDLC);

/// Raw storage of two equal slots.
pub trait RecordMedium {
    /// Bytes per slot.
    fn slot_bytes(&self) -> usize;
    /// Reads `buf.len()` bytes at `offset` of `slot`.
    fn read(&mut self, slot: usize, offset: usize, buf: &mut [u8]) -> Result<(), ConfigError>;
    /// Erases `slot` (to `0xFF` on flash; any medium may just overwrite later).
    fn erase(&mut self, slot: usize) -> Result<(), ConfigError>;
    /// Programs `data` at `offset` of an erased `slot`. `offset` is a multiple of
    /// [`HEADER_BYTES`]; the medium pads a short last unit with `0xFF`.
    fn program(&mut self, slot: usize, offset: usize, data: &[u8]) -> Result<(), ConfigError>;
}

/// A [`ConfigStore`] over a [`RecordMedium`].
#[derive(Debug)]
pub struct AbStore<M> {
    medium: M,
}

#[derive(Clone, Copy, Debug)]
struct Header {
    generation: u32,
    len: usize,
    crc: u32,
}

impl<M: RecordMedium> AbStore<M> {
    /// A store over `medium`.
    pub const fn new(medium: M) -> Self {
        Self { medium }
    }

    /// The medium back.
    pub fn into_inner(self) -> M {
        self.medium
    }

    fn header(&mut self, slot: usize) -> Option<Header> {
        let mut raw = [0u8; 16];
        self.medium.read(slot, 0, &mut raw).ok()?;
        let word = |i: usize| u32::from_le_bytes([raw[i], raw[i + 1], raw[i + 2], raw[i + 3]]);
        if word(0) != RECORD_MAGIC {
            return None;
        }
        let len = word(8) as usize;
        if len > self.capacity() {
            return None;
        }
        Some(Header { generation: word(4), len, crc: word(12) })
    }

    /// The valid slot with the newest record, checking the CRC by streaming the blob.
    fn newest(&mut self) -> Option<(usize, Header)> {
        let mut best: Option<(usize, Header)> = None;
        for slot in 0..2 {
            let Some(h) = self.header(slot) else { continue };
            if !self.crc_ok(slot, &h) {
                continue;
            }
            best = match best {
                Some((_, b)) if (h.generation.wrapping_sub(b.generation) as i32) <= 0 => best,
                _ => Some((slot, h)),
            };
        }
        best
    }

    fn crc_ok(&mut self, slot: usize, h: &Header) -> bool {
        let mut digest = CRC32.digest();
        digest.update(&h.generation.to_le_bytes());
        digest.update(&(h.len as u32).to_le_bytes());
        let mut chunk = [0u8; 64];
        let mut done = 0;
        while done < h.len {
            let n = (h.len - done).min(chunk.len());
            if self.medium.read(slot, HEADER_BYTES + done, &mut chunk[..n]).is_err() {
                return false;
            }
            digest.update(&chunk[..n]);
            done += n;
        }
        digest.finalize() == h.crc
    }
}

impl<M: RecordMedium> ConfigStore for AbStore<M> {
    fn capacity(&self) -> usize {
        self.medium.slot_bytes() - HEADER_BYTES
    }

    fn read(&mut self, buf: &mut [u8]) -> Result<usize, ConfigError> {
        let Some((slot, h)) = self.newest() else {
            // A slot with a record header but no intact record anywhere: corrupt, not blank.
            let written = (0..2).any(|slot| self.header(slot).is_some());
            return Err(if written { ConfigError::Corrupt } else { ConfigError::Empty });
        };
        if buf.len() < h.len {
            return Err(ConfigError::TooLarge { needed: h.len });
        }
        self.medium.read(slot, HEADER_BYTES, &mut buf[..h.len])?;
        Ok(h.len)
    }

    fn write(&mut self, blob: &[u8]) -> Result<(), ConfigError> {
        if blob.len() > self.capacity() {
            return Err(ConfigError::TooLarge { needed: blob.len() });
        }
        let (slot, generation) = match self.newest() {
            Some((s, h)) => (1 - s, h.generation.wrapping_add(1)),
            None => (0, 1),
        };
        let mut digest = CRC32.digest();
        digest.update(&generation.to_le_bytes());
        digest.update(&(blob.len() as u32).to_le_bytes());
        digest.update(blob);
        let mut header = [0xFFu8; HEADER_BYTES];
        header[0..4].copy_from_slice(&RECORD_MAGIC.to_le_bytes());
        header[4..8].copy_from_slice(&generation.to_le_bytes());
        header[8..12].copy_from_slice(&(blob.len() as u32).to_le_bytes());
        header[12..16].copy_from_slice(&digest.finalize().to_le_bytes());
        self.medium.erase(slot)?;
        if !blob.is_empty() {
            self.medium.program(slot, HEADER_BYTES, blob)?;
        }
        self.medium.program(slot, 0, &header)
    }
}

/// A [`RecordMedium`] in plain memory (the QEMU PSRAM region, or a test buffer): two
/// consecutive slots of `slot_bytes` at `base`, accessed with volatile byte operations.
#[derive(Debug)]
pub struct MemoryMedium {
    base: *mut u8,
    slot_bytes: usize,
}

// SAFETY: the region is owned by the one store that holds this medium.
unsafe impl Send for MemoryMedium {}

impl MemoryMedium {
    /// Two slots of `slot_bytes` starting at `base`.
    ///
    /// # Safety
    /// `base .. base + 2 * slot_bytes` must be valid, writable memory used by nothing else.
    pub const unsafe fn new(base: *mut u8, slot_bytes: usize) -> Self {
        Self { base, slot_bytes }
    }

    fn check(&self, offset: usize, len: usize) -> Result<(), ConfigError> {
        if offset + len > self.slot_bytes {
            return Err(ConfigError::TooLarge { needed: offset + len });
        }
        Ok(())
    }
}

impl RecordMedium for MemoryMedium {
    fn slot_bytes(&self) -> usize {
        self.slot_bytes
    }

    fn read(&mut self, slot: usize, offset: usize, buf: &mut [u8]) -> Result<(), ConfigError> {
        self.check(offset, buf.len())?;
        let at = slot * self.slot_bytes + offset;
        for (i, b) in buf.iter_mut().enumerate() {
            // SAFETY: in bounds by `check` and the constructor's contract.
            *b = unsafe { self.base.add(at + i).read_volatile() };
        }
        Ok(())
    }

    fn erase(&mut self, slot: usize) -> Result<(), ConfigError> {
        // Only the header decides validity: invalidating it is the erase.
        self.program(slot, 0, &[0xFF; HEADER_BYTES])
    }

    fn program(&mut self, slot: usize, offset: usize, data: &[u8]) -> Result<(), ConfigError> {
        self.check(offset, data.len())?;
        let at = slot * self.slot_bytes + offset;
        for (i, b) in data.iter().enumerate() {
            // SAFETY: in bounds by `check` and the constructor's contract.
            unsafe { self.base.add(at + i).write_volatile(*b) };
        }
        core::sync::atomic::fence(core::sync::atomic::Ordering::SeqCst);
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn store(mem: &mut [u8]) -> AbStore<MemoryMedium> {
        AbStore::new(unsafe { MemoryMedium::new(mem.as_mut_ptr(), mem.len() / 2) })
    }

    #[test]
    fn empty_then_round_trip_then_newest_wins() {
        let mut mem = vec![0u8; 512];
        let mut s = store(&mut mem);
        let mut buf = [0u8; 256];
        assert_eq!(s.read(&mut buf), Err(ConfigError::Empty));
        s.write(b"first").unwrap();
        assert_eq!(s.read(&mut buf), Ok(5));
        assert_eq!(&buf[..5], b"first");
        s.write(b"second!").unwrap();
        s.write(b"third").unwrap();
        assert_eq!(s.read(&mut buf), Ok(5));
        assert_eq!(&buf[..5], b"third");
        assert_eq!(s.write(&[0; 300]), Err(ConfigError::TooLarge { needed: 300 }));
    }

    #[test]
    fn a_torn_write_keeps_the_previous_blob() {
        let mut mem = vec![0u8; 512];
        {
            let mut s = store(&mut mem);
            s.write(b"good").unwrap();
            s.write(b"newer").unwrap();
        }
        // Corrupt one blob byte of the newest record (slot 1): its CRC fails.
        mem[256 + HEADER_BYTES] ^= 0x55;
        let mut s = store(&mut mem);
        let mut buf = [0u8; 64];
        assert_eq!(s.read(&mut buf), Ok(4));
        assert_eq!(&buf[..4], b"good");
    }

    #[test]
    fn a_store_with_no_intact_copy_is_corrupt_not_empty() {
        let mut mem = vec![0u8; 512];
        {
            let mut s = store(&mut mem);
            s.write(b"only").unwrap();
        }
        mem[HEADER_BYTES] ^= 0x01;
        let mut s = store(&mut mem);
        let mut buf = [0u8; 64];
        assert_eq!(s.read(&mut buf), Err(ConfigError::Corrupt));
        // A new write repairs it.
        s.write(b"again").unwrap();
        assert_eq!(s.read(&mut buf), Ok(5));
    }
}
