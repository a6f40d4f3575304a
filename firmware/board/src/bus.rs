//! Firmware side of the virtual analogue bus (layout in [`sts_twin_core::bus`]).
//!
//! Every access is volatile; a fence orders "slot, then sequence word" on write and
//! "sequence word, then slot" on read, as the layout requires. On Cortex-M the fence is a
//! `dmb`.

use core::sync::atomic::{fence, Ordering};
use sts_twin_core::bus::{self as layout, InputSlot, OutputSlot};

use crate::{AdcSource, DacSink, SampleError};

/// A view of the bus at a fixed address. Copyable: it is only a pointer.
#[derive(Clone, Copy, Debug)]
pub struct BusView {
    base: *mut u32,
}

// SAFETY: the bus is plain memory shared with the host; all accesses are volatile and the
// firmware writes each word from one context only (see the methods).
unsafe impl Send for BusView {}
unsafe impl Sync for BusView {}

impl BusView {
    /// A view of the bus at `base`.
    ///
    /// # Safety
    /// `base` must point to [`layout::BUS_BYTES`] bytes of memory, 4-byte aligned, that
    /// nothing else in the program uses (the host on the other side is fine).
    pub const unsafe fn new(base: *mut u32) -> Self {
        Self { base }
    }

    #[inline(always)]
    fn read(&self, word: usize) -> u32 {
        // SAFETY: `word` < BUS_BYTES / 4 for every caller (layout constants).
        unsafe { self.base.add(word).read_volatile() }
    }

    #[inline(always)]
    fn write(&self, word: usize, value: u32) {
        // SAFETY: as in `read`.
        unsafe { self.base.add(word).write_volatile(value) }
    }

    /// True when the host wrote the magic word and the layout version this firmware speaks.
    pub fn header_valid(&self) -> bool {
        self.read(layout::WORD_MAGIC) == layout::MAGIC && self.read(layout::WORD_VERSION) == layout::BUS_VERSION
    }

    /// Announces that the firmware serves the bus, starting from output sequence `fw_seq`.
    pub fn set_ready(&self, fw_seq: u32) {
        self.write(layout::WORD_FW_SEQ, fw_seq);
        fence(Ordering::SeqCst);
        self.write(layout::FW_READY, layout::FW_READY_MAGIC);
        fence(Ordering::SeqCst);
    }

    /// Inputs the host has written so far.
    #[inline(always)]
    pub fn host_seq(&self) -> u32 {
        let seq = self.read(layout::WORD_HOST_SEQ);
        fence(Ordering::SeqCst);
        seq
    }

    /// True while the host asks the firmware not to wait for inputs.
    #[inline(always)]
    pub fn host_stop(&self) -> bool {
        self.read(layout::WORD_HOST_STOP) != 0
    }

    /// Input slot `tick` (valid once `host_seq() > tick`).
    #[inline(always)]
    pub fn read_input(&self, tick: u32) -> InputSlot {
        let word = layout::input_slot_word(tick);
        let mut words = [0u32; InputSlot::WORDS];
        for (i, w) in words.iter_mut().enumerate() {
            *w = self.read(word + i);
        }
        InputSlot::from_words(words)
    }

    /// Writes output slot `output.tick`, then publishes `FW_SEQ = output.tick + 1`.
    #[inline(always)]
    pub fn write_output(&self, output: &OutputSlot) {
        let word = layout::output_slot_word(output.tick);
        for (i, w) in output.to_words().iter().enumerate() {
            self.write(word + i, *w);
        }
        fence(Ordering::SeqCst);
        self.write(layout::WORD_FW_SEQ, output.tick.wrapping_add(1));
    }

    /// Publishes the underrun and overrun counters.
    #[inline(always)]
    pub fn write_counters(&self, underruns: u32, overruns: u32) {
        self.write(layout::WORD_FW_UNDERRUNS, underruns);
        self.write(layout::WORD_FW_OVERRUNS, overruns);
    }
}

/// The bus as the servo's input: waits (bounded spin) for the host's input slot.
#[derive(Debug)]
pub struct BusAdc {
    bus: BusView,
    spin_bound: u32,
}

impl BusAdc {
    /// Input side of `bus`; a tick gives up after `spin_bound` polls of `HOST_SEQ`.
    pub const fn new(bus: BusView, spin_bound: u32) -> Self {
        Self { bus, spin_bound }
    }
}

impl AdcSource for BusAdc {
    #[inline(always)]
    fn sample(&mut self, tick: u32) -> Result<InputSlot, SampleError> {
        // `HOST_SEQ > tick`, in wrapping arithmetic: the host is never more than a ring ahead.
        let ready = |seq: u32| (seq.wrapping_sub(tick) as i32) > 0;
        let mut polls = 0u32;
        loop {
            if ready(self.bus.host_seq()) {
                return Ok(self.bus.read_input(tick));
            }
            if self.bus.host_stop() {
                return Err(SampleError::Paused);
            }
            polls += 1;
            if polls >= self.spin_bound {
                return Err(SampleError::Late);
            }
            // No `spin_loop()` hint here: it is a YIELD, which makes QEMU leave translated
            // code on every poll (about a microsecond each).
        }
    }
}

/// The bus as the servo's output.
#[derive(Debug)]
pub struct BusDac {
    bus: BusView,
}

impl BusDac {
    /// Output side of `bus`.
    pub const fn new(bus: BusView) -> Self {
        Self { bus }
    }
}

impl DacSink for BusDac {
    #[inline(always)]
    fn write(&mut self, output: &OutputSlot) {
        self.bus.write_output(output);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use sts_twin_core::bus::{BUS_BYTES, WORD_HOST_SEQ, WORD_HOST_STOP};

    #[test]
    fn adc_waits_for_host_seq_and_dac_publishes_fw_seq() {
        let mut mem = vec![0u32; BUS_BYTES / 4];
        let base = mem.as_mut_ptr();
        let poke = |word: usize, value: u32| unsafe { base.add(word).write_volatile(value) };
        let bus = unsafe { BusView::new(base) };
        let mut adc = BusAdc::new(bus, 10);
        assert_eq!(adc.sample(0), Err(SampleError::Late));
        let input = InputSlot {
            tick: 0,
            acc_code: -3,
            flags: 1,
            cmd_phase_turns: 7,
            cmd_pos_nm: -9,
            x_acc_um_per_s2: -11,
            spindle_turns: 13,
        };
        let slot = sts_twin_core::bus::input_slot_word(0);
        for (i, w) in input.to_words().iter().enumerate() {
            poke(slot + i, *w);
        }
        poke(WORD_HOST_SEQ, 1);
        assert_eq!(adc.sample(0), Ok(input));
        assert_eq!(adc.sample(1), Err(SampleError::Late));
        poke(WORD_HOST_STOP, 1);
        assert_eq!(adc.sample(1), Err(SampleError::Paused));
        let mut dac = BusDac::new(bus);
        dac.write(&OutputSlot { tick: 0, dac_code: 5, ..Default::default() });
        assert_eq!(unsafe { base.add(sts_twin_core::bus::WORD_FW_SEQ).read_volatile() }, 1);
    }
}
