//! Per-ray traversal counts of the obvhs CWBVH traversals (the `bvh` module doc, "Counting").

use crsh_core::Stats;
use obvhs::cwbvh::node::CwBvhNode;

use super::{child_mask, leaf_top_bits};

/// Per-ray (or summed) traversal counts (the `bvh` module doc, "Counting").
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub(crate) struct Counts {
    /// Child boxes tested.
    pub bounds: u64,
    /// Leaf primitives tested.
    pub prims: u64,
    /// Inner nodes visited (children tested).
    pub inner: u64,
    /// Leaves whose primitives were tested.
    pub leaves: u64,
    /// Child boxes the ray overlapped (of `bounds`; counted by [`trace_cwbvh`] with `TALLY`).
    pub bounds_passed: u64,
    /// Leaf primitive tests that found a hit (of `prims`; as `bounds_passed`).
    pub prims_hit: u64,
}

impl Counts {
    /// Counts a visit of `node` whose children `hit` (bit `c` for child `c`, [`child_test`])
    /// passed the node test: its non-empty children's boxes are tested, and the leaf children
    /// that passed will have their primitives tested (`traverse!` tests a node's whole
    /// primitive group before it visits another node; an any-hit ray that stops inside the
    /// group takes back the leaves it did not reach with [`Counts::stop`]).
    #[inline(always)]
    pub(super) fn visit(&mut self, node: &CwBvhNode, hit: u32) {
        self.inner += 1;
        let children = child_mask(node);
        self.bounds += u64::from(children.count_ones());
        self.leaves += u64::from((hit & children & !u32::from(node.imask)).count_ones());
    }

    /// Takes back the leaves of `node` (the node visited last) that a ray stopping with the
    /// primitive bits `remaining` still untested did not start: those whose first-tested
    /// primitive ([`leaf_top_bits`]) is among them. Once per stopping ray, so the per-node
    /// count stays one popcount.
    #[inline(always)]
    pub(super) fn stop(&mut self, node: &CwBvhNode, remaining: u32) {
        let tops = leaf_top_bits(node, child_mask(node));
        self.leaves -= u64::from((remaining & tops).count_ones());
    }

    /// The sum of two counts.
    #[inline]
    pub fn add(self, o: Counts) -> Counts {
        Counts {
            bounds: self.bounds + o.bounds,
            prims: self.prims + o.prims,
            inner: self.inner + o.inner,
            leaves: self.leaves + o.leaves,
            bounds_passed: self.bounds_passed + o.bounds_passed,
            prims_hit: self.prims_hit + o.prims_hit,
        }
    }

    /// Adds these counts to `stats`.
    pub fn record(self, stats: &mut Stats) {
        stats.add_bounds(self.bounds);
        stats.add_ray_triangle(self.prims);
        stats.add_visits(self.inner, self.leaves);
    }
}
