//! How the host retries a request whose answer does not come, and what it saw doing so.
//!
//! An attempt whose answer does not come in time (dropped, corrupted, or just slow) is asked
//! for again with a new sequence number, and answers to earlier attempts are ignored. The
//! requests of the control protocol are idempotent (setting a value twice is setting it
//! once), which makes retrying safe even when only the answer was lost.

use std::time::Duration;

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
