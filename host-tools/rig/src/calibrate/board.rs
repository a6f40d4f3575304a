//! The co-processor as a board that can be power-cycled with its config store kept: the
//! calibration reboots it to check that what it stored is what the firmware loads.

use sts_twin_core::bus::{InputSlot, OutputSlot};
use sts_twin_core::wire::{Request, Response};

use crate::{request_on, Coprocessor, RigError, SimCoprocessor};
use sts_hil::{Hil, HilConfig};

/// A [`Coprocessor`] that can be rebooted, keeping its persistent config store.
pub trait Board: Coprocessor {
    /// Power-cycles the co-processor: it boots again from its config store (tick count,
    /// program and settings not in the store are lost).
    fn reboot(&mut self) -> Result<(), RigError>;
    /// The board as a plain co-processor.
    fn coprocessor(&mut self) -> &mut dyn Coprocessor;
}

impl Board for SimCoprocessor {
    fn reboot(&mut self) -> Result<(), RigError> {
        let stored = self.twin().stored_config().to_vec();
        *self = SimCoprocessor::boot(&stored);
        Ok(())
    }

    fn coprocessor(&mut self) -> &mut dyn Coprocessor {
        self
    }
}

/// The firmware in QEMU, rebootable on the same bus file (whose config store survives).
pub struct HilBoard {
    hil: Option<Hil>,
    seq: u16,
}

impl HilBoard {
    /// Boots the firmware (building it if needed). With `config.bus_path` the board's memory
    /// (and its config store) is that named file, kept after the run.
    pub fn start(config: HilConfig) -> Result<Self, RigError> {
        let hil = Hil::start(config).map_err(RigError::Start)?;
        Ok(Self { hil: Some(hil), seq: 0 })
    }

    /// The harness (for logs, counters and the bus file).
    pub fn hil(&mut self) -> Result<&mut Hil, RigError> {
        self.hil.as_mut().ok_or(RigError::NotRunning { reason: "a reboot failed" })
    }

    /// Ends QEMU.
    pub fn shutdown(mut self) -> Result<(), RigError> {
        if let Some(hil) = self.hil.take() {
            hil.shutdown().map_err(RigError::Stop)?;
        }
        Ok(())
    }
}

impl Coprocessor for HilBoard {
    fn tick(&mut self, input: &InputSlot) -> Result<OutputSlot, RigError> {
        Ok(self.hil()?.step(*input)?)
    }

    fn request(&mut self, request: Request) -> Result<Response, RigError> {
        self.seq = self.seq.wrapping_add(1);
        let seq = self.seq;
        request_on(self.hil()?, seq, request)
    }

    fn kind(&self) -> &'static str {
        "hil"
    }
}

impl Board for HilBoard {
    fn reboot(&mut self) -> Result<(), RigError> {
        let hil = self.hil.take().ok_or(RigError::NotRunning { reason: "an earlier reboot failed" })?;
        // On failure the old QEMU is already gone and the new one is killed on drop.
        self.hil = Some(hil.reboot().map_err(RigError::Reboot)?);
        self.seq = 0;
        Ok(())
    }

    fn coprocessor(&mut self) -> &mut dyn Coprocessor {
        self
    }
}
