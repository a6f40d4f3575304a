//! Extremes, empty states, the ring margin (`Torn`), concurrent reads and bit-exact
//! golden values. Run in debug too: integer overflow then panics, so these tests also show
//! that no arithmetic overflows.

use crate::features_util as util;
use crate::reference;

use reference::features_f64_detail;
use std::sync::{Arc, Mutex};
use sts_twin_core::features::*;
use util::{close, table, MaxExtractor};

/// Fixed-point vs reference, loosely (the tight comparison is in features_prop.rs); and
/// everything finite.
fn check_against_reference(codes: &[i16], cfg: FeatureConfig, f: &Features) {
    let r = features_f64_detail(codes, &cfg).unwrap();
    let a = f.as_array();
    assert!(a.iter().all(|v| v.is_finite()), "non-finite\n{}", table(&a, &r.values));
    for i in 1..FEATURE_COUNT {
        if i == MEAN_FREQ_HZ {
            continue;
        }
        assert!(close(a[i] as f64, r.values[i], 2e-6, 1e-9), "{}\n{}", FEATURE_NAMES[i], table(&a, &r.values));
    }
    assert!(
        close(a[MEAN_FREQ_HZ] as f64, r.values[MEAN_FREQ_HZ], 5e-5, 1e-4 * r.bin_hz),
        "f11\n{}",
        table(&a, &r.values)
    );
}

fn extreme_sequences(len: usize) -> Vec<(&'static str, Vec<i16>)> {
    vec![
        ("all MIN", vec![i16::MIN; len]),
        ("all MAX", vec![i16::MAX; len]),
        ("alternating MIN/MAX", (0..len).map(|i| if i % 2 == 0 { i16::MIN } else { i16::MAX }).collect()),
        ("MIN/MAX blocks of 16", (0..len).map(|i| if (i / 16) % 2 == 0 { i16::MIN } else { i16::MAX }).collect()),
        ("one MAX in MIN", (0..len).map(|i| if i % 9973 == 5 { i16::MAX } else { i16::MIN }).collect()),
        ("MIN then MAX", (0..len).map(|i| if i < len / 2 { i16::MIN } else { i16::MAX }).collect()),
    ]
}

#[test]
fn extremes_at_the_largest_window() {
    let cfg = FeatureConfig { window_samples: MAX_WINDOW_SAMPLES as u32, ..FeatureConfig::DEFAULT };
    let mut fx = Box::new(MaxExtractor::new(cfg).unwrap());
    for (name, codes) in extreme_sequences(MAX_WINDOW_SAMPLES + 5_000) {
        fx.reconfigure(cfg).unwrap();
        fx.push_slice(&codes);
        let f = fx.features();
        assert_eq!(f.window_samples_used(), MAX_WINDOW_SAMPLES as u32, "{name}");
        check_against_reference(&codes, cfg, &f);
    }
}

#[test]
fn extremes_at_the_default_window_keep_sliding() {
    let cfg = FeatureConfig::DEFAULT;
    let mut fx = Box::new(DefaultFeatureExtractor::new(cfg).unwrap());
    let mut all = Vec::new();
    // Back to back, without reset: 6 x 45,000 samples through one window.
    for (_, codes) in extreme_sequences(45_000) {
        fx.push_slice(&codes);
        all.extend_from_slice(&codes);
        check_against_reference(&all, cfg, &fx.features());
    }
    // The peak about the mean of alternating extremes is 32767.5 LSB.
    fx.push_slice(&(0..40_000).map(|i| if i % 2 == 0 { i16::MIN } else { i16::MAX }).collect::<Vec<_>>());
    assert!((fx.features().peak_mps2() - 3.27675).abs() < 1e-5);
}

#[test]
fn fresh_state_finishes_to_zeros() {
    let rings = SpectralRings::<2756>::new();
    let state = DefaultFeatureState::new(FeatureConfig::DEFAULT).unwrap();
    let mut scratch = Box::new(DefaultScratch::new());
    let cap = state.capture(&rings);
    assert_eq!(cap.samples, 0);
    let f = rings.finish(&cap, &mut scratch).unwrap();
    assert_eq!(f, Features::default());
}

#[test]
fn scratch_too_small_is_an_error() {
    let cfg = FeatureConfig { window_samples: 2048, ..FeatureConfig::DEFAULT };
    let rings = SpectralRings::<384>::new();
    let mut state = FeatureState::<128>::new(cfg).unwrap();
    for i in 0..3000 {
        state.push(&rings, (i % 100) as i16);
    }
    let mut small = Scratch::<32>::new();
    assert_eq!(
        rings.finish(&state.capture(&rings), &mut small),
        Err(FeatureError::ScratchTooSmall { needed_half_len: 64 })
    );
    let mut enough = Scratch::<64>::new();
    assert!(rings.finish(&state.capture(&rings), &mut enough).is_ok());
}

#[test]
fn margin_is_honoured_and_torn_reads_are_detected() {
    // Window 128 blocks, ring 384: push may run 256 blocks (4,096 samples) past a capture.
    let cfg = FeatureConfig { window_samples: 2048, ..FeatureConfig::DEFAULT };
    let rings = SpectralRings::<384>::new();
    let mut state = FeatureState::<128>::new(cfg).unwrap();
    let mut scratch = Scratch::<64>::new();
    let code = |i: usize| ((i * 7919) % 20_000) as i16 - 10_000;
    let mut i = 0;
    while i < 5000 {
        state.push(&rings, code(i));
        i += 1;
    }
    let cap = state.capture(&rings);
    assert_eq!(cap.partial_len, 8);
    let before = rings.finish(&cap, &mut scratch).unwrap();
    // 8 + 4,096 samples complete exactly 256 more blocks: still within the margin.
    while i < 5000 + 4096 {
        state.push(&rings, code(i));
        i += 1;
    }
    assert_eq!(rings.finish(&cap, &mut scratch), Ok(before));
    // One more block overwrites the oldest slot the capture needs.
    while i < 5000 + 4096 + 16 {
        state.push(&rings, code(i));
        i += 1;
    }
    assert_eq!(rings.finish(&cap, &mut scratch), Err(FeatureError::Torn));
    // A new capture reads fine again.
    assert!(rings.finish(&state.capture(&rings), &mut scratch).is_ok());
}

static SHARED_RINGS: SpectralRings<384> = SpectralRings::new();

/// The interrupt-owned state can be built in a `static` too (`FeatureState::new` is const).
static SHARED_STATE: Mutex<FeatureState<128>> =
    Mutex::new(match FeatureState::new(FeatureConfig { window_samples: 1024, ..FeatureConfig::DEFAULT }) {
        Ok(state) => state,
        Err(_) => panic!("invalid feature configuration"),
    });

#[test]
fn rings_live_in_a_static_and_are_sync() {
    fn assert_sync<T: Sync>(_: &T) {}
    assert_sync(&SHARED_RINGS);
    let cfg = FeatureConfig { window_samples: 1024, ..FeatureConfig::DEFAULT };
    let codes: Vec<i16> = (0..3000).map(|i| ((i * 31) % 4000) as i16 - 2000).collect();
    for &c in &codes {
        SHARED_STATE.lock().unwrap().push(&SHARED_RINGS, c);
    }
    let capture = SHARED_STATE.lock().unwrap().capture(&SHARED_RINGS);
    let f = SHARED_RINGS.finish(&capture, &mut Scratch::<64>::new()).unwrap();
    assert_eq!(f, util::run::<128, 384, 64>(&codes, cfg));
}

/// A reader on another thread, with the writer pushing meanwhile: every read that is not
/// `Torn` equals, bit for bit, the features computed with no concurrency.
#[test]
fn concurrent_reads_are_exact_or_torn() {
    let cfg = FeatureConfig { window_samples: 2048, ..FeatureConfig::DEFAULT };
    let total = 300_000usize;
    let codes: Arc<Vec<i16>> = Arc::new(
        (0..total)
            .map(|i| (((i * 2_654_435_761) >> 7) % 30_000) as i16 - 15_000 + if (i / 40) % 2 == 0 { 800 } else { -800 })
            .collect(),
    );
    let rings = Arc::new(SpectralRings::<384>::new());
    let state = Arc::new(Mutex::new(FeatureState::<128>::new(cfg).unwrap()));
    let writer = {
        let (rings, state, codes) = (Arc::clone(&rings), Arc::clone(&state), Arc::clone(&codes));
        std::thread::spawn(move || {
            for (i, &c) in codes.iter().enumerate() {
                state.lock().unwrap().push(&rings, c);
                if i % 32 == 0 {
                    std::thread::yield_now();
                }
            }
        })
    };
    let mut scratch = Scratch::<64>::new();
    let mut reads = Vec::new();
    let mut overlapped = 0;
    while !writer.is_finished() && reads.len() < 2000 {
        let cap = state.lock().unwrap().capture(&rings);
        if reads.len() % 8 == 7 {
            // Sometimes dawdle so that the writer laps the margin.
            std::thread::sleep(std::time::Duration::from_millis(2));
        }
        let result = rings.finish(&cap, &mut scratch);
        if state.lock().unwrap().capture(&rings).blocks_written != cap.blocks_written {
            overlapped += 1;
        }
        let pushed = cap.blocks_written as usize * BLOCK_SAMPLES + cap.partial_len as usize;
        reads.push((pushed, result));
    }
    writer.join().unwrap();
    // Replay without concurrency and compare every non-torn read.
    reads.sort_by_key(|r| r.0);
    let mut fx = Box::new(util::SmallExtractor::new(cfg).unwrap());
    let (mut fed, mut exact, mut torn) = (0, 0, 0);
    for (pushed, result) in &reads {
        fx.push_slice(&codes[fed..*pushed]);
        fed = *pushed;
        match result {
            Ok(f) => {
                assert_eq!(*f, fx.features(), "read after {pushed} samples");
                exact += 1;
            }
            Err(FeatureError::Torn) => torn += 1,
            Err(e) => panic!("unexpected {e}"),
        }
    }
    eprintln!("concurrent reads: {exact} exact, {torn} torn, {overlapped} overlapped with pushes");
    assert!(exact > 0);
}

/// Integer-only test signal (reproducible on the target without floating point): a
/// 62.5 Hz triangle of +-6,000 LSB on a 1,500 LSB offset plus xorshift noise of +-255 LSB.
pub fn golden_code(i: u32, noise: &mut u32) -> i16 {
    *noise ^= *noise << 13;
    *noise ^= *noise >> 17;
    *noise ^= *noise << 5;
    let phase = (i % 128) as i32;
    let tri = if phase < 64 { phase * 375 / 2 - 6000 } else { 6000 - (phase - 64) * 375 / 2 };
    (1500 + tri + (*noise & 0x1ff) as i32 - 256) as i16
}

/// The default extractor on 45,000 golden codes gives exactly these f32 bit patterns, on
/// the host and (by construction: integer arithmetic and IEEE basic operations only) on
/// the Cortex-M4F target. A firmware test can feed the same codes and compare.
#[test]
fn golden_bits() {
    let mut fx = Box::new(DefaultFeatureExtractor::new(FeatureConfig::DEFAULT).unwrap());
    let mut noise = 0x2545_f491;
    for i in 0..45_000 {
        fx.push(golden_code(i, &mut noise));
    }
    let bits = fx.features().as_array().map(f32::to_bits);
    let golden: [u32; FEATURE_COUNT] = GOLDEN;
    assert_eq!(bits, golden, "{:?}", fx.features());
}

const GOLDEN: [u32; FEATURE_COUNT] = [
    1115291658, 1050262630, 1039544568, 1059071223, 1051821183, 1072116554, 3122510914, 1072099883, 1074091502,
    1066650861, 1115459293, 1038513455,
];

proptest::proptest! {
    #![proptest_config(proptest::prelude::ProptestConfig { cases: 256, ..Default::default() })]

    /// Hand-made captures with arbitrary fields: `finish` returns an error or finite values,
    /// never panics (debug builds would panic on overflow).
    #[test]
    fn arbitrary_captures_never_panic(
        window_blocks in 0u32..300,
        scale in proptest::prop_oneof![proptest::prelude::any::<f32>(), 1e-9f32..1e3],
        samples in proptest::prop_oneof![proptest::prelude::any::<u32>(), 0u32..5000],
        s1 in proptest::prelude::any::<i32>(),
        s2 in proptest::prelude::any::<i64>(),
        s3 in proptest::prelude::any::<i64>(),
        s4 in proptest::prelude::any::<i128>(),
        sum_abs_q8 in proptest::prelude::any::<i64>(),
        blocks_written in proptest::prelude::any::<u32>(),
        ring_slot in 0u32..500,
        blocks in 0u32..300,
        partial_len in 0u32..20,
        partial_max in proptest::prelude::any::<i16>(),
        partial_min in proptest::prelude::any::<i16>(),
        pushed in 0usize..3000,
    ) {
        let rings = SpectralRings::<384>::new();
        let mut state = FeatureState::<128>::new(FeatureConfig { window_samples: 2048, ..FeatureConfig::DEFAULT }).unwrap();
        for i in 0..pushed {
            state.push(&rings, (i as i16).wrapping_mul(977));
        }
        let cfg = FeatureConfig { window_samples: window_blocks * 16, acc_mps2_per_lsb: scale, sample_rate_hz: 8000.0 };
        let cap = Capture {
            cfg, samples, s1, s2, s3, s4, sum_abs_q8, blocks_written, ring_slot, blocks, partial_len, partial_max, partial_min,
        };
        match rings.finish(&cap, &mut Scratch::<2048>::new()) {
            Ok(f) => proptest::prop_assert!(f.as_array().iter().all(|v| v.is_finite()), "{:?}", f),
            Err(e) => proptest::prop_assert!(!e.to_string().is_empty()),
        }
    }
}
