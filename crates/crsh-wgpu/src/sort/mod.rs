//! Ray sorting on the device.

pub mod compress;
pub mod radix;
