//! Middle-split kd-tree build (seed 003 fig. 2.9): every cell split in half on its longest
//! axis until it holds few triangles or the depth limit is reached. The baseline the SAH
//! build improves on, and a simple, obviously conservative tree for tests.
//!
//! A triangle goes to each child whose closed cell its bounding box overlaps, with a margin of
//! [`ASSIGN_MARGIN`] of the coordinates' magnitude, so a triangle touching the split plane is
//! listed on both sides.

use crsh_core::glam::Vec3;
use crsh_core::Aabb;

use super::{KdLeaf, KdNode, KdTree, LEAF};

/// Relative margin of the triangle-cell overlap test.
pub const ASSIGN_MARGIN: f32 = 1e-5;

/// Whether the box `b` overlaps the closed cell `c`, widened by [`ASSIGN_MARGIN`].
pub fn overlaps(b: &Aabb, c: &Aabb) -> bool {
    (0..3).all(|a| {
        let m = ASSIGN_MARGIN * c.min[a].abs().max(c.max[a].abs()).max(b.max[a].abs());
        b.min[a] <= c.max[a] + m && b.max[a] >= c.min[a] - m
    })
}

/// Builds a middle-split tree over `tris` (`(scene id, vertices)`; pass only hittable ones):
/// cells with more than `max_leaf` triangles are split until depth `max_depth`.
pub fn build(tris: &[(u32, [Vec3; 3])], max_depth: u32, max_leaf: usize) -> KdTree {
    let boxes: Vec<(u32, Aabb)> = tris
        .iter()
        .map(|&(id, v)| (id, Aabb::from_points(v)))
        .collect();
    let bounds = boxes.iter().fold(Aabb::EMPTY, |b, (_, t)| b.union(*t));
    let mut tree = KdTree {
        bounds,
        ..KdTree::default()
    };
    if boxes.is_empty() {
        return tree;
    }
    tree.nodes.push(KdNode {
        split: 0.0,
        axis: LEAF,
        index: 0,
    });
    // (node, cell, depth, triangles)
    let all: Vec<usize> = (0..boxes.len()).collect();
    let mut work = vec![(0usize, bounds, 0u32, all)];
    while let Some((n, cell, depth, ids)) = work.pop() {
        tree.depth = tree.depth.max(depth);
        let size = cell.size();
        let a = if size.x >= size.y && size.x >= size.z {
            0
        } else if size.y >= size.z {
            1
        } else {
            2
        };
        if ids.len() <= max_leaf || depth >= max_depth || size[a] <= 0.0 {
            tree.nodes[n] = KdNode {
                split: 0.0,
                axis: LEAF,
                index: tree.leaves.len() as u32,
            };
            tree.leaves.push(KdLeaf {
                min: cell.min.into(),
                start: tree.leaf_tris.len() as u32,
                max: cell.max.into(),
                count: ids.len() as u32,
            });
            tree.leaf_tris.extend(ids.iter().map(|&i| boxes[i].0));
            continue;
        }
        let split = (cell.min[a] + cell.max[a]) * 0.5;
        let (mut lc, mut rc) = (cell, cell);
        lc.max[a] = split;
        rc.min[a] = split;
        let left: Vec<usize> = ids
            .iter()
            .copied()
            .filter(|&i| overlaps(&boxes[i].1, &lc))
            .collect();
        let right: Vec<usize> = ids
            .iter()
            .copied()
            .filter(|&i| overlaps(&boxes[i].1, &rc))
            .collect();
        let child = tree.nodes.len();
        tree.nodes[n] = KdNode {
            split,
            axis: a as u32,
            index: child as u32,
        };
        let leaf = KdNode {
            split: 0.0,
            axis: LEAF,
            index: 0,
        };
        tree.nodes.push(leaf);
        tree.nodes.push(leaf);
        work.push((child + 1, rc, depth + 1, right));
        work.push((child, lc, depth + 1, left));
    }
    tree
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::kdtree::{trace_single, KdCounts};
    use crate::triangle::{MollerTrumbore, TriangleSet, TriangleTest};
    use crsh_core::{Hit, HitMode, Ray, RayKind};

    fn ray(o: Vec3, d: Vec3) -> Ray {
        Ray {
            origin: o,
            t_min: 0.0,
            dir: d.normalize(),
            t_max: f32::INFINITY,
            throughput: Vec3::ONE,
            kind: RayKind::Reflection as u32,
            pixel: 0,
            light: u32::MAX,
            depth: 1,
            source: 0,
        }
    }

    #[test]
    fn single_ray_hits_equal_brute_force_on_a_random_soup() {
        let mut s = 12345u64;
        let mut rnd = move || {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((s >> 40) as f32 / (1u64 << 24) as f32) * 2.0 - 1.0
        };
        let mut soup = Vec::new();
        for _ in 0..300 {
            let c = Vec3::new(rnd(), rnd(), rnd()) * 4.0;
            soup.push([
                c,
                c + Vec3::new(rnd(), rnd(), rnd()) * 0.5,
                c + Vec3::new(rnd(), rnd(), rnd()) * 0.5,
            ]);
        }
        let set = TriangleSet::<MollerTrumbore>::from_triangles(soup.iter().copied());
        let input: Vec<(u32, [Vec3; 3])> = soup
            .iter()
            .enumerate()
            .map(|(i, t)| (i as u32, *t))
            .collect();
        let tree = build(&input, 20, 4);
        tree.validate().unwrap();
        assert!(tree.nodes.len() > 20);
        let mut stack = Vec::new();
        let mut total = KdCounts::default();
        for _ in 0..2000 {
            let r = ray(
                Vec3::new(rnd(), rnd(), rnd()) * 6.0,
                Vec3::new(rnd(), rnd(), rnd()),
            );
            for mode in [HitMode::Closest, HitMode::Any] {
                let mut want = Hit::MISS;
                let rr = MollerTrumbore::ray_of(&r);
                for (i, t) in set.triangles().iter().enumerate() {
                    if let Some(h) = MollerTrumbore::hit(t, &rr, r.t_min, r.t_max, i as u32) {
                        if h.closer_than(&want) {
                            want = h;
                        }
                    }
                }
                let mut got = Hit::MISS;
                total = total.plus(trace_single::<MollerTrumbore>(
                    &tree,
                    set.triangles(),
                    &r,
                    mode,
                    &mut got,
                    &mut stack,
                ));
                match mode {
                    HitMode::Any => assert_eq!(got.is_hit(), want.is_hit()),
                    _ => assert_eq!(got, want),
                }
            }
        }
        // The tree saves work: under half the tests of brute force.
        assert!(total.tests < 2000 * 2 * 300 / 2, "{total:?}");
    }
}
