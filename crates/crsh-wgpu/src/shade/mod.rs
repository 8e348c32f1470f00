//! Shading on the device: Phong (eq. 3.17-3.19), and seed 001's ambient occlusion and diffuse
//! paths.

pub mod ao;
pub mod diffuse;
pub mod phong;
