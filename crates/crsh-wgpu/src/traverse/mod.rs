//! Ray-space hierarchy traversal on the device.

pub mod crsh;
