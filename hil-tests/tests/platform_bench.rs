//! Platform benchmarks (ignored by default; they print their figures):
//!
//! ```text
//! cargo test -p sts-hil-tests --release --test hil platform_bench:: -- --ignored --nocapture --test-threads=1
//! ```

use sts_hil::{bench_instructions, bench_throughput, HilConfig};

#[test]
#[ignore = "benchmark: run with --ignored --nocapture"]
fn bench_servo_tick_instructions() {
    let _serial = sts_hil_tests::serial();
    let report = bench_instructions(HilConfig::default(), 20_000).expect("instruction benchmark");
    println!("{report}");
    assert_eq!(report.underruns + report.overruns, 0);
}

#[test]
#[ignore = "benchmark: run with --ignored --nocapture"]
fn bench_hil_throughput() {
    let _serial = sts_hil_tests::serial();
    let report = bench_throughput(HilConfig::default(), 80_000).expect("throughput benchmark");
    println!("{report}");
}
