//! Edge-width shadow rays on the kd-tree (seed 003 §5, listing 5.1, eq. 5.1), with the
//! listing's errata fixed.
//!
//! Listing 5.1 visits the leaves front to back, gathers the crossings of each leaf inside the
//! leaf's interval `tNear ≤ t ≤ tFar`, sorts them and pairs them entry/exit with the open
//! entry carried from leaf to leaf, and stops once a pair is wider than `R`. Fixed here:
//! - **Open entry** (off by one): the entry carried to the next leaf is the leaf's last
//!   crossing (`distances[distCount]`), not `distances[distCount − 1]`. The pairing is
//!   [`crsh_core::edge_width::EdgeWidthScan`], shared with `brute` and `bvh`.
//! - **A crossing on a leaf boundary counts once**: the listing's closed intervals gather a hit
//!   on a split plane in both leaves (the triangle is listed in both), which shifts every
//!   later pair. The traversal's intervals are also widened for rounding ([`super::T_SLACK`]),
//!   so neighbouring leaves overlap a little and even half-open intervals would not partition
//!   the ray. A triangle crosses a segment at most once, so each crossing is taken the first
//!   time its triangle is found inside the current leaf's interval and never again (the
//!   triangles already taken are remembered per ray): each crossing counts exactly once.
//! - **Order across leaves**: because of the widening, a leaf visited later may hold a
//!   crossing a little before the last one of the leaf visited before it. Crossings are
//!   therefore fed to the pairing only once no leaf still to be visited can produce an earlier
//!   one: a leaf only yields crossings at `t ≥` its interval's start, and the intervals of all
//!   leaves to come start no earlier than the smallest start among the traversal stack's
//!   entries (descending never lowers an interval's start). So after each leaf the crossings
//!   before that bound are sorted (by `t`, ties by triangle id) and fed; at the end all are.
//!
//! The result is the brute-force answer bit for bit (the same crossings, by the same
//! triangle test, fed in the same order to the same scan), and the early exit of listing 5.1
//! applies as soon as a pair as wide as `R` is fed (or, with `R = 0`, the first crossing).
//! The walk is [`super::walk_leaves_until`], which hands each leaf the pending stack entries
//! the bound above is taken from.

use crsh_core::edge_width::{
    sort_crossings, Crossing, EdgePairing, EdgeWidthLights, EdgeWidthScan,
};
use crsh_core::{Hit, Ray};

use super::{walk_leaves_until, Entry, KdCounts, KdTree};
use crate::triangle::TriangleTest;

/// Traces the edge-width shadow ray `ray` through `tree` with test `T`, feeding its crossings
/// to `scan` (which holds the light's radius, `R` of eq. 5.1, and the pairing rule), storing the [`crsh_core::HitMode::EdgeWidth`] answer in `best`
/// (replaced, not merged). `stack` is scratch space. Returns the inner nodes, leaves and
/// triangle tests visited (see the module docs).
pub fn trace_edge_width<T: TriangleTest>(
    tree: &KdTree,
    tris: &[T::Tri],
    ray: &Ray,
    mut scan: EdgeWidthScan<'_>,
    best: &mut Hit,
    stack: &mut Vec<Entry>,
) -> KdCounts {
    let mut n = KdCounts::default();
    *best = Hit::MISS;
    if ray.t_min.partial_cmp(&ray.t_max) != Some(std::cmp::Ordering::Less) {
        return n;
    }
    let r = T::ray_of(ray);
    // Crossings found but not yet fed to the scan, and every triangle taken so far.
    let mut pending: Vec<Crossing> = Vec::new();
    let mut taken: Vec<u32> = Vec::new();
    n.inner = walk_leaves_until(
        tree,
        ray.origin,
        ray.dir,
        ray.t_min,
        ray.t_max,
        f32::INFINITY,
        stack,
        |l, near, far, to_come| {
            n.leaves += 1;
            let leaf = &tree.leaves[l];
            for &id in &tree.leaf_tris[leaf.range()] {
                n.tests += 1;
                if let Some(h) = T::hit(&tris[id as usize], &r, ray.t_min, ray.t_max, id) {
                    if h.t >= near && h.t <= far && !taken.contains(&id) {
                        taken.push(id);
                        pending.push(Crossing { t: h.t, tri: id });
                    }
                }
            }
            // Every leaf still to come starts at or after the smallest pending start.
            let bound = to_come.iter().map(|e| e.near).fold(f32::INFINITY, f32::min);
            (!feed(&mut scan, &mut pending, bound)).then_some(f32::INFINITY)
        },
    );
    feed(&mut scan, &mut pending, f32::INFINITY);
    *best = scan.finish();
    n
}

/// [`trace_edge_width`] for a batch, in parallel (each ray independently, so hits and counts
/// do not depend on the thread count): ray `i`'s answer goes to `hits[i]` (replaced), with `R`
/// the radius of its light in `lights` and crossings paired by `pairing`. What the `kdtree`
/// intersector runs for [`crsh_core::HitMode::EdgeWidth`].
///
/// # Errors
/// [`crsh_core::CoreError::InvalidInput`] when the lengths differ or a ray names a light
/// outside `lights`.
pub fn trace_batch_edge_width<T: TriangleTest>(
    tree: &KdTree,
    tris: &[T::Tri],
    rays: &[Ray],
    lights: &EdgeWidthLights,
    pairing: EdgePairing,
    hits: &mut [Hit],
) -> crsh_core::Result<KdCounts> {
    use rayon::prelude::*;
    crsh_core::ray::check_hits_per_ray("rays", rays.len(), hits.len())?;
    lights.check(rays)?;
    Ok(rays
        .par_chunks(256)
        .zip(hits.par_chunks_mut(256))
        .map(|(rs, hs)| {
            let mut stack = Vec::new();
            rs.iter().zip(hs).fold(KdCounts::default(), |n, (r, h)| {
                n.plus(trace_edge_width::<T>(
                    tree,
                    tris,
                    r,
                    lights.scan(r, pairing),
                    h,
                    &mut stack,
                ))
            })
        })
        .reduce(KdCounts::default, KdCounts::plus))
}

/// Feeds the pending crossings before `bound` to `scan` in sorted order and drops them;
/// returns whether the scan is done (fully occluded: the traversal may stop).
fn feed(scan: &mut EdgeWidthScan<'_>, pending: &mut Vec<Crossing>, bound: f32) -> bool {
    if scan.is_done() {
        return true;
    }
    if pending.is_empty() {
        return false;
    }
    sort_crossings(pending);
    let ready = pending.partition_point(|c| c.t < bound);
    for &c in &pending[..ready] {
        if scan.push(c) {
            return true;
        }
    }
    pending.drain(..ready);
    false
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::intersect::brute::tests::{random_rays, soup, test_ray};
    use crate::kdtree::middle;
    use crate::triangle::{MollerTrumbore, Projected, TriangleSet};
    use crsh_core::edge_width::{edge_width_hit, occlusion, SharedVertices};
    use crsh_core::glam::Vec3;
    use crsh_scene::{Scene, SceneBuilder};

    /// Brute force's edge-width answer for `ray` with test `T` (every triangle).
    fn brute<T: TriangleTest>(set: &TriangleSet<T>, ray: &Ray, radius: f32) -> Hit {
        brute_with(set, ray, radius, None)
    }

    /// [`brute`] pairing by `shared`.
    fn brute_with<T: TriangleTest>(
        set: &TriangleSet<T>,
        ray: &Ray,
        radius: f32,
        shared: Option<&SharedVertices>,
    ) -> Hit {
        let r = T::ray_of(ray);
        let mut c: Vec<Crossing> = (0..set.len() as u32)
            .filter_map(|id| {
                T::hit(&set.triangles()[id as usize], &r, ray.t_min, ray.t_max, id)
                    .map(|h| Crossing { t: h.t, tri: id })
            })
            .collect();
        edge_width_hit(&mut c, radius, shared)
    }

    fn kd<T: TriangleTest>(scene: &Scene, leaf: usize) -> (KdTree, TriangleSet<T>) {
        let set = TriangleSet::<T>::from_triangles(
            (0..scene.triangle_count()).map(|t| scene.triangle(t)),
        );
        let tris: Vec<(u32, [Vec3; 3])> = (0..scene.triangle_count())
            .map(|t| (t as u32, scene.triangle(t)))
            .collect();
        let tree = middle::build(&tris, 24, leaf);
        tree.validate().unwrap();
        (tree, set)
    }

    /// Checks the kd-tree against brute force for every ray, radius and pairing rule, with
    /// trees of a few leaf sizes; returns how many answers were partial occlusions (penumbra)
    /// with each rule.
    fn check<T: TriangleTest>(scene: &Scene, rays: &[Ray], radii: &[f32]) -> [usize; 2] {
        let mut partial = [0; 2];
        let sv = SharedVertices::weld(&scene.positions, &scene.indices);
        for leaf in [1, 8] {
            let (tree, set) = kd::<T>(scene, leaf);
            let mut stack = Vec::new();
            for (rule, shared) in [None, Some(&sv)].into_iter().enumerate() {
                for &radius in radii {
                    for ray in rays {
                        let want = brute_with(&set, ray, radius, shared);
                        let mut got = Hit {
                            t: 1.0,
                            tri: 3,
                            u: 0.5,
                            v: 0.5,
                        };
                        trace_edge_width::<T>(
                            &tree,
                            set.triangles(),
                            ray,
                            EdgeWidthScan::new(radius, shared),
                            &mut got,
                            &mut stack,
                        );
                        assert_eq!(
                            (got.tri, got.t.to_bits(), got.u.to_bits(), got.v.to_bits()),
                            (
                                want.tri,
                                want.t.to_bits(),
                                want.u.to_bits(),
                                want.v.to_bits()
                            ),
                            "R {radius} leaf {leaf} rule {rule}: {ray:?}"
                        );
                        partial[rule] +=
                            usize::from(occlusion(&got) > 0.0 && occlusion(&got) < 1.0);
                    }
                }
            }
        }
        partial
    }

    #[test]
    fn batches_are_the_single_rays_and_check_their_lights() {
        let scene = slabs();
        let (tree, set) = kd::<MollerTrumbore>(&scene, 4);
        let rays: Vec<Ray> = [10.0, 2.75, 2.25, 1.5, 0.5].map(x_ray).to_vec();
        let mut hits = vec![Hit::MISS; rays.len()];
        let lights = EdgeWidthLights::new(vec![4.0], &scene.positions, &scene.indices);
        let n = trace_batch_edge_width::<MollerTrumbore>(
            &tree,
            set.triangles(),
            &rays,
            &lights,
            EdgePairing::Any,
            &mut hits,
        )
        .unwrap();
        assert!(n.tests > 0 && n.leaves > 0);
        for (r, h) in rays.iter().zip(&hits) {
            assert_eq!(*h, brute(&set, r, 4.0));
        }
        let mut bad = rays.clone();
        bad[1].light = 1;
        assert!(trace_batch_edge_width::<MollerTrumbore>(
            &tree,
            set.triangles(),
            &bad,
            &lights,
            EdgePairing::Any,
            &mut hits
        )
        .is_err());
        assert!(trace_batch_edge_width::<MollerTrumbore>(
            &tree,
            set.triangles(),
            &rays,
            &lights,
            EdgePairing::Any,
            &mut hits[1..]
        )
        .is_err());
    }

    #[test]
    fn equals_brute_force_on_a_soup() {
        let scene = soup(7, 200);
        let mut rays = random_rays(&scene, 11, 300);
        // Finite segments, light index 0.
        for r in &mut rays {
            r.t_max = r.t_max.min(3.0);
            r.light = 0;
        }
        let radii = [0.0, 0.05, 0.3, 10.0];
        let partial = check::<MollerTrumbore>(&scene, &rays, &radii);
        assert!(partial[0] > 0, "no penumbra ray");
        check::<Projected>(&scene, &rays, &radii);
    }

    /// Two slabs (closed boxes of 12 triangles) along x, `[0, 1]` and `[1.5, 2]` (y and z in
    /// `[-0.5, 0.5]`), seen by rays along +x from x = -1: a middle split of their box falls
    /// on x = 1, the first slab's exit face.
    fn slabs() -> Scene {
        let mut b = SceneBuilder::new("slabs");
        b.material(crsh_scene::Material::default());
        for (lo, hi) in [(0.0f32, 1.0f32), (1.5, 2.0)] {
            let h = 0.5;
            let p = Vec3::new;
            let corners = [
                p(lo, -h, -h),
                p(hi, -h, -h),
                p(hi, h, -h),
                p(lo, h, -h),
                p(lo, -h, h),
                p(hi, -h, h),
                p(hi, h, h),
                p(lo, h, h),
            ];
            let faces = [
                [0, 3, 2],
                [0, 2, 1],
                [4, 5, 6],
                [4, 6, 7],
                [0, 1, 5],
                [0, 5, 4],
                [3, 7, 6],
                [3, 6, 2],
                [0, 4, 7],
                [0, 7, 3],
                [1, 2, 6],
                [1, 6, 5],
            ];
            b.mesh("slab", &corners, None, &faces, 0);
        }
        b.camera(crsh_scene::Camera {
            eye: Vec3::new(-5.0, 0.0, 0.0),
            target: Vec3::ZERO,
            up: Vec3::Y,
            vfov_deg: 45.0,
            aspect: None,
        });
        b.build("two slabs").unwrap()
    }

    /// A ray along +x from x = -1 (off the faces' diagonals), ending at `t_max`.
    fn x_ray(t_max: f32) -> Ray {
        let mut r = test_ray(Vec3::new(-1.0, 0.1, 0.05), Vec3::X, 0.0, t_max, 0);
        r.light = 0;
        r
    }

    #[test]
    fn a_crossing_on_a_split_plane_counts_once() {
        let scene = slabs();
        for leaf in [1, 4, 16] {
            let (tree, set) = kd::<MollerTrumbore>(&scene, leaf);
            assert_eq!((tree.nodes[0].axis, tree.nodes[0].split), (0, 1.0));
            let mut stack = Vec::new();
            // Widths 1 and 0.5; R = 2: occlusion 0.5 from the first slab. Counting the face
            // on the split plane twice would pair (0, 1), (1, 1.5) and leave x = 2 open:
            // fully occluded.
            let mut got = Hit::MISS;
            trace_edge_width::<MollerTrumbore>(
                &tree,
                set.triangles(),
                &x_ray(10.0),
                EdgeWidthScan::new(2.0, None),
                &mut got,
                &mut stack,
            );
            assert_eq!((got.t, got.u, got.v), (1.0, 0.5, 1.0), "leaf size {leaf}");
            assert_eq!(got, brute(&set, &x_ray(10.0), 2.0));
        }
    }

    #[test]
    fn an_unpaired_entry_occludes_fully() {
        let scene = slabs();
        for leaf in [1, 16] {
            let (tree, set) = kd::<MollerTrumbore>(&scene, leaf);
            let mut stack = Vec::new();
            let mut got = Hit::MISS;
            let mut run = |t_max: f32, radius: f32| {
                trace_edge_width::<MollerTrumbore>(
                    &tree,
                    set.triangles(),
                    &x_ray(t_max),
                    EdgeWidthScan::new(radius, None),
                    &mut got,
                    &mut stack,
                );
                assert_eq!(got, brute(&set, &x_ray(t_max), radius));
                (got.t, got.u, got.v)
            };
            // Ending inside the second slab: three crossings, the last one unpaired.
            assert_eq!(run(2.75, 100.0), (2.5, 1.0, f32::INFINITY));
            // Ending inside the first slab: one crossing.
            assert_eq!(run(1.5, 100.0), (1.0, 1.0, f32::INFINITY));
            // Ending between the slabs: one pair of width 1 against R = 4.
            assert_eq!(run(2.25, 4.0), (1.0, 0.25, 1.0));
        }
    }

    #[test]
    fn exits_early_once_a_pair_is_as_wide_as_r() {
        let scene = slabs();
        let (tree, set) = kd::<MollerTrumbore>(&scene, 1);
        let mut stack = Vec::new();
        let mut got = Hit::MISS;
        let ray = x_ray(10.0);
        let all = trace_edge_width::<MollerTrumbore>(
            &tree,
            set.triangles(),
            &ray,
            EdgeWidthScan::new(100.0, None),
            &mut got,
            &mut stack,
        );
        assert_eq!((got.t, got.u, got.v), (1.0, 0.01, 1.0));
        let early = trace_edge_width::<MollerTrumbore>(
            &tree,
            set.triangles(),
            &ray,
            EdgeWidthScan::new(0.75, None),
            &mut got,
            &mut stack,
        );
        assert_eq!((got.t, got.u, got.v), (1.0, 1.0, 1.0));
        assert_eq!(got, brute(&set, &ray, 0.75));
        assert!(early.leaves < all.leaves, "{early:?} vs {all:?}");
    }
}
