//! Ray-space hierarchy construction on the device. The consumers of hierarchies with
//! [`crsh_core::RayHierarchy::leaf_offsets`] check them with the shared host functions
//! ([`crsh_core::check_leaf_offsets`],
//! [`crsh_cpu::traverse::crsh::check_shape`]).
//!
//! [`sphere_cone`]: seed 000's bottom-up sphere-cone levels (fixed groups of `subdivision`
//! leaves). [`tile_cone`]: seed 004's enclosing cones of screen tiles (one level of apex cones,
//! variable leaves per node through the leaf offsets).

pub mod sphere_cone;
pub mod tile_cone;

use crsh_core::{CoreError, Result};

/// Refuses an `order` of `order_len` leaves for a batch of `n` rays (a builder's order must
/// be a permutation of the batch), naming the `variant`.
pub(crate) fn check_order_len(variant: &str, order_len: usize, n: usize) -> Result<()> {
    if order_len != n {
        return Err(CoreError::InvalidInput(format!(
            "{variant}: {order_len} leaves for a batch of {n} rays (the order must be a permutation)"
        )));
    }
    Ok(())
}
