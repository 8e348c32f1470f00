//! Primary visibility on the device.

pub mod raster;
