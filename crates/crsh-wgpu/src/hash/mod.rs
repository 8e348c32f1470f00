//! Ray hashing on the device.

pub mod thesis;
