//! A serial port as the control link (the `serialport` crate): the board's UART through a
//! USB virtual COM port (the NUCLEO-H743ZI's ST-LINK), a USB-serial adapter, or QEMU's UART as
//! a pseudo-terminal (`-serial pty`) in CI.

use std::io::{self, Read, Write};
use std::time::Duration;

use serialport::{ClearBuffer, SerialPort, TTYPort};

use super::{LinkError, Transport};

/// The control link's default baud rate (the firmware's USART3: 115200 8N1).
pub const DEFAULT_BAUD: u32 = 115_200;

/// An open serial port, held exclusively (a second opener gets [`LinkError::Busy`]).
pub struct SerialLink {
    port: TTYPort,
    path: String,
    baud: u32,
}

impl SerialLink {
    /// Opens `path` at `baud`, 8N1, no flow control, and discards whatever was waiting in
    /// its buffers.
    pub fn open(path: &str, baud: u32) -> Result<Self, LinkError> {
        if !std::path::Path::new(path).exists() {
            return Err(LinkError::Missing { port: path.to_string() });
        }
        let port = serialport::new(path, baud)
            .data_bits(serialport::DataBits::Eight)
            .parity(serialport::Parity::None)
            .stop_bits(serialport::StopBits::One)
            .flow_control(serialport::FlowControl::None)
            .timeout(Duration::from_millis(10))
            .open_native()
            .map_err(|e| open_error(path, e))?;
        port.clear(ClearBuffer::All).map_err(|e| open_error(path, e))?;
        Ok(Self { port, path: path.to_string(), baud })
    }

    /// The port's path.
    pub fn path(&self) -> &str {
        &self.path
    }
}

fn open_error(path: &str, error: serialport::Error) -> LinkError {
    let port = path.to_string();
    match error.kind() {
        serialport::ErrorKind::Io(io::ErrorKind::NotFound) => LinkError::Missing { port },
        serialport::ErrorKind::Io(io::ErrorKind::PermissionDenied) => LinkError::Permission { port },
        // serialport reports a port another process holds (TIOCEXCL, flock) as NoDevice.
        serialport::ErrorKind::NoDevice => LinkError::Busy { port, detail: error.description },
        _ => LinkError::Open { port, detail: error.to_string() },
    }
}

impl Transport for SerialLink {
    fn describe(&self) -> String {
        format!("serial port {} at {} baud", self.path, self.baud)
    }

    fn bytes_per_second(&self) -> Option<f64> {
        // 8N1: ten bit times a byte.
        Some(f64::from(self.baud) / 10.0)
    }

    fn write_all(&mut self, bytes: &[u8]) -> io::Result<()> {
        self.port.write_all(bytes)?;
        self.port.flush()
    }

    fn read(&mut self, buf: &mut [u8], timeout: Duration) -> io::Result<usize> {
        self.port.set_timeout(timeout.max(Duration::from_millis(1)))?;
        match self.port.read(buf) {
            Ok(n) => Ok(n),
            Err(e) if matches!(e.kind(), io::ErrorKind::TimedOut | io::ErrorKind::WouldBlock) => Ok(0),
            Err(e) => Err(e),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_way_a_port_fails_to_open_gets_its_own_error_naming_the_port() {
        use serialport::{Error, ErrorKind};
        let cases = [
            (ErrorKind::Io(io::ErrorKind::NotFound), "no such serial port"),
            (ErrorKind::Io(io::ErrorKind::PermissionDenied), "no permission"),
            (ErrorKind::NoDevice, "the port is busy"),
            (ErrorKind::InvalidInput, "cannot open the port"),
        ];
        for (kind, says) in cases {
            let err = open_error("/dev/ttyACM7", Error::new(kind, "as the OS said"));
            let text = err.to_string();
            assert!(text.starts_with("/dev/ttyACM7: ") && text.contains(says), "{text}");
        }
        let missing = SerialLink::open("/dev/sts-twin-no-such-port", DEFAULT_BAUD).err().unwrap();
        assert!(matches!(missing, LinkError::Missing { .. }), "{missing}");
    }
}
