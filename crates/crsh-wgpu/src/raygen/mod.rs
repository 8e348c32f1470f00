//! Secondary ray generation on the device.

pub mod whitted;
