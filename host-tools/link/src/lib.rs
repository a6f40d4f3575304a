#![doc = include_str!("../README.md")]
#![deny(missing_docs)]

mod board;
mod error;
mod faults;
mod retry;
mod serial;
mod transport;

pub use board::{request_name, Board};
pub use error::LinkError;
pub use faults::{FrameFate, FrameInjector, InjectedFaults, LinkFaults};
pub use retry::{LinkStats, RetryPolicy};
pub use serial::{SerialLink, DEFAULT_BAUD};
pub use transport::Transport;
