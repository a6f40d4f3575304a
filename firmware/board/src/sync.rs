//! Sharing between the servo interrupt, the control-link interrupts and the background
//! context, without a heap and without blocking the servo for more than a few instructions.

use core::cell::{RefCell, UnsafeCell};
use core::future::poll_fn;
use core::mem::MaybeUninit;
use core::sync::atomic::{AtomicU32, AtomicUsize, Ordering};
use core::task::Poll;

use critical_section::Mutex;
use embassy_sync::waitqueue::AtomicWaker;

/// A static initialised once at boot, before the interrupts that use it are enabled: the
/// contexts' own state (servo, background), too large or too hot for a [`SharedCell`].
pub struct BootCell<T>(UnsafeCell<MaybeUninit<T>>);

// SAFETY: written once in `main` before any interrupt that reads it is unmasked; afterwards
// each cell is used by one context only (documented at each static).
unsafe impl<T> Sync for BootCell<T> {}

impl<T> BootCell<T> {
    /// An empty cell, for a `static`.
    pub const fn new() -> Self {
        Self(UnsafeCell::new(MaybeUninit::uninit()))
    }

    /// Stores the value and returns it.
    ///
    /// # Safety
    /// Call once, before any reader runs.
    #[allow(clippy::mut_from_ref)]
    pub unsafe fn init(&self, value: T) -> &mut T {
        unsafe { (*self.0.get()).write(value) }
    }

    /// The value.
    ///
    /// # Safety
    /// After `init`, and from the one context that owns the cell (or shared-only use).
    #[allow(clippy::mut_from_ref)]
    pub unsafe fn get(&self) -> &mut T {
        unsafe { (*self.0.get()).assume_init_mut() }
    }
}

impl<T> Default for BootCell<T> {
    fn default() -> Self {
        Self::new()
    }
}

/// State shared between the servo tick and the background context. Access happens inside
/// a critical section, so keep each access short (copy values in or out, don't compute).
pub struct SharedCell<T> {
    inner: Mutex<RefCell<T>>,
}

impl<T> SharedCell<T> {
    /// A cell holding `value`.
    pub const fn new(value: T) -> Self {
        Self { inner: Mutex::new(RefCell::new(value)) }
    }

    /// Runs `f` on the shared value inside a critical section.
    #[inline(always)]
    pub fn with<R>(&self, f: impl FnOnce(&mut T) -> R) -> R {
        critical_section::with(|cs| f(&mut self.inner.borrow_ref_mut(cs)))
    }
}

/// Bytes the slice operations of a [`ByteQueue`] move per critical section: a byte costs the
/// servo tick's start some ten instructions, a frame of a few hundred bytes in one section
/// over a thousand.
pub const SLICE_CHUNK: usize = 16;

/// A bounded byte queue between an interrupt (one side) and the background (other side).
/// Each operation is a short critical section.
pub struct ByteQueue<const N: usize> {
    inner: Mutex<RefCell<Ring<N>>>,
    dropped: AtomicUsize,
}

struct Ring<const N: usize> {
    buf: [u8; N],
    head: usize,
    len: usize,
}

impl<const N: usize> ByteQueue<N> {
    /// An empty queue.
    pub const fn new() -> Self {
        Self { inner: Mutex::new(RefCell::new(Ring { buf: [0; N], head: 0, len: 0 })), dropped: AtomicUsize::new(0) }
    }

    /// Appends one byte; when full the byte is dropped and counted.
    pub fn push(&self, byte: u8) -> bool {
        let ok = critical_section::with(|cs| {
            let mut r = self.inner.borrow_ref_mut(cs);
            if r.len == N {
                return false;
            }
            let at = (r.head + r.len) % N;
            r.buf[at] = byte;
            r.len += 1;
            true
        });
        if !ok {
            self.dropped.fetch_add(1, Ordering::Relaxed);
        }
        ok
    }

    /// Appends as many of `bytes` as fit, returning how many; [`SLICE_CHUNK`] bytes per
    /// critical section.
    pub fn push_slice(&self, bytes: &[u8]) -> usize {
        let mut pushed = 0;
        for chunk in bytes.chunks(SLICE_CHUNK) {
            let n = critical_section::with(|cs| {
                let mut r = self.inner.borrow_ref_mut(cs);
                let n = chunk.len().min(N - r.len);
                for &b in &chunk[..n] {
                    let at = (r.head + r.len) % N;
                    r.buf[at] = b;
                    r.len += 1;
                }
                n
            });
            pushed += n;
            if n < chunk.len() {
                break;
            }
        }
        pushed
    }

    /// Removes the oldest byte.
    pub fn pop(&self) -> Option<u8> {
        critical_section::with(|cs| {
            let mut r = self.inner.borrow_ref_mut(cs);
            if r.len == 0 {
                return None;
            }
            let b = r.buf[r.head];
            r.head = (r.head + 1) % N;
            r.len -= 1;
            Some(b)
        })
    }

    /// Moves up to `out.len()` of the oldest bytes into `out`, returning how many;
    /// [`SLICE_CHUNK`] bytes per critical section.
    pub fn pop_slice(&self, out: &mut [u8]) -> usize {
        let mut popped = 0;
        for chunk in out.chunks_mut(SLICE_CHUNK) {
            let n = critical_section::with(|cs| {
                let mut r = self.inner.borrow_ref_mut(cs);
                let n = chunk.len().min(r.len);
                for o in &mut chunk[..n] {
                    *o = r.buf[r.head];
                    r.head = (r.head + 1) % N;
                }
                r.len -= n;
                n
            });
            popped += n;
            if n < chunk.len() {
                break;
            }
        }
        popped
    }

    /// True when nothing is queued.
    pub fn is_empty(&self) -> bool {
        critical_section::with(|cs| self.inner.borrow_ref(cs).len == 0)
    }

    /// Bytes dropped because the queue was full.
    pub fn dropped(&self) -> usize {
        self.dropped.load(Ordering::Relaxed)
    }
}

impl<const N: usize> Default for ByteQueue<N> {
    fn default() -> Self {
        Self::new()
    }
}

/// Event bits raised from interrupts and awaited by one background task.
pub struct Events {
    bits: AtomicU32,
    waker: AtomicWaker,
    /// Pends the interrupt of the executor that runs the waiting task: given, the servo
    /// tick's raise leaves waking the task to that interrupt ([`Events::wake_deferred`]).
    pend_executor: Option<fn()>,
}

impl Events {
    /// No event pending.
    pub const fn new() -> Self {
        Self { bits: AtomicU32::new(0), waker: AtomicWaker::new(), pend_executor: None }
    }

    /// No event pending; [`Events::raise_from_tick`] only sets the bits and calls
    /// `pend_executor` (which pends the interrupt of the executor running the waiting task),
    /// and that interrupt wakes the task ([`Events::wake_deferred`]). Waking a task from the
    /// servo tick itself costs it some 50 instructions (a critical section and the
    /// executor's run queue).
    pub const fn with_deferred_wake(pend_executor: fn()) -> Self {
        Self { bits: AtomicU32::new(0), waker: AtomicWaker::new(), pend_executor: Some(pend_executor) }
    }

    /// Raises `bits` and wakes the waiting task. Callable from any interrupt.
    #[inline(always)]
    pub fn raise(&self, bits: u32) {
        self.bits.fetch_or(bits, Ordering::Release);
        self.waker.wake();
    }

    /// Raises `bits` from the servo tick: as [`Events::raise`], or, with a deferred wake,
    /// only the bits and the executor's interrupt.
    #[inline(always)]
    pub fn raise_from_tick(&self, bits: u32) {
        match self.pend_executor {
            Some(pend) => {
                self.bits.fetch_or(bits, Ordering::Release);
                pend();
            }
            None => self.raise(bits),
        }
    }

    /// Wakes the waiting task if bits are pending: call it from the executor's interrupt,
    /// before the executor polls, when the events defer their wake.
    pub fn wake_deferred(&self) {
        if self.bits.load(Ordering::Acquire) != 0 {
            self.waker.wake();
        }
    }

    /// Takes the pending bits without waiting (0 when none).
    pub fn take(&self) -> u32 {
        self.bits.swap(0, Ordering::Acquire)
    }

    /// Waits until some bit is raised, then takes all pending bits.
    pub async fn wait(&self) -> u32 {
        poll_fn(|cx| {
            let bits = self.take();
            if bits != 0 {
                return Poll::Ready(bits);
            }
            self.waker.register(cx.waker());
            let bits = self.take();
            if bits != 0 {
                Poll::Ready(bits)
            } else {
                Poll::Pending
            }
        })
        .await
    }
}

impl Default for Events {
    fn default() -> Self {
        Self::new()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn byte_queue_is_fifo_and_counts_drops() {
        let q: ByteQueue<4> = ByteQueue::new();
        assert_eq!(q.push_slice(b"abc"), 3);
        assert!(q.push(b'd'));
        assert!(!q.push(b'e'));
        assert_eq!(q.dropped(), 1);
        assert_eq!(q.pop(), Some(b'a'));
        assert!(q.push(b'f'));
        let mut out = [0u8; 8];
        assert_eq!(q.pop_slice(&mut out), 4);
        assert_eq!(&out[..4], b"bcdf");
        assert!(q.is_empty());
    }

    #[test]
    fn slices_longer_than_a_chunk_keep_their_order_and_stop_when_full() {
        let q: ByteQueue<40> = ByteQueue::new();
        let bytes: std::vec::Vec<u8> = (0..50).collect();
        assert_eq!(q.push_slice(&bytes[..3]), 3);
        assert_eq!(q.pop_slice(&mut [0u8; 3]), 3);
        // 40 fit (the ring wraps), the rest is refused.
        assert_eq!(q.push_slice(&bytes), 40);
        let mut out = [0u8; 50];
        assert_eq!(q.pop_slice(&mut out[..17]), 17);
        assert_eq!(q.pop_slice(&mut out[17..]), 23);
        assert_eq!(&out[..40], &bytes[..40]);
        assert!(q.is_empty());
    }

    #[test]
    fn deferred_events_pend_the_executor_and_wake_from_it() {
        use core::sync::atomic::AtomicU32;
        static PENDED: AtomicU32 = AtomicU32::new(0);
        fn pend() {
            PENDED.fetch_add(1, Ordering::Relaxed);
        }
        let e = Events::with_deferred_wake(pend);
        e.raise_from_tick(2);
        e.raise_from_tick(8);
        assert_eq!(PENDED.load(Ordering::Relaxed), 2);
        e.wake_deferred();
        assert_eq!(e.take(), 10);
        let plain = Events::new();
        plain.raise_from_tick(1);
        assert_eq!(plain.take(), 1);
    }

    #[test]
    fn events_accumulate_until_taken() {
        let e = Events::new();
        e.raise(1);
        e.raise(4);
        assert_eq!(e.take(), 5);
        assert_eq!(e.take(), 0);
    }
}
