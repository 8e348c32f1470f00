//! 2×2 packet traversal (seed 003 §2.3.1, listing 2.4 fixed): the four rays of a pixel quad
//! traverse together, each with its own interval, held in [`F4`] lanes (SSE2, see
//! [`super::simd`]); a node is entered while any lane's interval is non-empty, a leaf's
//! triangles are tested against the active lanes with one packet-triangle test each.
//!
//! Listing 2.4 picks near and far children from the *first* ray's direction (`dir[0]`) and
//! divides by `dir[i][axis]` only after: it is correct only when all four rays have the same
//! direction sign on every axis, and `dir[0]` must read `dir[0][axis]` (erratum). Here near and
//! far come from the sign of the packet's direction component on the node's axis, and a quad
//! whose rays differ in sign pattern is split into sign-coherent sub-packets traced one after
//! the other (§2.3.1: "packets that do not obey this restriction must be split"); the paper's
//! omni-directional packets ([`super::omni`]) remove that restriction.
//!
//! Each lane's interval is split as in [`super::descend`], widened by [`T_SLACK`] for
//! rounding and keeping the old far distance for the far child (listing 2.2's erratum); a
//! lane whose origin lies on the split plane keeps both children whole. So every ray visits
//! the leaves it passes through front to back, and the exactness rule of [`super`] holds.

use super::group::{lanes_of, GroupState};
use super::simd::{F4, M4};
use super::{front_back, T_SLACK};
use crate::triangle::TriangleTest;

/// A packet stack entry: node and the four lanes' intervals.
#[derive(Clone, Copy, Debug)]
pub struct PacketEntry {
    /// Node index.
    pub node: u32,
    /// Interval starts.
    pub near: F4,
    /// Interval ends (an inactive lane has `near > far`).
    pub far: F4,
}

/// How a packet orders a node's children.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Order {
    /// Listing 2.4: near child by the (shared) direction sign per axis (`true`: negative).
    Signs([bool; 3]),
    /// Listing 4.1: front child by the origin's side, negative crossings `+∞`.
    Omni,
}

/// The direction sign pattern of a ray (sign bits, so `-0.0` counts as negative; either way
/// a zero component never crosses the plane).
#[inline]
pub fn signs(dir: crsh_core::glam::Vec3) -> [bool; 3] {
    [0, 1, 2].map(|a| dir[a].is_sign_negative())
}

/// Traces lanes `lanes` of packet `p` of `st` (they share the origin, and for
/// [`Order::Signs`] the sign pattern) through the tree. `stack` is scratch space.
pub fn trace_lanes<T: TriangleTest>(
    st: &mut GroupState<'_, T>,
    p: usize,
    lanes: u32,
    order: Order,
    stack: &mut Vec<PacketEntry>,
) {
    let tree = st.tree;
    let o = st.origin;
    let pk = st.packets[p];
    let start = pk.start as usize;
    let lanes = lanes & st.live(p);
    if lanes == 0 {
        return;
    }
    let mut near = [f32::INFINITY; 4];
    let mut far = [f32::NEG_INFINITY; 4];
    let mut inv = [[1.0f32; 4]; 3];
    for l in lanes_of(lanes) {
        if let Some((n, f)) = st.root[start + l] {
            (near[l], far[l]) = (n, f);
        }
        let d = st.rays[start + l].dir;
        for a in 0..3 {
            inv[a][l] = 1.0 / d[a];
        }
    }
    let inv = inv.map(F4::new);
    // Lanes moving strictly up / down each axis (a zero component moves neither way).
    let ninf = F4::splat(f32::NEG_INFINITY);
    let up = inv.map(|i| {
        F4::splat(0.0)
            .lt(i)
            .and(i.lt(F4::splat(f32::INFINITY)))
            .bits()
    });
    let down = inv.map(|i| i.lt(F4::splat(0.0)).and(ninf.lt(i)).bits());
    let (lo_f, hi_f) = (F4::splat(1.0 - T_SLACK), F4::splat(1.0 + T_SLACK));
    let inf = F4::splat(f32::INFINITY);
    let zero = F4::splat(0.0);
    stack.clear();
    stack.push(PacketEntry {
        node: 0,
        near: F4::new(near),
        far: F4::new(far),
    });
    while let Some(PacketEntry {
        mut node,
        mut near,
        mut far,
    }) = stack.pop()
    {
        loop {
            let alive = st.live(p) & lanes;
            // A lane whose best hit lies before this subtree needs nothing in it (a hit on a
            // split plane is final in no cell).
            let best = st.packet_best_t(p);
            let active = near.le(far).and(near.le(best)).and(M4::from_bits(alive));
            if active.bits() == 0 {
                break;
            }
            st.pc.nodes += 1;
            let n = &tree.nodes[node as usize];
            if n.is_leaf() {
                st.kd.leaves += 1;
                st.test_packet(n.index as usize, p, active.bits(), false);
                break;
            }
            st.kd.inner += 1;
            let a = n.axis as usize;
            let (first, second, dist) = match order {
                Order::Signs(neg) => {
                    let left = n.index as usize;
                    let (nr, fr) = if neg[a] {
                        (left + 1, left)
                    } else {
                        (left, left + 1)
                    };
                    (nr, fr, n.split - o[a])
                }
                Order::Omni => front_back(n, o[a]),
            };
            if dist == 0.0 {
                // Origin on the plane: a lane moving up the axis is in the right child for
                // every t > 0, one moving down in the left child, one with a zero component
                // in both; each with its whole interval.
                let left = n.index;
                let lb = active.bits() & !up[a];
                let rb = active.bits() & !down[a];
                let only = |bits: u32| F4::select(M4::from_bits(bits), near, inf);
                match (lb != 0, rb != 0) {
                    (true, true) => {
                        stack.push(PacketEntry {
                            node: left + 1,
                            near: only(rb),
                            far,
                        });
                        (node, near) = (left, only(lb));
                    }
                    (true, false) => (node, near) = (left, only(lb)),
                    (false, true) => (node, near) = (left + 1, only(rb)),
                    (false, false) => break,
                }
                continue;
            }
            let d = F4::splat(dist) * inv[a];
            let (lo, hi) = match order {
                Order::Signs(_) => {
                    // A crossing behind the origin is negative: the far child only.
                    let (x, y) = (d * lo_f, d * hi_f);
                    (x.min(y), x.max(y))
                }
                Order::Omni => {
                    // Modification 1: negative distances count as +∞.
                    let d = F4::select(d.ge(zero), d, inf);
                    (d * lo_f, d * hi_f)
                }
            };
            let first_far = far.min(hi);
            let second_near = near.max(lo);
            let fm = near.le(first_far).and(active).bits();
            let sm = second_near.le(far).and(active).bits();
            match (fm != 0, sm != 0) {
                (true, true) => {
                    stack.push(PacketEntry {
                        node: second as u32,
                        near: second_near,
                        far,
                    });
                    (node, far) = (first as u32, first_far);
                }
                (true, false) => (node, far) = (first as u32, first_far),
                (false, true) => (node, near) = (second as u32, second_near),
                (false, false) => break,
            }
        }
        if st.live(p) & lanes == 0 {
            break;
        }
    }
}

/// Listing 2.4 (fixed) on every packet of a group: each quad split into sign-coherent
/// sub-packets.
pub fn trace_group<T: TriangleTest>(st: &mut GroupState<'_, T>, stack: &mut Vec<PacketEntry>) {
    for p in 0..st.packets.len() {
        let start = st.packets[p].start as usize;
        let mut rest = st.live(p);
        while rest != 0 {
            let s = signs(st.rays[start + rest.trailing_zeros() as usize].dir);
            let sub = lanes_of(rest)
                .filter(|&l| signs(st.rays[start + l].dir) == s)
                .fold(0, |m, l| m | 1 << l);
            rest &= !sub;
            trace_lanes(st, p, sub, Order::Signs(s), stack);
        }
    }
}
