//! Ray sorting on the device.

pub mod radix;
