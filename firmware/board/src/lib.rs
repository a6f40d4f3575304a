//! The board seam.
#![no_std]
