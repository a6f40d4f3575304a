//! A lossy control link for fault tests, and the host's retries over it.
//!
//! [`LossyHilCoprocessor`] wraps the firmware in QEMU: every control frame, on the way in
//! and on the way out, is delivered, dropped or corrupted (one bit flipped, never creating
//! or removing a frame delimiter) as a seeded [`FrameInjector`] decides. Requests are sent
//! with [`RetryPolicy`]: an answer that does not come in time (dropped, corrupted, or just
//! slow) is asked for again with a new sequence number, and answers to earlier attempts are
//! ignored, so every request is carried out and answered despite the losses. Requests of
//! the control protocol are idempotent (setting a value twice is setting it once), which
//! makes retrying safe even when only the answer was lost.

use std::time::Duration;

use sts_twin_core::bus::{InputSlot, OutputSlot};
use sts_twin_core::wire::{encode_frame, FrameDecoder, Request, Response, MAX_ENCODED_FRAME};

use super::{Coprocessor, HilCoprocessor, RigError};
use sts_hil::{Hil, HilError};
use sts_link::{FrameFate, FrameInjector, InjectedFaults, LinkFaults, LinkStats, RetryPolicy};

/// The firmware in QEMU behind a lossy control link: every control frame, in and out, is
/// delivered, dropped or corrupted as a seeded [`FrameInjector`] decides, and requests are
/// sent with a [`RetryPolicy`] (a new sequence number per attempt, late answers ignored), so
/// every request is carried out and answered despite the losses.
pub struct LossyHilCoprocessor {
    inner: HilCoprocessor,
    inbound: FrameInjector,
    outbound: FrameInjector,
    policy: RetryPolicy,
    seq: u16,
    stats: LinkStats,
}

impl LossyHilCoprocessor {
    /// Wraps `inner`: requests lose frames at `inbound` rates, answers at `outbound` rates,
    /// the two directions seeded from `seed`.
    pub fn new(
        inner: HilCoprocessor,
        inbound: LinkFaults,
        outbound: LinkFaults,
        seed: u64,
        policy: RetryPolicy,
    ) -> Self {
        Self {
            inner,
            inbound: FrameInjector::new(inbound, seed),
            outbound: FrameInjector::new(outbound, seed ^ 0x6F75_7462_6F75_6E64),
            policy,
            // Away from the sequence numbers a plain HilCoprocessor starts with.
            seq: 0x8000,
            stats: LinkStats::default(),
        }
    }

    /// The faults injected into requests (host to firmware).
    pub fn inbound(&self) -> InjectedFaults {
        self.inbound.counts()
    }

    /// The faults injected into answers (firmware to host).
    pub fn outbound(&self) -> InjectedFaults {
        self.outbound.counts()
    }

    /// What the host saw.
    pub fn stats(&self) -> LinkStats {
        self.stats
    }

    /// The harness.
    pub fn hil(&mut self) -> &mut Hil {
        self.inner.hil()
    }

    /// The wrapped co-processor (its requests bypass the lossy link).
    pub fn inner(&mut self) -> &mut HilCoprocessor {
        &mut self.inner
    }

    /// Ends QEMU.
    pub fn shutdown(self) -> Result<(), RigError> {
        self.inner.shutdown()
    }

    /// One attempt: `Some(answer)` or `None` when none came within `timeout`.
    fn attempt(&mut self, request: &Request, timeout: Duration) -> Result<Option<Response>, RigError> {
        self.seq = self.seq.wrapping_add(1);
        let seq = self.seq;
        let mut frame = [0u8; MAX_ENCODED_FRAME + 1];
        // A leading delimiter resynchronises the firmware's decoder after a damaged frame.
        let len = encode_frame(seq, request, &mut frame[1..])
            .map_err(|error| RigError::Encode { request: Box::new(request.clone()), error })?;
        let wire: &[u8] = match self.inbound.pass(&mut frame[1..len]) {
            FrameFate::Dropped => &[],
            FrameFate::Delivered | FrameFate::Corrupted => &frame[..len + 1],
        };
        let outbound = &mut self.outbound;
        let stats = &mut self.stats;
        let mut answer = None;
        let mut judged = 0;
        let mut decoder = FrameDecoder::<Response>::new();
        let result = self.inner.hil().transact(wire, timeout, |bytes| {
            // Each complete frame that arrived passes the lossy link once.
            while let Some(end) = bytes[judged..].iter().position(|&b| b == 0) {
                let mut received = bytes[judged..judged + end].to_vec();
                judged += end + 1;
                if received.is_empty() || outbound.pass(&mut received) == FrameFate::Dropped {
                    continue;
                }
                received.push(0);
                for &b in &received {
                    match decoder.push(b) {
                        Some(Ok(envelope)) if envelope.seq == seq => answer = Some(envelope.body),
                        Some(Ok(_)) => stats.stale_answers += 1,
                        Some(Err(_)) => stats.bad_answers += 1,
                        None => {}
                    }
                }
            }
            answer.is_some()
        });
        match result {
            Ok(_) => Ok(answer),
            Err(HilError::Timeout { .. }) => {
                // Whatever half-frame is left belongs to an abandoned attempt.
                self.inner.hil().link().drain()?;
                Ok(None)
            }
            Err(e) => Err(e.into()),
        }
    }
}

impl Coprocessor for LossyHilCoprocessor {
    fn tick(&mut self, input: &InputSlot) -> Result<OutputSlot, RigError> {
        self.inner.tick(input)
    }

    fn request(&mut self, request: Request) -> Result<Response, RigError> {
        let mut timeout = self.policy.first_timeout;
        for attempt in 1..=self.policy.attempts {
            self.stats.attempts += 1;
            if let Some(answer) = self.attempt(&request, timeout)? {
                self.stats.requests += 1;
                self.stats.max_attempts = self.stats.max_attempts.max(attempt);
                return Ok(answer);
            }
            timeout = (timeout * 2).min(self.policy.max_timeout);
        }
        Err(RigError::NoAnswerLossy { request: Box::new(request), attempts: self.policy.attempts })
    }

    fn kind(&self) -> &'static str {
        "hil"
    }
}
