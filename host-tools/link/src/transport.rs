//! The byte pipe under the control protocol. Framing (COBS + CRC) and sequencing belong to
//! [`crate::Board`], not to the transport.

use std::io;
use std::time::Duration;

/// A bidirectional byte pipe to a co-processor: a serial port, or a test double.
pub trait Transport {
    /// What the user knows it by, for error messages: "serial port /dev/ttyACM0 at 115200
    /// baud".
    fn describe(&self) -> String;
    /// Bytes per second the line carries, when it is that slow that transfers count in the
    /// timeouts (a serial line); `None` for a fast one.
    fn bytes_per_second(&self) -> Option<f64>;
    /// Sends all of `bytes`.
    fn write_all(&mut self, bytes: &[u8]) -> io::Result<()>;
    /// Reads what arrives within `timeout` into `buf`: `Ok(0)` when nothing came.
    fn read(&mut self, buf: &mut [u8], timeout: Duration) -> io::Result<usize>;
}
