//! Exact ray-triangle intersection on the device: brute force (whole-scene and candidate
//! queries) and the object-BVH baseline.

pub mod brute;
pub mod bvh;

/// Shared WGSL of the triangle tests (`kernels/mt.wgsl`).
pub(crate) const MT_WGSL: &str = include_str!("../kernels/mt.wgsl");
