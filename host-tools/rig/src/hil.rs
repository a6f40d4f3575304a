//! The co-processor as the real firmware under QEMU: ticks over the analogue bus, requests
//! over the control link.

use std::time::Duration;

use sts_twin_core::bus::{InputSlot, OutputSlot};
use sts_twin_core::wire::{encode_frame, FrameDecoder, Request, Response, MAX_ENCODED_FRAME};

use super::{Coprocessor, RigError};
use sts_hil::{Hil, HilConfig};

/// How long a control request may take to be answered.
pub const REQUEST_TIMEOUT: Duration = Duration::from_secs(5);

/// The firmware in QEMU, attached through the HIL harness.
pub struct HilCoprocessor {
    hil: Hil,
    seq: u16,
}

impl HilCoprocessor {
    /// Boots the firmware (building it if needed).
    pub fn start(config: HilConfig) -> Result<Self, RigError> {
        let hil = Hil::start(config).map_err(RigError::Start)?;
        Ok(Self { hil, seq: 0 })
    }

    /// The harness, for logs and counters.
    pub fn hil(&mut self) -> &mut Hil {
        &mut self.hil
    }

    /// Ends QEMU.
    pub fn shutdown(self) -> Result<(), RigError> {
        self.hil.shutdown()?;
        Ok(())
    }

    /// Sends raw bytes on the control link and returns the first response frame that comes
    /// back, if any (for tests of corrupted frames).
    pub fn exchange_raw(&mut self, bytes: &[u8], timeout: Duration) -> Result<Vec<u8>, RigError> {
        Ok(self.hil.transact(bytes, timeout, |reply| reply.contains(&0))?)
    }
}

impl Coprocessor for HilCoprocessor {
    fn tick(&mut self, input: &InputSlot) -> Result<OutputSlot, RigError> {
        Ok(self.hil.step(*input)?)
    }

    fn request(&mut self, request: Request) -> Result<Response, RigError> {
        self.seq = self.seq.wrapping_add(1);
        request_on(&mut self.hil, self.seq, request)
    }

    fn kind(&self) -> &'static str {
        "hil"
    }
}

/// Sends `request` with sequence number `seq` over the firmware's control link (the bus
/// paused meanwhile) and returns its answer.
pub fn request_on(hil: &mut Hil, seq: u16, request: Request) -> Result<Response, RigError> {
    let mut frame = [0u8; MAX_ENCODED_FRAME + 1];
    // A leading delimiter resynchronises the firmware's decoder after any line noise.
    let len = encode_frame(seq, &request, &mut frame[1..])
        .map_err(|error| RigError::Encode { request: Box::new(request.clone()), error })?;
    let reply = hil.transact(&frame[..len + 1], REQUEST_TIMEOUT, |bytes| answered(bytes, seq))?;
    let mut decoder = FrameDecoder::<Response>::new();
    for &byte in &reply {
        if let Some(Ok(envelope)) = decoder.push(byte)
            && envelope.seq == seq
        {
            return Ok(envelope.body);
        }
    }
    Err(RigError::NoAnswer { request: Box::new(request), seq })
}

/// Whether `bytes` hold a well-formed response with sequence number `seq`.
fn answered(bytes: &[u8], seq: u16) -> bool {
    let mut decoder = FrameDecoder::<Response>::new();
    bytes.iter().any(|&b| matches!(decoder.push(b), Some(Ok(envelope)) if envelope.seq == seq))
}
