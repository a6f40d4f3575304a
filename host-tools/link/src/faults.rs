//! Seeded faults on a control link, for tests: each frame, in either direction, is
//! delivered, dropped or corrupted (one bit flipped, never creating or removing a frame
//! delimiter) as a [`FrameInjector`] decides. [`crate::Board::with_faults`] puts them on a
//! real port; `sts_rig::LossyHilCoprocessor` on QEMU's control link.

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
