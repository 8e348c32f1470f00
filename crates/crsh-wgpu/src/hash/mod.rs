//! Ray hashing on the device.

pub mod morton_octa;
pub mod thesis;
pub mod tile;
