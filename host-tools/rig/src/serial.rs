//! A board on a serial port as a [`Coprocessor`]: it answers control requests, and runs its
//! servo ticks on its own timer (a tick from the host is an error).

use sts_link::{Board, SerialLink};
use sts_twin_core::bus::{InputSlot, OutputSlot};
use sts_twin_core::wire::{Request, Response};

use super::{Coprocessor, RigError};

/// A co-processor board reached over a serial port.
pub struct SerialCoprocessor {
    board: Board<SerialLink>,
}

impl SerialCoprocessor {
    /// Wraps a connected board.
    pub fn new(board: Board<SerialLink>) -> Self {
        Self { board }
    }

    /// The link, for its description and statistics.
    pub fn board(&mut self) -> &mut Board<SerialLink> {
        &mut self.board
    }
}

impl Coprocessor for SerialCoprocessor {
    fn tick(&mut self, _input: &InputSlot) -> Result<OutputSlot, RigError> {
        Err(RigError::NotTickable { port: self.board.describe() })
    }

    fn request(&mut self, request: Request) -> Result<Response, RigError> {
        Ok(self.board.request(request)?)
    }

    fn kind(&self) -> &'static str {
        "board"
    }
}
