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

/// How often a frame is lost or damaged in one direction.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LinkFaults {
    /// Probability that a frame is dropped whole.
    pub drop_probability: f64,
    /// Probability that a frame arrives with one bit flipped.
    pub corrupt_probability: f64,
}

impl LinkFaults {
    /// 1% dropped and 0.1% corrupted frames.
    pub const TYPICAL: Self = Self { drop_probability: 0.01, corrupt_probability: 0.001 };
}

/// What happened to one frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FrameFate {
    /// Passed unchanged.
    Delivered,
    /// Never arrived.
    Dropped,
    /// Arrived with one bit flipped.
    Corrupted,
}

/// Counts of what an injector did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct InjectedFaults {
    /// Frames that passed.
    pub frames: u64,
    /// Frames dropped.
    pub dropped: u64,
    /// Frames corrupted.
    pub corrupted: u64,
}

/// Decides the fate of frames in one direction: seeded, so the same seed and the same
/// frames give the same fates.
#[derive(Clone, Debug)]
pub struct FrameInjector {
    faults: LinkFaults,
    rng: SplitMix64,
    counts: InjectedFaults,
}

impl FrameInjector {
    /// An injector with the given rates and seed.
    pub fn new(faults: LinkFaults, seed: u64) -> Self {
        Self { faults, rng: SplitMix64(seed), counts: InjectedFaults::default() }
    }

    /// Decides the fate of `frame` (the bytes of one frame without its delimiters) and,
    /// if corrupted, flips one bit of it in place such that no byte becomes 0x00.
    pub fn pass(&mut self, frame: &mut [u8]) -> FrameFate {
        self.counts.frames += 1;
        let draw = self.rng.unit();
        if draw < self.faults.drop_probability {
            self.counts.dropped += 1;
            return FrameFate::Dropped;
        }
        if draw < self.faults.drop_probability + self.faults.corrupt_probability && !frame.is_empty() {
            let at = (self.rng.next() % frame.len() as u64) as usize;
            let mut bit = (self.rng.next() % 8) as u32;
            // A flip that makes 0x00 would split the frame in two: take the next bit.
            if frame[at] ^ (1 << bit) == 0 {
                bit = (bit + 1) % 8;
            }
            frame[at] ^= 1 << bit;
            self.counts.corrupted += 1;
            return FrameFate::Corrupted;
        }
        FrameFate::Delivered
    }

    /// What this injector did so far.
    pub fn counts(&self) -> InjectedFaults {
        self.counts
    }
}

/// SplitMix64 (Steele, Lea, Flood 2014): a tiny seeded generator, enough for fault
/// decisions and fully deterministic.
#[derive(Clone, Debug)]
struct SplitMix64(u64);

impl SplitMix64 {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in [0, 1).
    fn unit(&mut self) -> f64 {
        (self.next() >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// How the host retries a control request whose answer does not come.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RetryPolicy {
    /// Wait for the first attempt's answer.
    pub first_timeout: Duration,
    /// Longest wait of any attempt (each retry doubles the wait up to this).
    pub max_timeout: Duration,
    /// Attempts before giving up.
    pub attempts: u32,
}

impl Default for RetryPolicy {
    fn default() -> Self {
        Self { first_timeout: Duration::from_millis(80), max_timeout: Duration::from_secs(2), attempts: 12 }
    }
}

/// What the host saw on the lossy link.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct LinkStats {
    /// Requests answered.
    pub requests: u64,
    /// Attempts sent (requests + retries).
    pub attempts: u64,
    /// Answer frames the host received but could not decode (corrupted on the way out).
    pub bad_answers: u64,
    /// Answers to earlier attempts that arrived late and were ignored.
    pub stale_answers: u64,
    /// The most attempts one request needed.
    pub max_attempts: u32,
}

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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fates_are_seeded_and_near_their_rates() {
        let faults = LinkFaults::TYPICAL;
        let run = |seed| {
            let mut injector = FrameInjector::new(faults, seed);
            let fates: Vec<FrameFate> = (0..200_000).map(|_| injector.pass(&mut [1, 2, 3])).collect();
            (fates, injector.counts())
        };
        let (a, counts) = run(5);
        assert_eq!(a, run(5).0, "same seed, same fates");
        assert_ne!(a, run(6).0);
        assert_eq!(counts.frames, 200_000);
        // 2,000 and 200 expected: within five standard deviations.
        assert!((counts.dropped as i64 - 2000).abs() < 5 * 45, "{counts:?}");
        assert!((counts.corrupted as i64 - 200).abs() < 5 * 15, "{counts:?}");
    }

    #[test]
    fn corruption_flips_one_bit_and_never_makes_a_delimiter() {
        let mut injector = FrameInjector::new(LinkFaults { drop_probability: 0.0, corrupt_probability: 1.0 }, 1);
        for k in 0..5000u32 {
            // Bytes with a single bit set are the ones a flip could zero.
            let original: Vec<u8> = (0..9).map(|i| 1u8 << ((k + i) % 8)).collect();
            let mut frame = original.clone();
            assert_eq!(injector.pass(&mut frame), FrameFate::Corrupted);
            let flipped: u32 = frame.iter().zip(&original).map(|(a, b)| (a ^ b).count_ones()).sum();
            assert_eq!(flipped, 1);
            assert!(frame.iter().all(|&b| b != 0));
        }
        // An empty frame cannot be corrupted.
        assert_eq!(injector.pass(&mut []), FrameFate::Delivered);
    }
}
