//! SAH kd-tree build with "perfect" split candidates (seed 003 §2.2.1 eq. 2.1, §3.2.1).
//!
//! # Cost (eq. 2.1) and termination
//!
//! A cell holding `N` triangles is split at the plane that minimises
//! `C_split = C_trav + C_isect·(N_L·SA_L/SA + N_R·SA_R/SA)` (`SA`: the cell's surface area,
//! `SA_L`, `SA_R`: its children's; a triangle in both children counts on both sides). The
//! paper's ratio is `C_isect = 5·C_trav` ([`SahParams::default`]). A cell becomes a leaf when
//! no plane beats the cost of the leaf, `C_isect·N` (the paper's criterion 1), at the depth
//! limit (criterion 2), when it holds no triangle (criterion 3), or when it holds at most
//! [`SahParams::leaf_size`] triangles (a parameter the paper does not have; `0` leaves the
//! decision to the cost alone). A depth limit of 0 asks for PBRT's `8 + 1.3·⌊log₂ N⌋`
//! ([`auto_max_depth`]).
//!
//! # Perfect splits
//!
//! The cost changes only where `N_L` or `N_R` does, so the candidates are the faces of each
//! triangle's bounding box: 2 per axis per triangle, `6N` per cell. As §2.2.1 and §3.2.1 ask,
//! the box is that of the triangle *clipped to the cell* (Sutherland-Hodgman in `f64`,
//! [`clip_box`]), not of the whole triangle, so a triangle straddling the cell's border
//! offers the planes where it really ends inside the cell. Per axis the boxes' minima and
//! maxima are sorted and swept in order (`O(N log N)` per cell, `O(N log² N)` for the tree).
//! After a split only the triangles that straddle the plane are clipped again, to their
//! child's cell.
//!
//! # Which leaves list a triangle
//!
//! A triangle is listed in every leaf whose closed cell it touches, and in every leaf it
//! comes closer than a margin `m` to (per axis `m = `[`CLIP_MARGIN`]` · max(|min|, |max|,
//! largest extent)` of the root box): a ray-triangle test can report a hit a rounding error
//! away from the triangle, and the hit point must lie in a leaf that lists the triangle. The
//! clip runs against the cell widened by `m`; the clipped box widened by `m` again (rounded
//! outward to `f32`) is the triangle's *extent* `E` in the cell. At a plane `s` the triangle
//! goes left when `E.min < s` and right when `E.max > s`: exactly when the clipped part comes
//! closer than `m` to the child's cell. A triangle lying in a split plane is therefore on
//! both sides (the paper's conservative choice), and the candidates `E.min`, `E.max` are the
//! planes that just leave a triangle out of one child.
//!
//! # Determinism
//!
//! Subtrees of large cells are built in parallel ([`rayon::join`]), each into its own
//! intermediate node, and the tree is laid out afterwards in one fixed order (children
//! allocated together, left subtree first), so the result does not depend on the thread
//! count. Ties between equal costs go to the lowest axis, then the lowest plane.

use crsh_core::glam::{DVec3, Vec3};
use crsh_core::{f32_down, f32_up, Aabb};

use super::{KdLeaf, KdNode, KdTree, LEAF};

/// Relative margin of triangle-cell membership (module doc, "Which leaves list a triangle"):
/// four times the traversal's final-hit margin ([`super::CELL_MARGIN`]), so that a hit on a
/// face the SAH cut just beyond (at the triangle's extent) is final in its leaf
/// ([`super::KdLeaf::holds_final`]) instead of sending the ray on through every leaf behind.
pub const CLIP_MARGIN: f64 = 4.0 * super::CELL_MARGIN as f64;

/// Cells with more triangles than this build their two subtrees in parallel.
const PAR_MIN: usize = 2048;

/// Depth limit the parameter can ask for (deeper trees only duplicate triangles).
pub const MAX_DEPTH_LIMIT: u32 = 64;

/// The SAH build's parameters.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SahParams {
    /// `C_trav` of eq. 2.1: the cost of one traversal step.
    pub c_trav: f64,
    /// `C_isect` of eq. 2.1: the cost of one ray-triangle test.
    pub c_isect: f64,
    /// Depth limit (the root alone: depth 0); 0 asks for [`auto_max_depth`].
    pub max_depth: u32,
    /// Cells with at most this many triangles are not split.
    pub leaf_size: usize,
}

impl Default for SahParams {
    /// The paper's costs (`C_isect = 5·C_trav`), automatic depth limit, leaves of 1.
    fn default() -> Self {
        SahParams {
            c_trav: 1.0,
            c_isect: 5.0,
            max_depth: 0,
            leaf_size: 1,
        }
    }
}

/// PBRT's depth limit for `n` triangles: `round(8 + 1.3·⌊log₂ n⌋)`, at most
/// [`MAX_DEPTH_LIMIT`].
pub fn auto_max_depth(n: usize) -> u32 {
    let log2 = usize::BITS - 1 - n.max(1).leading_zeros();
    ((8.0 + 1.3 * log2 as f64).round() as u32).min(MAX_DEPTH_LIMIT)
}

/// The bounding box `(min, max)` of triangle `v` clipped to the box `[lo, hi]`
/// (Sutherland-Hodgman, in `f64`), `None` when nothing of it is inside.
pub fn clip_box(v: &[DVec3; 3], lo: DVec3, hi: DVec3) -> Option<(DVec3, DVec3)> {
    let mut poly = [DVec3::ZERO; 9];
    let mut next = [DVec3::ZERO; 9];
    poly[..3].copy_from_slice(v);
    let mut n = 3;
    for a in 0..3 {
        for (plane, keep_above) in [(lo[a], true), (hi[a], false)] {
            let inside = |p: &DVec3| {
                if keep_above {
                    p[a] >= plane
                } else {
                    p[a] <= plane
                }
            };
            if poly[..n].iter().all(inside) {
                continue;
            }
            let mut m = 0;
            for i in 0..n {
                let (p, q) = (poly[i], poly[(i + 1) % n]);
                let (pin, qin) = (inside(&p), inside(&q));
                if pin {
                    next[m] = p;
                    m += 1;
                }
                if pin != qin {
                    let t = (plane - p[a]) / (q[a] - p[a]);
                    let mut r = p + (q - p) * t;
                    r[a] = plane;
                    next[m] = r;
                    m += 1;
                }
            }
            if m == 0 {
                return None;
            }
            std::mem::swap(&mut poly, &mut next);
            n = m;
        }
    }
    let (mut min, mut max) = (poly[0], poly[0]);
    for p in &poly[1..n] {
        min = min.min(*p);
        max = max.max(*p);
    }
    Some((min, max))
}

/// A triangle in a cell: its index in the build's input and its extent `E` there.
#[derive(Clone, Copy, Debug)]
struct Ref {
    tri: u32,
    min: [f32; 3],
    max: [f32; 3],
}

/// The build's fixed inputs.
struct Ctx {
    verts: Vec<[DVec3; 3]>,
    ids: Vec<u32>,
    /// Per-axis membership margin `m`.
    margin: DVec3,
    params: SahParams,
    max_depth: u32,
}

/// An intermediate node (subtrees are built independently, then laid out).
enum Node {
    Leaf {
        cell: Aabb,
        tris: Vec<u32>,
    },
    Inner {
        axis: u32,
        split: f32,
        children: Box<[Node; 2]>,
    },
}

/// `-0.0` as `+0.0` (so that planes compare and sort alike).
#[inline]
fn pos_zero(x: f32) -> f32 {
    x + 0.0
}

impl Ctx {
    /// The extent of triangle `tri` clipped to `cell` (module doc), `None` when it does not
    /// come within the margin of the cell.
    fn extent(&self, tri: u32, cell: &Aabb) -> Option<Ref> {
        let m = self.margin;
        let lo = cell.min.as_dvec3() - m;
        let hi = cell.max.as_dvec3() + m;
        let (bmin, bmax) = clip_box(&self.verts[tri as usize], lo, hi)?;
        let (emin, emax) = (bmin - m, bmax + m);
        Some(Ref {
            tri,
            min: [0, 1, 2].map(|a| pos_zero(f32_down(emin[a]))),
            max: [0, 1, 2].map(|a| pos_zero(f32_up(emax[a]))),
        })
    }

    /// Builds the subtree of `cell` holding `refs` at depth `depth`; returns it and the depth
    /// of its deepest leaf.
    fn build(&self, refs: Vec<Ref>, cell: Aabb, depth: u32) -> (Node, u32) {
        let n = refs.len();
        let p = &self.params;
        let split = if n == 0 || n <= p.leaf_size || depth >= self.max_depth {
            None
        } else {
            best_split(&refs, &cell, p).filter(|&(cost, _, _)| cost < p.c_isect * n as f64)
        };
        let Some((_, axis, s)) = split else {
            let mut tris: Vec<u32> = refs.iter().map(|r| self.ids[r.tri as usize]).collect();
            tris.sort_unstable();
            return (Node::Leaf { cell, tris }, depth);
        };
        let (mut lc, mut rc) = (cell, cell);
        lc.max[axis] = s;
        rc.min[axis] = s;
        let (mut left, mut right) = (Vec::new(), Vec::new());
        for r in refs {
            let (l, rt) = (r.min[axis] < s, r.max[axis] > s);
            match (l, rt) {
                (true, false) => left.push(r),
                (false, _) => right.push(r),
                (true, true) => {
                    left.extend(self.extent(r.tri, &lc));
                    right.extend(self.extent(r.tri, &rc));
                }
            }
        }
        let ((ln, ld), (rn, rd)) = if n >= PAR_MIN {
            rayon::join(
                || self.build(left, lc, depth + 1),
                || self.build(right, rc, depth + 1),
            )
        } else {
            (
                self.build(left, lc, depth + 1),
                self.build(right, rc, depth + 1),
            )
        };
        (
            Node::Inner {
                axis: axis as u32,
                split: s,
                children: Box::new([ln, rn]),
            },
            ld.max(rd),
        )
    }
}

/// Key of an `f32` that sorts like the number (for finite values; `-0.0` never occurs).
#[inline]
fn key(x: f32) -> u32 {
    let b = x.to_bits();
    if b >> 31 == 1 {
        !b
    } else {
        b | 0x8000_0000
    }
}

/// The number of an [`key`].
#[inline]
fn unkey(k: u32) -> f32 {
    f32::from_bits(if k >> 31 == 1 { k & 0x7fff_ffff } else { !k })
}

/// The cheapest split of `cell` holding `refs` by eq. 2.1: `(cost, axis, plane)`, over the
/// planes strictly inside the cell; `None` when there is none (a flat cell, or no extent
/// face inside it).
fn best_split(refs: &[Ref], cell: &Aabb, p: &SahParams) -> Option<(f64, usize, f32)> {
    let d = (cell.max - cell.min).as_dvec3();
    let area = d.x * d.y + d.y * d.z + d.z * d.x;
    if area.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) {
        return None;
    }
    let n = refs.len();
    let sweep = |a: usize| -> Option<(f64, usize, f32)> {
        let (lo, hi) = (cell.min[a], cell.max[a]);
        if lo >= hi {
            return None;
        }
        let mut mins: Vec<u32> = refs.iter().map(|r| key(r.min[a])).collect();
        let mut maxs: Vec<u32> = refs.iter().map(|r| key(r.max[a])).collect();
        mins.sort_unstable();
        maxs.sort_unstable();
        let (b, c) = ((a + 1) % 3, (a + 2) % 3);
        let (db, dc) = (d[b], d[c]);
        let (lo64, hi64) = (f64::from(lo), f64::from(hi));
        let mut best: Option<(f64, usize, f32)> = None;
        let (mut i, mut j) = (0, 0);
        while i < n || j < n {
            let k = match (mins.get(i), maxs.get(j)) {
                (Some(&x), Some(&y)) => x.min(y),
                (Some(&x), None) => x,
                (None, Some(&y)) => y,
                (None, None) => unreachable!("loop condition"),
            };
            // N_L: extents starting before the plane (all the minima consumed so far).
            let n_l = i;
            while j < n && maxs[j] == k {
                j += 1;
            }
            // N_R: extents ending after the plane.
            let n_r = n - j;
            while i < n && mins[i] == k {
                i += 1;
            }
            let s = unkey(k);
            if s > lo && s < hi {
                let s64 = f64::from(s);
                let (wl, wr) = (s64 - lo64, hi64 - s64);
                let area_l = wl * (db + dc) + db * dc;
                let area_r = wr * (db + dc) + db * dc;
                let cost =
                    p.c_trav + p.c_isect * (n_l as f64 * area_l + n_r as f64 * area_r) / area;
                if best.is_none_or(|(b, _, _)| cost < b) {
                    best = Some((cost, a, s));
                }
            }
        }
        best
    };
    let (x, (y, z)) = if n >= PAR_MIN {
        rayon::join(|| sweep(0), || rayon::join(|| sweep(1), || sweep(2)))
    } else {
        (sweep(0), (sweep(1), sweep(2)))
    };
    [x, y, z]
        .into_iter()
        .flatten()
        .fold(None, |best: Option<(f64, usize, f32)>, c| match best {
            Some(b) if b.0 <= c.0 => Some(b),
            _ => Some(c),
        })
}

/// Builds the SAH tree (module doc) over `tris` (`(scene id, vertices)`; pass only
/// hittable triangles: degenerate ones are never hit and only cost).
pub fn build(tris: &[(u32, [Vec3; 3])], params: &SahParams) -> KdTree {
    let bounds = tris
        .iter()
        .fold(Aabb::EMPTY, |b, (_, v)| b.union(Aabb::from_points(*v)));
    let mut tree = KdTree {
        bounds,
        ..KdTree::default()
    };
    if tris.is_empty() {
        return tree;
    }
    let (bmin, bmax) = (bounds.min.as_dvec3(), bounds.max.as_dvec3());
    let extent = (bmax - bmin).max_element();
    let scale = bmin.abs().max(bmax.abs()).max(DVec3::splat(extent));
    let margin = (scale * CLIP_MARGIN).max(DVec3::splat(f64::from(f32::MIN_POSITIVE)));
    let ctx = Ctx {
        verts: tris.iter().map(|(_, v)| v.map(|p| p.as_dvec3())).collect(),
        ids: tris.iter().map(|(id, _)| *id).collect(),
        margin,
        params: *params,
        max_depth: if params.max_depth == 0 {
            auto_max_depth(tris.len())
        } else {
            params.max_depth.min(MAX_DEPTH_LIMIT)
        },
    };
    let refs: Vec<Ref> = (0..tris.len() as u32)
        .filter_map(|t| ctx.extent(t, &bounds))
        .collect();
    let (root, depth) = ctx.build(refs, bounds, 0);
    tree.depth = depth;
    layout(root, &mut tree);
    tree
}

/// Lays `root` out in `tree` (nodes, leaves, leaf triangles): root at 0, each inner node's
/// children allocated together after it, the left subtree laid out before the right one.
fn layout(root: Node, tree: &mut KdTree) {
    let placeholder = KdNode {
        split: 0.0,
        axis: LEAF,
        index: 0,
    };
    tree.nodes.push(placeholder);
    let mut work = vec![(0usize, root)];
    while let Some((at, node)) = work.pop() {
        match node {
            Node::Leaf { cell, tris } => {
                tree.nodes[at] = KdNode {
                    split: 0.0,
                    axis: LEAF,
                    index: tree.leaves.len() as u32,
                };
                tree.leaves.push(KdLeaf {
                    min: cell.min.into(),
                    start: tree.leaf_tris.len() as u32,
                    max: cell.max.into(),
                    count: tris.len() as u32,
                });
                tree.leaf_tris.extend(tris);
            }
            Node::Inner {
                axis,
                split,
                children,
            } => {
                let c = tree.nodes.len();
                tree.nodes[at] = KdNode {
                    split,
                    axis,
                    index: c as u32,
                };
                tree.nodes.push(placeholder);
                tree.nodes.push(placeholder);
                let [l, r] = *children;
                work.push((c + 1, r));
                work.push((c, l));
            }
        }
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::kdtree::middle;
    use crate::triangle::tests::TestRng;
    use crsh_scene::Scene;

    /// The hittable triangles of `scene` (for Möller-Trumbore) as the builders take them.
    pub(crate) fn input(scene: &Scene) -> Vec<(u32, [Vec3; 3])> {
        (0..scene.triangle_count())
            .map(|t| (t as u32, scene.triangle(t)))
            .filter(|(_, [a, b, c])| !crate::triangle::is_degenerate(*a, *b, *c))
            .collect()
    }

    /// Every triangle of `tris` whose exact clip (`f64`) to a leaf's closed cell is not empty
    /// is listed in that leaf; a leaf lists each triangle once. Returns the pairs checked.
    pub(crate) fn check_membership(tree: &KdTree, tris: &[(u32, [Vec3; 3])]) -> usize {
        let mut touching = 0;
        for (l, leaf) in tree.leaves.iter().enumerate() {
            let listed = &tree.leaf_tris[leaf.range()];
            assert!(
                listed.windows(2).all(|w| w[0] < w[1]),
                "leaf {l}: unsorted or repeated triangles"
            );
            let cell = leaf.cell();
            for (id, v) in tris {
                let b = Aabb::from_points(*v);
                if (0..3).any(|a| b.min[a] > cell.max[a] || b.max[a] < cell.min[a]) {
                    continue;
                }
                let v64 = v.map(|p| p.as_dvec3());
                if clip_box(&v64, cell.min.as_dvec3(), cell.max.as_dvec3()).is_some() {
                    touching += 1;
                    assert!(
                        listed.binary_search(id).is_ok(),
                        "leaf {l} {cell:?} does not list triangle {id} {v:?}"
                    );
                }
            }
        }
        touching
    }

    fn random_soup(seed: u64, n: usize, scale: f32, offset: Vec3) -> Vec<(u32, [Vec3; 3])> {
        let mut rng = TestRng(seed);
        (0..n as u32)
            .map(|i| {
                let a = rng.vec3(-1.0, 1.0) * scale + offset;
                let size = if i % 10 == 0 { 0.5 } else { 0.1 } * scale;
                let mut b = a + rng.vec3(-size, size);
                let mut c = a + rng.vec3(-size, size);
                if i % 7 == 0 {
                    // Axis-aligned (flat on x): planar triangles in split planes.
                    b.x = a.x;
                    c.x = a.x;
                }
                (i * 2, [a, b, c])
            })
            .collect()
    }

    #[test]
    fn clip_box_clips_to_the_cell() {
        let v = [
            DVec3::ZERO,
            DVec3::new(2.0, 0.0, 0.0),
            DVec3::new(0.0, 2.0, 0.0),
        ];
        // Inside: the triangle's own box.
        assert_eq!(
            clip_box(&v, DVec3::splat(-1.0), DVec3::splat(3.0)),
            Some((DVec3::ZERO, DVec3::new(2.0, 2.0, 0.0)))
        );
        // Cut at x ≥ 1: the part with x in [1, 2] has y in [0, 1].
        assert_eq!(
            clip_box(&v, DVec3::new(1.0, -1.0, -1.0), DVec3::splat(3.0)),
            Some((DVec3::new(1.0, 0.0, 0.0), DVec3::new(2.0, 1.0, 0.0)))
        );
        // A box the triangle's box overlaps but the triangle misses (beyond the hypotenuse).
        assert_eq!(
            clip_box(&v, DVec3::new(1.5, 1.5, -1.0), DVec3::splat(3.0)),
            None
        );
        // Touching a corner of the cell: a point.
        assert_eq!(
            clip_box(&v, DVec3::new(2.0, -1.0, -1.0), DVec3::splat(3.0)),
            Some((DVec3::new(2.0, 0.0, 0.0), DVec3::new(2.0, 0.0, 0.0)))
        );
    }

    #[test]
    fn sort_keys_follow_the_float_order() {
        // (The outward rounding is tested with `crsh_core::f32_down`.)
        for x in [-2.5f32, -1e-3, 0.0, 1e-3, 7.0, 1e20] {
            assert_eq!(unkey(key(x)), x);
            assert!(key(x) < key(x.next_up()));
        }
    }

    #[test]
    fn trees_are_valid_and_list_every_touching_triangle() {
        for (seed, n, scale, offset) in [
            (1u64, 400usize, 1.0f32, Vec3::ZERO),
            (2, 60, 10.0, Vec3::new(-3.0, 50.0, 0.0)),
            (3, 300, 1.0, Vec3::splat(1e6)),
            (4, 1, 1.0, Vec3::ZERO),
        ] {
            let tris = random_soup(seed, n, scale, offset);
            for params in [
                SahParams::default(),
                SahParams {
                    leaf_size: 0,
                    ..SahParams::default()
                },
                SahParams {
                    leaf_size: 4,
                    max_depth: 6,
                    ..SahParams::default()
                },
            ] {
                let tree = build(&tris, &params);
                tree.validate().unwrap();
                assert!(tree.depth <= auto_max_depth(n).max(params.max_depth));
                let touching = check_membership(&tree, &tris);
                assert!(touching >= n, "seed {seed}: {touching} pairs");
                if n > 100 && offset == Vec3::ZERO {
                    assert!(tree.leaves.len() > 50, "seed {seed}: {}", tree.leaves.len());
                }
            }
        }
    }

    #[test]
    fn builtin_scene_trees_list_every_touching_triangle() {
        for name in crsh_scene::builtin::STATIC_NAMES {
            let scene = crsh_scene::builtin::build(name).unwrap();
            let tris = input(&scene);
            let tree = build(&tris, &SahParams::default());
            tree.validate().unwrap();
            assert!(tree.leaves.len() > 1, "{name}");
            check_membership(&tree, &tris);
        }
    }

    /// A ray moving away from a split plane (crossing at `+∞`) gets no interval behind it:
    /// `∞ − ∞·T_SLACK` was NaN and opened the back child to the whole interval, so every
    /// ray walked every leaf along its line to the root's exit.
    #[test]
    fn a_ray_leaving_a_plane_never_enters_the_side_behind_it() {
        use crate::kdtree::{crossing, descend};
        let d = crossing(-1.0, 2.0);
        assert_eq!(d, f32::INFINITY);
        assert_eq!(descend(0.0, 5.0, d, d), (Some((0.0, 5.0)), None));
        assert_eq!(descend(0.5, 5.0, 2.0, 2.0).1.unwrap().1, 5.0);
    }

    #[test]
    fn empty_input_gives_an_empty_tree() {
        let tree = build(&[], &SahParams::default());
        assert_eq!(tree, KdTree::default());
        tree.validate().unwrap();
    }

    #[test]
    fn the_depth_limit_holds() {
        let tris = random_soup(5, 2000, 1.0, Vec3::ZERO);
        for max_depth in [1, 2, 5, 9] {
            let tree = build(
                &tris,
                &SahParams {
                    max_depth,
                    leaf_size: 0,
                    ..SahParams::default()
                },
            );
            tree.validate().unwrap();
            assert_eq!(tree.depth, max_depth, "{max_depth}");
        }
        let auto = build(&tris, &SahParams::default());
        assert!(auto.depth <= auto_max_depth(2000) && auto.depth > 9);
        assert_eq!(auto_max_depth(1), 8);
        assert_eq!(auto_max_depth(262_144), 31);
        assert_eq!(auto_max_depth(usize::MAX), MAX_DEPTH_LIMIT);
    }

    /// One cell holding a few triangles whose boxes (not the triangles) reach into a corner:
    /// a split at the clipped box's face puts them on one side only.
    #[test]
    fn a_leaf_cell_costs_more_than_its_split() {
        // A big triangle far from a cluster of small ones: the best root split separates them.
        let mut tris = vec![(0u32, [Vec3::ZERO, Vec3::X, Vec3::Y])];
        for i in 1..20u32 {
            let o = Vec3::new(10.0, 10.0, i as f32 * 0.01);
            tris.push((i, [o, o + Vec3::X * 0.1, o + Vec3::Y * 0.1]));
        }
        let tree = build(&tris, &SahParams::default());
        tree.validate().unwrap();
        let root = tree.nodes[0];
        assert!(!root.is_leaf());
        // A costlier intersection makes splitting worth more, a costlier step less.
        let lazy = build(
            &tris,
            &SahParams {
                c_trav: 1e6,
                ..SahParams::default()
            },
        );
        assert_eq!(lazy.nodes.len(), 1);
        assert_eq!(lazy.leaf_tris.len(), 20);
    }

    #[test]
    fn perfect_splits_beat_unclipped_boxes() {
        // A long diagonal triangle across the whole scene with a cluster in one corner: once
        // the cells shrink, the clipped extent of the diagonal leaves most of them.
        let mut tris = vec![(
            0u32,
            [
                Vec3::ZERO,
                Vec3::new(10.0, 10.0, 0.0),
                Vec3::new(10.0, 10.0, 0.1),
            ],
        )];
        let mut rng = TestRng(9);
        for i in 1..400u32 {
            let o = rng.vec3(0.0, 10.0);
            tris.push((i, [o, o + rng.vec3(-0.1, 0.1), o + rng.vec3(-0.1, 0.1)]));
        }
        let tree = build(&tris, &SahParams::default());
        tree.validate().unwrap();
        check_membership(&tree, &tris);
        let with_diag = tree.leaf_tris.iter().filter(|&&t| t == 0).count();
        assert!(with_diag > 0);
        // The diagonal's unclipped box is the whole scene: every leaf would list it.
        assert!(
            with_diag * 4 < tree.leaves.len(),
            "{with_diag} of {}",
            tree.leaves.len()
        );
    }

    #[test]
    fn the_same_tree_for_any_thread_count() {
        let tris = random_soup(6, 3 * PAR_MIN, 1.0, Vec3::ZERO);
        let one = crate::with_threads(1, || build(&tris, &SahParams::default())).unwrap();
        let two = crate::with_threads(2, || build(&tris, &SahParams::default())).unwrap();
        assert_eq!(one, two);
        let four = crate::with_threads(4, || build(&tris, &SahParams::default())).unwrap();
        assert_eq!(one, four);
        one.validate().unwrap();
    }

    /// The SAH tree of a scene with many triangles does fewer triangle tests per ray than the
    /// middle-split tree (seed 003 fig. 2.9 against 2.10).
    #[test]
    fn sah_needs_fewer_tests_than_middle_splits() {
        use crate::kdtree::{trace_single, KdCounts};
        use crate::triangle::{MollerTrumbore, TriangleSet};
        use crsh_core::{Hit, HitMode};
        let scene = crsh_scene::builtin::build("office-boxes").unwrap();
        let tris = input(&scene);
        let set = TriangleSet::<MollerTrumbore>::new(&scene);
        let sah = build(&tris, &SahParams::default());
        let depth = sah.depth.max(auto_max_depth(tris.len()));
        let mid = middle::build(&tris, depth, 2);
        let rays = crate::intersect::brute::tests::random_rays(&scene, 7, 2000);
        let count = |tree: &KdTree| {
            let mut stack = Vec::new();
            rays.iter().fold(KdCounts::default(), |n, r| {
                let mut h = Hit::MISS;
                n.plus(trace_single::<MollerTrumbore>(
                    tree,
                    set.triangles(),
                    r,
                    HitMode::Closest,
                    &mut h,
                    &mut stack,
                ))
            })
        };
        let (s, m) = (count(&sah), count(&mid));
        eprintln!(
            "office-boxes ({} triangles): SAH {s:?} ({} nodes), middle {m:?} ({} nodes)",
            tris.len(),
            sah.nodes.len(),
            mid.nodes.len()
        );
        assert!(s.tests < m.tests, "SAH {s:?} middle {m:?}");
    }
}

/// Build times and tree sizes on the shared scenes (`cargo test --release -p crsh-cpu --lib
/// kdtree::sah::bench -- --ignored --nocapture`); skipped when the scenes are absent.
#[cfg(test)]
mod bench {
    use super::*;

    #[test]
    #[ignore = "a measurement: run in release with --ignored --nocapture"]
    fn shared_scene_build_times() {
        let dir = std::env::var_os("CRSH_SCENES")
            .map(std::path::PathBuf::from)
            .unwrap_or_else(|| {
                std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/scenes")
            });
        for rel in ["sponza/sponza.toml", "dining-room/dining-room.toml"] {
            let path = dir.join(rel);
            if !path.is_file() {
                eprintln!("SKIP: {} not found (set CRSH_SCENES)", path.display());
                continue;
            }
            let scene = crsh_scene::load_path(&path).unwrap();
            let tris = tests::input(&scene);
            for threads in [1, 2] {
                let t0 = std::time::Instant::now();
                let tree =
                    crate::with_threads(threads, || build(&tris, &SahParams::default())).unwrap();
                let ms = t0.elapsed().as_secs_f64() * 1e3;
                let empty = tree.leaves.iter().filter(|l| l.count == 0).count();
                eprintln!(
                    "{rel}: {} triangles, {threads} thread(s): {ms:.0} ms; {} nodes, {} leaves \
                     ({empty} empty), {} references ({:.2} per triangle), depth {} (limit {}), \
                     {:.1} MiB",
                    tris.len(),
                    tree.nodes.len(),
                    tree.leaves.len(),
                    tree.leaf_tris.len(),
                    tree.leaf_tris.len() as f64 / tris.len() as f64,
                    tree.depth,
                    auto_max_depth(tris.len()),
                    tree.bytes() as f64 / (1 << 20) as f64
                );
            }
        }
    }
}
