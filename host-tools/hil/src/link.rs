//! The control link: QEMU's UART0 as a loopback TCP socket, raw bytes with timeouts.
//! Framing (COBS + CRC) belongs to `sts_twin_core::wire`.

use std::io::{ErrorKind, Read, Write};
use std::net::{SocketAddr, TcpStream};
use std::time::{Duration, Instant};

use super::HilError;

/// The host end of the control link.
#[derive(Debug)]
pub struct ControlPort {
    stream: TcpStream,
    pending: Vec<u8>,
}

impl ControlPort {
    /// Connects to QEMU's serial server at `addr`, retrying until `timeout` (QEMU listens a
    /// moment after it starts).
    pub(crate) fn connect(
        addr: SocketAddr,
        timeout: Duration,
        alive: &mut dyn FnMut() -> Result<(), HilError>,
    ) -> Result<Self, HilError> {
        let deadline = Instant::now() + timeout;
        loop {
            match TcpStream::connect_timeout(&addr, Duration::from_millis(200)) {
                Ok(stream) => {
                    stream.set_nodelay(true).map_err(|e| HilError::io("setting TCP_NODELAY", e))?;
                    return Ok(Self { stream, pending: Vec::new() });
                }
                Err(e) if Instant::now() >= deadline => {
                    return Err(HilError::io(format!("connecting the control link to {addr}"), e));
                }
                Err(_) => {
                    alive()?;
                    std::thread::sleep(Duration::from_millis(5));
                }
            }
        }
    }

    /// Sends `bytes` (blocking until the socket took them all).
    pub fn send(&mut self, bytes: &[u8]) -> Result<(), HilError> {
        self.stream.set_write_timeout(Some(Duration::from_secs(10))).ok();
        self.stream.write_all(bytes).map_err(|e| HilError::io("sending on the control link", e))
    }

    /// Receives whatever arrives within `timeout` (at least one byte, unless the time runs
    /// out: then an empty vector).
    pub fn recv(&mut self, timeout: Duration) -> Result<Vec<u8>, HilError> {
        if !self.pending.is_empty() {
            return Ok(std::mem::take(&mut self.pending));
        }
        self.fill(timeout)?;
        Ok(std::mem::take(&mut self.pending))
    }

    /// Receives exactly `n` bytes, or fails after `timeout`.
    pub fn recv_exact(&mut self, n: usize, timeout: Duration) -> Result<Vec<u8>, HilError> {
        let deadline = Instant::now() + timeout;
        while self.pending.len() < n {
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return Err(HilError::Timeout {
                    what: format!("{n} bytes on the control link (got {})", self.pending.len()),
                    seconds: timeout.as_secs_f64(),
                });
            }
            self.fill(left)?;
        }
        let rest = self.pending.split_off(n);
        Ok(std::mem::replace(&mut self.pending, rest))
    }

    /// Receives until `done(bytes so far)` says the reply is complete, or fails after
    /// `timeout`. Returns everything received (bytes past the reply stay pending only if
    /// `done` stops early: it sees the whole buffer).
    pub fn recv_until(&mut self, timeout: Duration, mut done: impl FnMut(&[u8]) -> bool) -> Result<Vec<u8>, HilError> {
        let deadline = Instant::now() + timeout;
        while !done(&self.pending) {
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return Err(HilError::Timeout {
                    what: format!("a complete reply on the control link (got {} bytes)", self.pending.len()),
                    seconds: timeout.as_secs_f64(),
                });
            }
            self.fill(left)?;
        }
        Ok(std::mem::take(&mut self.pending))
    }

    /// Discards everything received so far.
    pub fn drain(&mut self) -> Result<(), HilError> {
        self.pending.clear();
        while !self.fill(Duration::from_millis(1))?.eq(&0) {}
        self.pending.clear();
        Ok(())
    }

    /// Reads what arrives within `timeout` into `pending`; returns how many bytes.
    fn fill(&mut self, timeout: Duration) -> Result<usize, HilError> {
        let mut buf = [0u8; 4096];
        self.stream.set_read_timeout(Some(timeout.max(Duration::from_millis(1)))).ok();
        match self.stream.read(&mut buf) {
            Ok(0) => Err(HilError::Protocol("QEMU closed the control link".into())),
            Ok(n) => {
                self.pending.extend_from_slice(&buf[..n]);
                Ok(n)
            }
            Err(e) if matches!(e.kind(), ErrorKind::WouldBlock | ErrorKind::TimedOut | ErrorKind::Interrupted) => Ok(0),
            Err(e) => Err(HilError::io("receiving on the control link", e)),
        }
    }
}
