//! The emulated A3200-like Z axis: servo loop, Z slide, structure, sensors and switchable physical effects.
#![deny(missing_docs)]
