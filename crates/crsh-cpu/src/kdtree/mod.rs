//! RTTest's kd-tree (seed 003 §2.2.1, §3.2.1): the tree layout, its traversal primitives and
//! the single-ray traversal every coherent traversal falls back to.
//!
//! # Layout (seed 003 §3.2.1, `kd_node`)
//!
//! [`KdNode`]s in one array, root at 0. An inner node splits its cell at `split` on `axis`;
//! its children are allocated together: the *left* child (the cell's part with coordinates
//! `≤ split`) at `index`, the *right* one (`≥ split`) at `index + 1`. This is listing 2.1's
//! convention; listing 4.1 labels them the other way round (erratum), so the traversals here
//! never use "left"/"right" to mean near or far: they pick the *front* child (the one on the
//! ray origin's side) and the *back* child with [`front_back`]. A leaf's `index` names a
//! [`KdLeaf`] (its cell box and its run of [`KdTree::leaf_tris`]); RTTest keeps the same box
//! in `kd_leaf::ext` for packet/leaf culling.
//!
//! A triangle is listed in every leaf whose (closed) cell it touches, decided conservatively
//! (a rounding margin widens the test), so a ray's hit point always lies in some leaf that
//! lists the triangle. Triangles the configured ray-triangle test can never hit (degenerate
//! ones) are left out.
//!
//! # Traversal (listings 2.2 and 4.1, fixed)
//!
//! All traversals here follow listing 4.1's two omni-directional modifications, for single
//! rays too: front and back children are chosen by the origin's side of the split plane (for
//! rays sharing an origin that is a front-to-back order for every one of them), and a
//! negative distance to the plane counts as `+∞` (the ray never crosses it going forwards).
//! Listing 2.2's stack entry for the far child must keep the *old* far distance (the listing
//! pushes the new one, erratum): [`descend`] returns both children's intervals. Split
//! distances are widened by a relative rounding bound ([`T_SLACK`]), so a ray's interval
//! in a child always covers the part of the ray inside that child's cell.
//!
//! # Exactness
//!
//! A closest-hit ray stops only when its best hit point lies strictly inside the current
//! leaf's cell, shrunk by a rounding margin ([`KdLeaf::holds_final`]): every closer point of
//! the ray lies in a leaf visited before or in this one, and every triangle through such a
//! point is listed there. So hits (triangle, `t`, `u`, `v`) are brute force's with the same
//! triangle test, ties on `t` included (a tie on a cell boundary keeps the ray going).

pub mod coherent;
pub mod cone;
pub mod edge_width;
pub mod frustum;
pub mod group;
pub mod mft;
pub mod middle;
pub mod omni;
pub mod packet;
pub mod sah;
pub mod simd;

use bytemuck::{Pod, Zeroable};
use crsh_core::glam::Vec3;
use crsh_core::{Aabb, Hit, HitMode, Ray};

use crate::triangle::TriangleTest;

/// The `axis` of a leaf node.
pub const LEAF: u32 = 3;

/// Relative widening of split and box distances along a ray, for their rounding.
pub const T_SLACK: f32 = 1e-5;

/// Relative margin (of the coordinates' magnitude) by which a leaf cell is shrunk before a
/// hit point inside it is taken as final ([`KdLeaf::holds_final`]).
pub const CELL_MARGIN: f32 = 1e-5;

/// One node (12 bytes; RTTest's `kd_node` without its unused count).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct KdNode {
    /// Inner node: the split plane's coordinate on `axis`. Leaf: 0.
    pub split: f32,
    /// Inner node: 0, 1 or 2 (x, y, z). Leaf: [`LEAF`].
    pub axis: u32,
    /// Inner node: the left child (`≤ split`); the right child is `index + 1`.
    /// Leaf: index into [`KdTree::leaves`].
    pub index: u32,
}

impl KdNode {
    /// Whether this node is a leaf.
    #[inline(always)]
    pub fn is_leaf(&self) -> bool {
        self.axis == LEAF
    }
}

/// A leaf's cell and triangles (32 bytes; RTTest's `kd_leaf`).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct KdLeaf {
    /// The cell's minimum corner.
    pub min: [f32; 3],
    /// First entry in [`KdTree::leaf_tris`].
    pub start: u32,
    /// The cell's maximum corner.
    pub max: [f32; 3],
    /// Number of triangles.
    pub count: u32,
}

impl KdLeaf {
    /// The leaf's triangle-list range in [`KdTree::leaf_tris`].
    #[inline(always)]
    pub fn range(&self) -> std::ops::Range<usize> {
        self.start as usize..(self.start + self.count) as usize
    }

    /// The cell as a box.
    pub fn cell(&self) -> Aabb {
        Aabb {
            min: Vec3::from(self.min),
            max: Vec3::from(self.max),
        }
    }

    /// Whether a hit at `p` is final for a ray whose leaves are visited front to back once
    /// this leaf's triangles are tested: `p` lies inside the cell shrunk by
    /// [`CELL_MARGIN`] of the coordinates' magnitude on every axis.
    #[inline(always)]
    pub fn holds_final(&self, p: Vec3) -> bool {
        (0..3).all(|a| {
            let (lo, hi) = (self.min[a], self.max[a]);
            let m = CELL_MARGIN * lo.abs().max(hi.abs()).max(p[a].abs());
            p[a] > lo + m && p[a] < hi - m
        })
    }
}

/// A built kd-tree over a scene's triangles.
#[derive(Clone, Debug, PartialEq)]
pub struct KdTree {
    /// Nodes, root at 0 (empty for a scene without hittable triangles).
    pub nodes: Vec<KdNode>,
    /// Leaves, indexed by a leaf node's `index`.
    pub leaves: Vec<KdLeaf>,
    /// Scene triangle ids, leaf by leaf (a triangle appears once per leaf it touches).
    pub leaf_tris: Vec<u32>,
    /// The root cell: the hittable triangles' box.
    pub bounds: Aabb,
    /// Depth of the deepest leaf (the root alone: 0).
    pub depth: u32,
}

impl Default for KdTree {
    fn default() -> Self {
        KdTree {
            nodes: Vec::new(),
            leaves: Vec::new(),
            leaf_tris: Vec::new(),
            bounds: Aabb::EMPTY,
            depth: 0,
        }
    }
}

impl KdTree {
    /// Bytes of the tree's arrays.
    pub fn bytes(&self) -> u64 {
        (self.nodes.len() * std::mem::size_of::<KdNode>()
            + self.leaves.len() * std::mem::size_of::<KdLeaf>()
            + self.leaf_tris.len() * 4) as u64
    }

    /// Checks the structure: children in range and allocated after their parent, leaf runs
    /// inside `leaf_tris`, every leaf reached once, child cells splitting their parent's at
    /// `split`. Returns the first violation.
    pub fn validate(&self) -> Result<(), String> {
        if self.nodes.is_empty() {
            return if self.leaves.is_empty() && self.leaf_tris.is_empty() {
                Ok(())
            } else {
                Err("leaves without nodes".into())
            };
        }
        let mut seen = vec![false; self.leaves.len()];
        let mut stack = vec![(0usize, self.bounds)];
        while let Some((n, cell)) = stack.pop() {
            let node = self.nodes[n];
            if node.is_leaf() {
                let l = node.index as usize;
                let leaf = self
                    .leaves
                    .get(l)
                    .ok_or_else(|| format!("node {n}: leaf {l} out of range"))?;
                if std::mem::replace(&mut seen[l], true) {
                    return Err(format!("leaf {l} reached twice"));
                }
                if leaf.range().end > self.leaf_tris.len() {
                    return Err(format!("leaf {l}: triangles past the end"));
                }
                if leaf.cell() != cell {
                    return Err(format!("leaf {l}: cell {:?} is not {cell:?}", leaf.cell()));
                }
                continue;
            }
            let a = node.axis as usize;
            let c = node.index as usize;
            if node.axis > 2 || c <= n || c + 1 >= self.nodes.len() {
                return Err(format!("node {n}: bad axis or children"));
            }
            if !(node.split >= cell.min[a] && node.split <= cell.max[a]) {
                return Err(format!("node {n}: split {} outside its cell", node.split));
            }
            let (mut left, mut right) = (cell, cell);
            left.max[a] = node.split;
            right.min[a] = node.split;
            stack.push((c, left));
            stack.push((c + 1, right));
        }
        match seen.iter().position(|s| !s) {
            Some(l) => Err(format!("leaf {l} is not reached")),
            None => Ok(()),
        }
    }
}

/// Per-ray traversal counts: inner nodes visited (one split-plane test each), leaves visited,
/// triangles tested.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct KdCounts {
    /// Inner nodes visited.
    pub inner: u64,
    /// Leaves visited (empty ones included).
    pub leaves: u64,
    /// Ray-triangle tests.
    pub tests: u64,
}

impl KdCounts {
    /// The sum of two counts.
    #[inline]
    pub fn plus(self, o: KdCounts) -> KdCounts {
        KdCounts {
            inner: self.inner + o.inner,
            leaves: self.leaves + o.leaves,
            tests: self.tests + o.tests,
        }
    }

    /// Records these counts: one bound test per inner node (its split plane), the visits,
    /// and the triangle tests.
    pub fn record(self, stats: &mut crsh_core::Stats) {
        stats.add_bounds(self.inner);
        stats.add_ray_triangle(self.tests);
        stats.add_visits(self.inner, self.leaves);
    }
}

/// The distance interval `(near, far)` of the ray `origin + t·dir`, `t ∈ [t_min, t_max]`,
/// inside `bounds` (slab test widened by [`T_SLACK`]); `None` when it misses the box (then a
/// traversal visits nothing: listing 2.3 loops forever on such a ray, erratum).
#[inline]
pub fn clip(bounds: &Aabb, origin: Vec3, dir: Vec3, t_min: f32, t_max: f32) -> Option<(f32, f32)> {
    let mut near = t_min.max(0.0);
    let mut far = t_max;
    for a in 0..3 {
        let inv = 1.0 / dir[a];
        let t0 = (bounds.min[a] - origin[a]) * inv;
        let t1 = (bounds.max[a] - origin[a]) * inv;
        if dir[a] == 0.0 {
            // Parallel to the slab: inside it for every t, or never.
            if origin[a] < bounds.min[a] || origin[a] > bounds.max[a] {
                return None;
            }
            continue;
        }
        let (lo, hi) = if t0 <= t1 { (t0, t1) } else { (t1, t0) };
        near = near.max(lo - lo.abs() * T_SLACK);
        far = far.min(hi + hi.abs() * T_SLACK);
    }
    (near <= far).then_some((near, far))
}

/// Front and back child of inner node `node` for an origin coordinate `o` on its axis:
/// `(front, back, dist)` with `dist = split − o`. The front child is the one on the origin's
/// side (listing 4.1's modification 2, with listing 2.1's child order); on the plane
/// (`dist == 0`) the left child is front.
#[inline(always)]
pub fn front_back(node: &KdNode, o: f32) -> (usize, usize, f32) {
    let dist = node.split - o;
    let left = node.index as usize;
    if dist < 0.0 {
        (left + 1, left, dist)
    } else {
        (left, left + 1, dist)
    }
}

/// The distance at which a ray with inverse direction component `inv` crosses a split plane
/// `dist` away along the axis, with listing 4.1's modification 1: a crossing behind the
/// origin (or never) is `+∞`. `dist == 0` (origin on the plane) gives `+∞` too: the ray is
/// on the front side's plane for `t = 0` only if it leaves it, and the caller keeps both
/// children then ([`descend`]).
#[inline(always)]
pub fn crossing(dist: f32, inv: f32) -> f32 {
    let d = dist * inv;
    if d >= 0.0 {
        d
    } else {
        f32::INFINITY
    }
}

/// One step of interval traversal at an inner node: for a ray (or a proxy for a group) whose
/// crossings of the split plane lie in `[d_min, d_max]` and whose current interval is
/// `[near, far]`, the front child's interval and the back child's (each `None` when empty),
/// widened by [`T_SLACK`]. The back interval keeps the old `far` (listing 2.2's erratum).
#[inline(always)]
pub fn descend(
    near: f32,
    far: f32,
    d_min: f32,
    d_max: f32,
) -> (Option<Interval>, Option<Interval>) {
    // An infinite crossing stays infinite (`∞ − ∞·T_SLACK` would be NaN, and `max(near, NaN)`
    // would hand the back child the whole interval of a ray that never reaches it).
    let hi = if d_max.is_finite() {
        d_max + d_max.abs() * T_SLACK
    } else {
        d_max
    };
    let lo = if d_min.is_finite() {
        d_min - d_min.abs() * T_SLACK
    } else {
        d_min
    };
    let front_far = far.min(hi);
    let back_near = near.max(lo);
    (
        (near <= front_far).then_some((near, front_far)),
        (back_near <= far).then_some((back_near, far)),
    )
}

/// An interval `(near, far)` along a ray.
pub type Interval = (f32, f32);

/// A traversal stack entry: a node and its interval.
#[derive(Clone, Copy, Debug)]
pub struct Entry {
    /// Node index.
    pub node: u32,
    /// Interval start.
    pub near: f32,
    /// Interval end.
    pub far: f32,
}

/// Visits the leaves the ray `origin + t·dir` (`t ∈ [t_min, t_max]`) passes through, front to
/// back, calling `leaf(leaf_index, near, far, pending)` with the ray's (widened) interval in
/// the leaf's cell and the stack entries still to visit (every leaf to come lies in one of
/// them, and their intervals only shrink as they are descended). `leaf` returns how far the
/// ray still needs to go: `None` stops, `Some(limit)` goes on and skips every stacked subtree
/// whose interval starts beyond `limit` (for a closest-hit ray: its best `t`; the intervals
/// are widened, so a subtree that could hold a hit at `t ≤ limit` is never skipped). `limit`
/// is the one in force before the first leaf. Returns the inner nodes visited. `stack` is
/// scratch space (cleared here).
#[inline]
#[allow(clippy::too_many_arguments)]
pub fn walk_leaves_until(
    tree: &KdTree,
    origin: Vec3,
    dir: Vec3,
    t_min: f32,
    t_max: f32,
    mut limit: f32,
    stack: &mut Vec<Entry>,
    mut leaf: impl FnMut(usize, f32, f32, &[Entry]) -> Option<f32>,
) -> u64 {
    let mut inner = 0;
    stack.clear();
    let Some((near, far)) = (!tree.nodes.is_empty())
        .then(|| clip(&tree.bounds, origin, dir, t_min, t_max))
        .flatten()
    else {
        return 0;
    };
    let inv = Vec3::ONE / dir;
    stack.push(Entry { node: 0, near, far });
    while let Some(Entry {
        mut node,
        mut near,
        mut far,
    }) = stack.pop()
    {
        if near > limit {
            continue;
        }
        loop {
            let n = &tree.nodes[node as usize];
            if n.is_leaf() {
                match leaf(n.index as usize, near, far, stack) {
                    Some(l) => limit = l,
                    None => return inner,
                }
                break;
            }
            inner += 1;
            let a = n.axis as usize;
            let (front, back, dist) = front_back(n, origin[a]);
            if dist == 0.0 {
                // On the plane: for t > 0 the ray lies strictly on the side its direction
                // points to (`front` is the left child here); with a zero component it stays
                // on the plane, in both cells. Whole interval either way.
                if dir[a] > 0.0 {
                    node = back as u32;
                } else if dir[a] < 0.0 {
                    node = front as u32;
                } else {
                    stack.push(Entry {
                        node: back as u32,
                        near,
                        far,
                    });
                    node = front as u32;
                }
                continue;
            }
            let d = crossing(dist, inv[a]);
            match descend(near, far, d, d) {
                (Some(f), Some(b)) => {
                    stack.push(Entry {
                        node: back as u32,
                        near: b.0,
                        far: b.1,
                    });
                    (node, near, far) = (front as u32, f.0, f.1);
                }
                (Some(f), None) => (node, near, far) = (front as u32, f.0, f.1),
                (None, Some(b)) => (node, near, far) = (back as u32, b.0, b.1),
                (None, None) => break,
            }
        }
    }
    inner
}

/// Tests `ray` against the triangles of `leaf` with test `T`, merging into `best` as brute
/// force does ([`Hit::closer_than`]; any hit: stops at the first). Returns the tests done.
#[inline(always)]
pub fn test_leaf<T: TriangleTest>(
    tree: &KdTree,
    tris: &[T::Tri],
    leaf: &KdLeaf,
    ray: &Ray,
    r: &T::Ray,
    mode: HitMode,
    best: &mut Hit,
) -> u64 {
    let mut tests = 0;
    for &id in &tree.leaf_tris[leaf.range()] {
        tests += 1;
        if let Some(h) = T::hit(&tris[id as usize], r, ray.t_min, ray.t_max, id) {
            if h.closer_than(best) {
                *best = h;
                if mode == HitMode::Any {
                    break;
                }
            }
        }
    }
    tests
}

/// Listing 2.2, fixed: traces one ray front to back through `tree` with test `T`, merging into
/// `best` (any hit: skipped when `best` already is a hit, stops at the first hit). Closest
/// hits stop at the first leaf that [`KdLeaf::holds_final`] the best hit (module doc), and
/// skip the stacked subtrees that start beyond it ([`walk_leaves_until`]).
pub fn trace_single<T: TriangleTest>(
    tree: &KdTree,
    tris: &[T::Tri],
    ray: &Ray,
    mode: HitMode,
    best: &mut Hit,
    stack: &mut Vec<Entry>,
) -> KdCounts {
    let mut n = KdCounts::default();
    if crate::intersect::nothing_to_trace(ray, mode, best) {
        return n;
    }
    let r = T::ray_of(ray);
    let limit = match mode {
        HitMode::Any => f32::INFINITY,
        _ => best.t,
    };
    n.inner = walk_leaves_until(
        tree,
        ray.origin,
        ray.dir,
        ray.t_min,
        ray.t_max,
        limit,
        stack,
        |l, _, _, _| {
            n.leaves += 1;
            let leaf = &tree.leaves[l];
            n.tests += test_leaf::<T>(tree, tris, leaf, ray, &r, mode, best);
            let finished = match mode {
                HitMode::Any => best.is_hit(),
                _ => best.is_hit() && leaf.holds_final(ray.at(best.t)),
            };
            // A hit on a split plane is never final in either cell: the subtrees whose
            // intervals start past it are skipped instead.
            (!finished).then_some(best.t)
        },
    );
    n
}
