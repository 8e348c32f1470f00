//! Exact ray-triangle intersection on the device: brute force (whole-scene and candidate
//! queries), the object-BVH baseline, the uniform grid and RTTest's kd-tree.

pub mod brute;
pub mod bvh;
pub mod grid;
pub mod kdtree;

/// Shared WGSL of the triangle tests (`kernels/mt.wgsl`).
pub(crate) const MT_WGSL: &str = include_str!("../kernels/mt.wgsl");

/// Refuses a ray-triangle test other than Möller-Trumbore (the only one with a WGSL twin) for
/// intersector `variant`.
pub(crate) fn require_mt(spec: &crsh_core::StageSpec, variant: &str) -> crsh_core::Result<()> {
    let test = spec.str("test")?;
    if test == "mt" {
        return Ok(());
    }
    Err(crsh_core::CoreError::Unsupported {
        stage: "intersect",
        variant: variant.into(),
        what: format!("test `{test}` on the wgpu backend (only `mt` has a WGSL twin)"),
    })
}
