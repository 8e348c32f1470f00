//! Multiple frustum traversal, MFT (seed 003 §4.1.5): a tile is split into its four quadrants,
//! and the four quadrant frusta traverse the tree together, one per [`F4`] lane, like the rays
//! of a 2×2 packet. The paper's seven steps, as done here:
//!
//! 1. Each frustum is a "ray" with its own interval `(t_near, t_far)`, updated by frustum
//!    interval traversal ([`super::frustum`]: its own per-axis crossing multipliers).
//! 2. A frustum is active while its interval is non-empty *and* it has unfinished rays.
//! 3. The four intervals are split at each node with 4-wide operations.
//! 4. A node pushed on the stack carries the active mask of the frusta that enter it.
//! 5. When no frustum is active, traversal of the current node stops.
//! 6. At a leaf only the packets of active frusta are tested (with packet/leaf culling as an
//!    option, as for the single frustum).
//! 7. A frustum whose rays are all finished becomes inactive: its lane is dropped from the
//!    mask of every node popped afterwards.
//!
//! Each lane uses exactly the arithmetic of the single frustum ([`super::frustum::Proxy`],
//! [`super::frustum::widen_lo`] / [`super::frustum::widen_hi`], SSE's min/max rule), and a
//! quadrant's crossing range lies inside its tile's, so for closest-hit rays MFT never visits
//! a node or tests a packet at a leaf that the single frustum over the whole tile would not
//! (§4.1.5: "MFT never performs more traversal or intersection operations"; a closest-hit ray
//! finishes at the same leaf in both). Any-hit rays finish at their first hit, which the
//! single frustum, testing more packets, may find earlier, so there the bound can fail.
//!
//! The lanes may be cones instead of pyramids ([`Shape::Cone`], table 4.5's "MFT cone"): each
//! lane keeps its own units (`t` for a pyramid, `h` for a cone), which never mix.

use super::cone::Cone;
use super::frustum::{live_dirs, root_span, Proxy, NEVER_NEG, NEVER_POS};
use super::group::GroupState;
use super::simd::F4;
use super::{front_back, T_SLACK};
use crate::triangle::TriangleTest;

/// The proxy shape of each quadrant.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Shape {
    /// Pyramid frusta (table 4.3).
    Pyramid,
    /// Cones (table 4.5's MFT cone); a quadrant too spread for a cone uses its pyramid.
    Cone,
}

/// An MFT stack entry: node, the four intervals and the active mask.
#[derive(Clone, Copy, Debug)]
pub struct MftEntry {
    /// Node index.
    pub node: u32,
    /// Interval starts.
    pub near: F4,
    /// Interval ends.
    pub far: F4,
    /// Frusta that entered this node.
    pub mask: u32,
}

/// MFT over one group: its packets' quadrants are the four frusta. `stack` is scratch space.
pub fn trace_group<T: TriangleTest>(
    st: &mut GroupState<'_, T>,
    shape: Shape,
    cull: bool,
    stack: &mut Vec<MftEntry>,
) {
    let mut near = [f32::INFINITY; 4];
    let mut far = [f32::NEG_INFINITY; 4];
    let mut m = [[[[1.0f32; 4]; 2]; 2]; 3];
    let mut mask = 0u32;
    for q in 0..4 {
        let dirs = live_dirs(st, 1 << q);
        let cone = match shape {
            Shape::Cone => Cone::enclosing(&dirs),
            Shape::Pyramid => None,
        };
        let lane = match cone {
            Some(c) => c
                .root_span(st, 1 << q)
                .map(|r| (Cone::proxy(c.axis, c.tan_alpha), r)),
            None => Proxy::pyramid(&dirs).zip(root_span(st, 1 << q)),
        };
        let Some((proxy, (n, f))) = lane else {
            continue;
        };
        (near[q], far[q]) = (n, f);
        mask |= 1 << q;
        for (ma, pa) in m.iter_mut().zip(&proxy.m) {
            for (ms, ps) in ma.iter_mut().zip(pa) {
                for (mb, pb) in ms.iter_mut().zip(ps) {
                    mb[q] = *pb;
                }
            }
        }
    }
    if mask == 0 {
        return;
    }
    // Lanes needing the left / right child when the origin is on a split plane
    // (`Proxy::on_plane`).
    let lane_bits =
        |f: &dyn Fn(usize) -> bool| (0..4).filter(|&q| f(q)).fold(0u32, |b, q| b | 1 << q);
    let on_left: [u32; 3] = std::array::from_fn(|a| lane_bits(&|q| m[a][0][1][q] == NEVER_POS));
    let on_right: [u32; 3] = std::array::from_fn(|a| lane_bits(&|q| m[a][1][1][q] == NEVER_NEG));
    let m = m.map(|ma| ma.map(|ms| ms.map(F4::new)));
    let tree = st.tree;
    let o = st.origin;
    let (lo_f, hi_f) = (F4::splat(1.0 - T_SLACK), F4::splat(1.0 + T_SLACK));
    let inf = F4::splat(f32::INFINITY);
    let zero = F4::splat(0.0);
    stack.clear();
    stack.push(MftEntry {
        node: 0,
        near: F4::new(near),
        far: F4::new(far),
        mask,
    });
    while let Some(MftEntry {
        mut node,
        mut near,
        mut far,
        mut mask,
    }) = stack.pop()
    {
        loop {
            // Steps 2, 5 and 7.
            mask &= st.alive_quadrants();
            // Quadrants whose unfinished rays all have hits before this subtree.
            for q in 0..4 {
                if near.lane(q) > st.limits[q] {
                    mask &= !(1 << q);
                }
            }
            if mask == 0 {
                break;
            }
            st.pc.nodes += 1;
            let n = &tree.nodes[node as usize];
            if n.is_leaf() {
                st.kd.leaves += 1;
                // Step 6.
                for p in 0..st.packets.len() {
                    if mask >> st.packets[p].quadrant & 1 == 1 {
                        st.test_packet(n.index as usize, p, 0xF, cull);
                    }
                }
                st.update_limits();
                break;
            }
            st.kd.inner += 1;
            let a = n.axis as usize;
            let (front, back, dist) = front_back(n, o[a]);
            if dist == 0.0 {
                let left = n.index;
                let (lb, rb) = (mask & on_left[a], mask & on_right[a]);
                match (lb != 0, rb != 0) {
                    (true, true) => {
                        stack.push(MftEntry {
                            node: left + 1,
                            near,
                            far,
                            mask: rb,
                        });
                        (node, mask) = (left, lb);
                    }
                    (true, false) => (node, mask) = (left, lb),
                    (false, true) => (node, mask) = (left + 1, rb),
                    (false, false) => break,
                }
                continue;
            }
            // Step 3: the four crossing ranges, negative ones +∞.
            let ms = &m[a][usize::from(dist < 0.0)];
            let d = F4::splat(dist);
            let past = |x: F4| F4::select(x.ge(zero), x, inf);
            let lo = past(d * ms[0]) * lo_f;
            let hi = past(d * ms[1]) * hi_f;
            let front_far = far.min(hi);
            let back_near = near.max(lo);
            let fm = near.le(front_far).bits() & mask;
            let bm = back_near.le(far).bits() & mask;
            match (fm != 0, bm != 0) {
                (true, true) => {
                    // Step 4.
                    stack.push(MftEntry {
                        node: back as u32,
                        near: back_near,
                        far,
                        mask: bm,
                    });
                    (node, far, mask) = (front as u32, front_far, fm);
                }
                (true, false) => (node, far, mask) = (front as u32, front_far, fm),
                (false, true) => (node, near, mask) = (back as u32, back_near, bm),
                (false, false) => break,
            }
        }
        if st.all_done() {
            break;
        }
    }
}
