//! What can go wrong on the control link, each error naming the port.

/// An error of the control link. Every variant names the port (or the transport's
/// description) and says what to do where there is something to do.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum LinkError {
    /// The port does not exist.
    #[error("{port}: no such serial port (is the board plugged in and powered? `ls /dev/ttyACM* /dev/ttyUSB*` lists the candidates)")]
    Missing {
        /// The port's path.
        port: String,
    },
    /// Another process holds the port.
    #[error("{port}: the port is busy: another program has it open (a terminal, another sts-twin, ModemManager); close it and retry ({detail})")]
    Busy {
        /// The port's path.
        port: String,
        /// The operating system's words.
        detail: String,
    },
    /// No permission to open the port.
    #[error("{port}: no permission to open the port: add your user to the group that owns it (`ls -l {port}`; often `sudo usermod -aG dialout $USER`) and log in again")]
    Permission {
        /// The port's path.
        port: String,
    },
    /// The port could not be opened for another reason.
    #[error("{port}: cannot open the port: {detail}")]
    Open {
        /// The port's path.
        port: String,
        /// The operating system's words.
        detail: String,
    },
    /// Reading or writing failed after the port was open (unplugged, for instance).
    #[error("{port}: {what} failed: {source}")]
    Io {
        /// The transport's description.
        port: String,
        /// "sending" or "receiving".
        what: &'static str,
        /// The operating system's error.
        source: std::io::Error,
    },
    /// The board did not answer in time, however often asked.
    #[error("{port}: no answer to {request} after {attempts} attempts over {seconds:.1} s: is the sts-twin firmware running on the board (not the bring-up app, not a debugger halt), and at this baud rate?")]
    NoAnswer {
        /// The transport's description.
        port: String,
        /// The request, by name.
        request: &'static str,
        /// Attempts made.
        attempts: u32,
        /// Time spent.
        seconds: f64,
    },
    /// The firmware speaks another version of the control protocol.
    #[error("{port}: the firmware speaks control protocol version {found}, this sts-twin speaks version {expected}: flash the firmware of this sts-twin release (README \"Flashing a real board\") or use the sts-twin of the firmware's release")]
    Version {
        /// The transport's description.
        port: String,
        /// The firmware's version.
        found: u16,
        /// This host's version.
        expected: u16,
    },
    /// Intact frames came back that do not decode as this protocol's answers.
    #[error("{port}: the board answers with {frames} intact frames that are not answers of control protocol version {expected}: a firmware of another protocol version (flash the firmware of this sts-twin release)")]
    Undecodable {
        /// The transport's description.
        port: String,
        /// Frames that passed their CRC but did not decode.
        frames: u64,
        /// This host's version.
        expected: u16,
    },
    /// The request could not be encoded (too large for a frame).
    #[error("{port}: cannot send {request}: {detail}")]
    Encode {
        /// The transport's description.
        port: String,
        /// The request, by name.
        request: &'static str,
        /// Why.
        detail: String,
    },
    /// The board answered, but not as the protocol says it should.
    #[error("{port}: {request} was answered with {answer}")]
    Unexpected {
        /// The transport's description.
        port: String,
        /// The request, by name.
        request: &'static str,
        /// The answer, in debug form.
        answer: String,
    },
}
