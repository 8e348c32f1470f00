//! Secondary ray generation on the device.

mod slots;
pub mod whitted;
