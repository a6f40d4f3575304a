//! Shared helpers of the HIL tests.
