//! The recent ticks' command positions, handed from the servo tick to the low-priority side
//! without a lock: the axis twin's compensator ([`crate::axis::compensate`]) simulates the
//! axis on them there, so that the tick itself only stores them.
//!
//! A ring of atomics, so it is `Sync`, needs no `unsafe` and can live in a `static`. Each
//! slot carries the tick it was written for: the writer stores the tick, then the position;
//! a reader takes a slot only if it names the tick asked for before and after the position
//! is read, so a slot never written, written for another tick, or overwritten during the read
//! is refused rather than misread.
//!
//! ```
//! use sts_twin_core::commands::CommandRing;
//! let ring = CommandRing::<4>::new();
//! for tick in 0..6u32 {
//!     ring.push(tick, 100 * tick as i32);
//! }
//! assert_eq!(ring.get(5), Some(500));
//! assert_eq!(ring.get(2), Some(200));
//! assert_eq!(ring.get(1), None, "overwritten by tick 5");
//! assert_eq!(ring.get(6), None, "not written yet");
//! ```

use core::sync::atomic::{compiler_fence, fence, AtomicI32, AtomicU32, Ordering};

/// Ticks the firmware's ring holds: 256 ms at 8 kHz, far beyond a model interval.
pub const COMMAND_RING_TICKS: usize = 2048;

/// The ring of the firmware's size.
pub type DefaultCommandRing = CommandRing<COMMAND_RING_TICKS>;

/// Command positions of the last `TICKS` ticks written (`TICKS` a power of two). Memory:
/// `8 * TICKS` bytes.
#[derive(Debug)]
pub struct CommandRing<const TICKS: usize> {
    /// The tick each slot was last written for (`u32::MAX` before the first write).
    tick: [AtomicU32; TICKS],
    /// The command position of that tick, nm.
    pos_nm: [AtomicI32; TICKS],
}

impl<const TICKS: usize> Default for CommandRing<TICKS> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const TICKS: usize> CommandRing<TICKS> {
    const MASK: usize = {
        assert!(TICKS.is_power_of_two() && TICKS >= 2, "TICKS must be a power of two");
        TICKS - 1
    };

    /// An empty ring.
    #[allow(clippy::declare_interior_mutable_const)] // only to build the arrays
    pub const fn new() -> Self {
        const NEVER: AtomicU32 = AtomicU32::new(u32::MAX);
        const ZERO: AtomicI32 = AtomicI32::new(0);
        Self { tick: [NEVER; TICKS], pos_nm: [ZERO; TICKS] }
    }

    /// The servo tick: stores tick `tick`'s command position. Out of line: inlined, its
    /// registers made every program's tick dearer, those that store nothing too.
    #[inline(never)]
    pub fn push(&self, tick: u32, pos_nm: i32) {
        let i = tick as usize & Self::MASK;
        self.tick[i].store(tick, Ordering::Relaxed);
        // The reader runs on the same core at a lower priority: it sees the writer's stores
        // in program order, so ordering them in the compiler is enough (no barrier).
        compiler_fence(Ordering::Release);
        self.pos_nm[i].store(pos_nm, Ordering::Relaxed);
    }

    /// Tick `tick`'s command position, if its slot holds it.
    pub fn get(&self, tick: u32) -> Option<i32> {
        let i = tick as usize & Self::MASK;
        if self.tick[i].load(Ordering::Acquire) != tick {
            return None;
        }
        let pos_nm = self.pos_nm[i].load(Ordering::Relaxed);
        fence(Ordering::Acquire);
        (self.tick[i].load(Ordering::Relaxed) == tick).then_some(pos_nm)
    }
}
