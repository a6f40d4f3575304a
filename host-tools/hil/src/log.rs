//! The firmware's defmt logs: semihosting writes land on QEMU's stdout, decoded here
//! against the ELF's defmt table.

use std::io::Read;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

use super::HilError;

/// One decoded log line of the firmware.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct LogLine {
    /// `TRACE`, `DEBUG`, `INFO`, `WARN`, `ERROR`, or `PRINTLN` (no level).
    pub level: String,
    /// The defmt timestamp (the firmware stamps the served tick count).
    pub timestamp: String,
    /// The formatted message.
    pub message: String,
    /// `file:line` of the log statement, when known.
    pub location: Option<String>,
}

impl std::fmt::Display for LogLine {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{:5} [{}] {}", self.level, self.timestamp, self.message)?;
        if let Some(loc) = &self.location {
            write!(f, " ({loc})")?;
        }
        Ok(())
    }
}

/// Collected output of one QEMU run: decoded log lines and QEMU's stderr.
#[derive(Debug, Default)]
pub(crate) struct LogSink {
    pub(crate) lines: Vec<LogLine>,
    pub(crate) stderr: String,
    pub(crate) malformed_frames: usize,
    /// QEMU's own first line on stdout, before the defmt frames, when it has one to print
    /// ("char device redirected to /dev/pts/N (label serial0)" with `-serial pty`).
    pub(crate) banner: Option<String>,
}

pub(crate) type SharedLog = Arc<Mutex<LogSink>>;

/// The ELF's defmt table, parsed once, checked before QEMU starts.
pub(crate) fn check_table(elf: &Path) -> Result<(), HilError> {
    let bytes = std::fs::read(elf).map_err(|e| HilError::io(format!("reading {}", elf.display()), e))?;
    match defmt_decoder::Table::parse(&bytes) {
        Ok(Some(_)) => Ok(()),
        Ok(None) => Err(HilError::Defmt { path: elf.into(), reason: "no .defmt section".into() }),
        Err(e) => Err(HilError::Defmt { path: elf.into(), reason: e.to_string() }),
    }
}

/// Decodes `stdout` (defmt frames) into `sink` until QEMU closes it. When `echo` is set,
/// every line is also printed to stderr as it arrives. With `banner`, QEMU's first line of
/// text (which precedes the guest's frames) is taken out into [`LogSink::banner`] first.
pub(crate) fn spawn_decoder(
    elf: PathBuf,
    mut stdout: impl Read + Send + 'static,
    sink: SharedLog,
    echo: bool,
    banner: bool,
) {
    std::thread::Builder::new()
        .name("sts-hil-defmt".into())
        .spawn(move || {
            let Ok(bytes) = std::fs::read(&elf) else { return };
            let Ok(Some(table)) = defmt_decoder::Table::parse(&bytes) else { return };
            let locations = table.get_locations(&bytes).unwrap_or_default();
            let mut decoder = table.new_stream_decoder();
            let mut buf = [0u8; 4096];
            let mut head: Option<Vec<u8>> = banner.then(Vec::new);
            loop {
                let n = match stdout.read(&mut buf) {
                    Ok(0) | Err(_) => return,
                    Ok(n) => n,
                };
                match head.as_mut() {
                    Some(text) => {
                        text.extend_from_slice(&buf[..n]);
                        let Some(end) = text.iter().position(|&b| b == b'\n') else { continue };
                        let line = String::from_utf8_lossy(&text[..end]).trim().to_string();
                        decoder.received(&text[end + 1..]);
                        sink.lock().unwrap_or_else(|e| e.into_inner()).banner = Some(line);
                        head = None;
                    }
                    None => decoder.received(&buf[..n]),
                }
                // A malformed frame is dropped by the decoder; the bound only guards against
                // a decoder that would not make progress.
                for _ in 0..100_000 {
                    match decoder.decode() {
                        Ok(frame) => {
                            let location =
                                locations.get(&frame.index()).map(|l| format!("{}:{}", l.file.display(), l.line));
                            let line = LogLine {
                                level: frame
                                    .level()
                                    .map(|l| l.as_str().to_uppercase())
                                    .unwrap_or_else(|| "PRINTLN".into()),
                                timestamp: frame.display_timestamp().map(|t| t.to_string()).unwrap_or_default(),
                                message: frame.display_message().to_string(),
                                location,
                            };
                            if echo {
                                eprintln!("firmware: {line}");
                            }
                            sink.lock().unwrap_or_else(|e| e.into_inner()).lines.push(line);
                        }
                        Err(defmt_decoder::DecodeError::UnexpectedEof) => break,
                        Err(defmt_decoder::DecodeError::Malformed) => {
                            sink.lock().unwrap_or_else(|e| e.into_inner()).malformed_frames += 1;
                        }
                    }
                }
            }
        })
        .expect("spawning the defmt decoder thread");
}

/// Collects `stderr` (QEMU's own messages) into `sink`.
pub(crate) fn spawn_stderr_reader(mut stderr: impl Read + Send + 'static, sink: SharedLog) {
    std::thread::Builder::new()
        .name("sts-hil-stderr".into())
        .spawn(move || {
            let mut buf = [0u8; 1024];
            while let Ok(n) = stderr.read(&mut buf) {
                if n == 0 {
                    return;
                }
                sink.lock().unwrap_or_else(|e| e.into_inner()).stderr.push_str(&String::from_utf8_lossy(&buf[..n]));
            }
        })
        .expect("spawning the stderr reader thread");
}
