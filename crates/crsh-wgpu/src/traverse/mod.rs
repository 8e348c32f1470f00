//! Ray-space hierarchy traversal on the device.

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
