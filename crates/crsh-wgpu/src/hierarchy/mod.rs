//! Ray-space hierarchy construction on the device.

pub mod sphere_cone;
