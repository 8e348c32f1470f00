//! `bvh2`: obvhs's binary BVH (`Bvh2`) over the scene's triangles, traversed by a stack loop
//! written here: the object hierarchy whose node and leaf visits compare with the binary and
//! 4-wide Embree BVHs of seed 001 (Zoet and Bikker, tables 2-4), next to the 8-wide `bvh`.
//!
//! # Build
//!
//! The tree is built once, when the stage is constructed ([`BinaryBvh::new`]), as `bvh` builds
//! its binary tree before compressing it ([`crate::intersect::bvh`]): obvhs's PLOC builder and
//! reinsertion optimizer with the preset chosen by `build_quality` (the `slow` preset without
//! spatial pre-splits, for the reason `bvh` gives). PLOC makes one leaf per triangle; obvhs's
//! SAH leaf collapsing (`leaf_collapser::collapse`, with the preset's
//! `collapse_traversal_cost`) then merges sibling leaves into leaves of up to
//! `max_prims_per_leaf` triangles where the surface area heuristic prefers them, and a second
//! reinsertion pass follows (the preset's `post_collapse_reinsertion_batch_ratio_multiplier`),
//! exactly as obvhs's `build_bvh2_from_tris`. The default, 4, is the size of Embree's
//! `Triangle4` leaf block, so leaves hold one to four triangles as Embree's SAH leaves of
//! one block do; `max_prims_per_leaf = 1` keeps PLOC's single-triangle leaves (collapsing is
//! skipped). Leaf triangles are stored in leaf order, prepared for `test`. Degenerate
//! triangles are left out of the tree.
//!
//! # Identical to brute force
//!
//! Primitive tests use the ray-triangle test of parameter `test` (`mt`, `watertight`,
//! `projected`: [`crate::triangle`]) on scene triangle ids, merged with [`Hit::closer_than`],
//! so closest hits (triangle, `t`, `u`, `v`) are the brute-force ones bit for bit, ties
//! included, under the same rules as `bvh`'s (its module doc):
//!
//! - The slab test ([`box_entry`]) uses the ray's own interval `[t_min, min(t_max, best t)]`
//!   widened by a relative `1e-5` for the rounding of the triangle test's `t`, and the
//!   comparison is inclusive, so a triangle at exactly the best `t` with a lower id is still
//!   reached.
//! - Zero direction components are clamped to `±1e-25` (a perturbation of `1e-25·t`), never
//!   divided by; every slab is widened by `1e-6·(|(min - o)/d| + |(max - o)/d|)`, a bound on
//!   the rounding of the two plane distances (each `(b - o)·(1/d)`, three roundings). Where
//!   the origin lies in a slab of non-zero width and the component was clamped, one of the
//!   two terms is huge, so the slab never culls, as for the exact axis-parallel ray. Boxes are
//!   obvhs's exact `f32` triangle bounds (no quantization).
//! - The box test is geometric, so the one difference `bvh` documents applies here too: a
//!   spurious self-hit (a computed `t` of pure rounding noise, or the projected test's
//!   cancelling `t` far from the origin) that lies outside its triangle's box can be culled.
//!
//! # Traversal
//!
//! Depth first with an explicit stack, nearest child first: a visited inner node tests both
//! children's boxes; both hit, the nearer (smaller entry distance; the left one on a tie) is
//! visited next and the other pushed with its entry distance, which is compared again with
//! the culling distance when popped (the same test the box would get again: the culling
//! distance only shrinks). The root's own box is not tested (every ray visits the root, as in
//! Embree). Any-hit rays stop at the first hit.
//!
//! # Moving geometry (`update`)
//!
//! `update = "rebuild"` (the default) builds the tree anew every frame. `update = "refit"`
//! keeps the first frame's topology and leaves: the next frame copies the tree, recomputes its
//! leaf boxes from the moved triangles and refits the inner boxes bottom-up
//! (`Bvh2::refit_all`), as `bvh` does before re-compressing; traversal degrades as the
//! geometry moves away from the topology, hits do not. When the set of triangles the test can
//! hit changes, the tree is built anew instead.
//!
//! # Counting
//!
//! - `stats.add_bounds`: one per child box tested (two per inner node visited).
//! - `stats.add_ray_triangle`: one per leaf primitive tested.
//! - `stats.add_visits(inner, leaves)` (seed 001's visited internal nodes / leaves): `inner`
//!   counts the inner nodes visited (both children tested); `leaves` the leaf nodes visited,
//!   i.e. whose primitives are tested (an any-hit ray stopping in a leaf counts it). So
//!   `bounds = 2·inner`, `leaves <= ray_triangle`, and `inner >= 1` per ray traced, except
//!   on a tree whose root is a leaf (a scene of one hittable triangle): its triangles are
//!   tested without a box test, one leaf visit and no inner one. A pushed child culled when
//!   popped is not visited.
//!
//! Rays whose stored hit is already a hit are skipped in any-hit mode (nothing counted). Rays
//! are traced in parallel with rayon, each independently, so results and counts do not
//! depend on the thread count. [`Query::Candidates`] is not supported: it returns
//! [`CoreError::Unsupported`](crsh_core::CoreError::Unsupported).

use std::sync::Arc;
use std::time::Duration;

use crsh_core::glam::Vec3A;
use crsh_core::{
    Hit, HitMode, Intersector, ParamInfo, Query, Ray, Registry, Result, StageContext, StageKind,
    StageSpec, StageVariantInfo, Stats,
};
use crsh_scene::Scene;
use obvhs::aabb::Aabb;
use obvhs::bvh2::leaf_collapser::collapse;
use obvhs::bvh2::reinsertion::ReinsertionOptimizer;
use obvhs::bvh2::Bvh2;

use crate::backend::Cpu;
use crate::intersect::bvh::{
    build_bvh2, build_params, cull_distance, hittable_triangles, obvhs_intersector, quality_param,
    refit_bvh2, start_trace, test_param, update_param, BuildQuality, Counts, LeafTracer, Leaves,
    NodeRay, SLAB_SLACK,
};
use crate::triangle::{TestKind, TriangleTest};

/// The default of `max_prims_per_leaf`: one Embree `Triangle4` block.
pub const DEFAULT_MAX_PRIMS_PER_LEAF: u32 = 4;

/// The largest `max_prims_per_leaf` (obvhs's `Bvh2` limit).
pub const MAX_PRIMS_PER_LEAF: u32 = 255;

/// The binary BVH intersector (variant `bvh2`).
pub struct BinaryBvh {
    bvh: Bvh2,
    /// Prepared triangle and scene triangle id per primitive slot.
    leaves: Leaves,
    quality: BuildQuality,
    max_prims_per_leaf: u32,
    build_time: Duration,
    /// The scene ids of the tree's triangles in build order (what `bvh.primitive_indices`
    /// index), kept for the next frame's refit (`update = "refit"`).
    refit_ids: Option<Vec<u32>>,
}

impl std::fmt::Debug for BinaryBvh {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("BinaryBvh")
            .field("nodes", &self.bvh.nodes.len())
            .field("primitives", &self.leaves.ids.len())
            .field("quality", &self.quality)
            .field("max_prims_per_leaf", &self.max_prims_per_leaf)
            .field("test", &self.test())
            .field("build_time", &self.build_time)
            .finish()
    }
}

/// The catalogue entry of the `bvh2` intersector.
pub fn info() -> StageVariantInfo {
    StageVariantInfo::new(
        StageKind::Intersect,
        "bvh2",
        "obvhs binary BVH (Bvh2: PLOC, reinsertion, SAH leaf collapsing), stack traversal \
         nearest child first, closest and any hit, node, triangle and visit counts; \
         whole-scene queries only",
    )
    .param(quality_param())
    .param(ParamInfo::int(
        "max_prims_per_leaf",
        DEFAULT_MAX_PRIMS_PER_LEAF as i64,
        1,
        MAX_PRIMS_PER_LEAF as i64,
        "most triangles per leaf after obvhs's SAH leaf collapsing (4: an Embree Triangle4 \
         block; 1: no collapsing)",
    ))
    .param(update_param(
        "per frame of a moving scene: build anew with `build_quality`, or refit the boxes of \
         the first frame's tree (obvhs `Bvh2::refit_all`)",
    ))
    .param(test_param())
    .scene_only()
}

/// Registers `bvh2` ([`info`], [`BinaryBvh::new`]).
pub fn register(registry: &mut Registry<Cpu>) -> Result<()> {
    registry.add_intersector(info(), |ctx, spec| {
        Ok(Box::new(BinaryBvh::new(ctx.scene, spec)?))
    })?;
    Ok(())
}

impl BinaryBvh {
    /// Builds the tree of `scene` with `spec.build_quality` (`fast` | `medium` | `slow`) and
    /// `spec.max_prims_per_leaf` (1 ..= 255), its leaves prepared for `spec.test`.
    pub fn new(scene: &Arc<Scene>, spec: &StageSpec) -> Result<BinaryBvh> {
        let (quality, refit, test) = build_params(spec, "bvh2")?;
        let max_prims = spec.u32_in("max_prims_per_leaf", 1..=MAX_PRIMS_PER_LEAF)?;
        let mut bvh = BinaryBvh::build(scene, quality, max_prims, test);
        if !refit {
            bvh.refit_ids = None;
        }
        Ok(bvh)
    }

    /// Builds the tree of `scene` with the given preset and leaf size (clamped to
    /// 1 ..= 255), its leaves prepared for test `test` (kept for a refit).
    pub fn build(
        scene: &Scene,
        quality: BuildQuality,
        max_prims_per_leaf: u32,
        test: TestKind,
    ) -> BinaryBvh {
        let max_prims = max_prims_per_leaf.clamp(1, MAX_PRIMS_PER_LEAF);
        let (ids, tris) = hittable_triangles(scene, test);
        let mut build_time = Duration::ZERO;
        let bvh = if tris.is_empty() {
            Bvh2::default()
        } else {
            // obvhs's `build_bvh2_from_tris` without pre-splits.
            let params = quality.params();
            let t0 = std::time::Instant::now();
            let mut bvh = build_bvh2(&tris, &params);
            collapse(&mut bvh, max_prims, params.collapse_traversal_cost);
            ReinsertionOptimizer::default().run(
                &mut bvh,
                params.reinsertion_batch_ratio
                    * params.post_collapse_reinsertion_batch_ratio_multiplier,
                None,
            );
            build_time = t0.elapsed();
            bvh
        };
        let slot_ids = bvh
            .primitive_indices
            .iter()
            .map(|&i| ids[i as usize])
            .collect();
        BinaryBvh {
            bvh,
            leaves: Leaves::new(scene, slot_ids, test),
            quality,
            max_prims_per_leaf: max_prims,
            build_time,
            refit_ids: Some(ids),
        }
    }

    /// The tree of `scene` (the same triangles as the one this was built for, moved) with
    /// this one's topology and leaves: leaf boxes recomputed, inner boxes refitted. `None`
    /// when nothing was kept (`update = "rebuild"`) or the triangles the test can hit are not
    /// the same set.
    pub fn refitted(&self, scene: &Scene) -> Option<BinaryBvh> {
        let ids = self.refit_ids.as_ref()?;
        let test = self.test();
        let (current, tris) = hittable_triangles(scene, test);
        if &current != ids {
            return None;
        }
        let t0 = std::time::Instant::now();
        let mut bvh = self.bvh.clone();
        refit_bvh2(&mut bvh, &tris);
        let build_time = t0.elapsed();
        Some(BinaryBvh {
            bvh,
            leaves: Leaves::new(scene, self.leaves.ids.clone(), test),
            quality: self.quality,
            max_prims_per_leaf: self.max_prims_per_leaf,
            build_time,
            refit_ids: Some(current),
        })
    }

    /// The build preset used.
    pub fn quality(&self) -> BuildQuality {
        self.quality
    }

    /// The largest leaf allowed (`max_prims_per_leaf`, clamped).
    pub fn max_prims_per_leaf(&self) -> u32 {
        self.max_prims_per_leaf
    }

    /// The ray-triangle test of the leaves.
    pub fn test(&self) -> TestKind {
        self.leaves.test()
    }

    /// Number of nodes (inner and leaf).
    pub fn node_count(&self) -> usize {
        self.bvh.nodes.len()
    }

    /// The number of triangles of each leaf, in node order.
    pub fn leaf_sizes(&self) -> Vec<u32> {
        self.bvh
            .nodes
            .iter()
            .filter(|n| n.is_leaf())
            .map(|n| n.prim_count)
            .collect()
    }

    /// Core build time (PLOC, reinsertion, collapsing; or the refit).
    pub fn build_time(&self) -> Duration {
        self.build_time
    }
}

/// The entry distance of the ray into `aabb` within `[t_lo, t_hi]`, each slab widened for
/// rounding (module doc), or `None` when the widened intervals do not overlap.
#[inline(always)]
pub fn box_entry(aabb: &Aabb, nr: &NodeRay, t_lo: f32, t_hi: f32) -> Option<f32> {
    let a = (aabb.min - nr.origin) * nr.inv_dir;
    let b = (aabb.max - nr.origin) * nr.inv_dir;
    let slack = (a.abs() + b.abs()) * SLAB_SLACK;
    let near: Vec3A = a.min(b) - slack;
    let far: Vec3A = a.max(b) + slack;
    let t0 = near.x.max(near.y).max(near.z).max(t_lo);
    let t1 = far.x.min(far.y).min(far.z).min(t_hi);
    (t0 <= t1).then_some(t0)
}

impl LeafTracer for BinaryBvh {
    /// The stack of pushed children and their entry distances.
    type Scratch = Vec<(u32, f32)>;

    fn leaves(&self) -> &Leaves {
        &self.leaves
    }

    #[inline]
    fn trace<T: TriangleTest>(
        &self,
        leaf_tris: &[T::Tri],
        ray: &Ray,
        mode: HitMode,
        best: &mut Hit,
        stack: &mut Vec<(u32, f32)>,
    ) -> Counts {
        let mut n = Counts::default();
        let nodes = &self.bvh.nodes;
        if nodes.is_empty() {
            return n;
        }
        let Some((r, nr, t_lo, mut t_hi)) = start_trace::<T>(ray, mode, best) else {
            return n;
        };
        stack.clear();
        let mut index = 0usize;
        loop {
            let node = &nodes[index];
            if node.is_leaf() {
                n.leaves += 1;
                let slots =
                    node.first_index as usize..(node.first_index + node.prim_count) as usize;
                for (tri, &id) in leaf_tris[slots.clone()].iter().zip(&self.leaves.ids[slots]) {
                    n.prims += 1;
                    if let Some(h) = T::hit(tri, &r, ray.t_min, ray.t_max, id) {
                        if mode == HitMode::Any {
                            *best = h;
                            return n;
                        }
                        if h.closer_than(best) {
                            *best = h;
                            t_hi = cull_distance(ray.t_max.min(best.t));
                        }
                    }
                }
            } else {
                n.inner += 1;
                n.bounds += 2;
                let left = node.first_index as usize;
                let a = box_entry(nodes[left].aabb(), &nr, t_lo, t_hi);
                let b = box_entry(nodes[left + 1].aabb(), &nr, t_lo, t_hi);
                match (a, b) {
                    (Some(ta), Some(tb)) => {
                        let (near, far, t_far) = if ta <= tb {
                            (left, left + 1, tb)
                        } else {
                            (left + 1, left, ta)
                        };
                        stack.push((far as u32, t_far));
                        index = near;
                        continue;
                    }
                    (Some(_), None) => {
                        index = left;
                        continue;
                    }
                    (None, Some(_)) => {
                        index = left + 1;
                        continue;
                    }
                    (None, None) => {}
                }
            }
            loop {
                match stack.pop() {
                    None => return n,
                    Some((i, t)) if t <= t_hi => {
                        index = i as usize;
                        break;
                    }
                    Some(_) => {}
                }
            }
        }
    }
}

obvhs_intersector!(BinaryBvh, "bvh2");

#[cfg(test)]
mod tests {
    use super::*;
    use crate::intersect::brute::tests::{random_rays, soup, test_ray};
    use crate::intersect::bvh::tests::{
        box_room, builtin_rays, check_exact, check_moved_frame, check_never_hits,
        check_visit_counts, degenerate_scene, one, rejects_candidates_and_bad_rays, run,
        same_for_one_and_two_threads,
    };
    use crate::surface::tests::raw_scene;
    use crsh_core::glam::Vec3;
    use crsh_core::{FrameSize, ParamValue, StageContext};

    fn builtin(name: &str) -> Scene {
        crsh_scene::builtin::build(name).unwrap_or_else(|e| panic!("{name}: {e}"))
    }

    #[test]
    fn identical_to_brute_force_on_builtin_scenes() {
        for name in crsh_scene::builtin::STATIC_NAMES {
            let scene = builtin(name);
            let rays = builtin_rays(&scene, 61, 1200);
            for test in TestKind::ALL {
                let bvh = BinaryBvh::build(&scene, BuildQuality::Medium, 4, test);
                assert_eq!(bvh.test(), test);
                check_exact(&scene, &rays, test, &bvh, &format!("bvh2 {name}"));
            }
        }
    }

    #[test]
    fn identical_to_brute_force_on_random_soups() {
        for (seed, n) in [(21u64, 500usize), (22, 60), (23, 1)] {
            let scene = soup(seed, n);
            let rays = random_rays(&scene, seed + 100, 1500);
            for (q, max_prims) in [
                (BuildQuality::Fast, 1),
                (BuildQuality::Medium, 4),
                (BuildQuality::Slow, 8),
            ] {
                for test in TestKind::ALL {
                    let bvh = BinaryBvh::build(&scene, q, max_prims, test);
                    check_exact(
                        &scene,
                        &rays,
                        test,
                        &bvh,
                        &format!("bvh2 {q:?} {max_prims}"),
                    );
                }
            }
        }
    }

    /// Flat boxes (axis-aligned walls), rays grazing along them, starting on them, and
    /// axis-parallel directions (zero components clamped in the slab test).
    #[test]
    fn identical_to_brute_force_on_grazing_axis_aligned_rays() {
        let (scene, rays) = box_room();
        for q in [BuildQuality::Fast, BuildQuality::Medium] {
            for test in TestKind::ALL {
                let bvh = BinaryBvh::build(&scene, q, DEFAULT_MAX_PRIMS_PER_LEAF, test);
                check_exact(&scene, &rays, test, &bvh, &format!("bvh2 {q:?}"));
            }
        }
    }

    #[test]
    fn visit_counts_on_builtin_scenes() {
        for name in crsh_scene::builtin::STATIC_NAMES {
            let scene = builtin(name);
            let bvh = BinaryBvh::build(&scene, BuildQuality::Medium, 4, TestKind::MollerTrumbore);
            let rays = builtin_rays(&scene, 71, 300);
            check_visit_counts(&bvh, &rays, 1);
            same_for_one_and_two_threads(&bvh, &rays);
            for mode in [HitMode::Closest, HitMode::Any] {
                let (_, stats) = run(&bvh, &rays, mode);
                assert_eq!(stats.tests.bounds, 2 * stats.tests.inner_nodes, "{mode:?}");
            }
        }
    }

    /// On the same rays, the binary tree visits more inner nodes per ray than the 8-wide
    /// CWBVH `bvh` compresses from the same PLOC tree (a CWBVH node replaces up to seven
    /// binary ones) and tests two boxes per visit; both count leaves no more than triangle
    /// tests. Prints the per-ray figures (`--nocapture`).
    #[test]
    fn binary_tree_visits_more_inner_nodes_than_the_wide_one() {
        use crate::intersect::bvh::CwBvh;
        for name in crsh_scene::builtin::STATIC_NAMES {
            let scene = builtin(name);
            let rays = builtin_rays(&scene, 91, 2000);
            let wide = CwBvh::build(&scene, BuildQuality::Medium);
            let binary =
                BinaryBvh::build(&scene, BuildQuality::Medium, 4, TestKind::MollerTrumbore);
            for mode in [HitMode::Closest, HitMode::Any] {
                let per_ray = |x: &dyn Intersector<Cpu>| {
                    let t = run(x, &rays, mode).1.tests;
                    let n = rays.len() as f64;
                    [t.inner_nodes, t.leaves, t.bounds, t.ray_triangle].map(|c| c as f64 / n)
                };
                let (w, b) = (per_ray(&wide), per_ray(&binary));
                println!(
                    "{name} {mode:?} ({} triangles) per ray: bvh inner {:.2} leaves {:.2} \
                     bounds {:.2} triangles {:.2} | bvh2 inner {:.2} leaves {:.2} bounds {:.2} \
                     triangles {:.2}",
                    scene.triangle_count(),
                    w[0],
                    w[1],
                    w[2],
                    w[3],
                    b[0],
                    b[1],
                    b[2],
                    b[3]
                );
                assert!(b[0] > w[0], "{name} {mode:?}: bvh2 {b:?} bvh {w:?}");
            }
        }
    }

    /// Leaves hold at most `max_prims_per_leaf` triangles, collapsing does merge leaves, and
    /// leaf size 1 keeps PLOC's single-triangle leaves; every hittable triangle is in one leaf.
    #[test]
    fn leaf_sizes_follow_max_prims_per_leaf() {
        let scene = builtin("office-boxes");
        for max_prims in [1u32, 2, 4, 8] {
            let bvh = BinaryBvh::build(
                &scene,
                BuildQuality::Medium,
                max_prims,
                TestKind::Watertight,
            );
            let sizes = bvh.leaf_sizes();
            assert!(
                sizes.iter().all(|&s| (1..=max_prims).contains(&s)),
                "{max_prims}"
            );
            assert_eq!(
                sizes.iter().map(|&s| s as usize).sum::<usize>(),
                bvh.leaves.ids.len()
            );
            assert_eq!(bvh.node_count(), 2 * sizes.len() - 1);
            if max_prims > 1 {
                assert!(
                    sizes.iter().any(|&s| s > 1),
                    "{max_prims}: nothing collapsed"
                );
            }
        }
        let mut sorted = BinaryBvh::build(&scene, BuildQuality::Medium, 4, TestKind::Watertight)
            .leaves
            .ids;
        sorted.sort_unstable();
        let (hittable, _) = hittable_triangles(&scene, TestKind::Watertight);
        assert_eq!(sorted, hittable);
    }

    /// Two triangles facing each other along z (one leaf each): the nearer leaf is visited
    /// first from either side and the farther one culled when popped; a ray away from both
    /// visits the root alone; a one-triangle tree is a root leaf (no inner visit, no box test).
    #[test]
    fn visits_on_a_two_leaf_tree() {
        let quad = |z: f32| {
            [
                Vec3::new(-1.0, -1.0, z),
                Vec3::new(3.0, -1.0, z),
                Vec3::new(-1.0, 3.0, z),
            ]
        };
        let mut positions = quad(1.0).to_vec();
        positions.extend(quad(3.0));
        let scene = raw_scene(positions, vec![Vec3::Z; 6], vec![[0, 1, 2], [3, 4, 5]]);
        let bvh = BinaryBvh::build(&scene, BuildQuality::Medium, 4, TestKind::MollerTrumbore);
        assert_eq!((bvh.node_count(), bvh.leaf_sizes()), (3, vec![1, 1]));
        let counts = |c: crsh_core::TestCounts| (c.inner_nodes, c.bounds, c.leaves, c.ray_triangle);
        for (o, d, tri) in [(0.0f32, 1.0f32, 0u32), (4.0, -1.0, 1)] {
            let ray = test_ray(
                Vec3::new(0.2, 0.3, o),
                Vec3::new(0.0, 0.0, d),
                0.0,
                f32::INFINITY,
                0,
            );
            for mode in [HitMode::Closest, HitMode::Any] {
                let (h, c) = one(&bvh, &ray, mode);
                assert_eq!(h.tri, tri, "{mode:?} from z = {o}");
                assert_eq!(counts(c), (1, 2, 1, 1), "{mode:?} from z = {o}");
            }
        }
        let away = test_ray(Vec3::new(0.2, 0.3, 5.0), Vec3::Z, 0.0, f32::INFINITY, 0);
        let (h, c) = one(&bvh, &away, HitMode::Closest);
        assert!(!h.is_hit());
        assert_eq!(counts(c), (1, 2, 0, 0));

        let single = raw_scene(quad(1.0).to_vec(), vec![Vec3::Z; 3], vec![[0, 1, 2]]);
        let bvh = BinaryBvh::build(&single, BuildQuality::Medium, 4, TestKind::MollerTrumbore);
        let ray = test_ray(Vec3::new(0.2, 0.3, 0.0), Vec3::Z, 0.0, f32::INFINITY, 0);
        let (h, c) = one(&bvh, &ray, HitMode::Closest);
        assert_eq!(h.tri, 0);
        assert_eq!(counts(c), (0, 0, 1, 1));
    }

    /// Built through the registry (defaults: medium, 4 triangles a leaf, rebuild, mt); with
    /// `update = "refit"` the stage's refit answers exactly as brute force on each moved frame,
    /// with `rebuild` it offers none; bad parameters and candidate queries are refused.
    #[test]
    fn registry_refit_and_bad_params() {
        let registry = Registry::<Cpu>::builtin();
        let v = registry.variant(StageKind::Intersect, "bvh2").unwrap();
        assert!(v.scene_only);
        let (anim, _) = crsh_scene::load_animated("cornell-mirrors-animated").unwrap();
        let first = Arc::new(anim.scene().clone());
        let frame = FrameSize::new(8, 8).unwrap();
        let ctx = StageContext::new(&Cpu, &first, frame);
        let x = registry
            .build_intersector(&ctx, &StageSpec::new("bvh2"))
            .unwrap();
        assert_eq!(x.name(), "bvh2");
        assert!(x.refit(&ctx).is_none(), "rebuild keeps nothing");
        for test in TestKind::ALL {
            let mut spec = StageSpec::new("bvh2");
            spec.params
                .insert("update".into(), ParamValue::Str("refit".into()));
            spec.params
                .insert("test".into(), ParamValue::Str(test.name().into()));
            let mut x = registry.build_intersector(&ctx, &spec).unwrap();
            let mut scene = anim.scene().clone();
            for f in [3, 7, 11] {
                anim.update(&mut scene, f, false).unwrap();
                let moved = Arc::new(scene.clone());
                x = x
                    .refit(&StageContext::new(&Cpu, &moved, frame))
                    .expect("a kept tree")
                    .unwrap();
                check_moved_frame(&moved, f, test, x.as_ref());
            }
        }
        for (key, value) in [
            ("max_prims_per_leaf", ParamValue::Int(0)),
            ("max_prims_per_leaf", ParamValue::Int(256)),
            ("build_quality", ParamValue::Str("ultra".into())),
            ("update", ParamValue::Str("sometimes".into())),
            ("test", ParamValue::Str("square".into())),
        ] {
            let mut spec = StageSpec::new("bvh2");
            spec.params.insert(key.into(), value);
            assert!(
                registry.build_intersector(&ctx, &spec).is_err(),
                "{key} accepted"
            );
        }
        let scene = soup(41, 20);
        let bvh = BinaryBvh::build(&scene, BuildQuality::Fast, 4, TestKind::MollerTrumbore);
        rejects_candidates_and_bad_rays(&bvh, &scene);
    }

    #[test]
    fn all_degenerate_scene_never_hits() {
        let scene = degenerate_scene();
        let bvh = BinaryBvh::build(&scene, BuildQuality::Medium, 4, TestKind::MollerTrumbore);
        assert_eq!(bvh.node_count(), 0);
        check_never_hits(&bvh, &scene);
    }
}
