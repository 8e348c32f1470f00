//! Ray-space hierarchy traversal on the device.

use crsh_core::{RayHierarchy, Result};

use crate::adapter::GpuContext;
use crate::backend::Wgpu;

pub mod crsh;
pub mod dual;

/// The prepared ray-node bound and its conservative node test (`node_bound.wgsl`: the twin of
/// [`crsh_cpu::traverse::crsh::NodeBound`]) with the trigonometry it needs, appended to the
/// traversal kernels.
pub(crate) const NODE_BOUND_WGSL: &str = concat!(
    include_str!("node_bound.wgsl"),
    "\n",
    include_str!("../kernels/trig.wgsl")
);

/// `Bound` in `node_bound.wgsl` (48 bytes): a prepared ray node, only ever on the device.
pub(crate) type BoundWords = [u32; 12];

/// Checks a hierarchy's shape for a traversal of `n_rays` rays as the CPU twins do
/// ([`crsh_cpu::traverse::crsh::check_shape`]) and its leaf offsets, if any (downloaded: a
/// traversal does not read them, but a hierarchy the intersector would refuse is refused
/// here, once); returns the level lengths.
pub(crate) fn check_hierarchy(
    ctx: &GpuContext,
    h: &RayHierarchy<Wgpu>,
    n_rays: usize,
) -> Result<Vec<usize>> {
    let level_lens: Vec<usize> = h.levels.iter().map(|l| l.len()).collect();
    let reach_lens: Vec<usize> = h.reach.iter().map(|r| r.len()).collect();
    crsh_cpu::traverse::crsh::check_shape(
        n_rays,
        h.subdivision,
        h.order.len(),
        &level_lens,
        &reach_lens,
        h.leaf_offsets.as_ref().map(|o| o.len()),
    )?;
    if let Some(offsets) = &h.leaf_offsets {
        let host = offsets.to_vec(ctx)?;
        crsh_core::check_leaf_offsets(&host, level_lens[0], n_rays)?;
    }
    Ok(level_lens)
}
