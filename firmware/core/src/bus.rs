//! The virtual analogue bus: one ADC sample in and one DAC code out per servo tick, shared
//! between the firmware and the host in lockstep.
//!
//! Under QEMU the bus lives in the mps2-an386 PSRAM (0x2100_0000), which QEMU maps to a file
//! in `/dev/shm` that the host maps too. The layout is a header of sequence counters and two
//! rings of [`RING_SLOTS`] slots of little-endian `u32` words ([`INPUT_SLOT_WORDS`] per
//! input slot, [`OUTPUT_SLOT_WORDS`] per output slot):
//!
//! | byte offset | word | what | written by |
//! |---|---|---|---|
//! | 0x000 | `MAGIC` | `0x5354_5342` ("STSB") | host, before boot |
//! | 0x004 | `VERSION` | [`BUS_VERSION`] | host, before boot |
//! | 0x008 | `HOST_SEQ` | inputs written so far (tick `k` is ready when `HOST_SEQ > k`) | host |
//! | 0x00C | `FW_SEQ` | outputs written so far | firmware |
//! | 0x010 | `FW_READY` | [`FW_READY_MAGIC`] once the firmware polls the bus | firmware |
//! | 0x014 | `FW_UNDERRUNS` | ticks on which the host's input was late | firmware |
//! | 0x018 | `FW_OVERRUNS` | ticks that started before the previous one ended | firmware |
//! | 0x01C | `HOST_STOP` | non-zero: the host asks the firmware to stop waiting | host |
//! | 0x100 | input ring | [`InputSlot`] `k` at `0x100 + 32 * (k % RING_SLOTS)` | host |
//! | 0x100 + 32 * RING_SLOTS | output ring | [`OutputSlot`] `k` at `+ 16 * (k % RING_SLOTS)` | firmware |
//!
//! Ordering: a writer fills a slot, then (after a memory barrier) bumps its sequence word; a
//! reader reads the sequence word, then the slot. Fewer than [`RING_SLOTS`] ticks are ever
//! in flight: the host writes input `k` only once it has read output `k - RING_SLOTS + 1`. The firmware's output for tick `k` is applied to
//! the plant at tick `k + 1`, always: that is the bus's fixed one-tick latency.
//!
//! This module only defines the layout and the slot encodings; the volatile access lives in
//! the board crate (firmware) and the HIL harness (host).

/// Magic word at offset 0: "STSB".
pub const MAGIC: u32 = 0x5354_5342;
/// Layout version of this bus (2: input slots carry the X acceleration and spindle angle).
pub const BUS_VERSION: u32 = 2;
/// Value the firmware writes to [`FW_READY`] once it is serving the bus.
pub const FW_READY_MAGIC: u32 = 0x5245_4459;

/// Word offsets (in `u32` words) of the header fields.
pub const WORD_MAGIC: usize = 0;
/// Word offset of the layout version.
pub const WORD_VERSION: usize = 1;
/// Word offset of the host's input sequence counter.
pub const WORD_HOST_SEQ: usize = 2;
/// Word offset of the firmware's output sequence counter.
pub const WORD_FW_SEQ: usize = 3;
/// Word offset of the firmware's ready flag.
pub const FW_READY: usize = 4;
/// Word offset of the firmware's underrun counter.
pub const WORD_FW_UNDERRUNS: usize = 5;
/// Word offset of the firmware's overrun counter.
pub const WORD_FW_OVERRUNS: usize = 6;
/// Word offset of the host's stop request.
pub const WORD_HOST_STOP: usize = 7;

/// Slots per ring. A power of two.
pub const RING_SLOTS: usize = 256;
/// Words per input slot (six used, a power of two so that the slot address is a shift).
pub const INPUT_SLOT_WORDS: usize = 8;
/// Words per output slot.
pub const OUTPUT_SLOT_WORDS: usize = 4;
/// Word offset of the input ring.
pub const WORD_INPUT_RING: usize = 0x100 / 4;
/// Word offset of the output ring.
pub const WORD_OUTPUT_RING: usize = WORD_INPUT_RING + RING_SLOTS * INPUT_SLOT_WORDS;
/// Total bytes of the bus layout.
pub const BUS_BYTES: usize = (WORD_OUTPUT_RING + RING_SLOTS * OUTPUT_SLOT_WORDS) * 4;

/// Word offset of input slot `tick`.
pub const fn input_slot_word(tick: u32) -> usize {
    WORD_INPUT_RING + (tick as usize % RING_SLOTS) * INPUT_SLOT_WORDS
}

/// Word offset of output slot `tick`.
pub const fn output_slot_word(tick: u32) -> usize {
    WORD_OUTPUT_RING + (tick as usize % RING_SLOTS) * OUTPUT_SLOT_WORDS
}

/// Input flags: bit set when the motion controller's command phase is valid.
pub const IN_FLAG_PHASE_VALID: u16 = 1 << 0;

/// What the host hands the firmware for one servo tick.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct InputSlot {
    /// Tick index this slot is for.
    pub tick: u32,
    /// Accelerometer ADC code.
    pub acc_code: i16,
    /// `IN_FLAG_*` bits.
    pub flags: u16,
    /// Command phase of the motion controller, a full turn is 2^32.
    pub cmd_phase_turns: u32,
    /// Command position of the Z axis in nanometres.
    pub cmd_pos_nm: i32,
    /// X slide acceleration, micrometres per s^2 (0 where the machine does not provide it).
    pub x_acc_um_per_s2: i32,
    /// Spindle angle, a full turn is 2^32 (0 where the machine does not provide it).
    pub spindle_turns: u32,
}

impl InputSlot {
    /// Bus words used by an input slot (the rest of [`INPUT_SLOT_WORDS`] is reserved, zero).
    pub const WORDS: usize = 6;

    /// The slot as its bus words.
    pub const fn to_words(&self) -> [u32; Self::WORDS] {
        [
            self.tick,
            (self.acc_code as u16 as u32) | ((self.flags as u32) << 16),
            self.cmd_phase_turns,
            self.cmd_pos_nm as u32,
            self.x_acc_um_per_s2 as u32,
            self.spindle_turns,
        ]
    }

    /// The slot from its bus words.
    pub const fn from_words(words: [u32; Self::WORDS]) -> Self {
        Self {
            tick: words[0],
            acc_code: words[1] as u16 as i16,
            flags: (words[1] >> 16) as u16,
            cmd_phase_turns: words[2],
            cmd_pos_nm: words[3] as i32,
            x_acc_um_per_s2: words[4] as i32,
            spindle_turns: words[5],
        }
    }
}

/// Output status bit: compensation is enabled (possibly still ramping).
pub const OUT_FLAG_ENABLED: u16 = 1 << 0;
/// Output status bit: the firmware does not trust its inputs, or the supervisor holds
/// compensation off, and ramps to zero (the status's degraded bits say why).
pub const OUT_FLAG_DEGRADED: u16 = 1 << 1;
/// Output status bit: the DAC code was clamped at full scale this tick.
pub const OUT_FLAG_SATURATED: u16 = 1 << 2;
/// Output status bit: the output was slew-limited this tick.
pub const OUT_FLAG_SLEWING: u16 = 1 << 3;
/// Output status bit: a twin program is active.
pub const OUT_FLAG_MODEL_ACTIVE: u16 = 1 << 4;

/// What the firmware hands back for one servo tick.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct OutputSlot {
    /// Tick index this slot answers.
    pub tick: u32,
    /// DAC code written to the analogue output.
    pub dac_code: i16,
    /// `OUT_FLAG_*` bits.
    pub flags: u16,
    /// The predicted dynamic error this tick, in picometres (for logging and tests).
    pub de_pred_pm: i32,
    /// Free-running count of faults seen so far (low 32 bits).
    pub fault_count: u32,
}

impl OutputSlot {
    /// The slot as its four bus words.
    pub const fn to_words(&self) -> [u32; OUTPUT_SLOT_WORDS] {
        [
            self.tick,
            (self.dac_code as u16 as u32) | ((self.flags as u32) << 16),
            self.de_pred_pm as u32,
            self.fault_count,
        ]
    }

    /// The slot from its four bus words.
    pub const fn from_words(words: [u32; OUTPUT_SLOT_WORDS]) -> Self {
        Self {
            tick: words[0],
            dac_code: words[1] as u16 as i16,
            flags: (words[1] >> 16) as u16,
            de_pred_pm: words[2] as i32,
            fault_count: words[3],
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn slots_round_trip_through_words() {
        let input = InputSlot {
            tick: 7,
            acc_code: -32768,
            flags: 1,
            cmd_phase_turns: u32::MAX,
            cmd_pos_nm: -5,
            x_acc_um_per_s2: i32::MIN,
            spindle_turns: 0x8000_0001,
        };
        assert_eq!(InputSlot::from_words(input.to_words()), input);
        let output = OutputSlot { tick: 9, dac_code: -1, flags: 0x1f, de_pred_pm: i32::MIN, fault_count: 3 };
        assert_eq!(OutputSlot::from_words(output.to_words()), output);
    }

    #[test]
    fn rings_do_not_overlap_and_fit_the_psram() {
        const { assert!(WORD_INPUT_RING > WORD_HOST_STOP) };
        assert_eq!(output_slot_word(0), input_slot_word(RING_SLOTS as u32 - 1) + INPUT_SLOT_WORDS);
        assert!(InputSlot::WORDS <= INPUT_SLOT_WORDS && INPUT_SLOT_WORDS.is_power_of_two());
        const { assert!(BUS_BYTES <= 16 * 1024 * 1024) };
        assert!(RING_SLOTS.is_power_of_two());
    }
}
