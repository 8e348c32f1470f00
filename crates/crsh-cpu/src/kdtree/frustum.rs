//! Frustum interval traversal (seed 003 §2.3.2, listing 4.2 with the omni-directional
//! modifications): one interval `[near, far]` for a whole group of rays that share an origin
//! (a screen tile of camera rays, or of shadow rays from a point light), updated at each split
//! plane with the smallest and largest crossing distance over the group's rays; at a leaf the
//! group's 2×2 packets are tested, optionally after packet/leaf culling (§4.1.4, table 4.2).
//!
//! # The crossing range of a group ([`Proxy`])
//!
//! Listing 4.2 takes the min and max over the four corner rays' crossings with SIMD at every
//! node. Corner rays bound a pinhole camera's tile but not arbitrary shared-origin rays (a
//! light's shadow rays to the surface points of a tile), so here the extremes are taken once
//! per group, per axis, over *all* its rays' inverse directions (4 rays at a time with
//! [`F4`], then a horizontal min/max, the listing's `sseHorizontalMin/Max`), and a node costs
//! two multiplies. With `dist = split − origin` on the node's axis, a ray crosses the plane at
//! `dist · (1/dir)` when that is positive and never (`+∞`, listing 4.1's modification 1)
//! otherwise. For `dist > 0` only rays with `1/dir > 0` (finite) cross: the smallest crossing
//! is `dist · min(1/dir)` over them and the largest `dist · max(1/dir)`, or `+∞` as soon as
//! one ray does not cross (zero or negative component); `dist < 0` mirrors it with the
//! negative inverses. [`Proxy::m`] stores these multipliers (a sentinel of the wrong sign
//! stands for `+∞`). Multiplication by `dist` is monotone under rounding, so the group's
//! computed bounds enclose every ray's computed crossing, and both are widened by
//! [`T_SLACK`] ([`widen_lo`], [`widen_hi`]) for the rounding of the crossings themselves.
//!
//! Front and back children are chosen by the shared origin's side (listing 4.2's modification
//! 1, [`front_back`]), which is a front-to-back order for every ray of the group; an origin on
//! the split plane keeps both children with the whole interval. Each ray's interval in a node
//! lies inside the group's, so every leaf a ray passes through is visited, in its order, and
//! the exactness rule of [`super`] holds for each ray; the traversal stops when all rays are
//! finished.
//!
//! The same scalar loop traverses a cone ([`super::cone`]): only the multipliers and the
//! units of the interval differ.

use super::group::GroupState;
use super::simd::F4;
use super::{front_back, Entry, Interval, T_SLACK};
use crate::triangle::TriangleTest;
use crsh_core::glam::Vec3;

/// Per-axis crossing multipliers of a proxy (a frustum or a cone): for a split plane at
/// `dist = split − origin` on axis `a`, the smallest and largest crossing distances are
/// `dist · m[a][s][0]` and `dist · m[a][s][1]` (`s = 0` for `dist > 0`, 1 for `dist < 0`),
/// each taken as `+∞` when negative ([`past`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Proxy {
    /// `[axis][side][min, max]` multipliers.
    pub m: [[[f32; 2]; 2]; 3],
}

/// Multiplier that makes a crossing `+∞` for `dist > 0`.
pub const NEVER_POS: f32 = -1.0;
/// Multiplier that makes a crossing `+∞` for `dist < 0`.
pub const NEVER_NEG: f32 = 1.0;

/// Listing 4.1's modification 1: a negative (or NaN) crossing is `+∞`.
#[inline(always)]
pub fn past(d: f32) -> f32 {
    if d >= 0.0 {
        d
    } else {
        f32::INFINITY
    }
}

/// A non-negative crossing lowered by [`T_SLACK`] (the same product in every traversal).
#[inline(always)]
pub fn widen_lo(d: f32) -> f32 {
    d * (1.0 - T_SLACK)
}

/// A non-negative crossing raised by [`T_SLACK`].
#[inline(always)]
pub fn widen_hi(d: f32) -> f32 {
    d * (1.0 + T_SLACK)
}

/// SSE's `minps` rule on scalars (`a < b ? a : b`), so scalar and 4-wide traversals agree.
#[inline(always)]
pub fn min_ps(a: f32, b: f32) -> f32 {
    if a < b {
        a
    } else {
        b
    }
}

/// SSE's `maxps` rule on scalars (`a > b ? a : b`).
#[inline(always)]
pub fn max_ps(a: f32, b: f32) -> f32 {
    if a > b {
        a
    } else {
        b
    }
}

impl Proxy {
    /// The smallest and largest crossing of the split plane `dist` away on `axis` (`dist ≠ 0`).
    #[inline(always)]
    pub fn crossings(&self, axis: usize, dist: f32) -> (f32, f32) {
        let m = self.m[axis][usize::from(dist < 0.0)];
        (past(dist * m[0]), past(dist * m[1]))
    }

    /// For an origin on a split plane on `axis`: whether some direction of the proxy does not
    /// move strictly up the axis (so the left child, `≤ split`, is needed) and whether some
    /// does not move strictly down (the right child). Read off the sentinels: `m[axis][0][1]`
    /// is [`NEVER_POS`] exactly when some direction does not point up, `m[axis][1][1]` is
    /// [`NEVER_NEG`] exactly when some does not point down.
    #[inline(always)]
    pub fn on_plane(&self, axis: usize) -> (bool, bool) {
        (
            self.m[axis][0][1] == NEVER_POS,
            self.m[axis][1][1] == NEVER_NEG,
        )
    }

    /// The pyramid (frustum) proxy of rays with directions `dirs` from one origin (module
    /// doc): per axis the extremes of the crossing inverses, 4 rays at a time. `None` without
    /// rays.
    pub fn pyramid(dirs: &[Vec3]) -> Option<Proxy> {
        if dirs.is_empty() {
            return None;
        }
        let inf = F4::splat(f32::INFINITY);
        let ninf = F4::splat(f32::NEG_INFINITY);
        let zero = F4::splat(0.0);
        let mut m = [[[0.0f32; 2]; 2]; 3];
        for (a, ma) in m.iter_mut().enumerate() {
            let (mut pmin, mut pmax, mut nmin, mut nmax) = (inf, ninf, inf, ninf);
            let (mut all_pos, mut all_neg) = (true, true);
            for c in dirs.chunks(4) {
                // Padding lanes repeat the chunk's first ray.
                let inv = F4::new(std::array::from_fn(|l| 1.0 / c.get(l).unwrap_or(&c[0])[a]));
                let pos = zero.lt(inv).and(inv.lt(inf));
                let neg = inv.lt(zero).and(ninf.lt(inv));
                all_pos &= pos.bits() == 0xF;
                all_neg &= neg.bits() == 0xF;
                pmin = pmin.min(F4::select(pos, inv, inf));
                pmax = pmax.max(F4::select(pos, inv, ninf));
                nmin = nmin.min(F4::select(neg, inv, inf));
                nmax = nmax.max(F4::select(neg, inv, ninf));
            }
            let (pmin, pmax, nmin, nmax) = (pmin.hmin(), pmax.hmax(), nmin.hmin(), nmax.hmax());
            let any_pos = pmin < f32::INFINITY;
            let any_neg = nmax > f32::NEG_INFINITY;
            ma[0] = [
                if any_pos { pmin } else { NEVER_POS },
                if all_pos { pmax } else { NEVER_POS },
            ];
            // dist < 0: the inverse closest to zero crosses first.
            ma[1] = [
                if any_neg { nmax } else { NEVER_NEG },
                if all_neg { nmin } else { NEVER_NEG },
            ];
        }
        Some(Proxy { m })
    }
}

/// The smallest root `near` and largest root `far` over the unfinished rays of `st` whose
/// packets lie in the quadrants of `quadrants` (bit mask), in the rays' own `t`.
pub fn root_span<T: TriangleTest>(st: &GroupState<'_, T>, quadrants: u32) -> Option<Interval> {
    let mut span: Option<Interval> = None;
    for pk in st
        .packets
        .iter()
        .filter(|p| quadrants >> p.quadrant & 1 == 1)
    {
        for i in pk.start as usize..(pk.start + pk.len) as usize {
            if let (false, Some((n, f))) = (st.done[i], st.root[i]) {
                span = Some(span.map_or((n, f), |(a, b)| (a.min(n), b.max(f))));
            }
        }
    }
    span
}

/// The directions of the unfinished rays in the quadrants of `quadrants`.
pub fn live_dirs<T: TriangleTest>(st: &GroupState<'_, T>, quadrants: u32) -> Vec<Vec3> {
    st.packets
        .iter()
        .filter(|p| quadrants >> p.quadrant & 1 == 1)
        .flat_map(|p| p.start as usize..(p.start + p.len) as usize)
        .filter(|&i| !st.done[i])
        .map(|i| st.rays[i].dir)
        .collect()
}

/// Listing 4.2 (omni-directional): traverses `proxy` with interval `root` from the group's
/// origin, testing every packet of the group at each leaf (`cull`: packet/leaf culling), until
/// all rays are finished. `stack` is scratch space.
pub fn trace_proxy<T: TriangleTest>(
    st: &mut GroupState<'_, T>,
    proxy: &Proxy,
    root: Interval,
    cull: bool,
    stack: &mut Vec<Entry>,
) {
    let tree = st.tree;
    let o = st.origin;
    stack.clear();
    stack.push(Entry {
        node: 0,
        near: root.0,
        far: root.1,
    });
    while let Some(Entry {
        mut node,
        mut near,
        mut far,
    }) = stack.pop()
    {
        if near > st.limit() {
            continue;
        }
        loop {
            let n = &tree.nodes[node as usize];
            st.pc.nodes += 1;
            if n.is_leaf() {
                st.kd.leaves += 1;
                if st.tree.leaves[n.index as usize].count > 0 {
                    for p in 0..st.packets.len() {
                        st.test_packet(n.index as usize, p, 0xF, cull);
                    }
                }
                if st.all_done() {
                    return;
                }
                st.update_limits();
                break;
            }
            st.kd.inner += 1;
            let a = n.axis as usize;
            let (front, back, dist) = front_back(n, o[a]);
            if dist == 0.0 {
                let left = n.index;
                match proxy.on_plane(a) {
                    (true, true) => {
                        stack.push(Entry {
                            node: left + 1,
                            near,
                            far,
                        });
                        node = left;
                    }
                    (true, false) => node = left,
                    (false, true) => node = left + 1,
                    (false, false) => break,
                }
                continue;
            }
            let (d_min, d_max) = proxy.crossings(a, dist);
            let front_far = min_ps(far, widen_hi(d_max));
            let back_near = max_ps(near, widen_lo(d_min));
            match (near <= front_far, back_near <= far) {
                (true, true) => {
                    stack.push(Entry {
                        node: back as u32,
                        near: back_near,
                        far,
                    });
                    (node, far) = (front as u32, front_far);
                }
                (true, false) => (node, far) = (front as u32, front_far),
                (false, true) => (node, near) = (back as u32, back_near),
                (false, false) => break,
            }
        }
    }
}

/// Frustum interval traversal of one group (module doc): the pyramid over all its rays.
pub fn trace_group<T: TriangleTest>(
    st: &mut GroupState<'_, T>,
    cull: bool,
    stack: &mut Vec<Entry>,
) {
    let Some(root) = root_span(st, 0xF) else {
        return;
    };
    let Some(proxy) = Proxy::pyramid(&live_dirs(st, 0xF)) else {
        return;
    };
    trace_proxy(st, &proxy, root, cull, stack);
}
