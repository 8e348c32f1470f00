//! Shading on the device.

pub mod phong;
