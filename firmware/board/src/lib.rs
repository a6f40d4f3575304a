#![doc = include_str!("../README.md")]
#![cfg_attr(not(test), no_std)]
#![deny(missing_docs)]

pub mod bringup;
pub mod bus;
pub mod config;
pub mod qemu;
pub mod qemu_app;
pub mod servo;
pub mod sync;
pub mod twin;

pub use sts_twin_core::bus::{InputSlot, OutputSlot};

/// Why an [`AdcSource`] has no input for a tick.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum SampleError {
    /// The input did not arrive within the bounded wait: an underrun. The tick is retried.
    Late,
    /// The source is paused on purpose (e.g. the HIL host asked the firmware to stop
    /// waiting): no input this time, and no underrun either.
    Paused,
    /// The converter or interface reported a fault (board-specific code).
    Fault(u32),
}

impl core::fmt::Display for SampleError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::Late => write!(f, "the input did not arrive in time (underrun)"),
            Self::Paused => write!(f, "the input source is paused"),
            Self::Fault(code) => write!(f, "the converter or interface reported fault {code:#x}"),
        }
    }
}

impl core::error::Error for SampleError {}

/// The inputs of the servo: one accelerometer sample and the motion-controller interface
/// values per tick.
pub trait AdcSource {
    /// The inputs for servo tick `tick` (counted from 0 at boot, one per processed tick).
    ///
    /// May wait, but only for a bounded time: a source that has nothing returns
    /// [`SampleError::Late`] and the platform counts an underrun.
    fn sample(&mut self, tick: u32) -> Result<InputSlot, SampleError>;
}

/// The output of the servo: the DAC code (and, where the board has a way to report them,
/// the status bits and prediction of [`OutputSlot`]).
pub trait DacSink {
    /// Writes the output of one tick. Never blocks.
    fn write(&mut self, output: &OutputSlot);
}

/// The servo-rate interrupt source (8 kHz).
pub trait TickSource {
    /// Timer counts in one tick period.
    fn period_counts(&self) -> u32;
    /// Acknowledges the tick interrupt at the start of the handler.
    fn ack(&mut self);
    /// Called once the tick's input is in hand: boards whose input arrives after a variable
    /// wait (the QEMU bus) restart the period here so that the next tick comes one full
    /// period after the end of the wait; boards sampling on the tick itself do nothing.
    fn resync(&mut self);
    /// Timer counts elapsed since the period started (since [`TickSource::resync`] or the
    /// last tick edge): the busy time of the handler so far.
    fn elapsed_counts(&self) -> u32;
    /// At the end of the handler: true when the next tick is already due, i.e. the handler
    /// overran its period.
    fn overran(&mut self) -> bool;
}

/// Errors of a [`ConfigStore`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum ConfigError {
    /// Nothing is stored (fresh or erased storage).
    Empty,
    /// Something was stored but no copy of it is intact (bit rot, or every copy torn): the
    /// firmware boots on defaults and says so.
    Corrupt,
    /// The blob does not fit in the store (or in the caller's buffer on read): `needed` bytes.
    TooLarge {
        /// Bytes the operation needed.
        needed: usize,
    },
    /// The storage hardware reported an error (board-specific code).
    Hardware(u32),
}

impl core::fmt::Display for ConfigError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::Empty => write!(f, "nothing is stored"),
            Self::Corrupt => write!(f, "no intact copy of the stored blob"),
            Self::TooLarge { needed } => write!(f, "the blob needs {needed} bytes, more than there is room for"),
            Self::Hardware(code) => write!(f, "the storage hardware reported error {code:#x}"),
        }
    }
}

impl core::error::Error for ConfigError {}

/// Small persistent storage for one blob of bytes (settings and the active twin program).
/// A write replaces the whole blob; a write cut short (power loss, reset) leaves the
/// previous blob readable.
pub trait ConfigStore {
    /// The largest blob the store holds, in bytes.
    fn capacity(&self) -> usize;
    /// Reads the stored blob into `buf`, returning its length.
    fn read(&mut self, buf: &mut [u8]) -> Result<usize, ConfigError>;
    /// Replaces the stored blob with `blob`.
    fn write(&mut self, blob: &[u8]) -> Result<(), ConfigError>;
}

/// The control channel as a non-blocking byte pipe. Framing (COBS + CRC) is the core
/// library's `wire` module's business, not the link's.
pub trait ControlLink {
    /// Copies received bytes into `buf`, returning how many (0: nothing pending).
    fn read(&mut self, buf: &mut [u8]) -> usize;
    /// Queues `bytes` for sending, returning how many were accepted (fewer when the
    /// transmit buffer is full; the caller retries the rest later).
    fn write(&mut self, bytes: &[u8]) -> usize;
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn errors_say_what_went_wrong() {
        let errors: [(&dyn core::error::Error, &str); 3] = [
            (&SampleError::Fault(0x2a), "fault 0x2a"),
            (&ConfigError::TooLarge { needed: 300 }, "300 bytes"),
            (&ConfigError::Hardware(7), "error 0x7"),
        ];
        for (err, detail) in errors {
            assert!(err.to_string().contains(detail), "{err}");
            assert!(err.source().is_none());
        }
    }
}
