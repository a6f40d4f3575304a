//! The host side of the virtual analogue bus: the board's backing file, mapped.

use std::fs::{File, OpenOptions};
use std::os::fd::AsRawFd;
use std::path::{Path, PathBuf};
use std::sync::atomic::{fence, AtomicU32, AtomicU64, Ordering};

use memmap2::MmapRaw;
use sts_twin_board::qemu::{self as map, QemuBoard, DIAG_WORDS};
use sts_twin_core::bus::{self as layout, InputSlot, OutputSlot, OUTPUT_SLOT_WORDS};

use super::HilError;

/// The file behind the board's shared memory (the MPS2 PSRAM, `virt`'s RAM), mapped by the
/// host; the shared region lies at [`QemuBoard::shared_file_offset`] in it.
///
/// By default the file is created in `/dev/shm` and unlinked at once: QEMU opens it
/// through `/proc/self/fd/N` (the descriptor is inherited), so no file is ever left
/// behind, whatever way the process ends. The same `BusFile` can serve several QEMU runs
/// in turn (a reboot), which keeps the config store. [`BusFile::persistent`] uses a named
/// file instead, kept across processes.
#[derive(Debug)]
pub struct BusFile {
    file: File,
    map: MmapRaw,
    path: Option<PathBuf>,
    board: QemuBoard,
}

// SAFETY: the mapping is plain shared memory; all access goes through atomics.
unsafe impl Send for BusFile {}
unsafe impl Sync for BusFile {}

impl BusFile {
    /// A fresh, anonymous (already unlinked) bus file for `board`, all zero.
    pub fn anonymous(board: QemuBoard) -> Result<Self, HilError> {
        static COUNTER: AtomicU64 = AtomicU64::new(0);
        let dir = if Path::new("/dev/shm").is_dir() { PathBuf::from("/dev/shm") } else { std::env::temp_dir() };
        let nanos =
            std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map(|d| d.as_nanos()).unwrap_or(0);
        let name = format!("sts-twin-bus-{}-{}-{}", std::process::id(), COUNTER.fetch_add(1, Ordering::Relaxed), nanos);
        let path = dir.join(name);
        let file = OpenOptions::new()
            .read(true)
            .write(true)
            .create_new(true)
            .open(&path)
            .map_err(|e| HilError::io(format!("creating {}", path.display()), e))?;
        let unlinked = std::fs::remove_file(&path);
        let bus = Self::from_file(file, None, board);
        unlinked.map_err(|e| HilError::io(format!("unlinking {}", path.display()), e))?;
        bus
    }

    /// A named bus file for `board` at `path`, created (all zero) if missing and kept
    /// afterwards, so the config store survives across processes.
    pub fn persistent(path: &Path, board: QemuBoard) -> Result<Self, HilError> {
        let file = OpenOptions::new()
            .read(true)
            .write(true)
            .create(true)
            .truncate(false)
            .open(path)
            .map_err(|e| HilError::io(format!("opening {}", path.display()), e))?;
        Self::from_file(file, Some(path.to_path_buf()), board)
    }

    fn from_file(file: File, path: Option<PathBuf>, board: QemuBoard) -> Result<Self, HilError> {
        let len = file.metadata().map_err(|e| HilError::io("reading the bus file size", e))?.len();
        let bytes = board.backing_file_bytes() as u64;
        if len != bytes {
            file.set_len(bytes).map_err(|e| HilError::io("sizing the bus file", e))?;
        }
        let map = MmapRaw::map_raw(&file).map_err(|e| HilError::io("mapping the bus file", e))?;
        Ok(Self { file, map, path, board })
    }

    /// The board the file is laid out for.
    pub fn board(&self) -> QemuBoard {
        self.board
    }

    /// The `mem-path` QEMU is given: the inherited descriptor, or the named file.
    pub(crate) fn qemu_mem_path(&self) -> String {
        match &self.path {
            Some(p) => p.display().to_string(),
            None => format!("/proc/self/fd/{}", self.file.as_raw_fd()),
        }
    }

    /// Descriptors QEMU must inherit.
    pub(crate) fn inherited_fds(&self) -> Vec<i32> {
        if self.path.is_some() {
            Vec::new()
        } else {
            vec![self.file.as_raw_fd()]
        }
    }

    /// Word `index` from `byte_offset` of the shared region.
    fn word(&self, byte_offset: usize, index: usize) -> &AtomicU32 {
        let in_region = byte_offset + 4 * index;
        assert!(in_region + 4 <= map::SHARED_BYTES);
        let at = self.board.shared_file_offset() + in_region;
        // SAFETY: in bounds, 4-aligned (page-aligned mapping), shared memory of the mapping's
        // lifetime; all access to it is atomic.
        unsafe { AtomicU32::from_ptr(self.map.as_mut_ptr().add(at).cast()) }
    }

    fn bus(&self, index: usize) -> &AtomicU32 {
        self.word(0, index)
    }

    /// Resets the bus for a boot: zeroes the bus and the diagnostics block (not the config
    /// store), then writes the magic word and the layout version.
    pub(crate) fn reset_for_boot(&self) {
        for i in 0..layout::BUS_BYTES / 4 {
            self.bus(i).store(0, Ordering::Relaxed);
        }
        for i in 0..DIAG_WORDS {
            self.word(map::DIAG_OFFSET, i).store(0, Ordering::Relaxed);
        }
        self.bus(layout::WORD_VERSION).store(layout::BUS_VERSION, Ordering::Relaxed);
        fence(Ordering::SeqCst);
        self.bus(layout::WORD_MAGIC).store(layout::MAGIC, Ordering::SeqCst);
    }

    /// Clears the config store (a factory reset of the QEMU board).
    pub fn erase_config(&self) {
        for i in 0..2 * map::CONFIG_SLOT_BYTES / 4 {
            self.word(map::CONFIG_OFFSET, i).store(0, Ordering::Relaxed);
        }
        fence(Ordering::SeqCst);
    }

    /// True once the firmware announced that it serves the bus.
    pub fn firmware_ready(&self) -> bool {
        self.bus(layout::FW_READY).load(Ordering::Acquire) == layout::FW_READY_MAGIC
    }

    /// Outputs the firmware has written so far.
    pub fn fw_seq(&self) -> u32 {
        self.bus(layout::WORD_FW_SEQ).load(Ordering::Acquire)
    }

    /// Inputs the host has written so far.
    pub fn host_seq(&self) -> u32 {
        self.bus(layout::WORD_HOST_SEQ).load(Ordering::Acquire)
    }

    /// Writes input slot `input.tick`, then publishes `HOST_SEQ = input.tick + 1`.
    pub(crate) fn write_input(&self, input: &InputSlot) {
        let base = layout::input_slot_word(input.tick);
        for (i, w) in input.to_words().iter().enumerate() {
            self.bus(base + i).store(*w, Ordering::Relaxed);
        }
        self.bus(layout::WORD_HOST_SEQ).store(input.tick.wrapping_add(1), Ordering::Release);
    }

    /// Output slot `tick` (valid once `fw_seq() > tick`).
    pub(crate) fn read_output(&self, tick: u32) -> OutputSlot {
        let base = layout::output_slot_word(tick);
        let mut words = [0u32; OUTPUT_SLOT_WORDS];
        for (i, w) in words.iter_mut().enumerate() {
            *w = self.bus(base + i).load(Ordering::Acquire);
        }
        OutputSlot::from_words(words)
    }

    /// Sets or clears `HOST_STOP` (the firmware stops waiting for inputs while set).
    pub(crate) fn set_host_stop(&self, stop: bool) {
        self.bus(layout::WORD_HOST_STOP).store(u32::from(stop), Ordering::SeqCst);
    }

    /// The bus header's counters.
    pub fn counters(&self) -> BusCounters {
        BusCounters {
            host_seq: self.host_seq(),
            fw_seq: self.fw_seq(),
            underruns: self.bus(layout::WORD_FW_UNDERRUNS).load(Ordering::Acquire),
            overruns: self.bus(layout::WORD_FW_OVERRUNS).load(Ordering::Acquire),
        }
    }

    /// The firmware's diagnostics block.
    pub fn diagnostics(&self) -> Diagnostics {
        let d = |i| self.word(map::DIAG_OFFSET, i).load(Ordering::Acquire);
        Diagnostics {
            booted: d(map::DIAG_MAGIC) == map::DIAG_MAGIC_VALUE,
            period_counts: d(map::DIAG_PERIOD_COUNTS),
            entry_last_counts: d(map::DIAG_ENTRY_LAST),
            entry_max_counts: d(map::DIAG_ENTRY_MAX),
            busy_last_counts: d(map::DIAG_BUSY_LAST),
            busy_max_counts: d(map::DIAG_BUSY_MAX),
            busy_sum_counts: u64::from(d(map::DIAG_BUSY_SUM_LO)) | (u64::from(d(map::DIAG_BUSY_SUM_HI)) << 32),
            model_requests: d(map::DIAG_MODEL_REQUESTS),
            model_runs: d(map::DIAG_MODEL_RUNS),
            control_rx_bytes: d(map::DIAG_CONTROL_RX_BYTES),
            control_rx_dropped: d(map::DIAG_CONTROL_RX_DROPPED),
            input_faults: d(map::DIAG_INPUT_FAULTS),
            handler_last_counts: d(map::DIAG_HANDLER_LAST),
            handler_max_counts: d(map::DIAG_HANDLER_MAX),
            model_timing_hash: d(map::DIAG_MODEL_TIMING_HASH),
            paper_eval_counts: d(map::DIAG_PAPER_EVAL_COUNTS),
        }
    }
}

/// The bus header's sequence words and counters.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct BusCounters {
    /// Inputs written by the host.
    pub host_seq: u32,
    /// Outputs written by the firmware.
    pub fw_seq: u32,
    /// Ticks on which the firmware gave up waiting for an input.
    pub underruns: u32,
    /// Ticks whose handler ran into the next period.
    pub overruns: u32,
}

/// The firmware's diagnostics block (see [`sts_twin_board::qemu`]). Timer counts are of the
/// board's tick timer ([`QemuBoard::count_ns`]: the CMSDK timer's 40 ns, the RTC's 1 ns):
/// under `-icount shift=N` one count is `count_ns / 2^N` guest instructions.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Diagnostics {
    /// The firmware booted and initialised the block.
    pub booted: bool,
    /// Servo period in timer counts.
    pub period_counts: u32,
    /// Tick edge to the input wait, last tick.
    pub entry_last_counts: u32,
    /// Largest `entry_last_counts`.
    pub entry_max_counts: u32,
    /// Input arrival to handler end, last served tick.
    pub busy_last_counts: u32,
    /// Largest `busy_last_counts`.
    pub busy_max_counts: u32,
    /// Sum of `busy_last_counts` over served ticks.
    pub busy_sum_counts: u64,
    /// Model work requests.
    pub model_requests: u32,
    /// Model work runs.
    pub model_runs: u32,
    /// Control bytes received.
    pub control_rx_bytes: u32,
    /// Control bytes dropped.
    pub control_rx_dropped: u32,
    /// Input faults.
    pub input_faults: u32,
    /// Input arrival to the very end of the handler, previous served tick.
    pub handler_last_counts: u32,
    /// Largest `handler_last_counts`.
    pub handler_max_counts: u32,
    /// Hash of where in the tick periods the model work completed (see
    /// [`sts_twin_board::qemu::DIAG_MODEL_TIMING_HASH`]).
    pub model_timing_hash: u32,
    /// Timer counts of one evaluation of the paper program, measured at boot.
    pub paper_eval_counts: u32,
}
