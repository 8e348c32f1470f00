//! Omni-directional 2×2 packets (seed 003 §4.1.2, listing 4.1): packets of rays that share an
//! origin traverse with no direction-sign restriction, so a pixel quad is never split.
//!
//! The listing's two modifications: (1) a negative distance to the split plane counts as
//! `+∞` (the ray never crosses it going forwards); (2) the *front* child is the one on the
//! origin's side of the plane and the *back* child the other, whatever the directions. The
//! listing writes the children as `node.left + (node_index ^ 1)` / `node.left + node_index`
//! with `node_index = dist < 0`, which names the right child (`≥ split`) front when the origin
//! is left of the plane: its child order is the opposite of listing 2.1's (erratum). This
//! module uses [`super::front_back`], which follows listing 2.1's order (left `≤ split`); the
//! test `listing_4_1_child_convention_is_fixed` in [`super::coherent`] checks it.
//!
//! The per-lane loop is [`super::packet::trace_lanes`] with [`Order::Omni`].

use super::group::GroupState;
use super::packet::{trace_lanes, Order, PacketEntry};
use crate::triangle::TriangleTest;

/// Listing 4.1 on every packet of a group.
pub fn trace_group<T: TriangleTest>(st: &mut GroupState<'_, T>, stack: &mut Vec<PacketEntry>) {
    for p in 0..st.packets.len() {
        let live = st.live(p);
        trace_lanes(st, p, live, Order::Omni, stack);
    }
}
