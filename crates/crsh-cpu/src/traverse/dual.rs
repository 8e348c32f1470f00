//! `dual`: simultaneous top-down traversal of the ray-space hierarchy and an object hierarchy
//! over the triangles (seed 000 §3.2.8 with §5.1's future work: "combine our coherent ray
//! hierarchy with a deeper object hierarchy").
//!
//! The `crsh` traverser ([`super::crsh`], §3.2.8) tests, below the mesh level, every node
//! that reaches a mesh against every triangle sphere of that mesh, so a big mesh costs brute
//! force over its triangles. `dual` puts a binary hierarchy of bounding spheres over the
//! triangles and descends both trees together, so a ray node meets a triangle's sphere only
//! when it reached every object node above it.
//!
//! # Parameter `objects`
//!
//! - `lbvh` (default): the object side is an [`Lbvh`] built when the stage is constructed,
//!   i.e. once per frame (a moving scene rebuilds its stages every frame,
//!   [`crsh_core::Registry::rebuild`], and the build time is the stage's row in
//!   [`crsh_core::Pipeline::builds`]).
//! - `bvh`: the same bounds over the topology of obvhs's binary BVH ([`Lbvh::build_bvh2`]).
//! - `grid`: the same bounds over seed 002's uniform grid ([`Lbvh::build_grid`], parameter
//!   `grid_density`, default [`GRID_DENSITY`]), each leaf clipped to its cell (below).
//! - `meshes`: the thesis's mesh-sphere traversal, i.e. [`super::crsh::Crsh`] with mesh
//!   culling (whole-mesh spheres at the top level, then every triangle sphere of the kept
//!   meshes, level by level, §3.2.8). Same candidates, counters and batches as the `crsh`
//!   traverser with `mesh_culling = true`.
//!
//! # The object hierarchy (`lbvh`)
//!
//! A binary radix tree over the triangles sorted by the 63-bit Morton code (21 bits per axis)
//! of their bounding-sphere centres ([`crsh_scene::Scene::tri_spheres`]) within the centres'
//! bounding box, ties broken by triangle id (a total order: the tree does not depend on the
//! thread count of the parallel sort). A range of sorted leaves is split where its first and
//! last codes first differ (the highest differing bit), and in the middle when all its codes
//! are equal; internal nodes are numbered as in Karras 2012 (the root is 0, the left child of
//! a split after position `γ` is `γ`, the right child `γ + 1`), leaves are the sorted
//! positions. Leaves are single triangles whose bound is the triangle's sphere.
//!
//! Each internal node gets a sphere that contains the sphere of every triangle below it: the
//! smaller of the minimal sphere around its children's spheres and the circumscribed sphere
//! of the box around its triangles' spheres (a box is bounded by its circumscribed sphere, so
//! the node test stays the ray-node-against-sphere test), computed in `f64`, rounded outwards
//! to `f32` (radius enlarged by `1e-6` relative plus the centre's rounding).
//!
//! # The grid (`grid`)
//!
//! Seed 002's grid (its five passes, [`GridData::build_of`], every triangle binned in every
//! cell its margin-widened vertex box meets) gives the topology: cell ranges halved at the
//! middle of their longest axis down to single cells (halves without entries skipped), then
//! each cell's triangle list halved down to single entries. A leaf is one (cell, triangle)
//! entry, so a triangle in `m` cells is `m` leaves. Unclipped, a big triangle (a floor)
//! would give every cell node it crosses its whole box; so each entry's box is the
//! triangle's box ([`triangle_box`]) clipped to its **region** ([`entry_region`]: the closed
//! cell widened on each side by the margin the triangle's box has on that side), and its
//! sphere is the smaller of the triangle's sphere and the sphere around the clipped box.
//! Internal nodes get their bounds from their children as above.
//!
//! **No hit is lost.** A hit on `T` is reported inside `T`'s box, so within its margin of the
//! point `q` of `T`'s vertex box nearest to it; the grid lists `T` in the cell holding `q`,
//! whose region therefore holds the hit: that entry's clipped box contains it, and its sphere
//! is either `T`'s (the argument above) or one around a box that contains it. Internal nodes
//! contain their leaves' bounds, so every pair on the path to that entry passes. A triangle
//! reached through several cells becomes one candidate (a task sorts its candidates and
//! merges repeats, lane masks or'ed); only a task stopped by its share of the budget between
//! two such cells can hand the same pair on in two batches (tested twice, same hits).
//!
//! Measured at 1024², depth 3 (tests per ray at density 0.25 / 1 / 5): Sponza 43.0 / 42.2 /
//! 44.4, the dining room 53.0 / 59.4 / 79.5, cornell-mirror 6.4 / 5.8 / 6.6; 1 is the default.
//! The Morton build needs 40.6, 36.9 and 5.4 and is faster on all three, but the clipped
//! entries take the final tests below it (Sponza 18.2M against 27.3M ray-triangle tests) at
//! the price of more pair tests (34.2M against 23.0M).
//!
//! # Moving geometry (`update`)
//!
//! The object side is built with the stage, so a moving scene rebuilds it every frame
//! ([`crsh_core::Registry::rebuild`]). With `update = refit` (`objects = lbvh` or `bvh`) the
//! next frame's traverser is [`Dual::refitted`] instead: the first frame's topology is kept
//! and every bound computed again bottom-up from the moved triangles exactly as a build
//! computes it over that topology, so every node again contains what lies below it and the
//! hits are a fresh build's; only the tree's quality drifts with the motion (the Morton
//! order, or PLOC's clusters, of the first frame). With `wide_cone`, obvhs's binary tree the
//! 8-wide BVH comes from is kept too, refitted (leaf boxes, then `refit_all`) and compressed
//! again, as the `bvh` intersector's `update = refit` does. A grid's entries and the mesh
//! spheres follow the positions, so `grid` and `meshes` refuse `refit`.
//!
//! # Traversal
//!
//! Work starts from every (top-level ray node, object root) pair (with inline final tests,
//! from the nodes of a lower level when the top has few: see below). A pair is tested with
//! the box test (below, parameter `box_test`, on by default) and then
//! [`NodeBound::may_hit`] (the ray node against the object node's sphere); a pair that
//! passes both is
//!
//! - a candidate when the ray node is in the lowest level (`levels[0]`) and the object node
//!   is a triangle: the `(node, triangle)` pair handed to the intersector, as `crsh` does;
//! - split on the object side when the ray node is in the lowest level, on the ray side when
//!   the object node is a triangle;
//! - otherwise split on the **larger side**: the ray side when the node's rays spread wider
//!   at the object node than the object node's radius ([`NodeBound::spreads_wider_than`]:
//!   `r + D·sin α` against `R`), else the object side.
//!
//! Splitting the ray side pairs each existing child (`n·s .. (n+1)·s` of the level below)
//! with the object node; splitting the object side pairs the ray node with both children.
//! Each pair is reached along one path from its root pair (the split decision is a function
//! of the pair), so no candidate is emitted twice.
//!
//! **No intersecting pair is culled.** The tests are the ones `crsh` proves conservative
//! (module doc of [`super::crsh`], a conservative eq. 3.16): if a ray of lowest node `N` hits
//! triangle `T`, every ancestor `A` of `N` passes `may_hit` against `T`'s sphere. Every
//! object node `O` above `T` has a sphere containing `T`'s, and `may_hit` is monotone under
//! sphere inclusion (the half-lines from the node's apex that meet a ball also meet every
//! ball containing it, and the margins only grow with the radius: with `S ⊆ S'`,
//! `|P| − |P'| ≤ R' − R`, so the relative margin `1e-4·(R' − R)` covers the absolute one's
//! `1e-5·(R' − R)` change). So `(A, O)` passes for every pair on the path to `(N, T)`, and
//! the final tests see every pair brute force would hit. The exactness tests below check it
//! against brute force and `crsh`.
//!
//! # Single rays
//!
//! A lowest node of incoherent rays (reflections off a curved surface, a cone of 60° and
//! more) reaches nearly every triangle its cone sweeps, and all its rays are tested against
//! each. With parameter `single_rays` (on by default) a pair (lowest node `N`, internal
//! object node `O`) that passes, where `N`'s rays spread wider than `O`
//! ([`NodeBound::spreads_wider_than`]) and `N` has at most 32 rays, descends to `N`'s rays
//! instead, as a packet with a mask of live rays: each live ray is tested alone against
//! `O`'s box (its segment, the ray's interval, by slabs in `f32` on three lanes at once,
//! widened by a relative `1e-6` so that they pass whatever the exact `f64` slabs pass: see
//! `meets_box`; a ray that is not [`Ray::is_valid`] always passes, the intersector refuses it),
//! the rays that pass go on to `O`'s children, and a triangle that some ray reaches makes
//! `(N, T)` a candidate, once, for the rays that reached it: the batch carries a lane mask per
//! pair ([`CandidateBatch::lanes`], [`ALL_LANES`] for the pairs of whole nodes) and the
//! intersector tests only those rays. Exactness is the box test's argument for one ray. Each ray test counts as a bound test, in
//! the object-depth rows and, on the ray side, in the lowest node level's row (level 1): the
//! rows still sum to the bounds.
//!
//! # Wide ray nodes
//!
//! Single rays still descend a binary tree of one triangle per leaf, and at the pair levels
//! above them a wide node's box and cone cull little: on the dining room's reflection rays
//! (lowest-node cones of 63° on average) the pairs and single rays needed 512 tests per ray
//! against the 8-wide CWBVH's 340. With parameter `wide_cone` below 180 (inline final tests
//! only), a lowest node whose cone half-angle is at least that many degrees leaves the pair
//! traversal: its rays are traced one by one, before the task's pairs, through obvhs's
//! compressed 8-wide BVH (the `bvh` intersector's traversal and node test, so the hits are
//! brute force's: [`crate::intersect::bvh`], "Identical to brute force"; closest-hit rays merge
//! into the hits they bring, any-hit rays already hit are skipped), reading the triangles the
//! inline tests read, by scene id. The node has no live rays for the pairs (in either query
//! mode), an upper node with none left is not tested, and its segment box is empty, so the
//! boxes above it are those of the narrow nodes alone. With `objects = bvh` the CWBVH is
//! compressed from the very obvhs tree the object side was laid out from (one PLOC build);
//! with `lbvh` or `grid` it is built for it (`fast` preset). Counting: the CWBVH's child-box
//! tests (obvhs counts, [`crate::intersect::bvh`], "Counting") go to the bounds and the lowest
//! ray level's row, its triangle tests to the ray-triangle tests and the level-0 row; they are
//! not in the object-depth rows, which then sum to less than the bounds. [`DualReport`] counts
//! the rays traced this way. The `dual_screen_bvh` preset sets 60° (README, "Wide ray nodes
//! through an 8-wide BVH").
//!
//! # The box test
//!
//! Cones and spheres are loose around the shapes real scenes are made of: long thin
//! triangles, floors and walls along the axes, shadow rays that all start on one floor. So
//! each pair is first tested by boxes:
//!
//! - **Object side**: each triangle's box ([`triangle_box`]) is its vertices' box widened on
//!   every side by the margins the sphere test uses for the triangle's size
//!   (`REL_MARGIN` × half its diagonal + `ABS_MARGIN` × `max(1, |v|∞)`), rounded outwards to
//!   `f32`; an internal node's box is the union of its children's.
//! - **Ray side**: each ray's *segment box* ([`segment_box`]) holds every point
//!   `o + t·d` with `t` in the ray's interval, clipped to the box of all triangles (slabs in
//!   `f32` widened by a relative `1e-6`, so the interval contains the exact one); a ray whose
//!   interval misses it has the empty box and one that is not [`Ray::is_valid`] the whole
//!   space (the intersector refuses it). The end points are computed in `f32` and the box
//!   padded by `4ε·(|o| + |d|·|t|)` plus `2e-9` of its scale, which covers their rounding;
//!   the wgpu twin computes the same formula. A lowest node's box is the union of its rays'
//!   (their end points joined and padded once, which contains the union of their padded
//!   boxes), a higher node's the union of its children's; they are computed per traversal,
//!   O(rays), from the rays' segments gathered once in leaf order (which the single-ray tests
//!   read too). The `f32` boxes replaced `f64` extents rounded outwards, which were a
//!   third of a profile of the inline traversal of cornell-mirror's reflection rays (README,
//!   "Segment boxes in `f32`", for the frame times before and after).
//! - A pair passes when the boxes overlap (touching counts). The pair test (boxes, then
//!   cone and sphere) counts **once** in the counters below, as one node test of a BVH does.
//!
//! **No intersecting pair is culled**: if the `f32` ray-triangle test reports a hit of ray
//! `r` on triangle `T` at `t*` in `r`'s interval, the point `o + t*·d` is on `r`'s segment,
//! within the scene's box, so inside `r`'s segment box, and within the margin of `T` (the
//! test reports hits a hair outside a triangle and off its plane, never farther than the
//! margin the sphere test already relies on), so inside `T`'s box. Both boxes only grow up
//! the trees, so every pair on the path to `(N, T)` passes. The margin is needed: a shadow
//! segment that ends within rounding above a floor can be reported as hitting it (the tests
//! search such rays out and fail without the margin).
//!
//! # Inline final tests (`final_tests = inline`)
//!
//! Batched (the default), the traversal hands its (lowest node, triangle) pairs to the
//! intersector, which tests them after the round: a shadow ray that an early triangle occludes
//! still meets every node and triangle its node reaches, and a reflection ray meets every
//! triangle box along its whole line. With `final_tests = inline` the pipeline asks the
//! traverser to run the final tests itself ([`Traverser::trace`], with the intersector's
//! ray-triangle test, [`crsh_core::Intersector::candidate_test`], on `brute`'s own prepared
//! triangles, which [`crsh_core::Intersector::as_any`] reaches; another intersector's test gets
//! a set prepared once by this stage), and each task tests a pair the moment it finds it:
//!
//! - the node's rays named by the pair (all of them, or the lane mask of single rays) that are
//!   still traced sit in packets of [`LANES`] (built when the node first reaches a triangle)
//!   and are tested against the triangle, with the intersector's per-lane arithmetic;
//! - **any-hit**: a ray leaves at its first hit. Its lowest node's mask of live rays loses
//!   it, every ray node above keeps a count of live rays below it, and a pair whose ray node
//!   has none left is dropped before its test (uncounted);
//! - **closest-hit**: a hit that is [`Hit::closer_than`] the ray's best replaces it, and the
//!   ray's interval ends just above it (the next `f32`, so that a triangle at the same `t`
//!   with a lower id still counts) in its packet lane and in the segment its single-ray box
//!   tests clip;
//! - a pair split on the object side visits the child whose sphere centre lies nearer along
//!   the ray node's axis first (`NodeBound::along_axis`), so that near hits come early.
//!
//! **Exact.** A pair is dropped only when every ray below its ray node already has an
//! any-hit answer; a ray still traced meets every pair the batched traversal would give its
//! nodes. A closest-hit ray's interval shrinks to its best hit so far, and every hit at or
//! before that `t` lies on the shorter segment, inside the (unchanged, larger) node boxes and
//! its own clipped segment, so the box test's argument above still keeps it; the best of all
//! tested hits is then the nearest, ties to the lowest id. An any-hit ray reports the first
//! hit the traversal meets (the batched intersector reports its lowest-id candidate hit): both
//! are hits. The tests compare every ray with brute force, both tests (`mt`, `watertight`),
//! both modes, hits given beforehand (merged as [`crsh_core::Intersector::intersect`] merges
//! them: an any-hit ray that has one is not traced), and thread counts.
//!
//! A task is a ray node of the highest level with at least 64 nodes (else of the lowest level),
//! which meets the object root itself: a small batch (the dining room's first-bounce
//! reflection rays make 2 top nodes, their later bounces 1) would otherwise run on one or two
//! threads. The level depends on the hierarchy's shape alone, so the counters do not depend on
//! the thread count. Tasks keep their own rays' segments, node boxes, hits, masks and packets
//! (a task's rays are its node's, a contiguous run of leaves): each task gathers its rays'
//! segments through `order` itself and boxes its ray nodes from them (the same boxes as the
//! batched mode's), so no batch-wide array of segments is made (on Sponza's 1.24M shadow rays,
//! 40 MB written and faulted in before the traversal). They need no synchronization; up to 256
//! of them run in parallel, and each writes its own rays' hits into the batch's (a task's rays
//! are no other task's: `order` is a checked permutation). No candidate
//! arrays exist, so `candidate_budget_mb` does not apply; memory is O(rays) for the hits plus
//! the round's tasks' segments, boxes and packets. The pair counters are the batched mode's
//! rows; the final tests are the level-0 row and [`Stats::add_ray_triangle`], inside the
//! `traversal` stage time (the pipeline records no `final_tests`).
//!
//! A hierarchy with a lowest node of more than 32 rays, `objects = meshes`, and edge-width
//! queries stay batched (`trace` answers `None`, the pipeline then traverses and calls the
//! intersector as before). The wgpu twin has no inline tests: its catalogue offers
//! `final_tests = batched` only, and the `dual_inline` preset is CPU-only.
//!
//! Sponza, 1024², depth 3 (1.24M shadow rays, 2026-12-04, this 2-core machine, the `dual`
//! and `dual_inline` presets in alternating runs, identical images): traversal and final
//! tests 370-411 ms batched against 240-245 ms inline, 16.79M bound and 29.17M ray-triangle
//! tests against 13.07M and 31.75M; the dining room 356-389 against 182-189 ms (38.5 against
//! 23.8 tests per ray). The README has the table.
//!
//! # Memory bound and determinism
//!
//! Each top-level ray node is a task: a depth-first traversal with an explicit stack of
//! untested pairs. Tasks run in rounds of up to `G` tasks in parallel (rayon); in a round each
//! task runs until its stack is empty or it holds `C` candidates, then stops (a stopped task
//! resumes in the next round from its stack). A round's candidates (each task's sorted by
//! `(node, triangle)`, tasks in top-node order, so the batch is strictly increasing, the
//! order the intersector uses in place) go to the sink as one [`CandidateBatch`]; new tasks
//! join the next round in top-node order. `G` and `C` come from the budget alone:
//! with `P = candidate_budget_mb · 2²⁰ / 24` pairs (12 bytes each: the pair and its lane
//! mask), `G = clamp(P / 1024, 1, 256)` and
//! `C = max(1, P / G)`, and a task's array never grows past `C`, so the candidate arrays
//! alive at once (the tasks' arrays and the batch they are copied into) stay within
//! `2·G·C·12 ≤` the budget (at least one pair's worth). [`DualReport::peak_candidate_bytes`]
//! reports the peak reached. Nothing depends on the thread count: the rounds, the batches and
//! the counters are functions of the hierarchy, the scene and the budget.
//!
//! # Counters
//!
//! Every pair test counts in [`Stats::add_bounds`], and in two rows, one per side:
//!
//! - the ray side's [`Stats::levels`] with the thesis's numbering (`levels[i]` is level
//!   `i + 1`, the top is `levels.len()`, level 0 the final ray-triangle tests that the
//!   intersector records): the tests of ray nodes of that level against any object node, and
//!   how many passed;
//! - the object side's [`Stats::object_levels`], by the object node's depth (0 the root): the
//!   tests against object nodes at that depth, and how many passed.
//!
//! Each side's rows sum to the bounds tests (there is no mesh culling with `lbvh`; with
//! `wide_cone` the object rows leave out the wide BVH's tests, see *Wide ray nodes*), and
//! `tests = hits + misses` in every row.
//!
//! # Measured
//!
//! Sponza (262,205 triangles, 381 meshes), `crsh` preset, shadow rays, release build, one
//! run each side by side on a shared 2-core machine (times are noisy), identical images and
//! hits (agreement 1.000000 against `bvh`):
//!
//! | 1024², depth 3 | bounds/ray | triangle/ray | total/ray | traversal ms | final ms | Mrays/s |
//! |---|---:|---:|---:|---:|---:|---:|
//! | `crsh` | 613 | 173 | 786 | 2535 | 1662 | 0.28 |
//! | `dual`, `box_test = false` | 53 | 173 | 226 | 702 | 513 | 0.82 |
//! | `dual`, boxes, `single_rays = false` | 19 | 29 | 48 | 389 | 182 | 1.45 |
//! | `dual` (boxes, single rays) | 18.6 | 22.4 | 41.0 | 386 | 138 | 1.56 |
//! | `bvh` (obvhs CWBVH, whole scene) | 93 | 3.8 | 97 | – | 354 | 3.48 |
//!
//! Without boxes the bounds tests drop 11× against `crsh`, but the final tests (candidates ×
//! the 8 rays of a lowest node) stay `crsh`'s; the box test cuts them 6× (most of a shadow
//! node's sphere candidates are floor and wall triangles its segments never reach). On the
//! dining room's reflection rays (lowest-node cones of 63° on average) single rays take the
//! tests per ray from 61,147 to 730. The object hierarchy's build is part of the stage's
//! construction: about 27 ms for Sponza (stage builds 79 ms against `crsh`'s 53 ms).
//!
//! # The wgpu twin
//!
//! `crsh_wgpu::traverse::dual` uploads this module's object hierarchy ([`Lbvh::flat`]) and
//! runs the same pair test and split rule breadth first on the device (one round per level
//! of the pairs, stream compaction between rounds), with the candidates of a batch sorted and
//! merged there; its module doc lists what differs (`f32` tests that keep what these keep,
//! chunks of top nodes for the budget).
//!
//! # Errors
//!
//! As [`super::crsh`]: [`CoreError::InvalidParam`] for a budget that is not a finite positive
//! number or an unknown `objects`; [`CoreError::InvalidInput`] for an inconsistent hierarchy
//! ([`super::crsh::prepare_nodes`]) or a scene with 2³¹ triangles or more. With inline final
//! tests, also for an `order` that is not a permutation of the batch, hits of another length,
//! or a ray that is not [`Ray::is_valid`] (named as the intersector names it: the batch's
//! first); the tasks check the rays as they gather them, rather than a pass over the whole
//! batch before the traversal (a task that meets an invalid ray stops, and the batch is
//! an error).

use std::sync::Arc;

use crsh_core::glam::{DVec3, Vec3, Vec3A};
use crsh_core::{
    f32_down, f32_up, lowest_node_leaves, Aabb, Candidate, CandidateBatch, CoreError, Hit, HitMode,
    Intersector, ParamInfo, Ray, RayHierarchy, RayKind, Registry, Result, Sphere, StageContext,
    StageKind, StageSpec, StageVariantInfo, Stats, Traverser, ALL_LANES,
};
use crsh_scene::Scene;
use rayon::prelude::*;

use super::crsh::{budget_bytes, prepare_nodes, Crsh, NodeBound, ABS_MARGIN, REL_MARGIN};
use crate::backend::Cpu;
use crate::intersect::brute::{check_batch, check_permutation, merge_repeats, BruteForce};
use crate::intersect::bvh::{
    build_bvh2, compress_bvh2, obvhs_triangle, refit_bvh2, trace_cwbvh, BuildQuality, Counts,
};
use crate::intersect::grid::{GridData, MAX_DENSITY, MIN_DENSITY};
use crate::triangle::{AnyTriangleSet, TestKind, TriangleSet, TriangleTest, LANES};
use obvhs::bvh2::Bvh2;
use obvhs::triangle::Triangle;
use std::sync::{Mutex, OnceLock};

/// The choices of parameter `objects`.
pub const OBJECTS: [&str; 4] = ["lbvh", "bvh", "grid", "meshes"];
/// The default `grid_density` of `objects = grid`: about one cell per triangle (the fewest
/// tests per ray on Sponza and cornell-mirror among 0.25, 1 and 5, module doc).
pub const GRID_DENSITY: f64 = 1.0;
/// Most tasks (top-level ray nodes; inline, the nodes of [`task_level`]) traversed in one round.
const ROUND_TASKS: usize = 256;
/// Fewest candidates a task may hold before it stops, unless the budget is smaller.
const MIN_PIECE: u64 = 1024;
/// Bytes per candidate pair.
const PAIR_BYTES: u64 = (std::mem::size_of::<Candidate>() + std::mem::size_of::<u32>()) as u64;
/// Marks a leaf (a sorted triangle position) in an object node reference.
const LEAF: u32 = 1 << 31;

/// The catalogue entry of the `dual` traverser.
pub fn info() -> StageVariantInfo {
    StageVariantInfo::new(
        StageKind::Traverse,
        "dual",
        "simultaneous top-down traversal of the ray hierarchy and an object hierarchy over the \
         triangles, descending the larger side of each (ray node, object node) pair with the \
         conservative eq. 3.16 node test, seed 000 §3.2.8 and §5.1 (deeper object hierarchy)",
    )
    .param(ParamInfo::choice(
        "objects",
        "lbvh",
        &OBJECTS,
        "object side, built with the stage (once for a static scene, every frame for moving \
         geometry): `lbvh` a binary sphere hierarchy over the triangles by Morton codes; \
         `bvh` the same bounds over the topology of obvhs's binary BVH (PLOC with \
         reinsertion, `fast` preset); `grid` the same bounds over seed 002's uniform grid \
         (cell ranges halved, then each cell's triangles); `meshes` the thesis's mesh spheres \
         then triangle spheres (the `crsh` traverser with mesh culling)",
    ))
    .param(
        ParamInfo::float(
            "grid_density",
            GRID_DENSITY,
            "with `objects = grid`: k of seed 002 eq. 1, about k cells per triangle",
        )
        .range(MIN_DENSITY, MAX_DENSITY),
    )
    .param(ParamInfo::bool(
        "box_test",
        true,
        "with `objects = lbvh`, `bvh` or `grid`, test a pair's boxes before the cone-sphere \
         test: the box of the ray node's segments (clipped to the scene) against the object \
         node's box; false: the cone-sphere test alone",
    ))
    .param(ParamInfo::bool(
        "single_rays",
        true,
        "with `objects = lbvh`, `bvh` or `grid`, a lowest ray node whose rays spread wider \
         than an object node descends to its single rays, each tested against the object \
         nodes' boxes below (incoherent rays: reflections off curved surfaces); false: \
         lowest nodes stay whole",
    ))
    .param(
        ParamInfo::float(
            "wide_cone",
            WIDE_CONE_OFF,
            "with `final_tests = inline` and `objects = lbvh`, `bvh` or `grid`: a lowest ray \
             node whose cone half-angle is at least this many degrees leaves the pair \
             traversal, and its rays are traced one by one through an 8-wide BVH (obvhs \
             CWBVH, compressed from the object side's own obvhs tree with `objects = bvh`, \
             built for it otherwise); 180: never",
        )
        .range(0.0, WIDE_CONE_OFF),
    )
    .param(ParamInfo::choice(
        "update",
        "rebuild",
        &UPDATES,
        "per frame of a moving scene, with `objects = lbvh` or `bvh`: build the object side \
         anew, or keep the first frame's topology and recompute its bounds bottom-up (`refit`; \
         with `wide_cone`, obvhs's binary tree is refitted and compressed to the 8-wide BVH \
         again); the topology of `grid` and the mesh spheres follow the positions, so they \
         always rebuild",
    ))
    .param(ParamInfo::choice(
        "final_tests",
        "batched",
        &FINAL_TESTS,
        "with `objects = lbvh`, `bvh` or `grid`: `batched` hands the (lowest node, triangle) \
         pairs to the intersector in batches; `inline` tests each pair with the intersector's \
         ray-triangle test as soon as the traversal finds it, so an any-hit ray leaves the \
         traversal at its first hit and a closest-hit ray's segment ends at its nearest hit so \
         far (lowest nodes of at most 32 rays; others, and `meshes`, stay batched)",
    ))
    .param(
        ParamInfo::float(
            "candidate_budget_mb",
            64.0,
            "memory bound of the candidate arrays in MiB (> 0): rounds of ray-node tasks \
             stop at a share of it and hand their candidates on",
        )
        .range(1.0 / 1024.0, 1024.0 * 1024.0),
    )
}

/// Registers `dual` ([`info`], [`Dual::new`]).
pub fn register(registry: &mut Registry<Cpu>) -> Result<()> {
    registry.add_traverser(info(), |ctx, spec| {
        Ok(Box::new(Dual::new(ctx.scene, spec)?))
    })?;
    Ok(())
}

/// An internal node of an [`Lbvh`].
#[derive(Clone, Copy, Debug, PartialEq)]
struct Inner {
    /// Contains the sphere of every triangle below.
    sphere: Sphere,
    /// The union of its leaves' boxes (next to the sphere: a pair test reads one line).
    bx: Aabb,
    /// Child references: an internal node index, or [`LEAF`] | a sorted position.
    children: [u32; 2],
}

/// The bounds of a leaf of an [`Lbvh`].
#[derive(Clone, Copy, Debug, PartialEq)]
struct Leaf {
    /// The triangle's sphere.
    sphere: Sphere,
    /// The triangle's vertices' box widened by the margin ([`triangle_box`]).
    bx: Aabb,
}

/// A binary bounding-sphere hierarchy over a scene's triangles, built from the Morton codes
/// of their sphere centres (see the module doc).
#[derive(Clone, Debug, PartialEq)]
pub struct Lbvh {
    /// Internal nodes (`triangles − 1`, Karras numbering: 0 is the root).
    inner: Vec<Inner>,
    /// Triangle id of each sorted position.
    leaf_tris: Vec<u32>,
    /// Bounds of each sorted position's triangle.
    leaves: Vec<Leaf>,
    /// Deepest node (0: a single triangle or none).
    max_depth: usize,
}

/// One node of an [`Lbvh`] in its flat layout ([`Lbvh::flat`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FlatNode {
    /// Contains the sphere of every triangle below (a leaf: its triangle's, or the entry's).
    pub sphere: Sphere,
    /// Contains the box of every triangle below ([`triangle_box`], clipped for grid entries).
    pub bx: Aabb,
    /// An internal node's two children (indices in the flat array); `None` for a leaf.
    pub children: Option<[u32; 2]>,
    /// A leaf's triangle id (`u32::MAX` for an internal node).
    pub triangle: u32,
}

/// Spreads the low 21 bits of `v` to every third bit.
fn spread3(v: u64) -> u64 {
    let mut x = v & 0x1f_ffff;
    x = (x | x << 32) & 0x1f_0000_0000_ffff;
    x = (x | x << 16) & 0x1f_0000_ff00_00ff;
    x = (x | x << 8) & 0x100f_00f0_0f00_f00f;
    x = (x | x << 4) & 0x10c3_0c30_c30c_30c3;
    x = (x | x << 2) & 0x1249_2492_4924_9249;
    x
}

/// A sphere around `center`/`radius` (`f64`) rounded outwards to `f32`.
fn round_out(center: DVec3, radius: f64) -> Sphere {
    let c = center.as_vec3();
    let err = (c.as_dvec3() - center).length();
    let scale = center.abs().max_element().max(1.0);
    let r = (radius + err) * (1.0 + 1e-6) + 16.0 * f64::EPSILON * scale;
    Sphere::new(c, r as f32 * (1.0 + f32::EPSILON))
}

/// The smaller of the minimal sphere around `a` and `b` and the circumscribed sphere of
/// `bounds` (a box containing both), rounded outwards.
fn enclose(a: &Sphere, b: &Sphere, bounds: (DVec3, DVec3)) -> Sphere {
    let (ca, ra) = (a.center.as_dvec3(), a.radius as f64);
    let (cb, rb) = (b.center.as_dvec3(), b.radius as f64);
    let d = (cb - ca).length();
    let merged = if d + rb <= ra {
        (ca, ra)
    } else if d + ra <= rb {
        (cb, rb)
    } else {
        let r = (d + ra + rb) / 2.0;
        (ca + (cb - ca) * ((r - ra) / d), r)
    };
    let boxed = (
        (bounds.0 + bounds.1) / 2.0,
        (bounds.1 - bounds.0).length() / 2.0,
    );
    let (c, r) = if boxed.1 < merged.1 { boxed } else { merged };
    round_out(c, r)
}

/// The `f32` box around `[lo, hi]` (`f64`), each side widened by `pad` and rounded outwards.
fn round_box(lo: DVec3, hi: DVec3, pad: f64) -> Aabb {
    let (lo, hi) = (lo - DVec3::splat(pad), hi + DVec3::splat(pad));
    Aabb {
        min: Vec3::new(f32_down(lo.x), f32_down(lo.y), f32_down(lo.z)),
        max: Vec3::new(f32_up(hi.x), f32_up(hi.y), f32_up(hi.z)),
    }
}

/// The box a hit on triangle `[a, b, c]` can be reported in: the vertices' box widened on
/// every side by the margins of [`NodeBound::may_hit`] for the triangle's size (`REL_MARGIN`
/// × half its box diagonal + `ABS_MARGIN` × `max(1, |v|∞)`), so that a hit the `f32`
/// ray-triangle test reports a hair outside the triangle stays inside (module doc, *The box
/// test*).
pub fn triangle_box(tri: [Vec3; 3]) -> Aabb {
    let [a, b, c] = tri.map(|v| v.as_dvec3());
    let (lo, hi) = (a.min(b).min(c), a.max(b).max(c));
    let scale = lo.abs().max(hi.abs()).max_element().max(1.0);
    let pad = REL_MARGIN * (hi - lo).length() / 2.0 + ABS_MARGIN * scale;
    round_box(lo, hi, pad)
}

/// The box of the points `origin + t·dir` a ray can report a hit at: `t` in its interval,
/// clipped to `bounds` (the box of every triangle, margins included) when the interval is
/// unbounded (a bounded one is only boxed: its end points, no divisions), the empty box when
/// the interval is empty or misses `bounds`, and the whole space for a ray that is not
/// [`Ray::is_valid`] (it is then the intersector's to refuse). Computed in `f32`, each side
/// padded by `4ε·(|o| + |d|·|t|) + 2e-9·max(1, |corner|∞)` to cover the rounding of the end
/// points: the same formula as the wgpu twin's `segment_box`.
pub fn segment_box(ray: &Ray, bounds: &Aabb) -> Aabb {
    let seg = Segment::of(ray);
    let mut span = SegmentSpan::EMPTY;
    if span.add(&seg, inverse_f32(seg.dir), bounds) {
        span.padded()
    } else {
        EVERYWHERE
    }
}

/// What the box tests read of a ray (32 bytes of its 64): the traversal gathers them once in
/// leaf order, so that a lowest node's rays lie side by side.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Segment {
    origin: Vec3,
    t_min: f32,
    dir: Vec3,
    t_max: f32,
}

impl Segment {
    #[inline]
    fn of(ray: &Ray) -> Segment {
        Segment {
            origin: ray.origin,
            t_min: ray.t_min,
            dir: ray.dir,
            t_max: ray.t_max,
        }
    }

    /// [`Ray::is_valid`].
    #[inline]
    fn is_valid(&self) -> bool {
        crsh_core::ray::is_valid_segment(self.origin, self.dir, self.t_min, self.t_max)
    }
}

/// The rays' segments in leaf order (the hierarchy's `order`) and the segment box
/// ([`segment_box`]) of every ray node, by level as the hierarchy's `levels`: a lowest node's
/// is the union of its rays', a higher node's the union of its children's. One pass per lowest
/// node gathers its rays through the permutation (the next node's rays prefetched meanwhile)
/// and boxes them while they are in the cache: on Sponza's 1.24M shadow rays (two threads)
/// 25-31 ms, against 30-33 for the gather and a second pass for the boxes. The hierarchy's
/// shape must
/// have been checked ([`prepare_nodes`]).
fn leaf_segments_and_boxes(
    rays: &[Ray],
    h: &RayHierarchy<Cpu>,
    bounds: &Aabb,
) -> (Vec<Segment>, Vec<Vec<Aabb>>) {
    let (order, offsets) = (h.order.as_slice(), h.leaf_offsets.as_deref());
    let n = order.len();
    let leaves = |node: usize| lowest_node_leaves(node, h.subdivision, offsets, n);
    let mut segments: Vec<Segment> = Vec::with_capacity(n);
    // Each lowest node's range of the output (the ranges partition `0..n`, in order).
    let mut rest = &mut segments.spare_capacity_mut()[..n];
    let mut parts = Vec::with_capacity(h.levels[0].len());
    for node in 0..h.levels[0].len() {
        let (head, tail) = rest.split_at_mut(leaves(node).len());
        parts.push(head);
        rest = tail;
    }
    let lowest: Vec<Aabb> = parts
        .into_par_iter()
        .enumerate()
        .map(|(node, part)| {
            if node + 1 < h.levels[0].len() {
                for &r in &order[leaves(node + 1)] {
                    crate::prefetch(rays.get(r as usize));
                }
            }
            let mine = &order[leaves(node)];
            for (slot, &r) in part.iter_mut().zip(mine) {
                slot.write(Segment::of(&rays[r as usize]));
            }
            // The same rays again, now in the cache.
            let segs = mine.iter().map(|&r| {
                let s = Segment::of(&rays[r as usize]);
                (s, inverse_f32(s.dir))
            });
            segment_union_box(segs, bounds)
        })
        .collect();
    // SAFETY: the parts cover `0..n` (the node ranges partition the leaves, checked with the
    // hierarchy's shape), and each wrote every slot of its range.
    unsafe { segments.set_len(n) };
    let sub = h.subdivision as usize;
    let mut boxes = vec![lowest];
    for level in &h.levels[1..] {
        let below = boxes.last().expect("the lowest level");
        let next: Vec<Aabb> = (0..level.len())
            .into_par_iter()
            .map(|n| children_box(below, 0, below.len(), n, sub))
            .collect();
        boxes.push(next);
    }
    (segments, boxes)
}

/// The union of the boxes of node `n`'s children (`n·sub .. (n+1)·sub` of the level below, of
/// `below_len` nodes), from `below`, the boxes of that level's nodes `below_first ..` (the whole
/// level, or a task's part of it).
fn children_box(
    below: &[Aabb],
    below_first: usize,
    below_len: usize,
    n: usize,
    sub: usize,
) -> Aabb {
    let first = (n * sub).min(below_len) - below_first;
    let last = ((n + 1) * sub).min(below_len) - below_first;
    below[first..last]
        .iter()
        .fold(Aabb::EMPTY, |a, b| a.union(*b))
}

/// The end points of segments joined in `f32` before their padding ([`segment_box`]): the
/// running box `[lo, hi]` of the points `o + d·t` at the ends of each segment's interval
/// (clipped to the bounds when unbounded), and per axis the largest `|o| + |d|·max(|t₀|, |t₁|)`
/// over them, which bounds the rounding of those points. Empty (`lo > hi`) until a segment
/// with a non-empty extent joins.
#[derive(Clone, Copy, Debug)]
struct SegmentSpan {
    lo: Vec3A,
    hi: Vec3A,
    mag: Vec3A,
}

impl SegmentSpan {
    const EMPTY: SegmentSpan = SegmentSpan {
        lo: Vec3A::INFINITY,
        hi: Vec3A::NEG_INFINITY,
        mag: Vec3A::ZERO,
    };

    /// Joins `ray`'s extent (`inv`: its [`inverse_f32`]); `false` when the ray is not
    /// [`Ray::is_valid`] (its box is the whole space). The interval of an unbounded ray is
    /// [`slab_interval`]'s within `bounds`, which contains [`clip`]'s exact one.
    #[inline]
    fn add(&mut self, ray: &Segment, inv: Vec3A, bounds: &Aabb) -> bool {
        if !ray.is_valid() {
            return false;
        }
        self.add_valid(ray, inv, bounds);
        true
    }

    /// [`Self::add`] for a ray known to be [`Ray::is_valid`] (the inline tasks check their rays
    /// once, as they gather them).
    #[inline]
    fn add_valid(&mut self, ray: &Segment, inv: Vec3A, bounds: &Aabb) {
        let (t0, t1) = if ray.t_min.is_finite() && ray.t_max.is_finite() {
            // A bounded segment (shadow rays): its end points, no clipping (no divisions).
            (ray.t_min, ray.t_max)
        } else if bounds.is_empty() {
            return;
        } else {
            slab_interval(ray, inv, bounds)
        };
        // An empty interval (or a NaN end) joins nothing.
        if t0 <= t1 {
            let (o, d) = (Vec3A::from(ray.origin), Vec3A::from(ray.dir));
            let (p0, p1) = (o + d * t0, o + d * t1);
            self.lo = self.lo.min(p0.min(p1));
            self.hi = self.hi.max(p0.max(p1));
            self.mag = self.mag.max(o.abs() + d.abs() * t0.abs().max(t1.abs()));
        }
    }

    /// The box, each side padded by `4ε·mag + 2e-9·max(1, |corner|∞)` (`ε` = `f32::EPSILON`
    /// = `2u`): a point `o + d·t` computed in `f32` (a product and a sum, one rounding each,
    /// no fused multiply-add) is within `2u·(|o| + |d·t|)` of the exact one, the subtraction of
    /// the pad rounds by at most `u·(|lo| + pad)`, and the absolute term covers what
    /// subnormal products lose; `4ε = 8u` covers all of it with room. The empty box when
    /// nothing joined; an overflowing side (a coordinate near `f32::MAX`) becomes infinite.
    /// Padding a union once pads it at least as much as each of its segments alone, so a
    /// node's box holds its rays' boxes.
    #[inline]
    fn padded(&self) -> Aabb {
        if !self.lo.cmple(self.hi).all() {
            return Aabb::EMPTY;
        }
        let scale = self.lo.abs().max(self.hi.abs()).max_element().max(1.0);
        let pad = 4.0 * f32::EPSILON * self.mag + Vec3A::splat(2e-9 * scale);
        let (lo, hi) = (self.lo - pad, self.hi + pad);
        // NaN (an infinite end point less an infinite pad) only where a side overflowed.
        let lo = Vec3A::select(lo.cmpeq(lo), lo, Vec3A::NEG_INFINITY);
        let hi = Vec3A::select(hi.cmpeq(hi), hi, Vec3A::INFINITY);
        Aabb {
            min: lo.into(),
            max: hi.into(),
        }
    }
}

/// The union of [`segment_box`] over `rays` (each with its [`inverse_f32`]), padded once: the
/// whole space if one of them is not valid, the empty box if every extent is empty.
fn segment_union_box(rays: impl Iterator<Item = (Segment, Vec3A)>, bounds: &Aabb) -> Aabb {
    let mut span = SegmentSpan::EMPTY;
    for (ray, inv) in rays {
        if !span.add(&ray, inv, bounds) {
            return EVERYWHERE;
        }
    }
    span.padded()
}

/// [`segment_union_box`] of rays known to be [`Ray::is_valid`].
fn valid_segment_union_box(rays: impl Iterator<Item = (Segment, Vec3A)>, bounds: &Aabb) -> Aabb {
    let mut span = SegmentSpan::EMPTY;
    for (ray, inv) in rays {
        span.add_valid(&ray, inv, bounds);
    }
    span.padded()
}

/// The part `[t0, t1]` of a valid ray's interval inside the non-empty box `b` (slabs in
/// `f64`, widened by a relative `1e-9` for the rounding of the division), `None` when it is
/// empty.
#[inline]
fn clip(ray: &Segment, b: &Aabb) -> Option<(f64, f64)> {
    let (o, d) = (ray.origin.as_dvec3(), ray.dir.as_dvec3());
    let inv = DVec3::ONE / d;
    let (lo, hi) = (b.min.as_dvec3(), b.max.as_dvec3());
    let (mut t0, mut t1) = (ray.t_min as f64, ray.t_max as f64);
    for axis in 0..3 {
        if d[axis] == 0.0 {
            if o[axis] < lo[axis] || o[axis] > hi[axis] {
                return None;
            }
            continue;
        }
        let a = (lo[axis] - o[axis]) * inv[axis];
        let c = (hi[axis] - o[axis]) * inv[axis];
        let (near, far) = (a.min(c), a.max(c));
        t0 = t0.max(near - 1e-9 * near.abs());
        t1 = t1.min(far + 1e-9 * far.abs());
    }
    (t0 <= t1).then_some((t0, t1))
}

/// The relative widening of [`meets_box`]'s slab distances: `fl(fl(lo − o)·fl(1/d))` is off by
/// at most `3u` relative (`u = 2⁻²⁴`, one rounding each for the subtraction, the reciprocal
/// and the product, all of exact `f32` inputs), 1.8e-7, and the widening's own rounding adds
/// `u`; 1e-6 covers both with room, so the interval contains [`clip`]'s (whose widening is
/// 1e-9). The same widening as the wgpu twin's `clip`.
const SLAB_WIDEN: f32 = 1e-6;

/// The absolute part of [`meets_box`]'s widening: what an underflowing product can lose
/// (at most `2⁻¹⁴⁹` a rounding).
const SLAB_TINY: f32 = 1e-30;

/// A ray's `1 / d` per axis in `f32`, for [`meets_box`]: infinite where `d` is 0 (that axis is
/// tested apart), NaN everywhere when a non-zero component's reciprocal overflows (a
/// direction component below `2⁻¹²⁸`: [`meets_box`] then falls back to [`clip`]).
#[inline]
fn inverse_f32(d: Vec3) -> Vec3A {
    let d = Vec3A::from(d);
    let inv = Vec3A::ONE / d;
    if (inv.is_finite_mask() | d.cmpeq(Vec3A::ZERO)).all() {
        inv
    } else {
        Vec3A::NAN
    }
}

/// The part of the valid `ray`'s interval that may lie in box `b`, `(t₀, t₁)`, empty when
/// `t₀ > t₁` (or NaN): the slab test in `f32` on three lanes at once, each slab distance
/// widened by [`SLAB_WIDEN`] of itself plus [`SLAB_TINY`], so that the interval contains
/// [`clip`]'s (and rarely more: the widening is a millionth of the distance). An axis along
/// which the ray does not move constrains nothing when the origin lies within the box's slab
/// and empties the interval otherwise, as in [`clip`]. `inv` is the ray's [`inverse_f32`]
/// (NaN: the `f64` [`clip`] decides, its ends rounded outwards to `f32`).
#[inline]
fn slab_interval(ray: &Segment, inv: Vec3A, b: &Aabb) -> (f32, f32) {
    if inv.x.is_nan() {
        return match clip(ray, b) {
            Some((t0, t1)) => (f32_down(t0), f32_up(t1)),
            None => (f32::INFINITY, f32::NEG_INFINITY),
        };
    }
    let (o, d) = (Vec3A::from(ray.origin), Vec3A::from(ray.dir));
    let (lo, hi) = (Vec3A::from(b.min), Vec3A::from(b.max));
    let a = (lo - o) * inv;
    let c = (hi - o) * inv;
    let (near, far) = (a.min(c), a.max(c));
    let near = near - (near.abs() * SLAB_WIDEN + SLAB_TINY);
    let far = far + (far.abs() * SLAB_WIDEN + SLAB_TINY);
    // Axes the ray does not move along: everything or nothing, by where the origin lies.
    let still = d.cmpeq(Vec3A::ZERO);
    let inside = o.cmpge(lo) & o.cmple(hi);
    let (all, none) = (Vec3A::splat(f32::INFINITY), Vec3A::splat(f32::NEG_INFINITY));
    let near = Vec3A::select(still, Vec3A::select(inside, none, all), near);
    let far = Vec3A::select(still, Vec3A::select(inside, all, none), far);
    (
        near.max_element().max(ray.t_min),
        far.min_element().min(ray.t_max),
    )
}

/// Whether some point of the valid `ray`'s interval may lie in box `b`: [`slab_interval`] is
/// not empty, so it passes whenever [`clip`] does. In place of [`clip`]'s `f64` axis loop with
/// its branches, where the single-ray descents of wide-cone nodes (the dining room's
/// reflection rays) spent a third of their time: criterion `reflection/dual_lbvh_inline`
/// −44 % (README, "Wide cones").
#[inline]
fn meets_box(ray: &Segment, inv: Vec3A, b: &Aabb) -> bool {
    let (t0, t1) = slab_interval(ray, inv, b);
    t0 <= t1
}

/// Whether a point of `ray`'s segment (its interval) may lie in box `b`: [`clip`]; true for a
/// ray that is not [`Ray::is_valid`] (the intersector refuses it). The traversal calls
/// [`clip`] itself, on nodes whose rays are all valid.
#[cfg(test)]
fn segment_meets_box(ray: &Ray, b: &Aabb) -> bool {
    !ray.is_valid() || clip(&Segment::of(ray), b).is_some()
}

/// The box around a sphere, `f64`.
fn sphere_box(s: &Sphere) -> (DVec3, DVec3) {
    let c = s.center.as_dvec3();
    let r = DVec3::splat(s.radius as f64);
    (c - r, c + r)
}

impl Lbvh {
    /// Builds the hierarchy over `scene`'s triangle spheres. Errors on 2³¹ triangles or more.
    pub fn build(scene: &Scene) -> Result<Lbvh> {
        let spheres = &scene.tri_spheres;
        let n = spheres.len();
        if n >= LEAF as usize {
            return Err(CoreError::InvalidInput(format!(
                "{n} triangles: the object hierarchy holds fewer than 2^31"
            )));
        }
        let (lo, hi) = spheres.iter().fold(
            (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)),
            |(lo, hi), s| {
                let c = s.center.as_dvec3();
                (lo.min(c), hi.max(c))
            },
        );
        let extent = (hi - lo).max(DVec3::splat(f64::MIN_POSITIVE));
        let cells = ((1u64 << 21) - 1) as f64;
        let mut keys: Vec<(u64, u32)> = spheres
            .par_iter()
            .enumerate()
            .map(|(i, s)| {
                let q = ((s.center.as_dvec3() - lo) / extent * cells)
                    .clamp(DVec3::ZERO, DVec3::splat(cells));
                let code =
                    spread3(q.x as u64) << 2 | spread3(q.y as u64) << 1 | spread3(q.z as u64);
                (code, i as u32)
            })
            .collect();
        keys.par_sort_unstable();
        let codes: Vec<u64> = keys.iter().map(|k| k.0).collect();
        let leaf_tris: Vec<u32> = keys.iter().map(|k| k.1).collect();
        let mut inner = vec![
            Inner {
                sphere: Sphere::new(Vec3::ZERO, 0.0),
                bx: Aabb::EMPTY,
                children: [0, 0],
            };
            n.saturating_sub(1)
        ];
        // Top-down splits (pre-order), then bounds in reverse pre-order (children first).
        let mut preorder: Vec<u32> = Vec::with_capacity(inner.len());
        let mut max_depth = 0usize;
        let mut stack: Vec<(usize, usize, u32, usize)> = Vec::new();
        if n > 1 {
            stack.push((0, n - 1, 0, 0));
        }
        while let Some((a, b, index, depth)) = stack.pop() {
            preorder.push(index);
            max_depth = max_depth.max(depth + 1);
            let split = if codes[a] == codes[b] {
                (a + b) / 2
            } else {
                let prefix = (codes[a] ^ codes[b]).leading_zeros();
                let same =
                    codes[a..=b].partition_point(|&c| (codes[a] ^ c).leading_zeros() > prefix);
                a + same - 1
            };
            let child = |lo: usize, hi: usize, index: usize| -> u32 {
                if lo == hi {
                    LEAF | lo as u32
                } else {
                    index as u32
                }
            };
            let left = child(a, split, split);
            let right = child(split + 1, b, split + 1);
            inner[index as usize].children = [left, right];
            if left & LEAF == 0 {
                stack.push((a, split, left, depth + 1));
            }
            if right & LEAF == 0 {
                stack.push((split + 1, b, right, depth + 1));
            }
        }
        Ok(Lbvh::with_topology(
            scene, inner, leaf_tris, &preorder, max_depth, None,
        ))
    }

    /// Builds the hierarchy over the topology of obvhs's binary BVH (`Bvh2`, PLOC with
    /// reinsertion, preset `quality`) over all of `scene`'s triangles, one triangle per leaf
    /// (a leaf of several becomes a balanced subtree); the bounds are computed as for the
    /// Morton build. Errors on 2³¹ triangles or more.
    pub fn build_bvh2(scene: &Scene, quality: BuildQuality) -> Result<Lbvh> {
        Ok(Lbvh::build_bvh2_keeping(scene, quality)?.0)
    }

    /// [`Lbvh::build_bvh2`], and the obvhs tree it is laid out from (`None` below 2 triangles,
    /// which [`Lbvh::build`] lays out).
    fn build_bvh2_keeping(scene: &Scene, quality: BuildQuality) -> Result<(Lbvh, Option<Bvh2>)> {
        let n = scene.triangle_count();
        if n >= LEAF as usize {
            return Err(CoreError::InvalidInput(format!(
                "{n} triangles: the object hierarchy holds fewer than 2^31"
            )));
        }
        if n < 2 {
            return Ok((Lbvh::build(scene)?, None));
        }
        let bvh2 = scene_bvh2(scene, quality);
        Ok((Lbvh::over_bvh2(scene, &bvh2)?, Some(bvh2)))
    }

    /// [`Lbvh::build_bvh2`] over `bvh`, obvhs's binary BVH over all of `scene`'s triangles
    /// ([`scene_bvh2`]; at least 2 of them, fewer than 2³¹).
    fn over_bvh2(scene: &Scene, bvh: &Bvh2) -> Result<Lbvh> {
        let n = scene.triangle_count();
        /// A part of the obvhs tree still to convert: a node, or a run of a leaf's primitives.
        enum Part {
            Node(usize),
            Prims(usize, usize),
        }
        // An obvhs node: inner (no primitives) or a leaf's run of primitives.
        let part_of = |i: usize| {
            let node = &bvh.nodes[i];
            if node.prim_count == 0 {
                Part::Node(i)
            } else {
                Part::Prims(node.first_index as usize, node.prim_count as usize)
            }
        };
        let (inner, leaf_tris, preorder, max_depth) = lay_out(
            part_of(0),
            |part| match part {
                Part::Node(i) => {
                    let f = bvh.nodes[i].first_index as usize;
                    [part_of(f), part_of(f + 1)]
                }
                Part::Prims(start, count) => {
                    let half = count / 2;
                    [
                        Part::Prims(start, half),
                        Part::Prims(start + half, count - half),
                    ]
                }
            },
            |part| match part {
                Part::Prims(start, 1) => Some(bvh.primitive_indices[*start]),
                _ => None,
            },
        );
        if leaf_tris.len() != n || inner.len() != n - 1 {
            return Err(CoreError::InvalidInput(format!(
                "the obvhs BVH over {n} triangles has {} leaves and {} inner nodes",
                leaf_tris.len(),
                inner.len()
            )));
        }
        Ok(Lbvh::with_topology(
            scene, inner, leaf_tris, &preorder, max_depth, None,
        ))
    }

    /// Builds the hierarchy over seed 002's uniform grid ([`GridData::build_of`], density `k`
    /// of eq. 1, every triangle binned whatever the ray-triangle test): the cells are grouped
    /// by halving cell ranges (the whole grid, then each range split at the middle of its
    /// longest axis, lowest axis on ties; a half without triangles is skipped, so every node
    /// has two non-empty halves), a single cell's triangle list is split in halves down to
    /// single entries. A leaf is one (cell, triangle) entry of the grid: a triangle in `m`
    /// cells is `m` leaves, each with the triangle's own sphere and box, so the bounds and
    /// their proof are the Morton build's (every node's sphere and box contain those of every
    /// leaf below) and only the topology is the grid's. Errors on 2³¹ entries or more.
    pub fn build_grid(scene: &Scene, k: f64) -> Result<Lbvh> {
        let n = scene.triangle_count();
        if n < 2 {
            return Lbvh::build(scene);
        }
        let grid = GridData::build_of(scene, k, &vec![true; n])?;
        let entries = grid.cell_tris.len();
        if entries >= LEAF as usize {
            return Err(CoreError::InvalidInput(format!(
                "{entries} grid entries: the object hierarchy holds fewer than 2^31"
            )));
        }
        let dims = grid.geometry.dims;
        let counts = CellCounts::new(dims, &grid.cell_ranges);
        /// A part still to convert: a range of cells (lowest corner, highest exclusive) whose
        /// halves both hold entries, or a run of one cell's entries.
        enum Part {
            Cells([u32; 3], [u32; 3]),
            Entries(u32, usize, usize),
        }
        // The part a non-empty cell range becomes: its first range, going down through empty
        // halves, that splits into two non-empty halves, or a single cell's entries.
        let settle = |mut lo: [u32; 3], mut hi: [u32; 3]| -> Part {
            loop {
                let Some((left, right)) = halves(lo, hi) else {
                    let cell = grid.geometry.cell_id(lo);
                    let [start, count] = grid.cell_ranges[cell as usize];
                    return Part::Entries(cell, start as usize, count as usize);
                };
                match (counts.of(left.0, left.1), counts.of(right.0, right.1)) {
                    (0, _) => (lo, hi) = right,
                    (_, 0) => (lo, hi) = left,
                    _ => return Part::Cells(lo, hi),
                }
            }
        };
        let root = settle([0; 3], dims);
        if let Part::Entries(_, _, 1) = root {
            // Two or more triangles are two or more entries.
            return Err(CoreError::InvalidInput(format!(
                "the grid over {n} triangles has one entry"
            )));
        }
        let (inner, entry_leaves, preorder, max_depth) = lay_out(
            root,
            |part| match part {
                Part::Cells(lo, hi) => {
                    let (l, r) = halves(lo, hi).expect("a settled range splits");
                    [settle(l.0, l.1), settle(r.0, r.1)]
                }
                Part::Entries(cell, start, count) => {
                    let half = count / 2;
                    [
                        Part::Entries(cell, start, half),
                        Part::Entries(cell, start + half, count - half),
                    ]
                }
            },
            |part| match part {
                Part::Entries(cell, start, 1) => Some((grid.cell_tris[*start], *cell)),
                _ => None,
            },
        );
        let (leaf_tris, leaf_cells): (Vec<u32>, Vec<u32>) = entry_leaves.into_iter().unzip();
        if leaf_tris.len() != entries || inner.len() != entries - 1 {
            return Err(CoreError::InvalidInput(format!(
                "the grid's {entries} entries gave {} leaves and {} inner nodes",
                leaf_tris.len(),
                inner.len()
            )));
        }
        // Each entry's cell, closed.
        let g = &grid.geometry;
        let (nx, ny) = (g.dims[0], g.dims[1]);
        let cells: Vec<Aabb> = leaf_cells
            .par_iter()
            .map(|&cell| {
                let c = [cell % nx, (cell / nx) % ny, cell / (nx * ny)];
                Aabb {
                    min: Vec3::from_array([0, 1, 2].map(|a| g.planes[a][c[a] as usize])),
                    max: Vec3::from_array([0, 1, 2].map(|a| g.planes[a][c[a] as usize + 1])),
                }
            })
            .collect();
        Ok(Lbvh::with_topology(
            scene,
            inner,
            leaf_tris,
            &preorder,
            max_depth,
            Some(&cells),
        ))
    }

    /// The hierarchy with the given topology (`inner` nodes' children set, leaves' triangle
    /// ids, the inner nodes in an order where a parent precedes its children): leaf spheres
    /// and boxes from the scene, inner bounds bottom-up. With `cells` (one per leaf, the
    /// grid's), a leaf's box is its triangle's box within the cell's [`entry_region`], and its
    /// sphere the smaller of the triangle's and the one around that box.
    fn with_topology(
        scene: &Scene,
        mut inner: Vec<Inner>,
        leaf_tris: Vec<u32>,
        preorder: &[u32],
        max_depth: usize,
        cells: Option<&[Aabb]>,
    ) -> Lbvh {
        let spheres = &scene.tri_spheres;
        let leaves: Vec<Leaf> = leaf_tris
            .par_iter()
            .enumerate()
            .map(|(i, &t)| {
                let sphere = spheres[t as usize];
                let tri = scene.triangle(t as usize);
                let bx = triangle_box(tri);
                let Some(cell) = cells.map(|c| &c[i]) else {
                    return Leaf { sphere, bx };
                };
                let region = entry_region(tri, &bx, cell);
                let clipped = Aabb {
                    min: bx.min.max(region.min),
                    max: bx.max.min(region.max),
                };
                if clipped.is_empty() {
                    // No hit of the triangle is reported in this entry's region.
                    return Leaf {
                        sphere,
                        bx: Aabb::EMPTY,
                    };
                }
                let (lo, hi) = (clipped.min.as_dvec3(), clipped.max.as_dvec3());
                let around = round_out((lo + hi) / 2.0, (hi - lo).length() / 2.0);
                Leaf {
                    sphere: if around.radius < sphere.radius {
                        around
                    } else {
                        sphere
                    },
                    bx: clipped,
                }
            })
            .collect();
        let mut boxes = vec![(DVec3::ZERO, DVec3::ZERO); inner.len()];
        for &i in preorder.iter().rev() {
            let [l, r] = inner[i as usize].children;
            let part = |c: u32| -> (Sphere, (DVec3, DVec3)) {
                if c & LEAF != 0 {
                    let s = leaves[(c & !LEAF) as usize].sphere;
                    (s, sphere_box(&s))
                } else {
                    (inner[c as usize].sphere, boxes[c as usize])
                }
            };
            let (sl, bl) = part(l);
            let (sr, br) = part(r);
            let bounds = (bl.0.min(br.0), bl.1.max(br.1));
            inner[i as usize].sphere = enclose(&sl, &sr, bounds);
            boxes[i as usize] = bounds;
            let child_box = |c: u32| {
                if c & LEAF != 0 {
                    leaves[(c & !LEAF) as usize].bx
                } else {
                    inner[c as usize].bx
                }
            };
            inner[i as usize].bx = child_box(l).union(child_box(r));
        }
        Lbvh {
            inner,
            leaf_tris,
            leaves,
            max_depth,
        }
    }

    /// The hierarchy over this one's topology for `scene`, the same triangles moved (their
    /// spheres updated): every leaf's sphere and box, then every internal node's bottom-up,
    /// as [`Lbvh::build`] computes them (`with_topology`). For [`Lbvh::build`] and
    /// [`Lbvh::build_bvh2`] trees only: a grid's leaves are clipped to cells that the motion
    /// moves away from.
    fn refitted(&self, scene: &Scene) -> Lbvh {
        // Any order with every node before its children (the bounds run it backwards).
        let mut preorder = Vec::with_capacity(self.inner.len());
        let mut stack = if self.inner.is_empty() {
            Vec::new()
        } else {
            vec![0u32]
        };
        while let Some(i) = stack.pop() {
            preorder.push(i);
            for c in self.inner[i as usize].children {
                if c & LEAF == 0 {
                    stack.push(c);
                }
            }
        }
        Lbvh::with_topology(
            scene,
            self.inner.clone(),
            self.leaf_tris.clone(),
            &preorder,
            self.max_depth,
            None,
        )
    }

    /// Leaves: the triangles, or with [`Lbvh::build_grid`] the grid's (cell, triangle)
    /// entries (a triangle in several cells is several leaves).
    pub fn triangles(&self) -> usize {
        self.leaf_tris.len()
    }

    /// Depth of the deepest leaf (0 for one triangle or none).
    pub fn max_depth(&self) -> usize {
        self.max_depth
    }

    /// The root reference (`None` without triangles).
    fn root(&self) -> Option<u32> {
        match self.leaf_tris.len() {
            0 => None,
            1 => Some(LEAF),
            _ => Some(0),
        }
    }

    /// The sphere of a node reference.
    #[inline]
    fn sphere(&self, node: u32) -> &Sphere {
        if node & LEAF != 0 {
            &self.leaves[(node & !LEAF) as usize].sphere
        } else {
            &self.inner[node as usize].sphere
        }
    }

    /// The box of a node reference.
    #[inline]
    fn bx(&self, node: u32) -> &Aabb {
        if node & LEAF != 0 {
            &self.leaves[(node & !LEAF) as usize].bx
        } else {
            &self.inner[node as usize].bx
        }
    }

    /// The box around every triangle (with margins), the empty box without triangles.
    pub fn bounds(&self) -> Aabb {
        match self.root() {
            Some(r) => *self.bx(r),
            None => Aabb::EMPTY,
        }
    }

    /// The hierarchy as one array, the layout the wgpu twin uploads: the internal nodes
    /// first (Karras numbering, the root at 0 when there are two leaves or more), then the
    /// leaves in sorted order; with the root's index (`None` without triangles). An internal
    /// node's [`FlatNode::children`] index the same array; a leaf has none and names its
    /// triangle.
    pub fn flat(&self) -> (Vec<FlatNode>, Option<u32>) {
        let n_inner = self.inner.len() as u32;
        let index = |r: u32| {
            if r & LEAF != 0 {
                n_inner + (r & !LEAF)
            } else {
                r
            }
        };
        let inner = self.inner.iter().map(|n| FlatNode {
            sphere: n.sphere,
            bx: n.bx,
            children: Some(n.children.map(index)),
            triangle: u32::MAX,
        });
        let leaves = self
            .leaves
            .iter()
            .zip(&self.leaf_tris)
            .map(|(l, &t)| FlatNode {
                sphere: l.sphere,
                bx: l.bx,
                children: None,
                triangle: t,
            });
        (inner.chain(leaves).collect(), self.root().map(index))
    }

    /// Every triangle id below `node`, for tests.
    #[cfg(test)]
    fn triangles_below(&self, node: u32, out: &mut Vec<u32>) {
        if node & LEAF != 0 {
            out.push(self.leaf_tris[(node & !LEAF) as usize]);
        } else {
            for c in self.inner[node as usize].children {
                self.triangles_below(c, out);
            }
        }
    }
}

/// Where a hit on `tri` reported in grid cell `cell` (closed) can lie: the cell widened on
/// each side by the margin `tb` (the triangle's [`triangle_box`]) adds on that side, rounded
/// outwards. A hit is within [`triangle_box`], so within that margin of the point `q` of the
/// triangle's vertex box nearest to it, and the grid lists the triangle in the cell holding
/// `q` (it bins the triangle in every cell its widened vertex box meets); so the entry of that
/// cell keeps the hit inside its clipped box.
pub fn entry_region(tri: [Vec3; 3], tb: &Aabb, cell: &Aabb) -> Aabb {
    let (lo, hi) = (cell.min, cell.max);
    let (vlo, vhi) = (
        tri[0].min(tri[1]).min(tri[2]),
        tri[0].max(tri[1]).max(tri[2]),
    );
    let side = |a: usize| -> (f32, f32) {
        let down = lo[a] as f64 - (vlo[a] as f64 - tb.min[a] as f64);
        let up = hi[a] as f64 + (tb.max[a] as f64 - vhi[a] as f64);
        let slack = |x: f64| 1e-12 * x.abs().max(1.0);
        (f32_down(down - slack(down)), f32_up(up + slack(up)))
    };
    let [x, y, z] = [0, 1, 2].map(side);
    Aabb {
        min: Vec3::new(x.0, y.0, z.0),
        max: Vec3::new(x.1, y.1, z.1),
    }
}

/// Lays out the binary tree that `split` unfolds from `root` (which is not a leaf): a part for
/// which `leaf` gives a payload is a leaf, every other part an internal node split in two.
/// Returns the internal nodes (children set, bounds blank; the root is 0), the leaves'
/// payloads in left-to-right order (a leaf reference is [`LEAF`] | its position), the
/// internal nodes in an order where a parent precedes its children, and the depth of the
/// deepest leaf.
fn lay_out<P, L>(
    root: P,
    mut split: impl FnMut(P) -> [P; 2],
    mut leaf: impl FnMut(&P) -> Option<L>,
) -> (Vec<Inner>, Vec<L>, Vec<u32>, usize) {
    let blank = Inner {
        sphere: Sphere::new(Vec3::ZERO, 0.0),
        bx: Aabb::EMPTY,
        children: [0, 0],
    };
    let mut inner = vec![blank];
    let mut leaves = Vec::new();
    let mut preorder = Vec::new();
    let mut max_depth = 0usize;
    let mut stack: Vec<(P, u32, usize)> = vec![(root, 0, 0)];
    while let Some((part, index, depth)) = stack.pop() {
        preorder.push(index);
        max_depth = max_depth.max(depth + 1);
        let mut children = [0u32; 2];
        let mut later = Vec::with_capacity(2);
        for (k, half) in split(part).into_iter().enumerate() {
            children[k] = match leaf(&half) {
                Some(payload) => {
                    leaves.push(payload);
                    LEAF | (leaves.len() - 1) as u32
                }
                None => {
                    inner.push(blank);
                    let c = (inner.len() - 1) as u32;
                    later.push((half, c, depth + 1));
                    c
                }
            };
        }
        inner[index as usize].children = children;
        // Right first, so that the left subtree's leaves come first.
        stack.extend(later.into_iter().rev());
    }
    (inner, leaves, preorder, max_depth)
}

/// A range of grid cells: lowest corner, highest corner exclusive.
type CellRange = ([u32; 3], [u32; 3]);

/// The two halves of the cell range `lo .. hi` (highest corner exclusive), split at the middle
/// of its longest axis (the lowest such axis on ties); `None` for a single cell.
fn halves(lo: [u32; 3], hi: [u32; 3]) -> Option<(CellRange, CellRange)> {
    let ext = [0, 1, 2].map(|a| hi[a] - lo[a]);
    let a = (0..3).fold(0, |best, a| if ext[a] > ext[best] { a } else { best });
    if ext[a] <= 1 {
        return None;
    }
    let mid = lo[a] + ext[a] / 2;
    let (mut left_hi, mut right_lo) = (hi, lo);
    left_hi[a] = mid;
    right_lo[a] = mid;
    Some(((lo, left_hi), (right_lo, hi)))
}

/// Grid entries per cell range in O(1): a summed-volume table of the cells' entry counts.
struct CellCounts {
    /// `(nx + 1)·(ny + 1)·(nz + 1)` sums: entries of the cells below `(x, y, z)` on every axis.
    sums: Vec<u64>,
    dims: [usize; 3],
}

impl CellCounts {
    fn new(dims: [u32; 3], ranges: &[[u32; 2]]) -> CellCounts {
        let d = dims.map(|n| n as usize);
        let (sx, sy) = (d[0] + 1, d[1] + 1);
        let mut sums = vec![0u64; sx * sy * (d[2] + 1)];
        let at = |x: usize, y: usize, z: usize| x + sx * (y + sy * z);
        for z in 1..=d[2] {
            for y in 1..=d[1] {
                for x in 1..=d[0] {
                    let cell = (x - 1) + d[0] * ((y - 1) + d[1] * (z - 1));
                    sums[at(x, y, z)] = ranges[cell][1] as u64
                        + sums[at(x - 1, y, z)]
                        + sums[at(x, y - 1, z)]
                        + sums[at(x, y, z - 1)]
                        + sums[at(x - 1, y - 1, z - 1)]
                        - sums[at(x - 1, y - 1, z)]
                        - sums[at(x - 1, y, z - 1)]
                        - sums[at(x, y - 1, z - 1)];
                }
            }
        }
        CellCounts { sums, dims: d }
    }

    /// Entries in the cells `lo .. hi` (highest corner exclusive).
    fn of(&self, lo: [u32; 3], hi: [u32; 3]) -> u64 {
        let (sx, sy) = (self.dims[0] + 1, self.dims[1] + 1);
        let s =
            |x: u32, y: u32, z: u32| self.sums[x as usize + sx * (y as usize + sy * z as usize)];
        let (a, b) = (lo, hi);
        s(b[0], b[1], b[2]) + s(a[0], a[1], b[2]) + s(a[0], b[1], a[2]) + s(b[0], a[1], a[2])
            - s(a[0], b[1], b[2])
            - s(b[0], a[1], b[2])
            - s(b[0], b[1], a[2])
            - s(a[0], a[1], a[2])
    }
}

/// What one `dual` traversal did, for tests and tuning.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct DualReport {
    /// Rounds run (each hands its candidates, if any, to the sink).
    pub rounds: usize,
    /// Batches handed to the sink.
    pub batches: usize,
    /// Times a task stopped with a full candidate array and resumed in a later round.
    pub suspensions: usize,
    /// Most tasks in one round (`G`).
    pub round_tasks: usize,
    /// Most candidates a task holds before it stops (`C`).
    pub task_candidates: usize,
    /// The budget in bytes.
    pub budget_bytes: u64,
    /// Largest total size, in bytes, of the candidate arrays alive at once (the tasks' arrays
    /// and the batch they are concatenated into).
    pub peak_candidate_bytes: u64,
    /// Candidate pairs handed to the sink, over all batches.
    pub candidates: u64,
    /// Rays of wide lowest nodes traced through the 8-wide BVH (parameter `wide_cone`).
    pub wide_rays: u64,
}

/// The `dual` traverser (see the module doc).
#[derive(Clone, Debug)]
pub struct Dual {
    objects: Objects,
    /// With `final_tests = inline`: the scene, and its triangles prepared per ray-triangle
    /// test (by [`TestKind`] order: `mt`, `watertight`, `projected`) on first use when the
    /// intersector is not `brute` (whose prepared triangles are used otherwise).
    inline: Option<InlineSets>,
    /// Parameter `wide_cone` below 180 (inline final tests only).
    wide: Option<WideRays>,
    /// Parameter `update = refit` (`objects = lbvh` or `bvh`), shared by clones: the first
    /// refit takes what is kept.
    refit: Option<Arc<Kept>>,
}

/// The triangles an inline traversal tests when the pipeline's intersector does not share
/// its own, prepared per ray-triangle test when first needed.
#[derive(Clone, Debug)]
struct InlineSets {
    scene: Arc<Scene>,
    sets: Arc<[OnceLock<AnyTriangleSet>; 3]>,
}

impl InlineSets {
    fn new(scene: &Arc<Scene>) -> InlineSets {
        InlineSets {
            scene: scene.clone(),
            sets: Arc::default(),
        }
    }

    /// How many tests' triangles this stage prepared itself.
    #[cfg(test)]
    fn prepared(&self) -> usize {
        self.sets.iter().filter(|s| s.get().is_some()).count()
    }

    fn get(&self, kind: TestKind) -> &AnyTriangleSet {
        let i = match kind {
            TestKind::MollerTrumbore => 0,
            TestKind::Watertight => 1,
            TestKind::Projected => 2,
        };
        self.sets[i].get_or_init(|| AnyTriangleSet::new(&self.scene, kind))
    }
}

/// obvhs's binary BVH (PLOC with reinsertion, preset `quality`) over all of `scene`'s
/// triangles, in scene order (primitive `i` is triangle `i`).
fn scene_bvh2(scene: &Scene, quality: BuildQuality) -> Bvh2 {
    build_bvh2(&scene_triangles(scene), &quality.params())
}

/// `scene`'s triangles for obvhs, in scene order.
fn scene_triangles(scene: &Scene) -> Vec<Triangle> {
    (0..scene.triangle_count())
        .into_par_iter()
        .map(|t| obvhs_triangle(scene.triangle(t)))
        .collect()
}

/// Parameter `wide_cone` (see *Wide ray nodes* in the module doc): the compressed 8-wide BVH
/// the rays of wide lowest nodes are traced through, and the half-angle from which a node is
/// wide.
#[derive(Clone, Debug)]
struct WideRays {
    /// obvhs's CWBVH over all of the scene's triangles: primitive slot `s` is triangle
    /// `primitive_indices[s]`.
    bvh: Arc<obvhs::cwbvh::CwBvh>,
    /// The scene's triangle count (the prepared triangles must cover it).
    triangles: usize,
    /// The parameter, in degrees (below 180).
    degrees: f64,
}

impl WideRays {
    /// The CWBVH compressed from `bvh2` (obvhs's binary BVH over all of `scene`'s triangles,
    /// [`scene_bvh2`]; `None`: built here, `fast` preset), leaves of up to 3 triangles as the
    /// `bvh` intersector's.
    fn new(scene: &Scene, bvh2: Option<&Bvh2>, degrees: f64) -> WideRays {
        let n = scene.triangle_count();
        let bvh = if n == 0 {
            obvhs::cwbvh::CwBvh::default()
        } else {
            match bvh2 {
                Some(b) => compress_bvh2(b, BuildQuality::Fast),
                None => compress_bvh2(&scene_bvh2(scene, BuildQuality::Fast), BuildQuality::Fast),
            }
        };
        WideRays {
            bvh: Arc::new(bvh),
            triangles: n,
            degrees,
        }
    }

    /// Whether a lowest node of cone half-angle `half_angle` (radians) is wide.
    #[inline]
    fn is_wide(&self, half_angle: f32) -> bool {
        f64::from(half_angle) >= self.degrees.to_radians()
    }
}

/// The error of a refused parameter `wide_cone` of `degrees`: out of range, or set where it
/// cannot run (batched final tests, `objects = meshes`).
fn wide_cone_error(degrees: f64, out_of_range: bool) -> CoreError {
    let reason = if out_of_range {
        format!("{degrees} is not in 0 ..= {WIDE_CONE_OFF}")
    } else {
        format!("{degrees}° needs `final_tests = inline` and `objects = lbvh`, `bvh` or `grid`")
    };
    CoreError::InvalidParam {
        key: "traverse.wide_cone".into(),
        reason,
    }
}

/// The error of parameter `update = refit` with `objects` other than `lbvh` and `bvh`.
fn refit_error(objects: &str) -> CoreError {
    CoreError::InvalidParam {
        key: "traverse.update".into(),
        reason: format!(
            "`refit` needs `objects = lbvh` or `bvh` (with `{objects}` the object side follows \
             the positions: it is rebuilt)"
        ),
    }
}

/// Parameter `wide_cone`'s value that turns it off.
pub const WIDE_CONE_OFF: f64 = 180.0;

/// The choices of parameter `final_tests`.
pub const FINAL_TESTS: [&str; 2] = ["batched", "inline"];

/// The choices of parameter `update`.
pub const UPDATES: [&str; 2] = ["rebuild", "refit"];

/// With `update = refit`: what the next frame's [`Dual::refitted`] needs besides the object
/// tree (which it reads).
#[derive(Default)]
struct Kept {
    /// obvhs's binary tree over all of the scene's triangles (primitive `i` is triangle `i`,
    /// [`scene_bvh2`]) that the wide rays' CWBVH was compressed from, with `wide_cone` on;
    /// taken by the refit that uses it.
    bvh2: Mutex<Option<Bvh2>>,
}

impl std::fmt::Debug for Kept {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let kept = self.bvh2.lock().map(|b| b.is_some()).unwrap_or(false);
        f.debug_struct("Kept").field("bvh2", &kept).finish()
    }
}

/// The object side.
#[derive(Clone, Debug)]
enum Objects {
    /// A per-frame [`Lbvh`]; `box_test`: the pair test starts with the boxes;
    /// `single_rays`: lowest nodes may descend to their rays.
    Lbvh {
        tree: Box<Lbvh>,
        budget_bytes: u64,
        /// Whose topology the tree has: the `objects` value (`lbvh`, `bvh` or `grid`).
        source: &'static str,
        box_test: bool,
        single_rays: bool,
    },
    /// The thesis's mesh spheres ([`Crsh`] with mesh culling).
    Meshes(Crsh),
}

/// One (ray node, object node) pair waiting for its test.
#[derive(Clone, Copy, Debug)]
struct Pair {
    /// Node index within its ray level.
    node: u32,
    /// Object node reference.
    obj: u32,
    /// Ray level index (0: `levels[0]`).
    level: u16,
    /// Object node depth (0: the root).
    depth: u16,
    /// With `level == `[`SINGLE`]: which rays of lowest node `node` this pair still tests
    /// (bit `i`: the node's `i`-th leaf); otherwise unused.
    mask: u32,
}

/// The `level` of a pair that tests the single rays of a lowest node (see *Single rays*).
const SINGLE: u16 = u16::MAX;

/// Tests and passes per ray level and per object depth.
#[derive(Clone, Debug, Default)]
struct Counters {
    ray: Vec<[u64; 2]>,
    obj: Vec<[u64; 2]>,
}

impl Counters {
    fn new(levels: usize, depths: usize) -> Counters {
        Counters {
            ray: vec![[0; 2]; levels],
            obj: vec![[0; 2]; depths],
        }
    }

    /// Adds the tests to `stats`: bounds, ray-level rows and object-depth rows.
    fn record(&self, kind: RayKind, stats: &mut Stats) {
        stats.add_bounds(self.ray.iter().map(|c| c[0]).sum());
        for (li, c) in self.ray.iter().enumerate() {
            stats.add_level(kind, li as u32 + 1, c[0], c[1]);
        }
        for (depth, c) in self.obj.iter().enumerate() {
            stats.add_object_level(kind, depth as u32, c[0], c[1]);
        }
    }

    fn add(&mut self, o: &Counters) {
        for (a, b) in self.ray.iter_mut().zip(&o.ray) {
            a[0] += b[0];
            a[1] += b[1];
        }
        for (a, b) in self.obj.iter_mut().zip(&o.obj) {
            a[0] += b[0];
            a[1] += b[1];
        }
    }
}

/// A ray node's depth-first traversal (a top-level node's; inline, a node of [`task_level`]),
/// resumable.
struct Task {
    stack: Vec<Pair>,
}

/// A ray node prepared for the pair test: its segment box (the whole space when neither the
/// box test nor single rays need it) next to its cone-sphere bound.
#[derive(Clone, Copy, Debug)]
struct RayNode {
    bx: Aabb,
    bound: NodeBound,
}

/// The whole space: the box of a ray node nothing is culled by.
const EVERYWHERE: Aabb = Aabb {
    min: Vec3::NEG_INFINITY,
    max: Vec3::INFINITY,
};

/// What the tasks share.
struct Ctx<'a> {
    /// The batch's size.
    n_rays: usize,
    /// The batch (the inline tasks gather their own rays' segments from it).
    rays: &'a [Ray],
    /// The box of every triangle, which segment boxes are clipped to ([`Lbvh::bounds`]).
    bounds: Aabb,
    /// The rays' segments in leaf order (the batched traversal's, with boxes or single rays;
    /// empty for the inline one, whose tasks gather their own).
    segments: &'a [Segment],
    hierarchy: &'a RayHierarchy<Cpu>,
    /// Whether lowest nodes descend to single rays.
    single_rays: bool,
    /// Whether pairs are box-tested.
    box_test: bool,
    /// The ray nodes by level (lowest first).
    nodes: &'a [Vec<RayNode>],
    sub: usize,
    tree: &'a Lbvh,
    /// Parameter `wide_cone` (inline final tests only).
    wide: Option<&'a WideRays>,
}

impl Task {
    /// Pairs `p`'s ray side (node, level, live rays) with both children of its internal
    /// object node, the left one to be popped first.
    fn push_object_children(&mut self, tree: &Lbvh, p: Pair) {
        for &c in tree.inner[p.obj as usize].children.iter().rev() {
            self.stack.push(Pair {
                obj: c,
                depth: p.depth + 1,
                ..p
            });
        }
    }

    /// Runs until the stack is empty or `leaves` says stop, handing every (lowest node,
    /// triangle) pair that passes to `leaves`; returns the counters.
    fn run<L: Leaves>(&mut self, ctx: &Ctx<'_>, leaves: &mut L) -> Counters {
        let tree = ctx.tree;
        let mut counts = Counters::new(ctx.nodes.len(), tree.max_depth + 1);
        while let Some(p) = self.stack.pop() {
            if leaves.full() {
                self.stack.push(p);
                break;
            }
            if p.level == SINGLE {
                // The node's live rays, one by one, against the object node's box (counted
                // in the lowest level's row).
                let mask = p.mask & leaves.live_rays(p.node);
                if mask == 0 {
                    continue;
                }
                let first = lowest_node_leaves(
                    p.node as usize,
                    ctx.hierarchy.subdivision,
                    ctx.hierarchy.leaf_offsets.as_deref(),
                    ctx.n_rays,
                )
                .start;
                let bx = tree.bx(p.obj);
                let (mut live, mut left) = (0u32, mask);
                while left != 0 {
                    let i = left.trailing_zeros();
                    left &= left - 1;
                    if leaves.meets(ctx, first + i as usize, bx) {
                        live |= 1 << i;
                    }
                }
                let (tested, passed) = (mask.count_ones() as u64, live.count_ones() as u64);
                counts.ray[0][0] += tested;
                counts.ray[0][1] += passed;
                counts.obj[p.depth as usize][0] += tested;
                counts.obj[p.depth as usize][1] += passed;
                if live == 0 {
                    continue;
                }
                if p.obj & LEAF != 0 {
                    leaves.reach(p.node, tree.leaf_tris[(p.obj & !LEAF) as usize], live);
                } else {
                    self.push_object_children(tree, Pair { mask: live, ..p });
                }
                continue;
            }
            if !leaves.live(p.level, p.node) {
                continue;
            }
            let rn = &ctx.nodes[p.level as usize][p.node as usize];
            let nb = &rn.bound;
            let sphere = tree.sphere(p.obj);
            counts.ray[p.level as usize][0] += 1;
            counts.obj[p.depth as usize][0] += 1;
            let rbx = leaves.node_box(ctx, p.level, p.node);
            if ctx.box_test && !rbx.overlaps(tree.bx(p.obj)) {
                continue;
            }
            let Some(spreads) = nb.hit_and_spread(sphere) else {
                continue;
            };
            counts.ray[p.level as usize][1] += 1;
            counts.obj[p.depth as usize][1] += 1;
            let leaf = p.obj & LEAF != 0;
            let lowest = p.level == 0;
            let split_rays = match (lowest, leaf) {
                (true, true) => {
                    leaves.reach(p.node, tree.leaf_tris[(p.obj & !LEAF) as usize], ALL_LANES);
                    continue;
                }
                (true, false) => {
                    let rays = lowest_node_leaves(
                        p.node as usize,
                        ctx.hierarchy.subdivision,
                        ctx.hierarchy.leaf_offsets.as_deref(),
                        ctx.n_rays,
                    )
                    .len();
                    // A node with a ray that is not valid has the whole space as its box
                    // and stays whole (the single-ray test assumes valid rays).
                    if ctx.single_rays && rays <= 32 && rbx.min.is_finite() && spreads {
                        // The node's rays spread wider than the object node: test them one
                        // by one below it.
                        self.stack.push(Pair {
                            level: SINGLE,
                            mask: ((1u64 << rays) - 1) as u32,
                            ..p
                        });
                        continue;
                    }
                    false
                }
                (false, true) => true,
                (false, false) => spreads,
            };
            if split_rays {
                let below = &ctx.nodes[p.level as usize - 1];
                let first = (p.node as usize * ctx.sub).min(below.len());
                let last = ((p.node as usize + 1) * ctx.sub).min(below.len());
                // Reversed, so that the lowest child is popped first.
                for c in (first..last).rev() {
                    self.stack.push(Pair {
                        node: c as u32,
                        level: p.level - 1,
                        ..p
                    });
                }
            } else if L::NEAR_FIRST {
                let [a, b] = tree.inner[p.obj as usize].children;
                let (da, db) = (
                    nb.along_axis(tree.sphere(a).center),
                    nb.along_axis(tree.sphere(b).center),
                );
                let (first, second) = if db < da { (b, a) } else { (a, b) };
                for c in [second, first] {
                    self.stack.push(Pair {
                        obj: c,
                        depth: p.depth + 1,
                        ..p
                    });
                }
            } else {
                self.push_object_children(tree, p);
            }
        }
        counts
    }
}

/// Where a task's traversal hands its (lowest node, triangle) pairs, and what it asks about
/// the rays as it goes: [`Batched`] collects candidates for the intersector, [`Inline`] tests
/// them at once.
trait Leaves {
    /// Whether a pair split on the object side visits the child nearer along the ray node's
    /// axis first (else the left one).
    const NEAR_FIRST: bool;
    /// Whether the task must stop before its next pair.
    fn full(&mut self) -> bool;
    /// Whether ray node `node` of ray level `level` (0: the lowest) has a ray left to trace.
    fn live(&self, level: u16, node: u32) -> bool;
    /// The rays of lowest node `node` left to trace (bit `i`: its `i`-th leaf).
    fn live_rays(&self, node: u32) -> u32;
    /// Whether the segment of leaf `leaf`, as the single-ray test must see it now, meets box
    /// `bx` ([`clip`]).
    fn meets(&self, ctx: &Ctx<'_>, leaf: usize, bx: &Aabb) -> bool;
    /// The segment box of ray node `node` of ray level `level` ([`segment_box`]'s union over
    /// its rays; the whole space without boxes).
    fn node_box<'s>(&'s self, ctx: &'s Ctx<'_>, level: u16, node: u32) -> &'s Aabb;
    /// The rays `lanes` of lowest node `node` reached triangle `tri`.
    fn reach(&mut self, node: u32, tri: u32, lanes: u32);
}

/// Candidates for the intersector, at most `cap` held.
struct Batched {
    out: Vec<(Candidate, u32)>,
    cap: usize,
}

impl Leaves for Batched {
    const NEAR_FIRST: bool = false;

    #[inline]
    fn full(&mut self) -> bool {
        if self.out.len() < self.cap {
            return false;
        }
        // Grid triangles arrive once per cell: merge them, and stop only if that frees less
        // than a quarter of the share.
        sort_and_merge(&mut self.out);
        self.out.len() >= self.cap - self.cap / 4
    }

    #[inline]
    fn live(&self, _level: u16, _node: u32) -> bool {
        true
    }

    #[inline]
    fn live_rays(&self, _node: u32) -> u32 {
        ALL_LANES
    }

    #[inline]
    fn meets(&self, ctx: &Ctx<'_>, leaf: usize, bx: &Aabb) -> bool {
        let seg = &ctx.segments[leaf];
        meets_box(seg, inverse_f32(seg.dir), bx)
    }

    #[inline]
    fn node_box<'s>(&'s self, ctx: &'s Ctx<'_>, level: u16, node: u32) -> &'s Aabb {
        &ctx.nodes[level as usize][node as usize].bx
    }

    #[inline]
    fn reach(&mut self, node: u32, tri: u32, lanes: u32) {
        push_candidate(&mut self.out, self.cap, Candidate { node, tri }, lanes);
    }
}

/// The rays of one task (a node of [`task_level`]) traced inline: each (lowest node,
/// triangle) pair is tested as soon as the traversal reaches it, with test `T`; an any-hit ray
/// leaves the traversal at its first hit, a closest-hit ray's segment ends at its nearest hit
/// so far.
struct Inline<'a, T: TriangleTest> {
    tris: &'a [T::Tri],
    n_rays: usize,
    subdivision: u32,
    offsets: Option<&'a [u32]>,
    closest: bool,
    /// The task's first lowest node and first leaf.
    first_low: u32,
    first_leaf: usize,
    /// Per ray level `l ≥ 1` (entry `l − 1`): the task's first node there, and per node the
    /// number of rays below it left to trace (any-hit only).
    alive: Vec<(u32, Vec<u32>)>,
    /// Per lowest node of the task: its rays left to trace (none for a wide node).
    live: Vec<u32>,
    /// The task's wide lowest nodes (parameter `wide_cone`), traced by [`Inline::trace_wide`].
    wide: Vec<u32>,
    /// Per leaf of the task: its best hit so far.
    hits: Vec<Hit>,
    /// The task's segments in leaf order, gathered by the task (closest-hit: their `t_max`
    /// shrinks with each nearer hit).
    segments: Vec<Segment>,
    /// Per leaf of the task: its direction's [`inverse_f32`], for the single-ray box tests.
    inverse: Vec<Vec3A>,
    /// Per ray level (lowest first): the task's first node there and the segment boxes of its
    /// nodes there, from the segments as gathered.
    boxes: Vec<(u32, Vec<Aabb>)>,
    /// Packets of [`LANES`] rays per lowest node (`per_node` of them, enough for the batch's
    /// widest node), built when the node first reaches a triangle: `slot[k]` is where lowest
    /// node `first_low + k`'s start in `packets` (`u32::MAX`: not built).
    packets: Vec<T::Packet>,
    slot: Vec<u32>,
    per_node: usize,
    tests: u64,
    found: u64,
    /// Whether every ray of the task is [`Ray::is_valid`] (a task with an invalid ray does not
    /// run: the batch is an error).
    valid: bool,
}

/// The smallest `f32` above `t` (finite `t`): a closest-hit ray's interval is open, and a later
/// triangle at the same `t` with a lower id must still be seen.
fn next_above(t: f32) -> f32 {
    if t == 0.0 {
        f32::from_bits(1)
    } else if t > 0.0 {
        f32::from_bits(t.to_bits() + 1)
    } else {
        f32::from_bits(t.to_bits() - 1)
    }
}

impl<'a, T: TriangleTest> Inline<'a, T> {
    /// The state of the task of node `top` of ray level `top_level` ([`task_level`]), its
    /// rays' hits gathered from `hits` (any-hit rays already hit are not traced; `None`: every
    /// hit is a miss).
    fn new(
        ctx: &Ctx<'a>,
        tris: &'a [T::Tri],
        mode: HitMode,
        (top_level, top): (usize, usize),
        widest: usize,
        hits: Option<&TaskHits<'_>>,
    ) -> Inline<'a, T> {
        let h = ctx.hierarchy;
        let order = h.order.as_slice();
        let sub = ctx.sub;
        // The task's nodes at ray level `l ≤ top_level`: those below node `top`.
        let nodes_at = |l: usize| {
            let (span, len) = (sub.pow((top_level - l) as u32), ctx.nodes[l].len());
            (top * span).min(len)..((top + 1) * span).min(len)
        };
        let lowest = nodes_at(0);
        let (first_low, last_low) = (lowest.start, lowest.end);
        let leaves_of =
            |n: usize| lowest_node_leaves(n, h.subdivision, h.leaf_offsets.as_deref(), ctx.n_rays);
        let first_leaf = leaves_of(first_low).start;
        let last_leaf = if last_low > first_low {
            leaves_of(last_low - 1).end
        } else {
            first_leaf
        };
        let closest = mode == HitMode::Closest;
        // A fresh batch (every hit a miss, as the pipeline starts) needs no gather.
        let mine: Vec<Hit> = match hits {
            Some(hits) => order[first_leaf..last_leaf]
                .iter()
                // SAFETY: this task's rays (the leaves of its node under a checked
                // permutation) are no other task's.
                .map(|&r| unsafe { hits.get(r as usize) })
                .collect(),
            None => vec![Hit::MISS; last_leaf - first_leaf],
        };
        let lowest_cones = &h.levels[0];
        let is_wide = |n: usize| {
            ctx.wide
                .is_some_and(|w| w.is_wide(lowest_cones[n].cone.half_angle))
        };
        let wide: Vec<u32> = (first_low..last_low)
            .filter(|&n| is_wide(n))
            .map(|n| n as u32)
            .collect();
        let live: Vec<u32> = (first_low..last_low)
            .map(|n| {
                if is_wide(n) {
                    // Traced through the wide BVH, not by the pairs.
                    return 0;
                }
                let leaves = leaves_of(n);
                let mut m = ((1u64 << leaves.len()) - 1) as u32;
                if !closest {
                    for (i, leaf) in leaves.enumerate() {
                        if mine[leaf - first_leaf].is_hit() {
                            m &= !(1 << i);
                        }
                    }
                }
                m
            })
            .collect();
        let alive = (1..=top_level)
            .map(|l| {
                let span_l = sub.pow(l as u32);
                let (first, last) = (nodes_at(l).start, nodes_at(l).end);
                let mut count = vec![0u32; last - first];
                for (k, m) in live.iter().enumerate() {
                    count[(first_low + k) / span_l - first] += m.count_ones();
                }
                (first as u32, count)
            })
            .collect();
        // The task's rays in leaf order (a gather through the permutation, the ray a few
        // places ahead prefetched), boxed node by node before any interval shrinks.
        const AHEAD: usize = 16;
        let mine_order = &order[first_leaf..last_leaf];
        let mut segments: Vec<Segment> = mine_order
            .iter()
            .enumerate()
            .map(|(i, &r)| {
                if let Some(&next) = mine_order.get(i + AHEAD) {
                    crate::prefetch(ctx.rays.get(next as usize));
                }
                Segment::of(&ctx.rays[r as usize])
            })
            .collect();
        // The batch's rays are checked here, where the task reads them anyway (a pass over the
        // whole batch before the traversal read every ray once more).
        let valid = segments.iter().all(Segment::is_valid);
        let inverse: Vec<Vec3A> = segments.iter().map(|s| inverse_f32(s.dir)).collect();
        let mut boxes: Vec<(u32, Vec<Aabb>)> = Vec::with_capacity(top_level + 1);
        // A task with an invalid ray does not run (the batch is an error): no boxes for it.
        if valid {
            let lowest_boxes = (first_low..last_low)
                .map(|n| {
                    if is_wide(n) {
                        // No pair reaches it: its rays need not widen the boxes above it.
                        return Aabb::EMPTY;
                    }
                    let leaves = leaves_of(n);
                    let at = leaves.start - first_leaf..leaves.end - first_leaf;
                    let mine = segments[at.clone()]
                        .iter()
                        .copied()
                        .zip(inverse[at].iter().copied());
                    valid_segment_union_box(mine, &ctx.bounds)
                })
                .collect();
            boxes.push((first_low as u32, lowest_boxes));
            for l in 1..=top_level {
                let (below_first, below) = &boxes[l - 1];
                let below_len = ctx.nodes[l - 1].len();
                let nodes = nodes_at(l);
                let first = nodes.start as u32;
                let level = nodes
                    .map(|n| children_box(below, *below_first as usize, below_len, n, sub))
                    .collect();
                boxes.push((first, level));
            }
        }
        if closest {
            for (seg, hit) in segments.iter_mut().zip(&mine) {
                if hit.is_hit() {
                    seg.t_max = seg.t_max.min(next_above(hit.t));
                }
            }
        }
        let n = last_low - first_low;
        Inline {
            tris,
            n_rays: ctx.n_rays,
            subdivision: h.subdivision,
            offsets: h.leaf_offsets.as_deref(),
            closest,
            first_low: first_low as u32,
            first_leaf,
            alive,
            live,
            wide,
            hits: mine,
            segments,
            inverse,
            boxes,
            packets: Vec::new(),
            slot: vec![u32::MAX; n],
            per_node: widest.div_ceil(LANES),
            tests: 0,
            found: 0,
            valid,
        }
    }

    /// The segment of leaf `leaf` (absolute), its interval ending at its best hit so far.
    #[inline]
    fn seg(&self, leaf: usize) -> &Segment {
        &self.segments[leaf - self.first_leaf]
    }

    /// The ray of leaf `leaf` as the triangle tests read it: from its segment ([`Inline::seg`],
    /// gathered by the task in leaf order), not through `order` again.
    fn ray(&self, leaf: usize) -> Ray {
        let s = self.seg(leaf);
        Ray::new(RayKind::Shadow, s.origin, s.dir, s.t_min, s.t_max)
    }

    /// Traces the rays of the task's wide lowest nodes one by one through `wide`'s BVH with
    /// test `T` (query `mode`), merging into their hits; returns the BVH's counts and the rays
    /// traced.
    fn trace_wide(&mut self, wide: &WideRays, mode: HitMode) -> (Counts, u64) {
        let (tris, ids) = (self.tris, &wide.bvh.primitive_indices);
        let leaf = |slot: usize| {
            let id = ids[slot];
            (&tris[id as usize], id)
        };
        let (mut counts, mut rays) = (Counts::default(), 0u64);
        for k in 0..self.wide.len() {
            let node = self.wide[k] as usize;
            for leaf_at in lowest_node_leaves(node, self.subdivision, self.offsets, self.n_rays) {
                let ray = self.ray(leaf_at);
                let i = leaf_at - self.first_leaf;
                counts = counts.add(trace_cwbvh::<T, true>(
                    &wide.bvh,
                    leaf,
                    &ray,
                    mode,
                    &mut self.hits[i],
                ));
                rays += 1;
            }
        }
        (counts, rays)
    }
}

impl<T: TriangleTest> Leaves for Inline<'_, T> {
    const NEAR_FIRST: bool = true;

    #[inline]
    fn full(&mut self) -> bool {
        false
    }

    #[inline]
    fn live(&self, level: u16, node: u32) -> bool {
        // Closest-hit rays stay live to the end, but a wide node's are not the pairs' to trace.
        if level == 0 {
            return self.live[(node - self.first_low) as usize] != 0;
        }
        let (first, count) = &self.alive[level as usize - 1];
        count[(node - first) as usize] != 0
    }

    #[inline]
    fn live_rays(&self, node: u32) -> u32 {
        self.live[(node - self.first_low) as usize]
    }

    #[inline]
    fn meets(&self, _ctx: &Ctx<'_>, leaf: usize, bx: &Aabb) -> bool {
        meets_box(self.seg(leaf), self.inverse[leaf - self.first_leaf], bx)
    }

    #[inline]
    fn node_box<'s>(&'s self, _ctx: &'s Ctx<'_>, level: u16, node: u32) -> &'s Aabb {
        let (first, boxes) = &self.boxes[level as usize];
        &boxes[(node - first) as usize]
    }

    fn reach(&mut self, node: u32, tri: u32, lanes: u32) {
        let k = (node - self.first_low) as usize;
        let want = lanes & self.live[k];
        if want == 0 {
            return;
        }
        let leaves = lowest_node_leaves(node as usize, self.subdivision, self.offsets, self.n_rays);
        if self.slot[k] == u32::MAX {
            let at = self.packets.len();
            self.slot[k] = at as u32;
            self.packets.resize(at + self.per_node, T::empty_packet());
            for (i, leaf) in leaves.clone().enumerate() {
                let ray = self.ray(leaf);
                T::set_lane(&mut self.packets[at + i / LANES], i % LANES, &ray);
            }
        }
        let at = self.slot[k] as usize;
        let t = &self.tris[tri as usize];
        for j in 0..self.per_node {
            let sub = (want >> (j * LANES)) & ((1 << LANES) - 1);
            if sub == 0 {
                continue;
            }
            self.tests += sub.count_ones() as u64;
            let (mask, bh) = T::test_packet(&self.packets[at + j], t);
            let mut hit = mask & sub;
            self.found += hit.count_ones() as u64;
            while hit != 0 {
                let l = hit.trailing_zeros() as usize;
                hit &= hit - 1;
                let i = j * LANES + l;
                let leaf = leaves.start + i;
                let h = Hit {
                    t: bh.t[l],
                    tri,
                    u: bh.u[l],
                    v: bh.v[l],
                };
                let best = &mut self.hits[leaf - self.first_leaf];
                if self.closest {
                    if h.closer_than(best) {
                        *best = h;
                        let seg = &mut self.segments[leaf - self.first_leaf];
                        seg.t_max = seg.t_max.min(next_above(h.t));
                        let ray = self.ray(leaf);
                        T::set_lane(&mut self.packets[at + j], l, &ray);
                    }
                } else {
                    *best = h;
                    self.live[k] &= !(1 << i);
                    let low = node as usize;
                    for (li, (first, count)) in self.alive.iter_mut().enumerate() {
                        let span = (self.subdivision as usize).pow(li as u32 + 1);
                        count[low / span - *first as usize] -= 1;
                    }
                }
            }
        }
    }
}

/// The ray side of a traversal of `tree` over `rays`: the object root, the ray nodes by level
/// (lowest first; with `boxes`, their segment boxes, else the whole space) and, with `boxes`,
/// the rays' segments in leaf order (what the node boxes and the single-ray tests read).
/// `None` when the tree is empty.
#[allow(clippy::type_complexity)]
fn ray_side(
    rays: &[Ray],
    hierarchy: &RayHierarchy<Cpu>,
    tree: &Lbvh,
    boxes: bool,
) -> Result<Option<(u32, Vec<Vec<RayNode>>, Vec<Segment>)>> {
    let nodes = prepare_nodes(rays.len(), hierarchy)?;
    let Some(root) = tree.root() else {
        return Ok(None);
    };
    let (segments, node_boxes) = if boxes {
        let (s, b) = leaf_segments_and_boxes(rays, hierarchy, &tree.bounds());
        (s, Some(b))
    } else {
        (Vec::new(), None)
    };
    let nodes = nodes
        .into_iter()
        .enumerate()
        .map(|(l, level)| {
            level
                .into_iter()
                .enumerate()
                .map(|(n, bound)| RayNode {
                    bx: node_boxes.as_ref().map_or(EVERYWHERE, |b| b[l][n]),
                    bound,
                })
                .collect()
        })
        .collect();
    Ok(Some((root, nodes, segments)))
}

/// Sorts a task's candidates by `(node, triangle)` and merges repeats (a triangle in several
/// grid cells is reached once per cell) into one candidate for the rays of all of them.
fn sort_and_merge(out: &mut Vec<(Candidate, u32)>) {
    sort_candidates(out);
    merge_repeats(out);
}

/// Sorts a task's candidates by `(node, triangle)` (the order of `Candidate`'s `Ord`): one
/// counting pass groups them by node (a task's nodes lie under one top node, so their range is
/// that node's lowest nodes), then each node's run is sorted by triangle on its own (runs are
/// short); a comparison sort for short arrays or a node range wider than the array. It replaced a radix sort on the packed
/// key `(node − lowest node, triangle)`, whose three or four scatter passes over the whole
/// array took a quarter of Sponza's traversal. Equal pairs (grid repeats) end up adjacent in
/// some order, which [`merge_repeats`] does not depend on.
fn sort_candidates(out: &mut Vec<(Candidate, u32)>) {
    let key = |e: &(Candidate, u32)| (e.0.node as u64) << 32 | e.0.tri as u64;
    let (mut lo, mut hi) = (u32::MAX, 0u32);
    for (c, _) in out.iter() {
        lo = lo.min(c.node);
        hi = hi.max(c.node);
    }
    if out.len() < 256 || (hi - lo) as usize >= out.len() {
        out.sort_unstable_by_key(key);
        return;
    }
    // Where each node's run starts, then a stable scatter into those runs.
    let mut start = vec![0u32; (hi - lo) as usize + 2];
    for (c, _) in out.iter() {
        start[(c.node - lo) as usize + 1] += 1;
    }
    for i in 1..start.len() {
        start[i] += start[i - 1];
    }
    let mut at = start.clone();
    let mut sorted = vec![(Candidate { node: 0, tri: 0 }, 0u32); out.len()];
    for e in out.iter() {
        let slot = &mut at[(e.0.node - lo) as usize];
        sorted[*slot as usize] = *e;
        *slot += 1;
    }
    // Within a run the node is the same: the triangle alone orders it.
    for w in start.windows(2) {
        sorted[w[0] as usize..w[1] as usize].sort_unstable_by_key(|e| e.0.tri);
    }
    *out = sorted;
}

/// Appends a candidate and its lane mask to a task's array, growing it by at least 256 pairs
/// at a time but never past `cap` (more only when the task is already over it).
fn push_candidate(out: &mut Vec<(Candidate, u32)>, cap: usize, c: Candidate, lanes: u32) {
    if out.len() == out.capacity() {
        let more = out
            .capacity()
            .max(256)
            .min(cap.saturating_sub(out.len()))
            .max(1);
        out.reserve_exact(more);
    }
    out.push((c, lanes));
}

impl Dual {
    /// The traverser over `scene` with `spec`'s `objects` and `candidate_budget_mb`; with
    /// `objects = lbvh`, `bvh` or `grid` it builds the object hierarchy now.
    pub fn new(scene: &Arc<Scene>, spec: &StageSpec) -> Result<Dual> {
        let objects = spec.str("objects")?;
        let mb = spec.f64("candidate_budget_mb")?;
        let wide = spec.f64("wide_cone")?;
        // Refused before any object hierarchy is built.
        let inline = spec.str("final_tests")? == "inline";
        if wide < WIDE_CONE_OFF && (!inline || objects == "meshes") {
            return Err(wide_cone_error(wide, false));
        }
        let refit = match spec.str("update")? {
            "rebuild" => false,
            "refit" => true,
            other => {
                return Err(CoreError::InvalidParam {
                    key: "traverse.update".into(),
                    reason: format!("`{other}` is not one of {}", UPDATES.join(", ")),
                })
            }
        };
        if refit && !matches!(objects, "lbvh" | "bvh") {
            return Err(refit_error(objects));
        }
        // With `objects = bvh`, the obvhs tree the object side is laid out from: the wide
        // rays' CWBVH is compressed from it (kept only for that).
        let mut bvh2 = None;
        let mut dual = match objects {
            "grid" => Dual::over_grid(scene, spec.f64("grid_density")?, mb)?,
            "bvh" => {
                let (dual, tree) = Dual::over_bvh(scene, mb)?;
                bvh2 = tree.filter(|_| wide < WIDE_CONE_OFF);
                dual
            }
            _ => Dual::with_options(scene, objects, mb)?,
        };
        dual.set_box_test(spec.bool("box_test")?);
        dual.set_single_rays(spec.bool("single_rays")?);
        match spec.str("final_tests")? {
            "batched" => {}
            "inline" => dual.set_inline(scene, true),
            other => {
                return Err(CoreError::InvalidParam {
                    key: "traverse.final_tests".into(),
                    reason: format!("`{other}` is not one of {}", FINAL_TESTS.join(", ")),
                })
            }
        }
        dual.set_refit(refit)?;
        dual.set_wide_cone_over(scene, wide, bvh2)?;
        Ok(dual)
    }

    /// The traverser with explicit options: `objects` one of [`OBJECTS`], `budget_mb` in MiB
    /// (finite and > 0); the box test and single rays on ([`Dual::set_box_test`],
    /// [`Dual::set_single_rays`]).
    /// `objects = grid` builds the grid at [`GRID_DENSITY`] ([`Dual::over_grid`] for
    /// another).
    pub fn with_options(scene: &Arc<Scene>, objects: &str, budget_mb: f64) -> Result<Dual> {
        let objects = match objects {
            "lbvh" => return Dual::over_tree("lbvh", Lbvh::build(scene)?, budget_mb),
            "bvh" => return Ok(Dual::over_bvh(scene, budget_mb)?.0),
            "grid" => return Dual::over_grid(scene, GRID_DENSITY, budget_mb),
            "meshes" => Objects::Meshes(Crsh::with_options(scene, true, budget_mb)?),
            other => {
                return Err(CoreError::InvalidParam {
                    key: "traverse.objects".into(),
                    reason: format!("`{other}` is not one of {}", OBJECTS.join(", ")),
                })
            }
        };
        Ok(Dual {
            objects,
            inline: None,
            wide: None,
            refit: None,
        })
    }

    /// The traverser with `objects = grid` at density `k` (seed 002 eq. 1, within
    /// [`MIN_DENSITY`] ..= [`MAX_DENSITY`]), budget as [`Dual::with_options`].
    pub fn over_grid(scene: &Arc<Scene>, k: f64, budget_mb: f64) -> Result<Dual> {
        if !(MIN_DENSITY..=MAX_DENSITY).contains(&k) {
            return Err(CoreError::InvalidParam {
                key: "traverse.grid_density".into(),
                reason: format!("{k} is not in {MIN_DENSITY} ..= {MAX_DENSITY}"),
            });
        }
        Dual::over_tree("grid", Lbvh::build_grid(scene, k)?, budget_mb)
    }

    /// The traverser with `objects = bvh` ([`Lbvh::build_bvh2`], `fast` preset), budget as
    /// [`Dual::with_options`], and the obvhs tree its object side is laid out from (`None`
    /// below 2 triangles).
    fn over_bvh(scene: &Scene, budget_mb: f64) -> Result<(Dual, Option<Bvh2>)> {
        let (tree, bvh2) = Lbvh::build_bvh2_keeping(scene, BuildQuality::Fast)?;
        Ok((Dual::over_tree("bvh", tree, budget_mb)?, bvh2))
    }

    /// The traverser over the object hierarchy `tree` built for `objects = source`, box test
    /// and single rays on.
    fn over_tree(source: &'static str, tree: Lbvh, budget_mb: f64) -> Result<Dual> {
        Ok(Dual {
            objects: Objects::Lbvh {
                budget_bytes: budget_bytes(budget_mb)?,
                tree: Box::new(tree),
                source,
                box_test: true,
                single_rays: true,
            },
            inline: None,
            wide: None,
            refit: None,
        })
    }

    /// The object side (one of [`OBJECTS`]).
    pub fn objects(&self) -> &'static str {
        match self.objects {
            Objects::Lbvh { source, .. } => source,
            Objects::Meshes(_) => "meshes",
        }
    }

    /// Sets parameter `wide_cone` (degrees in `0 ..= 180`; 180 turns it off): lowest ray
    /// nodes whose cone half-angle is at least `degrees` are traced ray by ray through an
    /// 8-wide BVH (see *Wide ray nodes* in the module doc), built here when this traverser has
    /// none yet (obvhs PLOC, `fast` preset, over all of `scene`'s triangles; `scene` must be
    /// this traverser's). Errors on a value out of range, and on a value below 180 without
    /// inline final tests ([`Dual::set_inline`]) or with `objects = meshes`.
    pub fn set_wide_cone(&mut self, scene: &Scene, degrees: f64) -> Result<()> {
        self.set_wide_cone_over(scene, degrees, None)
    }

    /// [`Dual::set_wide_cone`], a CWBVH it builds compressed from `bvh2` when given (obvhs's
    /// binary BVH over all of `scene`'s triangles, [`scene_bvh2`]), which `update = refit`
    /// keeps (it builds one to keep when none is given).
    fn set_wide_cone_over(
        &mut self,
        scene: &Scene,
        degrees: f64,
        bvh2: Option<Bvh2>,
    ) -> Result<()> {
        if !(0.0..=WIDE_CONE_OFF).contains(&degrees) {
            return Err(wide_cone_error(degrees, true));
        }
        if degrees >= WIDE_CONE_OFF {
            self.wide = None;
            self.keep_bvh2(None);
            return Ok(());
        }
        if self.inline.is_none() || matches!(self.objects, Objects::Meshes(_)) {
            return Err(wide_cone_error(degrees, false));
        }
        match &mut self.wide {
            Some(w) => w.degrees = degrees,
            None => {
                let bvh2 = match bvh2 {
                    None if self.refit.is_some() && scene.triangle_count() > 0 => {
                        Some(scene_bvh2(scene, BuildQuality::Fast))
                    }
                    given => given,
                };
                self.wide = Some(WideRays::new(scene, bvh2.as_ref(), degrees));
                self.keep_bvh2(bvh2);
            }
        }
        Ok(())
    }

    /// Keeps `bvh2` for the next refit (with `update = refit`).
    fn keep_bvh2(&self, bvh2: Option<Bvh2>) {
        if let Some(Ok(mut kept)) = self.refit.as_ref().map(|k| k.bvh2.lock()) {
            *kept = bvh2;
        }
    }

    /// Sets parameter `update`: `true` for `refit` ([`Dual::refitted`]; `objects = lbvh` or
    /// `bvh`, an error with the others), `false` for `rebuild`.
    pub fn set_refit(&mut self, on: bool) -> Result<()> {
        if !on {
            self.refit = None;
            return Ok(());
        }
        match &self.objects {
            Objects::Lbvh { source, .. } if matches!(*source, "lbvh" | "bvh") => {}
            _ => return Err(refit_error(self.objects())),
        }
        if self.refit.is_none() {
            self.refit = Some(Arc::new(Kept::default()));
        }
        Ok(())
    }

    /// Whether parameter `update` is `refit`.
    pub fn refits(&self) -> bool {
        self.refit.is_some()
    }

    /// With `update = refit`, this traverser for `scene` (the same triangles as the scene it
    /// was built for, moved; triangle and mesh spheres updated): the object hierarchy keeps
    /// its topology and its bounds are computed again bottom-up as a fresh build computes
    /// them, so every node again contains what lies below it and the hits are those of a
    /// fresh build, whatever the tree's quality after the motion. With
    /// `wide_cone`, the kept obvhs tree is refitted (`refit_bvh2`, as the `bvh` intersector's
    /// `update = refit`) and compressed again (built anew if another refit took it). The
    /// other settings carry over. `None` with `update = rebuild` or when the triangle count
    /// differs: build anew.
    pub fn refitted(&self, scene: &Arc<Scene>) -> Option<Dual> {
        let kept = self.refit.as_ref()?;
        let Objects::Lbvh {
            tree,
            budget_bytes,
            source,
            box_test,
            single_rays,
        } = &self.objects
        else {
            return None;
        };
        let n = scene.triangle_count();
        if tree.triangles() != n {
            return None;
        }
        let mut out = Dual {
            objects: Objects::Lbvh {
                tree: Box::new(tree.refitted(scene)),
                budget_bytes: *budget_bytes,
                source,
                box_test: *box_test,
                single_rays: *single_rays,
            },
            inline: self.inline.as_ref().map(|_| InlineSets::new(scene)),
            wide: None,
            refit: Some(Arc::new(Kept::default())),
        };
        if let Some(w) = &self.wide {
            let taken = kept.bvh2.lock().ok().and_then(|mut b| b.take());
            let bvh2 = match taken {
                Some(mut b) if n > 0 => {
                    refit_bvh2(&mut b, &scene_triangles(scene));
                    Some(b)
                }
                _ => None,
            };
            // Builds the tree anew when none was kept (and keeps it).
            out.set_wide_cone_over(scene, w.degrees, bvh2).ok()?;
        }
        Some(out)
    }

    /// Parameter `wide_cone` in degrees (180: off).
    pub fn wide_cone(&self) -> f64 {
        self.wide.as_ref().map_or(WIDE_CONE_OFF, |w| w.degrees)
    }

    /// Turns the box test of `objects = lbvh`, `bvh` or `grid` on or off (no effect with
    /// `meshes`).
    pub fn set_box_test(&mut self, on: bool) {
        if let Objects::Lbvh { box_test, .. } = &mut self.objects {
            *box_test = on;
        }
    }

    /// Turns the descent of lowest nodes to single rays (`objects = lbvh`, `bvh` or `grid`) on
    /// or off.
    pub fn set_single_rays(&mut self, on: bool) {
        if let Objects::Lbvh { single_rays, .. } = &mut self.objects {
            *single_rays = on;
        }
    }

    /// Turns inline final tests on or off (`final_tests = inline`, see *Inline final tests*;
    /// `objects = lbvh`, `bvh` or `grid`; `scene` is the one the stage was built for).
    /// Turning them off also turns `wide_cone` off ([`Dual::set_wide_cone`]).
    pub fn set_inline(&mut self, scene: &Arc<Scene>, on: bool) {
        self.inline =
            (on && matches!(self.objects, Objects::Lbvh { .. })).then(|| InlineSets::new(scene));
        if self.inline.is_none() {
            self.wide = None;
            self.keep_bvh2(None);
        }
    }

    /// Whether the final tests run inline ([`Traverser::trace`]).
    pub fn inline(&self) -> bool {
        self.inline.is_some()
    }

    /// Whether lowest nodes may descend to single rays (`objects = lbvh`, `bvh` or `grid` with
    /// `single_rays`).
    pub fn single_rays(&self) -> bool {
        matches!(
            self.objects,
            Objects::Lbvh {
                single_rays: true,
                ..
            }
        )
    }

    /// Whether pairs are box-tested first (`objects = lbvh`, `bvh` or `grid` with `box_test`).
    pub fn box_test(&self) -> bool {
        matches!(self.objects, Objects::Lbvh { box_test: true, .. })
    }

    /// The candidate-array budget in bytes.
    pub fn budget_bytes(&self) -> u64 {
        match &self.objects {
            Objects::Lbvh { budget_bytes, .. } => *budget_bytes,
            Objects::Meshes(c) => c.budget_bytes(),
        }
    }

    /// The object hierarchy (`objects = lbvh`, `bvh` or `grid`; `None` for `meshes`).
    pub fn lbvh(&self) -> Option<&Lbvh> {
        match &self.objects {
            Objects::Lbvh { tree, .. } => Some(tree),
            Objects::Meshes(_) => None,
        }
    }

    /// The round shape for the budget: (tasks per round `G`, candidates per task `C`).
    pub fn round_shape(&self) -> (usize, usize) {
        let pairs = (self.budget_bytes() / (2 * PAIR_BYTES)).max(1);
        let g = (pairs / MIN_PIECE).clamp(1, ROUND_TASKS as u64);
        (g as usize, (pairs / g).max(1) as usize)
    }

    /// [`Traverser::traverse`], returning what it did. With `objects = meshes` the report
    /// carries [`super::crsh::TraversalReport`]'s batches, peak and candidates.
    pub fn traverse_with_report(
        &self,
        rays: &[Ray],
        kind: RayKind,
        hierarchy: &RayHierarchy<Cpu>,
        sink: &mut dyn FnMut(CandidateBatch<Cpu>, &mut Stats) -> Result<()>,
        stats: &mut Stats,
    ) -> Result<DualReport> {
        let (tree, budget, box_test, single_rays) = match &self.objects {
            Objects::Meshes(crsh) => {
                let r = crsh.traverse_with_report(rays, kind, hierarchy, sink, stats)?;
                return Ok(DualReport {
                    rounds: r.batches,
                    batches: r.batches,
                    budget_bytes: r.budget_bytes,
                    peak_candidate_bytes: r.peak_candidate_bytes,
                    candidates: r.candidates,
                    ..DualReport::default()
                });
            }
            Objects::Lbvh {
                tree,
                budget_bytes,
                box_test,
                single_rays,
                ..
            } => (tree, *budget_bytes, *box_test, *single_rays),
        };
        let (g, cap) = self.round_shape();
        let mut report = DualReport {
            budget_bytes: budget,
            round_tasks: g,
            task_candidates: cap,
            ..DualReport::default()
        };
        if rays.is_empty() {
            return Ok(report);
        }
        let Some((root, nodes, segments)) =
            ray_side(rays, hierarchy, tree, box_test || single_rays)?
        else {
            return Ok(report);
        };
        let top_level = nodes.len() - 1;
        let n_top = nodes[top_level].len();
        let ctx = Ctx {
            n_rays: rays.len(),
            rays,
            bounds: tree.bounds(),
            segments: &segments,
            hierarchy,
            single_rays,
            box_test,
            nodes: &nodes,
            sub: hierarchy.subdivision as usize,
            tree,
            wide: None,
        };
        let mut active: Vec<Task> = Vec::new();
        let mut next_top = 0usize;
        loop {
            while active.len() < g && next_top < n_top {
                active.push(Task {
                    stack: vec![Pair {
                        node: next_top as u32,
                        obj: root,
                        level: top_level as u16,
                        depth: 0,
                        mask: 0,
                    }],
                });
                next_top += 1;
            }
            if active.is_empty() {
                break;
            }
            let results: Vec<(Vec<(Candidate, u32)>, Counters)> = active
                .par_iter_mut()
                .map(|t| {
                    let mut b = Batched {
                        out: Vec::new(),
                        cap,
                    };
                    let counts = t.run(&ctx, &mut b);
                    sort_and_merge(&mut b.out);
                    (b.out, counts)
                })
                .collect();
            report.rounds += 1;
            let n_pairs: usize = results.iter().map(|r| r.0.len()).sum();
            let held: u64 = results.iter().map(|r| r.0.capacity() as u64).sum::<u64>();
            let mut pairs = Vec::with_capacity(n_pairs);
            let mut lanes = Vec::with_capacity(if single_rays { n_pairs } else { 0 });
            let mut counts = Counters::new(nodes.len(), tree.max_depth + 1);
            for (piece, c) in &results {
                pairs.extend(piece.iter().map(|e| e.0));
                if single_rays {
                    lanes.extend(piece.iter().map(|e| e.1));
                }
                counts.add(c);
            }
            // Counted before the sink runs, as `crsh` does per batch.
            counts.record(kind, stats);
            report.peak_candidate_bytes = report.peak_candidate_bytes.max(
                held * PAIR_BYTES
                    + (pairs.capacity() * std::mem::size_of::<Candidate>()
                        + lanes.capacity() * std::mem::size_of::<u32>())
                        as u64,
            );
            drop(results);
            active.retain(|t| !t.stack.is_empty());
            report.suspensions += active.len();
            if !pairs.is_empty() {
                report.batches += 1;
                report.candidates += pairs.len() as u64;
                let batch = if single_rays {
                    CandidateBatch::with_lanes(pairs, lanes)
                } else {
                    CandidateBatch::new(pairs)
                };
                sink(batch, stats)?;
            }
        }
        Ok(report)
    }
}

impl Dual {
    /// Traces `rays` of `kind` with inline final tests (query `mode`) against `tris` (this
    /// scene's triangles prepared for a ray-triangle test, e.g. [`BruteForce::triangles`]),
    /// merging each ray's hit into `hits`; `Ok(None)` when this traverser does not run them
    /// inline here: `final_tests = batched`, `objects = meshes`, an edge-width query, or a
    /// lowest node of more than 32 rays. See *Inline final tests* in the module doc.
    #[allow(clippy::too_many_arguments)]
    pub fn trace_with_report(
        &self,
        rays: &[Ray],
        kind: RayKind,
        mode: HitMode,
        tris: &AnyTriangleSet,
        hierarchy: &RayHierarchy<Cpu>,
        hits: &mut [Hit],
        stats: &mut Stats,
    ) -> Result<Option<DualReport>> {
        let (
            Some(_),
            Objects::Lbvh {
                tree,
                box_test,
                single_rays,
                ..
            },
        ) = (&self.inline, &self.objects)
        else {
            return Ok(None);
        };
        if !matches!(mode, HitMode::Any | HitMode::Closest) {
            return Ok(None);
        }
        let mut report = DualReport::default();
        if rays.is_empty() {
            crsh_core::ray::check_hits_per_ray("rays", rays.len(), hits.len())?;
            return Ok(Some(report));
        }
        // Declined before any gather, so that the batched traversal does not repeat it.
        let offsets = hierarchy.leaf_offsets.as_deref();
        let lowest = hierarchy.levels.first().map_or(0, Vec::len);
        let widest = (0..lowest)
            .map(|n| lowest_node_leaves(n, hierarchy.subdivision, offsets, rays.len()).len())
            .max()
            .unwrap_or(0);
        if widest > 32 {
            return Ok(None);
        }
        // Triangles prepared for another scene would be read out of range.
        if let Some(&id) = tree
            .leaf_tris
            .iter()
            .max()
            .filter(|&&id| id as usize >= tris.len())
        {
            return Err(CoreError::InvalidInput(format!(
                "the object hierarchy names triangle {id}, but only {} are prepared",
                tris.len()
            )));
        }
        if let Some(w) = self.wide.as_ref().filter(|w| w.triangles > tris.len()) {
            return Err(CoreError::InvalidInput(format!(
                "the wide rays' BVH holds {} triangles, but only {} are prepared",
                w.triangles,
                tris.len()
            )));
        }
        // No boxes here: each task gathers its own rays' segments and boxes its nodes.
        let Some((root, nodes, segments)) = ray_side(rays, hierarchy, tree, false)? else {
            check_batch(rays, hits)?;
            return Ok(Some(report));
        };
        // The rays themselves are checked by the tasks that read them.
        crsh_core::ray::check_hits_per_ray("rays", rays.len(), hits.len())?;
        check_permutation(&hierarchy.order, rays.len())?;
        let ctx = Ctx {
            n_rays: rays.len(),
            rays,
            bounds: tree.bounds(),
            segments: &segments,
            hierarchy,
            single_rays: *single_rays,
            box_test: *box_test,
            nodes: &nodes,
            sub: hierarchy.subdivision as usize,
            tree,
            wide: self.wide.as_ref(),
        };
        let level = task_level(&nodes);
        let InlineTally {
            tests,
            found,
            counts,
            wide_rays,
        } = match tris {
            AnyTriangleSet::MollerTrumbore(s) => {
                trace_tasks(&ctx, s, mode, (root, level), widest, hits)?
            }
            AnyTriangleSet::Watertight(s) => {
                trace_tasks(&ctx, s, mode, (root, level), widest, hits)?
            }
            AnyTriangleSet::Projected(s) => {
                trace_tasks(&ctx, s, mode, (root, level), widest, hits)?
            }
        };
        counts.record(kind, stats);
        stats.add_level(kind, 0, tests, found);
        stats.add_ray_triangle(tests);
        report.wide_rays = wide_rays;
        report.rounds = nodes[level].len().div_ceil(ROUND_TASKS);
        Ok(Some(report))
    }
}

/// Tasks the inline traversal starts from the highest ray level that has this many nodes.
const MIN_TASKS: usize = 64;

/// The ray level whose nodes are the inline traversal's tasks: the highest with at least
/// [`MIN_TASKS`] nodes, else the lowest. A small batch (the dining room's 7,716 first-bounce
/// reflection rays make 2 top nodes at subdivision 16, depth 3; its later bounces 1) would
/// otherwise run on one or two threads; its tasks start lower and each meets the object root
/// itself, which costs the upper ray levels' pair tests (for wide cones those split at once
/// anyway). The choice depends on the hierarchy's shape alone, never on the thread count, so
/// the counters do not either.
fn task_level<N>(levels: &[Vec<N>]) -> usize {
    (0..levels.len())
        .rev()
        .find(|&l| levels[l].len() >= MIN_TASKS)
        .unwrap_or(0)
}

/// The batch's hits while the inline tasks run: each task reads the hits given for its own rays
/// and writes their results, `hits[order[leaf]]` for the leaves of its node, in parallel. Sound
/// because `order` is a permutation of the batch (checked before any task runs) and tasks own
/// disjoint runs of leaves, so no entry is touched by two tasks; each access is bounds-checked.
/// (The tasks used to hand their hits back for the caller to scatter after each round, on one
/// thread while the others waited.)
struct TaskHits<'h> {
    ptr: *mut Hit,
    len: usize,
    _hits: std::marker::PhantomData<&'h mut [Hit]>,
}

// SAFETY: the entries are plain data, and the callers of `get` and `set` keep each entry to one
// thread (see the type's doc).
unsafe impl Send for TaskHits<'_> {}
// SAFETY: as for `Send`.
unsafe impl Sync for TaskHits<'_> {}

impl<'h> TaskHits<'h> {
    fn new(hits: &'h mut [Hit]) -> TaskHits<'h> {
        TaskHits {
            ptr: hits.as_mut_ptr(),
            len: hits.len(),
            _hits: std::marker::PhantomData,
        }
    }

    /// Entry `i`.
    ///
    /// # Safety
    /// No other thread accesses entry `i` at the same time.
    unsafe fn get(&self, i: usize) -> Hit {
        assert!(i < self.len, "hit {i} of {}", self.len);
        // SAFETY: in bounds (checked), and the caller keeps the entry to this thread.
        unsafe { self.ptr.add(i).read() }
    }

    /// Sets entry `i` to `hit`.
    ///
    /// # Safety
    /// No other thread accesses entry `i` at the same time.
    unsafe fn set(&self, i: usize, hit: Hit) {
        assert!(i < self.len, "hit {i} of {}", self.len);
        // SAFETY: in bounds (checked), and the caller keeps the entry to this thread.
        unsafe { self.ptr.add(i).write(hit) }
    }
}

/// Every task's traversal (from the object root `root` and the nodes of ray level `top_level`,
/// the [`task_level`]) with inline final tests of test `T` ([`Inline`]), in rounds of
/// [`ROUND_TASKS`] tasks run in parallel; each task writes its rays' hits into `hits` itself
/// ([`TaskHits`]). `hits` must have one entry per ray and `order` be a permutation of them
/// (the caller checks both). Returns the ray-triangle tests, the hits they found and the pair
/// counters.
fn trace_tasks<'a, T: TriangleTest>(
    ctx: &Ctx<'a>,
    set: &'a TriangleSet<T>,
    mode: HitMode,
    (root, top_level): (u32, usize),
    widest: usize,
    hits: &mut [Hit],
) -> Result<InlineTally> {
    let order = ctx.hierarchy.order.as_slice();
    let n_top = ctx.nodes[top_level].len();
    let mut total = InlineTally {
        tests: 0,
        found: 0,
        counts: Counters::new(ctx.nodes.len(), ctx.tree.max_depth + 1),
        wide_rays: 0,
    };
    let miss = bytemuck::bytes_of(&Hit::MISS);
    let fresh = crate::position_first(hits, |h| bytemuck::bytes_of(h) != miss).is_none();
    assert_eq!(order.len(), hits.len(), "one hit per leaf");
    let out = TaskHits::new(hits);
    for first in (0..n_top).step_by(ROUND_TASKS) {
        // After a round some rays have hits, but the next round's rays are others: a fresh
        // batch stays one for them.
        let current = (!fresh).then_some(&out);
        // `None`: the task has an invalid ray (and did not run).
        let round: Vec<Option<InlineTally>> = (first..(first + ROUND_TASKS).min(n_top))
            .into_par_iter()
            .map(|top| {
                let mut state = Inline::<T>::new(
                    ctx,
                    set.triangles(),
                    mode,
                    (top_level, top),
                    widest,
                    current,
                );
                if !state.valid {
                    return None;
                }
                let (wide, wide_rays) = match ctx.wide {
                    Some(w) => state.trace_wide(w, mode),
                    None => (Counts::default(), 0),
                };
                let mut task = Task {
                    stack: vec![Pair {
                        node: top as u32,
                        obj: root,
                        level: top_level as u16,
                        depth: 0,
                        mask: 0,
                    }],
                };
                let mut c = task.run(ctx, &mut state);
                for (leaf, h) in order[state.first_leaf..].iter().zip(&state.hits) {
                    // SAFETY: as for the gather in `Inline::new`: this task's rays only.
                    unsafe { out.set(*leaf as usize, *h) };
                }
                // The wide BVH's box tests count in the lowest ray level's row (they test that
                // level's rays), not in the object-depth rows (not the object hierarchy's).
                c.ray[0][0] += wide.bounds;
                c.ray[0][1] += wide.bounds_passed;
                Some(InlineTally {
                    tests: state.tests + wide.prims,
                    found: state.found + wide.prims_hit,
                    counts: c,
                    wide_rays,
                })
            })
            .collect();
        if round.iter().any(Option::is_none) {
            // The error that names the batch's first invalid ray.
            check_batch(ctx.rays, hits)?;
            return Err(CoreError::InvalidInput(
                "dual: a ray of the batch is not valid".into(),
            ));
        }
        for task in round.iter().flatten() {
            total.add(task);
        }
    }
    Ok(total)
}

/// What inline tasks counted ([`trace_tasks`]).
struct InlineTally {
    /// Ray-triangle tests (the pairs' and the wide rays').
    tests: u64,
    /// Of them, hits.
    found: u64,
    /// Box tests by ray level and object depth (the wide rays' in the lowest ray level's row).
    counts: Counters,
    /// Rays traced through the wide BVH ([`DualReport::wide_rays`]).
    wide_rays: u64,
}

impl InlineTally {
    fn add(&mut self, o: &InlineTally) {
        self.tests += o.tests;
        self.found += o.found;
        self.counts.add(&o.counts);
        self.wide_rays += o.wide_rays;
    }
}

impl Traverser<Cpu> for Dual {
    fn name(&self) -> &str {
        "dual"
    }

    fn trace(
        &self,
        _backend: &Cpu,
        rays: &Vec<Ray>,
        kind: RayKind,
        mode: HitMode,
        intersector: &dyn Intersector<Cpu>,
        hierarchy: &RayHierarchy<Cpu>,
        hits: &mut Vec<Hit>,
        stats: &mut Stats,
    ) -> Option<Result<()>> {
        let sets = self.inline.as_ref()?;
        // `brute`'s prepared triangles when the intersector is `brute`; else this stage's own,
        // prepared for the test the intersector names.
        let brute = intersector
            .as_any()
            .and_then(|a| a.downcast_ref::<BruteForce>());
        let tris = match brute {
            Some(b) => b.triangles(),
            None => {
                let name = intersector.candidate_test()?;
                let Some(test) = TestKind::from_name(name) else {
                    return Some(Err(CoreError::InvalidParam {
                        key: "intersect.test".into(),
                        reason: format!(
                            "`{name}` is not one of {}",
                            crate::triangle::TEST_NAMES.join(", ")
                        ),
                    }));
                };
                sets.get(test)
            }
        };
        self.trace_with_report(rays, kind, mode, tris, hierarchy, hits, stats)
            .transpose()
            .map(|r| r.map(|_| ()))
    }

    fn traverse(
        &self,
        _backend: &Cpu,
        rays: &Vec<Ray>,
        kind: RayKind,
        hierarchy: &RayHierarchy<Cpu>,
        sink: &mut dyn FnMut(CandidateBatch<Cpu>, &mut Stats) -> Result<()>,
        stats: &mut Stats,
    ) -> Result<()> {
        let report = self.traverse_with_report(rays, kind, hierarchy, sink, stats)?;
        stats.peak_candidate_bytes = stats.peak_candidate_bytes.max(report.peak_candidate_bytes);
        Ok(())
    }

    fn refit(&self, ctx: &StageContext<'_, Cpu>) -> Option<Result<Box<dyn Traverser<Cpu>>>> {
        let refitted = self.refitted(ctx.scene)?;
        Some(Ok(Box::new(refitted)))
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::intersect::brute::tests::{random_rays, soup, test_ray};
    use crate::intersect::brute::BruteForce;
    use crate::traverse::crsh::tests::{
        assert_same, build, clustered, reference, shuffled, sink_calls_without_rays, test_rays,
        trace_with,
    };
    use crate::triangle::tests::TestRng;
    use crsh_core::{
        render_frame, Frame, FrameOptions, FrameSize, Hit, HitMode, Intersector, ParamValue,
        PipelineConfig, Query, StageContext,
    };

    /// [`trace_with`] for the `dual` traverser `trav`.
    fn trace(
        trav: &Dual,
        brute: &BruteForce,
        rays: &Vec<Ray>,
        h: &RayHierarchy<Cpu>,
        mode: HitMode,
    ) -> (Vec<Hit>, Vec<Vec<Candidate>>, Stats, DualReport) {
        trace_with(brute, rays, h, mode, |kind, sink, stats| {
            trav.traverse_with_report(rays, kind, h, sink, stats)
        })
    }

    /// The candidate sets of `trav` (`objects = lbvh`, both options on) and of its variants
    /// without single rays and without boxes, against `crsh`'s pairs (`crsh`) and the exact
    /// pairs (some ray of the node hits the triangle): each keeps every exact pair, only pairs
    /// its tests pass, and the options only remove pairs.
    fn check_lbvh_pairs(
        trav: &Dual,
        scene: &Scene,
        rays: &Vec<Ray>,
        h: &RayHierarchy<Cpu>,
        crsh: &[Candidate],
        mode: HitMode,
        what: &str,
    ) {
        use crate::triangle::{PreparedTriangle, RayPre};
        let brute = BruteForce::from_scene(scene);
        let boxes = leaf_segments_and_boxes(rays, h, &trav_bounds(trav)).1;
        let tri_box = |t: u32| triangle_box(scene.triangle(t as usize));
        let node_rays = |n: u32| -> Vec<Ray> {
            lowest_node_leaves(n as usize, h.subdivision, None, rays.len())
                .map(|l| rays[h.order[l] as usize])
                .collect()
        };
        let mut exact = Vec::new();
        for n in 0..h.levels[0].len() as u32 {
            for r in node_rays(n) {
                let pre = RayPre::of(&r);
                for t in 0..scene.triangle_count() as u32 {
                    let [a, b, c] = scene.triangle(t as usize);
                    if PreparedTriangle::new(a, b, c)
                        .intersect(&pre, r.t_min, r.t_max)
                        .is_some()
                    {
                        exact.push(Candidate { node: n, tri: t });
                    }
                }
            }
        }
        exact.sort_unstable();
        exact.dedup();
        let contains = |all: &[Candidate], want: &[Candidate], label: &str| {
            let mut at = 0;
            for p in want {
                at += all[at..].partition_point(|q| q < p);
                assert_eq!(all.get(at), Some(p), "{what} {label}");
            }
        };
        let mut sets = Vec::new();
        for (boxes_on, single) in [(true, true), (true, false), (false, false)] {
            let mut t = trav.clone();
            t.set_box_test(boxes_on);
            t.set_single_rays(single);
            let (hits, batches, _, _) = trace(&t, &brute, rays, h, mode);
            let label = format!("box {boxes_on} single {single}");
            assert_same(&hits, &reference(&brute, rays, mode), mode, &label);
            // Strictly increasing batches.
            let all = batches.concat();
            for b in &batches {
                assert!(b.windows(2).all(|w| w[0] < w[1]), "{what} {label}");
            }
            // A task stopped by its share of the budget may meet a grid triangle again in a
            // later round (another cell's entry).
            let mut all = all;
            all.sort_unstable();
            all.dedup();
            contains(&all, &exact, &label);
            let tree = trav.lbvh().unwrap();
            for p in &all {
                let nb = NodeBound::new(&h.levels[0][p.node as usize]).unwrap();
                // The triangle's sphere, or (grid) a sphere of one of its entries.
                let sphere = tree
                    .leaf_tris
                    .iter()
                    .zip(&tree.leaves)
                    .filter(|(&t, _)| t == p.tri)
                    .any(|(_, leaf)| nb.may_hit(&leaf.sphere));
                let one_ray = node_rays(p.node)
                    .iter()
                    .any(|r| segment_meets_box(r, &tri_box(p.tri)));
                let boxed = boxes[0][p.node as usize].overlaps(&tri_box(p.tri));
                let ok = match (boxes_on, single) {
                    (true, true) => boxed && (sphere || one_ray),
                    (true, false) => boxed && sphere,
                    _ => sphere,
                };
                assert!(ok, "{what} {label}: {p:?}");
            }
            // The grid's entries are clipped to their cells: it keeps fewer pairs than the
            // triangles' own bounds would, and still every exact one (checked above).
            let whole_triangles = trav.objects() != "grid";
            match (boxes_on, single) {
                _ if !whole_triangles => {}
                (false, false) => contains(&all, crsh, &label),
                (true, false) => {
                    let boxed: Vec<Candidate> = crsh
                        .iter()
                        .copied()
                        .filter(|p| boxes[0][p.node as usize].overlaps(&tri_box(p.tri)))
                        .collect();
                    contains(&all, &boxed, &label);
                }
                _ => {}
            }
            sets.push(all);
        }
        // Each option only removes pairs.
        contains(&sets[1], &sets[0], "single rays ⊆ boxes");
        contains(&sets[2], &sets[1], "boxes ⊆ spheres");
    }

    /// The box around the triangles of `trav`'s object hierarchy.
    fn trav_bounds(trav: &Dual) -> Aabb {
        trav.lbvh().unwrap().bounds()
    }

    /// The candidates of `crsh` (with or without mesh culling) for the same input, sorted.
    fn crsh_pairs(scene: &Arc<Scene>, rays: &[Ray], h: &RayHierarchy<Cpu>) -> Vec<Candidate> {
        let crsh = Crsh::with_options(scene, false, 64.0).unwrap();
        let mut all = Vec::new();
        crsh.traverse_with_report(
            rays,
            RayKind::Reflection,
            h,
            &mut |b, _| {
                all.extend(b.pairs);
                Ok(())
            },
            &mut Stats::default(),
        )
        .unwrap();
        all.sort_unstable();
        all
    }

    #[test]
    fn grid_entries_keep_every_point_of_their_triangles_boxes() {
        let scenes = [
            Arc::new(soup(11, 150)),
            Arc::new(clustered(12, 6, 30)),
            Arc::new(rooms(13, Vec3::new(1e4, -3e3, 5e3))),
        ];
        let mut rng = TestRng(14);
        for (scene, k) in scenes.iter().flat_map(|s| [0.3, 1.0, 16.0].map(|k| (s, k))) {
            let what = format!("{} k {k}", scene.name);
            let tree = crate::with_threads(1, || Lbvh::build_grid(scene, k))
                .unwrap()
                .unwrap();
            let again = crate::with_threads(3, || Lbvh::build_grid(scene, k))
                .unwrap()
                .unwrap();
            assert_eq!(tree, again, "{what}: the build depends on the threads");
            // The leaves are the grid's entries, every triangle at least once.
            let n = scene.triangle_count();
            let grid = GridData::build_of(scene, k, &vec![true; n]).unwrap();
            let mut entries = grid.cell_tris.clone();
            entries.sort_unstable();
            let mut leaves = tree.leaf_tris.clone();
            leaves.sort_unstable();
            assert_eq!(leaves, entries, "{what}");
            leaves.dedup();
            assert_eq!(leaves.len(), n, "{what}");
            // Every node's box and sphere contain those of every leaf below.
            for (i, node) in tree.inner.iter().enumerate() {
                let mut stack = vec![i as u32];
                while let Some(c) = stack.pop() {
                    if c & LEAF == 0 {
                        stack.extend(tree.inner[c as usize].children);
                        continue;
                    }
                    let leaf = &tree.leaves[(c & !LEAF) as usize];
                    if !leaf.bx.is_empty() {
                        assert!(
                            node.bx.min.cmple(leaf.bx.min).all()
                                && node.bx.max.cmpge(leaf.bx.max).all(),
                            "{what}: node {i}"
                        );
                    }
                    let d = leaf
                        .sphere
                        .center
                        .as_dvec3()
                        .distance(node.sphere.center.as_dvec3());
                    assert!(
                        d + leaf.sphere.radius as f64 <= node.sphere.radius as f64,
                        "{what}: node {i}"
                    );
                }
            }
            // What the exactness argument needs: every point of a triangle's box (where its
            // hits are reported) lies in the box and the sphere of one of its entries. The
            // corners are the farthest points from the triangle.
            for t in 0..n as u32 {
                let tb = triangle_box(scene.triangle(t as usize));
                let own: Vec<&Leaf> = tree
                    .leaf_tris
                    .iter()
                    .zip(&tree.leaves)
                    .filter(|(&u, _)| u == t)
                    .map(|(_, l)| l)
                    .collect();
                let corners = (0..8).map(|c| {
                    Vec3::new(
                        if c & 1 == 0 { tb.min.x } else { tb.max.x },
                        if c & 2 == 0 { tb.min.y } else { tb.max.y },
                        if c & 4 == 0 { tb.min.z } else { tb.max.z },
                    )
                });
                let inside = (0..8).map(|_| {
                    let f = rng.vec3(0.0, 1.0);
                    (tb.min + (tb.max - tb.min) * f).clamp(tb.min, tb.max)
                });
                for p in corners.chain(inside) {
                    // The sphere: the triangle's own (whose test allows for hits off the
                    // triangle, see `crsh`), or one around the entry's box that holds `p`.
                    let held = own.iter().any(|l| {
                        let in_box = l.bx.min.cmple(p).all() && l.bx.max.cmpge(p).all();
                        let d = l.sphere.center.as_dvec3().distance(p.as_dvec3());
                        let own_sphere = l.sphere == scene.tri_spheres[t as usize];
                        in_box && (own_sphere || d <= l.sphere.radius as f64)
                    });
                    assert!(held, "{what}: triangle {t}, point {p}");
                }
            }
        }
    }

    /// The flat layout the wgpu twin uploads: from the root every node is reached once, the
    /// leaves name the tree's triangles (grid entries included) and the bounds are the tree's.
    #[test]
    fn flat_layout_is_the_tree() {
        let scene = Arc::new(crsh_scene::builtin::build("office-boxes").unwrap());
        for tree in [
            Lbvh::build(&scene).unwrap(),
            Lbvh::build_grid(&scene, 1.0).unwrap(),
        ] {
            let (flat, root) = tree.flat();
            assert_eq!(flat.len(), tree.inner.len() + tree.leaves.len());
            let mut seen = vec![0u32; flat.len()];
            let mut stack = vec![root.unwrap()];
            let mut leaves = Vec::new();
            while let Some(i) = stack.pop() {
                seen[i as usize] += 1;
                let n = &flat[i as usize];
                match n.children {
                    Some([a, b]) => {
                        for c in [a, b] {
                            let cb = &flat[c as usize].bx;
                            assert!(n.bx.contains(cb.min) && n.bx.contains(cb.max));
                        }
                        stack.extend([a, b]);
                    }
                    None => leaves.push(n.triangle),
                }
            }
            assert!(seen.iter().all(|&c| c == 1), "a node not reached once");
            let mut want = tree.leaf_tris.clone();
            want.sort_unstable();
            leaves.sort_unstable();
            assert_eq!(leaves, want);
            assert_eq!(flat[root.unwrap() as usize].bx, tree.bounds());
        }
    }

    #[test]
    fn lbvh_spheres_contain_the_spheres_of_their_triangles() {
        let scenes = [
            Arc::new(soup(1, 200)),
            Arc::new(clustered(2, 6, 40)),
            Arc::new(crsh_scene::builtin::build("office-boxes").unwrap()),
        ];
        let builds: [fn(&Scene) -> Result<Lbvh>; 2] = [Lbvh::build, |s: &Scene| {
            Lbvh::build_bvh2(s, BuildQuality::Fast)
        }];
        for (scene, build) in scenes
            .iter()
            .flat_map(|s| builds.iter().map(move |b| (s, b)))
        {
            let tree = crate::with_threads(1, || build(scene)).unwrap().unwrap();
            let again = crate::with_threads(3, || build(scene)).unwrap().unwrap();
            assert_eq!(
                tree, again,
                "{}: the build depends on the threads",
                scene.name
            );
            let n = scene.triangle_count();
            assert_eq!(tree.triangles(), n);
            // The leaves are every triangle once.
            let mut all = Vec::new();
            tree.triangles_below(tree.root().unwrap(), &mut all);
            all.sort_unstable();
            assert_eq!(all, (0..n as u32).collect::<Vec<_>>());
            assert!(tree.max_depth() >= (n as f64).log2().floor() as usize);
            assert!(tree.max_depth() < 64 + 32);
            // Every internal node's sphere contains its triangles' spheres (in f64, exactly).
            for (i, node) in tree.inner.iter().enumerate() {
                let mut below = Vec::new();
                tree.triangles_below(i as u32, &mut below);
                assert!(below.len() >= 2);
                let c = node.sphere.center.as_dvec3();
                for &t in &below {
                    let s = &scene.tri_spheres[t as usize];
                    let d = s.center.as_dvec3().distance(c) + s.radius as f64;
                    assert!(d <= node.sphere.radius as f64, "node {i}, triangle {t}");
                }
            }
        }
        // Equal codes (all centres at one point) split in the middle: a balanced tree.
        let mut same = soup(3, 64);
        for s in &mut same.tri_spheres {
            s.center = Vec3::splat(0.5);
        }
        let tree = Lbvh::build(&same).unwrap();
        let n = same.triangle_count();
        assert!(n > 64);
        assert_eq!(tree.max_depth(), (n as f64).log2().ceil() as usize);
        // One triangle: the root is the leaf.
        let mut one = soup(4, 1);
        one.tri_spheres.truncate(1);
        let tree = Lbvh::build(&one).unwrap();
        assert_eq!((tree.root(), tree.max_depth()), (Some(LEAF), 0));
    }

    #[test]
    fn dual_traversal_gives_the_brute_force_hits() {
        let scenes = [
            (Arc::new(soup(3, 150)), "soup"),
            (Arc::new(clustered(4, 6, 30)), "clusters"),
        ];
        for (si, (scene, name)) in scenes.iter().enumerate() {
            let brute = BruteForce::from_scene(scene);
            let rays = test_rays(scene, 10 + si as u64, 230);
            let refs = [HitMode::Closest, HitMode::Any].map(|m| reference(&brute, &rays, m));
            for (sub, levels) in [(2u32, 3usize), (4, 1), (4, 2), (8, 2), (8, 3)] {
                for (oi, order) in [(0..rays.len() as u32).collect(), shuffled(rays.len(), 5)]
                    .into_iter()
                    .enumerate()
                {
                    let h = build(&rays, order, sub, levels);
                    let crsh = crsh_pairs(scene, &rays, &h);
                    for objects in OBJECTS {
                        let trav = Dual::with_options(scene, objects, 64.0).unwrap();
                        for (mode, want) in [HitMode::Closest, HitMode::Any].iter().zip(&refs) {
                            let what = format!(
                                "{name} sub {sub} levels {levels} order {oi} {objects} {mode:?}"
                            );
                            let run = || trace(&trav, &brute, &rays, &h, *mode);
                            let (hits, batches, stats, report) =
                                crate::with_threads(1, run).unwrap();
                            assert_same(&hits, want, *mode, &what);
                            let got3 = crate::with_threads(3, run).unwrap();
                            assert_eq!(got3.0, hits, "{what}");
                            assert_eq!(got3.1, batches, "{what}");
                            assert_eq!(got3.2, stats, "{what}");
                            assert_eq!(got3.3, report, "{what}");
                            if objects != "meshes" {
                                check_lbvh_pairs(&trav, scene, &rays, &h, &crsh, *mode, &what);
                                assert_eq!(report.candidates, batches.concat().len() as u64);
                                let _ = stats;
                            }
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn counters_account_for_every_test() {
        let scene = Arc::new(clustered(31, 5, 20));
        let brute = BruteForce::from_scene(&scene);
        let rays = test_rays(&scene, 32, 203);
        let h = build(&rays, shuffled(rays.len(), 33), 4, 3);
        let trav = Dual::with_options(&scene, "lbvh", 64.0).unwrap();
        let (_, batches, stats, report) = trace(&trav, &brute, &rays, &h, HitMode::Closest);
        let depth = trav.lbvh().unwrap().max_depth();
        let ray_rows: Vec<&crsh_core::LevelStats> =
            stats.levels.iter().filter(|l| l.level > 0).collect();
        assert_eq!(ray_rows.len(), 3);
        assert_eq!(stats.object_levels.len(), depth + 1);
        for l in ray_rows.iter().copied().chain(&stats.object_levels) {
            assert_eq!(l.tests, l.hits + l.misses, "{l:?}");
            assert_eq!(l.ray_kind, "reflection");
        }
        let ray_sum: u64 = ray_rows.iter().map(|l| l.tests).sum();
        let obj_sum: u64 = stats.object_levels.iter().map(|l| l.tests).sum();
        assert_eq!(ray_sum, stats.tests.bounds);
        assert_eq!(obj_sum, stats.tests.bounds);
        assert!(stats.mesh_culling.is_empty());
        // Every top node meets the root first (and children of a top node split on the ray
        // side meet it too).
        let root = &stats.object_levels[0];
        assert!(root.tests >= h.levels[2].len() as u64);
        // The final tests are level 0 (recorded by the intersector).
        let r0 = stats.levels.iter().find(|l| l.level == 0).unwrap();
        assert_eq!(r0.tests, stats.tests.ray_triangle);
        let n: usize = batches.iter().map(Vec::len).sum();
        assert_eq!(n as u64, report.candidates);
        assert!(n > 0 && n < h.levels[0].len() * scene.triangle_count());
    }

    #[test]
    fn small_budgets_split_rounds_and_stay_within_budget() {
        let scene = Arc::new(clustered(8, 4, 25));
        let brute = BruteForce::from_scene(&scene);
        let rays = test_rays(&scene, 9, 300);
        let h = build(&rays, shuffled(rays.len(), 3), 2, 2);
        let big = Dual::with_options(&scene, "lbvh", 64.0).unwrap();
        let mib = (1u64 << 20) as f64;
        for mode in [HitMode::Closest, HitMode::Any] {
            let want = reference(&brute, &rays, mode);
            let (h_big, b_big, s_big, r_big) = trace(&big, &brute, &rays, &h, mode);
            assert_eq!((r_big.batches, r_big.suspensions), (1, 0), "{r_big:?}");
            assert_same(&h_big, &want, mode, "big");
            let all_big: Vec<Candidate> = b_big.concat();
            for bytes in [32.0, 64.0, 128.0] {
                let trav = Dual::with_options(&scene, "lbvh", bytes / mib).unwrap();
                let run = || trace(&trav, &brute, &rays, &h, mode);
                let (hits, batches, stats, report) = crate::with_threads(3, run).unwrap();
                assert!(report.batches > 1 && report.suspensions > 0, "{report:?}");
                assert!(
                    report.peak_candidate_bytes <= trav.budget_bytes(),
                    "{report:?}"
                );
                assert!(batches
                    .iter()
                    .all(|b| b.len() <= report.round_tasks * report.task_candidates));
                assert_same(&hits, &want, mode, "small budget");
                // The same candidates and tests overall, only split into more batches.
                let mut all: Vec<Candidate> = batches.concat();
                all.sort_unstable();
                assert_eq!(all, all_big);
                assert_eq!(stats.tests.bounds, s_big.tests.bounds);
                assert_eq!(stats.object_levels, s_big.object_levels);
                assert_eq!(crate::with_threads(1, run).unwrap().1, batches);
            }
        }
    }

    #[test]
    fn objects_meshes_is_the_crsh_traversal_with_mesh_culling() {
        let scene = Arc::new(clustered(41, 5, 30));
        let brute = BruteForce::from_scene(&scene);
        let rays = test_rays(&scene, 42, 200);
        let h = build(&rays, shuffled(rays.len(), 43), 4, 2);
        let dual = Dual::with_options(&scene, "meshes", 0.01).unwrap();
        assert!(dual.lbvh().is_none());
        let crsh = Crsh::with_options(&scene, true, 0.01).unwrap();
        let (hits, batches, stats, report) = trace(&dual, &brute, &rays, &h, HitMode::Closest);
        let mut want_hits = vec![Hit::MISS; rays.len()];
        let mut want_batches = Vec::new();
        let mut want_stats = Stats::default();
        let r = crsh
            .traverse_with_report(
                &rays,
                RayKind::Reflection,
                &h,
                &mut |b, s| {
                    let q = Query::Candidates {
                        hierarchy: &h,
                        batch: &b,
                    };
                    brute.intersect(&Cpu, &rays, q, HitMode::Closest, &mut want_hits, s)?;
                    want_batches.push(b.pairs);
                    Ok(())
                },
                &mut want_stats,
            )
            .unwrap();
        assert_eq!(hits, want_hits);
        assert_eq!(batches, want_batches);
        assert_eq!(stats, want_stats);
        assert!(stats.object_levels.is_empty() && !stats.mesh_culling.is_empty());
        assert_eq!(
            (report.batches, report.candidates),
            (r.batches, r.candidates)
        );
    }

    #[test]
    fn constructor_reads_the_resolved_spec() {
        let scene = Arc::new(soup(51, 10));
        let info = info();
        assert_eq!((info.stage, info.name), (StageKind::Traverse, "dual"));
        let registry = Registry::<Cpu>::builtin();
        assert!(registry.variant(StageKind::Traverse, "dual").is_some());
        let mut spec = StageSpec::new("dual");
        for p in &info.params {
            spec.params.insert(p.name.to_string(), p.default.clone());
        }
        let t = Dual::new(&scene, &spec).unwrap();
        assert_eq!((t.objects(), t.budget_bytes()), ("lbvh", 64 << 20));
        assert_eq!(t.name(), "dual");
        assert_eq!(t.round_shape(), (256, (64 << 20) / 24 / 256));
        spec.params
            .insert("objects".into(), ParamValue::Str("meshes".into()));
        spec.params
            .insert("candidate_budget_mb".into(), ParamValue::Int(2));
        let t = Dual::new(&scene, &spec).unwrap();
        assert_eq!((t.objects(), t.budget_bytes()), ("meshes", 2 << 20));
        for mb in [0.0, -1.0, f64::NAN, f64::INFINITY] {
            for objects in OBJECTS {
                assert!(matches!(
                    Dual::with_options(&scene, objects, mb),
                    Err(CoreError::InvalidParam { .. })
                ));
            }
        }
        assert!(matches!(
            Dual::with_options(&scene, "kdtree", 1.0),
            Err(CoreError::InvalidParam { .. })
        ));
        assert_eq!(
            Dual::with_options(&scene, "bvh", 1.0).unwrap().objects(),
            "bvh"
        );
        // The grid's density comes from the spec and is checked.
        spec.params
            .insert("objects".into(), ParamValue::Str("grid".into()));
        spec.params
            .insert("grid_density".into(), ParamValue::Float(0.5));
        let t = Dual::new(&scene, &spec).unwrap();
        assert_eq!(t.objects(), "grid");
        let fine = Dual::over_grid(&scene, 4.0, 2.0).unwrap();
        assert!(fine.lbvh().unwrap().triangles() > t.lbvh().unwrap().triangles());
        for k in [0.0, -1.0, f64::NAN, 1e9] {
            let r = Dual::over_grid(&scene, k, 2.0);
            assert!(
                matches!(&r, Err(CoreError::InvalidParam { key, .. }) if key == "traverse.grid_density"),
                "{k}"
            );
        }
        spec.params.remove("objects");
        assert!(Dual::new(&scene, &spec).is_err());
    }

    #[test]
    fn bad_hierarchies_are_errors_and_empty_rays_call_no_sink() {
        let scene = Arc::new(soup(61, 20));
        let rays = random_rays(&scene, 62, 20);
        let trav = Dual::with_options(&scene, "lbvh", 1.0).unwrap();
        let mut nan = build(&rays, (0..20).collect(), 4, 2);
        nan.levels[1][0].sphere.radius = f32::NAN;
        let short = RayHierarchy {
            order: (0..19).collect(),
            ..build(&rays, (0..20).collect(), 4, 1)
        };
        for h in [nan, short] {
            let r = trav.traverse(
                &Cpu,
                &rays,
                RayKind::Shadow,
                &h,
                &mut |_, _| Ok(()),
                &mut Stats::default(),
            );
            assert!(matches!(r, Err(CoreError::InvalidInput(_))), "{r:?}");
        }
        assert_eq!(sink_calls_without_rays(&trav), 0);
    }

    /// One frame of built-in `scene` with the `crsh` preset and `sets`, on `threads` threads,
    /// checked against brute force on every batch. Shared with the `auto_shape` tests.
    pub(crate) fn frame(scene: &Arc<Scene>, sets: &[String], threads: usize) -> Frame<Cpu> {
        let registry = Registry::<Cpu>::builtin();
        let mut cfg = registry.preset("crsh").unwrap();
        for s in sets {
            cfg.set(s).unwrap();
        }
        let ctx = StageContext::new(&Cpu, scene, FrameSize::new(40, 30).unwrap());
        let opts = FrameOptions::default().with_max_depth(2);
        let reference = BruteForce::from_scene(scene);
        crate::with_threads(threads, || {
            let pipeline = registry.build(&ctx, &cfg).unwrap();
            render_frame(&Cpu, &pipeline, &opts, Some(&reference), &mut |_| {}).unwrap()
        })
        .unwrap()
    }

    /// The built-in scenes the frame tests render, each with its brute-force frame (40×30,
    /// depth 2).
    fn brute_frames() -> Vec<(&'static str, Arc<Scene>, Frame<Cpu>)> {
        let registry = Registry::<Cpu>::builtin();
        ["office-boxes", "cornell-mirrors"]
            .into_iter()
            .map(|name| {
                let scene = Arc::new(crsh_scene::builtin::build(name).unwrap());
                let ctx = StageContext::new(&Cpu, &scene, FrameSize::new(40, 30).unwrap());
                let plain = registry
                    .build(&ctx, &PipelineConfig::whitted("brute", "brute"))
                    .unwrap();
                let opts = FrameOptions::default().with_max_depth(2);
                let want = render_frame(&Cpu, &plain, &opts, None, &mut |_| {}).unwrap();
                (name, scene, want)
            })
            .collect()
    }

    /// [`frame`] with `sets` on one thread, checked: every ray agrees with the reference, and
    /// three threads give the same image and counts.
    fn checked_frame(scene: &Arc<Scene>, sets: &[String], what: &str) -> Frame<Cpu> {
        let got = frame(scene, sets, 1);
        let acc = got.stats.accuracy.clone().unwrap();
        assert!(acc.rays > 0);
        assert_eq!(acc.agreeing, acc.rays, "{what}: {acc:?}");
        let three = frame(scene, sets, 3);
        assert_eq!(three.image, got.image, "{what}");
        assert_eq!(three.stats.tests, got.stats.tests, "{what}");
        assert_eq!(three.stats.levels, got.stats.levels, "{what}");
        assert_eq!(three.stats.object_levels, got.stats.object_levels, "{what}");
        got
    }

    #[test]
    fn frames_with_dual_traversal_equal_brute_force_frames() {
        for (name, scene, want) in brute_frames() {
            for (sub, depth) in [(8, 2), (4, 3), (16, 1)] {
                for objects in OBJECTS {
                    let sets = vec![
                        "traverse.kind=dual".to_string(),
                        format!("traverse.objects={objects}"),
                        format!("hierarchy.subdivision={sub}"),
                        format!("hierarchy.depth={depth}"),
                    ];
                    let what = format!("{name} {sets:?}");
                    let got = checked_frame(&scene, &sets, &what);
                    assert_eq!(got.stats.stages["traverse"], "dual", "{what}");
                    assert_eq!(got.image, want.image, "{what}");
                    let s = &got.stats;
                    assert!(s.tests.ray_triangle < s.tests.brute_force, "{what}");
                    assert_eq!(s.object_levels.is_empty(), objects == "meshes", "{what}");
                }
            }
        }
    }

    #[test]
    fn fewer_tests_than_crsh_on_a_scene_with_a_big_mesh() {
        // glass-sphere: a 5000-triangle sphere mesh, which crsh tests triangle by triangle.
        let scene = Arc::new(crsh_scene::builtin::build("glass-sphere").unwrap());
        let crsh = frame(&scene, &[], 2);
        let dual = frame(&scene, &["traverse.kind=dual".to_string()], 2);
        assert_eq!(dual.image, crsh.image);
        for f in [&crsh, &dual] {
            let acc = f.stats.accuracy.clone().unwrap();
            assert_eq!(acc.agreeing, acc.rays, "{acc:?}");
        }
        let (c, d) = (&crsh.stats.tests, &dual.stats.tests);
        assert_eq!(crsh.stats.traced_rays, dual.stats.traced_rays);
        // The same final tests (the candidates crsh keeps are the exact set's cover either
        // way), a third of the bounds tests or fewer.
        assert!(
            d.ray_triangle <= c.ray_triangle,
            "dual {d:?} against crsh {c:?}"
        );
        assert!(
            d.bounds * 3 < c.bounds && d.total < c.total,
            "dual {d:?} against crsh {c:?}"
        );
    }

    #[test]
    fn f32_single_ray_box_test_passes_whatever_clip_passes() {
        let seg = |origin: Vec3, dir: Vec3, t_min: f32, t_max: f32| Segment {
            origin,
            t_min,
            dir,
            t_max,
        };
        let f32_says = |s: &Segment, b: &Aabb| meets_box(s, inverse_f32(s.dir), b);
        let mut rng = TestRng(0x51ab_5eed);
        // Rays aimed at a point of a box's surface (a face, an edge one time in four), some
        // along an axis plane, of boxes near and far from the origin, with `t_max` a few
        // ulps either side of the entry: where a slab test without its widening goes wrong.
        let (mut tight, mut extra, mut total) = (0u32, 0u32, 0u32);
        for i in 0..40_000usize {
            let scale = [1.0f32, 1e3, 1e-3][i % 3];
            let c = rng.vec3(-1.0, 1.0) * scale * [1.0, 100.0][i / 3 % 2];
            let h = rng.vec3(0.01, 1.0) * scale;
            let b = Aabb {
                min: c - h,
                max: c + h,
            };
            let axis = i % 3;
            let mut p = c + rng.vec3(-1.0, 1.0) * h;
            p[axis] = if rng.f32() < 0.5 {
                b.min[axis]
            } else {
                b.max[axis]
            };
            if i % 4 == 0 {
                p[(axis + 1) % 3] = b.max[(axis + 1) % 3];
            }
            let mut o = c + rng.unit() * (h.length() * rng.range(1.5, 20.0));
            if i % 7 == 0 {
                // A still axis: the origin in the plane of the target point.
                o[(axis + 2) % 3] = p[(axis + 2) % 3];
            }
            let d = p - o;
            let d = if i % 5 == 0 { d } else { d.normalize() };
            let Some((entry, _)) = clip(&seg(o, d, 0.0, f32::INFINITY), &b) else {
                continue;
            };
            let entry = entry as f32;
            for k in -6i32..=6 {
                let t_max = f32::from_bits((entry.to_bits() as i32 + k) as u32);
                let s = seg(o, d, 0.0, t_max);
                let (exact, fast) = (clip(&s, &b).is_some(), f32_says(&s, &b));
                assert!(!exact || fast, "{s:?} {b:?}: clip passes, f32 culls");
                total += 1;
                tight += u32::from(exact);
                extra += u32::from(fast && !exact);
            }
        }
        // Most intervals ending a few ulps past the entry pass, and the widening (a millionth
        // of the distance) lets through only intervals that end within it.
        assert!(tight > total / 3, "{tight} of {total}");
        assert!(extra < total / 2, "{extra} of {total}");
        // Random rays and boxes: the same answers but for a handful.
        let (mut differ, mut passed) = (0u32, 0u32);
        for _ in 0..40_000 {
            let b = Aabb::from_points([rng.vec3(-2.0, 2.0), rng.vec3(-2.0, 2.0)]);
            let s = seg(
                rng.vec3(-4.0, 4.0),
                rng.unit(),
                rng.range(0.0, 0.5),
                rng.range(0.5, 6.0),
            );
            let (exact, fast) = (clip(&s, &b).is_some(), f32_says(&s, &b));
            assert!(!exact || fast, "{s:?} {b:?}");
            differ += u32::from(exact != fast);
            passed += u32::from(exact);
        }
        assert!(passed > 500 && differ < 20, "{passed} {differ}");
        // A still axis: the origin within the slab (on its faces too) passes, outside culls.
        let unit = Aabb {
            min: Vec3::ZERO,
            max: Vec3::ONE,
        };
        for (y, want) in [
            (0.0, true),
            (1.0, true),
            (0.5, true),
            (-1e-7, false),
            (1.0001, false),
        ] {
            let s = seg(Vec3::new(-1.0, y, 0.5), Vec3::X, 0.0, 10.0);
            assert_eq!(f32_says(&s, &unit), want, "y {y}");
            assert_eq!(clip(&s, &unit).is_some(), want, "y {y}");
        }
        // The empty box culls like clip; a direction component whose reciprocal overflows in
        // f32 falls back to clip: a ray creeping up by 1e-40 per unit enters the slab at 1e37.
        let s = seg(
            Vec3::new(0.0, -1e-3, 0.0),
            Vec3::new(1.0, 1e-40, 0.0),
            0.0,
            f32::INFINITY,
        );
        assert!(inverse_f32(s.dir).x.is_nan());
        assert_eq!(f32_says(&s, &Aabb::EMPTY), clip(&s, &Aabb::EMPTY).is_some());
        let far = Aabb {
            min: Vec3::new(-1e38, 0.0, -1.0),
            max: Vec3::new(1e38, 1.0, 1.0),
        };
        assert!(clip(&s, &far).is_some());
        assert!(f32_says(&s, &far));
        let short = seg(s.origin, s.dir, 0.0, 1e36);
        assert!(clip(&short, &far).is_none() && !f32_says(&short, &far));
    }

    /// The `f32` segment boxes hold the exact (`f64`) end points of what they box, far from
    /// the origin too, where each rounding is large: unbounded rays clipped to a box 1e4..4e4
    /// away from the origin (the points on its faces where [`clip`] enters and leaves) and
    /// bounded segments there, one by one and joined in nodes; and a ray whose direction's
    /// reciprocal overflows, boxed through [`clip`]'s fallback. (Without the pad, end points
    /// fall outside.)
    #[test]
    fn f32_segment_boxes_hold_the_exact_end_points_far_away() {
        let bounds = Aabb {
            min: Vec3::new(1.0e4, -3.0e4, 5.0e3),
            max: Vec3::new(2.0e4, -1.0e4, 4.0e4),
        };
        let mut rng = TestRng(0x9e37_79b9);
        let inside =
            |p: DVec3, b: &Aabb| p.cmpge(b.min.as_dvec3()).all() && p.cmple(b.max.as_dvec3()).all();
        let (mut points, mut tight) = (0, 0);
        let mut rays = Vec::new();
        for i in 0..4000 {
            // Origins in the box and a tenth of its size around it.
            let o = bounds.min + (bounds.max - bounds.min) * rng.vec3(-0.1, 1.1);
            let t_max = if i % 2 == 0 {
                f32::INFINITY
            } else {
                rng.range(0.0, 3e4)
            };
            rays.push(test_ray(o, rng.unit(), 0.0, t_max, 0));
        }
        for r in &rays {
            let seg = Segment::of(r);
            let b = segment_box(r, &bounds);
            let ends = if r.t_max.is_finite() {
                Some((r.t_min as f64, r.t_max as f64))
            } else {
                clip(&seg, &bounds)
            };
            let Some((t0, t1)) = ends else {
                continue;
            };
            for t in [t0, t1] {
                let p = r.origin.as_dvec3() + r.dir.as_dvec3() * t;
                points += 1;
                assert!(inside(p, &b), "{r:?} t {t}: {p} outside {b:?}");
                // Within a few f32 ulps of a side: the rounding matters here.
                let gap = (p - b.min.as_dvec3())
                    .min(b.max.as_dvec3() - p)
                    .min_element();
                if gap < 1e-2 {
                    tight += 1;
                }
            }
        }
        assert!(points > 4000 && tight * 4 > points, "{points} {tight}");
        // Joined in nodes of 16, padded once.
        assert_node_boxes_hold_ray_boxes(&rays, &bounds, 16);
        // A direction component whose reciprocal overflows: the f64 clip's interval, rounded
        // outwards.
        let creep = test_ray(
            Vec3::new(1.5e4, -2.0e4, 1.0e4),
            Vec3::new(1.0, 1e-40, 0.0),
            0.0,
            f32::INFINITY,
            0,
        );
        assert!(inverse_f32(creep.dir).x.is_nan());
        let b = segment_box(&creep, &bounds);
        let (t0, t1) = clip(&Segment::of(&creep), &bounds).expect("the ray crosses the box");
        for t in [t0, t1] {
            let p = creep.origin.as_dvec3() + creep.dir.as_dvec3() * t;
            assert!(inside(p, &b), "t {t}: {p} outside {b:?}");
        }
        assert!(b.max.x < 2.1e4 && b.min.x > 1.4e4, "{b:?}");
    }

    /// The box of every `node`-ray chunk of `rays` (one [`segment_union_box`], padded once)
    /// holds each of its rays' own [`segment_box`].
    fn assert_node_boxes_hold_ray_boxes(rays: &[Ray], bounds: &Aabb, node: usize) {
        for group in rays.chunks(node) {
            let b = segment_union_box(with_inverse(group), bounds);
            // The inline tasks' union of rays they checked is the same box.
            if group.iter().all(Ray::is_valid) {
                assert_eq!(valid_segment_union_box(with_inverse(group), bounds), b);
            }
            for r in group {
                let one = segment_box(r, bounds);
                if !one.is_empty() {
                    assert!(one.min.cmpge(b.min).all() && one.max.cmple(b.max).all());
                }
            }
        }
    }

    /// `rays` as [`segment_union_box`] reads them: segments with their [`inverse_f32`].
    fn with_inverse(rays: &[Ray]) -> impl Iterator<Item = (Segment, Vec3A)> + '_ {
        rays.iter().map(|r| (Segment::of(r), inverse_f32(r.dir)))
    }

    #[test]
    fn outward_rounding_and_boxes_contain_what_they_must() {
        // (The outward rounding itself is tested with `crsh_core::f32_down`.)
        // A triangle's box holds its vertices with room to spare on every side.
        let scene = soup(72, 300);
        for t in 0..scene.triangle_count() {
            let tri = scene.triangle(t);
            let b = triangle_box(tri);
            for v in tri {
                assert!(v.cmpgt(b.min).all() && v.cmplt(b.max).all(), "{t}");
            }
        }
        // A segment box holds every point of the interval inside the bounds.
        let bounds = Aabb::from_points([Vec3::splat(-1.0), Vec3::splat(1.0)]);
        let rays = random_rays(&scene, 73, 400);
        let (mut empty, mut full) = (0, 0);
        for r in &rays {
            let b = segment_box(r, &bounds);
            if b.is_empty() {
                empty += 1;
            } else {
                full += 1;
            }
            let (t0, t1) = (r.t_min as f64, (r.t_max as f64).min(1e3));
            for k in 0..=64 {
                let t = t0 + (t1 - t0) * k as f64 / 64.0;
                let p = r.origin.as_dvec3() + r.dir.as_dvec3() * t;
                let (lo, hi) = (bounds.min.as_dvec3(), bounds.max.as_dvec3());
                if p.cmpge(lo).all() && p.cmple(hi).all() {
                    assert!(
                        p.cmpge(b.min.as_dvec3()).all() && p.cmple(b.max.as_dvec3()).all(),
                        "{r:?} t {t}: {b:?}"
                    );
                }
            }
        }
        assert!(empty > 0 && full > empty, "{empty} {full}");
        // Rays that miss the bounds, empty intervals, and invalid rays.
        let away = test_ray(Vec3::splat(2.0), Vec3::X, 0.0, f32::INFINITY, 0);
        assert!(segment_box(&away, &bounds).is_empty());
        let behind = test_ray(Vec3::new(-2.0, 0.0, 0.0), -Vec3::X, 0.0, f32::INFINITY, 0);
        assert!(segment_box(&behind, &bounds).is_empty());
        let short = test_ray(Vec3::new(-2.0, 0.0, 0.0), Vec3::X, 0.0, 0.5, 0);
        // A bounded segment is boxed, not clipped: its box misses the bounds.
        let b = segment_box(&short, &bounds);
        assert!(!b.is_empty() && !b.overlaps(&bounds), "{b:?}");
        let reversed = test_ray(Vec3::ZERO, Vec3::X, 0.5, 0.25, 0);
        assert!(segment_box(&reversed, &bounds).is_empty());
        let parallel = test_ray(Vec3::new(0.0, 0.5, -3.0), Vec3::Z, 0.0, f32::INFINITY, 0);
        let b = segment_box(&parallel, &bounds);
        assert!(b.min.z <= -1.0 && b.max.z >= 1.0 && b.min.y <= 0.5 && b.max.y >= 0.5);
        assert!(b.max.y - b.min.y < 1e-6, "{b:?}");
        let mut nan = parallel;
        nan.origin.x = f32::NAN;
        let all = segment_box(&nan, &bounds);
        assert!(all.min.cmpeq(Vec3::NEG_INFINITY).all() && all.max.cmpeq(Vec3::INFINITY).all());
        assert!(segment_box(&parallel, &Aabb::EMPTY).is_empty());
        // A node's box, padded once, holds the boxes of its rays padded one by one; an
        // invalid ray makes it the whole space, only empty extents the empty box.
        assert_node_boxes_hold_ray_boxes(&rays, &bounds, 8);
        let with_nan = [parallel, nan, short];
        let b = segment_union_box(with_inverse(&with_nan), &bounds);
        assert!(b.min.cmpeq(Vec3::NEG_INFINITY).all() && b.max.cmpeq(Vec3::INFINITY).all());
        assert!(segment_union_box(with_inverse(&[away, reversed]), &bounds).is_empty());
        assert!(segment_union_box(std::iter::empty(), &bounds).is_empty());
    }

    /// The radix sort of a task's candidates is the `(node, triangle)` order, with repeats
    /// adjacent, for short and long arrays and wide node and triangle ranges.
    #[test]
    fn candidates_sort_by_node_then_triangle() {
        let mut x = 0x2545_f491_4f6c_dd1du64;
        let mut next = move || {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            x
        };
        for (n, nodes, tris, base) in [
            (10usize, 5u32, 7u32, 0u32),
            (300, 64, 1000, 4096),
            (5000, 1, 262_144, 17),
            (5000, 4096, 3, 1 << 30),
            (20_000, 70_000, 4_000_000_000, 5),
        ] {
            let mut v: Vec<(Candidate, u32)> = (0..n)
                .map(|i| {
                    let c = Candidate {
                        node: base + (next() % nodes as u64) as u32,
                        tri: (next() % tris as u64) as u32,
                    };
                    (c, i as u32)
                })
                .collect();
            let mut want: Vec<Candidate> = v.iter().map(|e| e.0).collect();
            want.sort_unstable();
            sort_candidates(&mut v);
            assert_eq!(
                v.iter().map(|e| e.0).collect::<Vec<_>>(),
                want,
                "{n} {nodes} {tris}"
            );
        }
    }

    /// Axis-aligned floors and walls (flat boxes) made of grids of triangles, plus a few
    /// random ones, moved by `offset`.
    fn rooms(seed: u64, offset: Vec3) -> Scene {
        let mut rng = TestRng(seed);
        let mut positions = Vec::new();
        let mut indices = Vec::new();
        let mut quad = |p: [Vec3; 4], positions: &mut Vec<Vec3>| {
            let base = positions.len() as u32;
            positions.extend(p.map(|v| v + offset));
            indices.push([base, base + 1, base + 2]);
            indices.push([base, base + 2, base + 3]);
        };
        let n = 8;
        for i in 0..n {
            for j in 0..n {
                let (x, z) = (i as f32 - 4.0, j as f32 - 4.0);
                // Floor at y = 0, a wall at x = 2 and a ceiling at y = 3.
                let floor = [0.0, 3.0].map(|y| {
                    [
                        Vec3::new(x, y, z),
                        Vec3::new(x + 1.0, y, z),
                        Vec3::new(x + 1.0, y, z + 1.0),
                        Vec3::new(x, y, z + 1.0),
                    ]
                });
                for q in floor {
                    quad(q, &mut positions);
                }
                let (y, z) = (i as f32 * 3.0 / n as f32, j as f32 - 4.0);
                let h = 3.0 / n as f32;
                quad(
                    [
                        Vec3::new(2.0, y, z),
                        Vec3::new(2.0, y + h, z),
                        Vec3::new(2.0, y + h, z + 1.0),
                        Vec3::new(2.0, y, z + 1.0),
                    ],
                    &mut positions,
                );
            }
        }
        for _ in 0..40 {
            let a = rng.vec3(-3.0, 2.0).max(Vec3::new(-4.0, 0.1, -4.0));
            quad(
                [a, a + rng.vec3(-0.5, 0.5), a + rng.vec3(-0.5, 0.5), a],
                &mut positions,
            );
        }
        let normals = vec![Vec3::Y; positions.len()];
        crate::surface::tests::raw_scene(positions, normals, indices)
    }

    /// Rays where a box test could fail: leaving the floor (origin on it, a tiny `t_min`),
    /// grazing along the floor and the wall in their planes, shadow segments ending a hair
    /// above the floor, and rays along the axes (zero direction components).
    fn room_rays(scene: &Scene, seed: u64, n: usize, offset: Vec3) -> Vec<Ray> {
        let mut rng = TestRng(seed);
        let light = Vec3::new(0.3, 2.7, 0.2) + offset;
        (0..n)
            .map(|i| {
                let on = Vec3::new(rng.range(-3.9, 1.9), 0.0, rng.range(-3.9, 3.9)) + offset;
                let (o, d, t0, t1) = match i % 5 {
                    0 => (on, (rng.unit() + Vec3::Y).normalize(), 1e-5, f32::INFINITY),
                    1 => {
                        let d = Vec3::new(rng.range(-1.0, 1.0), 0.0, rng.range(-1.0, 1.0));
                        (on, d.normalize_or(Vec3::X), 0.0, f32::INFINITY)
                    }
                    2 => {
                        let end = on + Vec3::Y * 1e-4;
                        let d = end - light;
                        (light, d.normalize(), 1e-4, d.length() * (1.0 - 1e-6))
                    }
                    3 => {
                        let o = Vec3::new(2.0, rng.range(0.0, 3.0), -3.9) + offset;
                        (o, Vec3::Z, 0.0, f32::INFINITY)
                    }
                    _ => {
                        let o = Vec3::new(rng.range(-3.0, 1.0), rng.range(0.5, 2.5), -6.0);
                        (o + offset, Vec3::new(0.0, 0.0, 1.0), 0.0, f32::INFINITY)
                    }
                };
                let _ = scene;
                test_ray(o, d, t0, t1, i)
            })
            .collect()
    }

    /// Shadow segments from a light that end within rounding above the floor and that the
    /// `f32` test still reports as hitting it: the exact segment stops short of the floor's
    /// box, so only the triangle boxes' margin keeps these pairs. Up to `n`, searched among
    /// `tries` random ones.
    fn beyond_segment_rays(
        scene: &Scene,
        brute: &BruteForce,
        offset: Vec3,
        n: usize,
        tries: usize,
    ) -> Vec<Ray> {
        let mut rng = TestRng(84);
        let light = Vec3::new(0.3, 2.7, 0.2) + offset;
        let scale = offset.abs().max_element().max(4.0);
        let mut out = Vec::new();
        for i in 0..tries {
            let on = Vec3::new(rng.range(-3.9, 1.9), 0.0, rng.range(-3.9, 3.9)) + offset;
            let end = on + Vec3::Y * (rng.range(0.0, 3e-8) * scale);
            let d = end - light;
            let ray = test_ray(light, d.normalize(), 1e-4, d.length(), i);
            let exact_end = ray.origin.as_dvec3() + ray.dir.as_dvec3() * ray.t_max as f64;
            if exact_end.y <= offset.y as f64 {
                continue;
            }
            let hit = reference(brute, &vec![ray], HitMode::Closest)[0];
            let on_floor = |t: u32| scene.triangle(t as usize).iter().all(|v| v.y == offset.y);
            if hit.is_hit() && on_floor(hit.tri) {
                out.push(ray);
                if out.len() == n {
                    break;
                }
            }
        }
        out
    }

    #[test]
    fn box_test_keeps_every_hit_on_flat_grazing_and_far_geometry() {
        for offset in [Vec3::ZERO, Vec3::new(1e4, -3e3, 5e3)] {
            let scene = Arc::new(rooms(81, offset));
            let brute = BruteForce::from_scene(&scene);
            let mut rays = room_rays(&scene, 82, 400, offset);
            let beyond = beyond_segment_rays(&scene, &brute, offset, 40, 20_000);
            assert!(
                beyond.len() >= 10,
                "offset {offset}: {} found",
                beyond.len()
            );
            rays.extend(beyond);
            // The grid coarse and fine: hits near cell planes and triangles in many cells.
            let travs = [
                Dual::with_options(&scene, "lbvh", 64.0).unwrap(),
                Dual::over_grid(&scene, 0.3, 64.0).unwrap(),
                Dual::over_grid(&scene, 16.0, 64.0).unwrap(),
            ];
            for (trav, mode) in travs
                .iter()
                .flat_map(|t| [HitMode::Closest, HitMode::Any].map(|m| (t, m)))
            {
                assert!(trav.box_test());
                let mut plain = trav.clone();
                plain.set_box_test(false);
                plain.set_single_rays(false);
                let want = reference(&brute, &rays, mode);
                let n_hit = want.iter().filter(|h| h.is_hit()).count();
                assert!(n_hit > rays.len() / 8, "{n_hit}");
                for (sub, levels) in [(2u32, 3usize), (8, 2)] {
                    let h = build(&rays, shuffled(rays.len(), 83), sub, levels);
                    let what = format!(
                        "offset {offset} {} {} entries sub {sub} {mode:?}",
                        trav.objects(),
                        trav.lbvh().unwrap().triangles()
                    );
                    let (hits, _, stats, _) = trace(trav, &brute, &rays, &h, mode);
                    assert_same(&hits, &want, mode, &what);
                    let (_, _, s2, _) = trace(&plain, &brute, &rays, &h, mode);
                    // The boxes cull: fewer final tests than the spheres alone.
                    assert!(
                        stats.tests.ray_triangle < s2.tests.ray_triangle,
                        "{what}: {:?} against {:?}",
                        stats.tests,
                        s2.tests
                    );
                }
            }
        }
    }

    #[test]
    fn single_rays_cut_the_tests_of_incoherent_nodes() {
        let scene = Arc::new(soup(91, 400));
        let brute = BruteForce::from_scene(&scene);
        // Random rays in random order: every lowest node's cone is wide.
        let rays = random_rays(&scene, 92, 480);
        let h = build(&rays, shuffled(rays.len(), 93), 8, 2);
        let on = Dual::with_options(&scene, "lbvh", 64.0).unwrap();
        assert!(on.single_rays());
        let mut off = on.clone();
        off.set_single_rays(false);
        for mode in [HitMode::Closest, HitMode::Any] {
            let want = reference(&brute, &rays, mode);
            let (hits, _, s_on, _) = trace(&on, &brute, &rays, &h, mode);
            let (hits_off, _, s_off, _) = trace(&off, &brute, &rays, &h, mode);
            assert_same(&hits, &want, mode, "single rays");
            assert_same(&hits_off, &want, mode, "whole nodes");
            let (a, b) = (&s_on.tests, &s_off.tests);
            assert!(
                a.ray_triangle * 2 < b.ray_triangle && a.total < b.total,
                "{mode:?}: {a:?} against {b:?}"
            );
            // The per-ray tests are in the lowest level's row and the object rows.
            let rows: u64 = s_on
                .levels
                .iter()
                .filter(|l| l.level > 0)
                .map(|l| l.tests)
                .sum();
            let objs: u64 = s_on.object_levels.iter().map(|l| l.tests).sum();
            assert_eq!((rows, objs), (a.bounds, a.bounds));
        }
        // The batches name each pair's rays; every ray's nearest hit is in its mask.
        let want = reference(&brute, &rays, HitMode::Closest);
        for (trav, masked) in [(&on, true), (&off, false)] {
            let mut tagged: Vec<(Candidate, u32)> = Vec::new();
            trav.traverse_with_report(
                &rays,
                RayKind::Reflection,
                &h,
                &mut |batch, _| {
                    assert_eq!(batch.lanes.is_some(), masked);
                    let lanes = batch
                        .lanes
                        .unwrap_or_else(|| vec![ALL_LANES; batch.pairs.len()]);
                    tagged.extend(batch.pairs.into_iter().zip(lanes));
                    Ok(())
                },
                &mut Stats::default(),
            )
            .unwrap();
            let partial = tagged.iter().filter(|t| t.1 != ALL_LANES).count();
            assert_eq!(partial > 0, masked, "{partial} pairs for some rays only");
            for (leaf, &r) in h.order.iter().enumerate() {
                let hit = want[r as usize];
                if !hit.is_hit() {
                    continue;
                }
                let c = Candidate {
                    node: (leaf / 8) as u32,
                    tri: hit.tri,
                };
                let mask = tagged.iter().find(|t| t.0 == c).map(|t| t.1);
                assert!(
                    mask.is_some_and(|m| m == ALL_LANES || m & (1 << (leaf % 8)) != 0),
                    "ray {r}: {c:?} has mask {mask:?}"
                );
            }
        }
    }

    /// `trav`'s inline final tests (`mode`, triangles `tris`) of `rays` over `h`, merged into
    /// `start`: the hits, the stats and the report.
    fn trace_inline(
        trav: &Dual,
        rays: &[Ray],
        h: &RayHierarchy<Cpu>,
        mode: HitMode,
        tris: &AnyTriangleSet,
        start: &[Hit],
    ) -> (Vec<Hit>, Stats, DualReport) {
        let mut hits = start.to_vec();
        let mut stats = Stats::default();
        let report = trav
            .trace_with_report(rays, RayKind::Shadow, mode, tris, h, &mut hits, &mut stats)
            .unwrap()
            .expect("inline final tests");
        (hits, stats, report)
    }

    /// `objects` with inline final tests.
    fn inline_dual(scene: &Arc<Scene>, objects: &str) -> Dual {
        let mut trav = Dual::with_options(scene, objects, 64.0).unwrap();
        trav.set_inline(scene, true);
        assert!(trav.inline());
        trav
    }

    /// Checks that an inline traversal's ray-level rows (level ≥ 1) sum to its bound tests and
    /// its level-0 row is its ray-triangle tests; returns the object rows' sum.
    fn check_inline_rows(stats: &Stats, what: &str) -> u64 {
        let ray_rows: u64 = stats
            .levels
            .iter()
            .filter(|l| l.level > 0)
            .map(|l| l.tests)
            .sum();
        assert_eq!(ray_rows, stats.tests.bounds, "{what}");
        let row0 = stats.levels.iter().find(|l| l.level == 0).unwrap();
        assert_eq!(row0.tests, stats.tests.ray_triangle, "{what}");
        stats.object_levels.iter().map(|l| l.tests).sum()
    }

    #[test]
    fn inline_final_tests_give_the_brute_force_hits() {
        let scenes = [
            (Arc::new(soup(3, 150)), "soup"),
            (Arc::new(clustered(4, 6, 30)), "clusters"),
            (Arc::new(rooms(7, Vec3::ZERO)), "rooms"),
        ];
        for (si, (scene, name)) in scenes.iter().enumerate() {
            let rays = test_rays(scene, 20 + si as u64, 230);
            for test in [TestKind::MollerTrumbore, TestKind::Watertight] {
                let brute = BruteForce::with_test(scene, test);
                let refs = [HitMode::Closest, HitMode::Any].map(|m| reference(&brute, &rays, m));
                for (sub, levels) in [(2u32, 3usize), (4, 1), (8, 2), (16, 2), (32, 1)] {
                    let orders = [(0..rays.len() as u32).collect(), shuffled(rays.len(), 9)];
                    for (oi, order) in orders.into_iter().enumerate() {
                        let h = build(&rays, order, sub, levels);
                        for objects in ["lbvh", "bvh", "grid"] {
                            let trav = inline_dual(scene, objects);
                            for (mode, want) in [HitMode::Closest, HitMode::Any].iter().zip(&refs) {
                                let what = format!(
                                    "{name} {test:?} sub {sub} levels {levels} order {oi} \
                                     {objects} {mode:?}"
                                );
                                let miss = vec![Hit::MISS; rays.len()];
                                let run = || {
                                    trace_inline(&trav, &rays, &h, *mode, brute.triangles(), &miss)
                                };
                                let (hits, stats, report) = crate::with_threads(1, run).unwrap();
                                assert_same(&hits, want, *mode, &what);
                                let three = crate::with_threads(3, run).unwrap();
                                assert_eq!(three.0, hits, "{what}");
                                assert_eq!(three.1, stats, "{what}");
                                assert_eq!(three.2, report, "{what}");
                                // The pair rows sum to the bounds on each side; the final
                                // tests are the level-0 row and never exceed brute force.
                                let obj_rows = check_inline_rows(&stats, &what);
                                assert_eq!(obj_rows, stats.tests.bounds, "{what}");
                                let row0 = stats.levels.iter().find(|l| l.level == 0).unwrap();
                                assert_eq!(row0.hits + row0.misses, row0.tests, "{what}");
                                assert!(
                                    stats.tests.ray_triangle
                                        < (rays.len() * scene.triangle_count()) as u64,
                                    "{what}"
                                );
                            }
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn wide_nodes_trace_their_rays_through_the_wide_bvh_with_the_brute_force_hits() {
        let scenes = [
            (Arc::new(soup(61, 300)), "soup"),
            (Arc::new(rooms(62, Vec3::new(2.0, 1.0, -3.0))), "rooms"),
        ];
        for (si, (scene, name)) in scenes.iter().enumerate() {
            // Coherent rays in their own order (narrow nodes) and shuffled (wide ones).
            let rays = test_rays(scene, 63 + si as u64, 300);
            let n = rays.len();
            let brute = BruteForce::with_test(scene, TestKind::Watertight);
            let refs = [HitMode::Closest, HitMode::Any].map(|m| reference(&brute, &rays, m));
            for (oi, order) in [(0..n as u32).collect(), shuffled(n, 64)]
                .into_iter()
                .enumerate()
            {
                let h = build(&rays, order, 8, 2);
                let cones: Vec<f64> = h.levels[0]
                    .iter()
                    .map(|c| f64::from(c.cone.half_angle).to_degrees())
                    .collect();
                let mut sorted = cones.clone();
                sorted.sort_by(f64::total_cmp);
                // Every node wide, none, and about half of them.
                let median = sorted[sorted.len() / 2];
                for objects in ["lbvh", "bvh", "grid"] {
                    for wide in [0.0, median, WIDE_CONE_OFF] {
                        let mut trav = inline_dual(scene, objects);
                        trav.set_wide_cone(scene, wide).unwrap();
                        assert_eq!(trav.wide_cone(), wide);
                        let wide_rays: u64 = (0..cones.len())
                            .filter(|&k| {
                                let half = f64::from(h.levels[0][k].cone.half_angle);
                                wide < WIDE_CONE_OFF && half >= wide.to_radians()
                            })
                            .map(|k| lowest_node_leaves(k, 8, None, n).len() as u64)
                            .sum();
                        for (mode, want) in [HitMode::Closest, HitMode::Any].iter().zip(&refs) {
                            let what = format!("{name} order {oi} {objects} {wide}° {mode:?}");
                            // Half the rays start with their hit (merged, as a later round's).
                            let start: Vec<Hit> = (0..n)
                                .map(|r| if r % 2 == 0 { want[r] } else { Hit::MISS })
                                .collect();
                            for given in [vec![Hit::MISS; n], start] {
                                let run = || {
                                    trace_inline(&trav, &rays, &h, *mode, brute.triangles(), &given)
                                };
                                let (hits, stats, report) = crate::with_threads(1, run).unwrap();
                                assert_same(&hits, want, *mode, &what);
                                let three = crate::with_threads(3, run).unwrap();
                                assert_eq!((&three.0, &three.1), (&hits, &stats), "{what}");
                                assert_eq!(report.wide_rays, wide_rays, "{what}");
                                // The wide BVH's box tests are in the lowest ray level's row,
                                // its triangle tests in the level-0 row; the object rows hold
                                // the pairs' tests alone.
                                let obj_rows = check_inline_rows(&stats, &what);
                                if wide == 0.0 {
                                    assert_eq!(obj_rows, 0, "{what}: no pair is tested");
                                } else if wide_rays == 0 {
                                    assert_eq!(obj_rows, stats.tests.bounds, "{what}");
                                } else {
                                    assert!(obj_rows < stats.tests.bounds, "{what}");
                                }
                            }
                        }
                    }
                }
            }
        }
        // From the spec: off by default; on, with `objects = bvh` compressed from the object
        // side's own tree; refused where it would not run.
        let scene = Arc::new(soup(65, 40));
        let mut spec = dual_spec(&[]);
        assert_eq!(Dual::new(&scene, &spec).unwrap().wide_cone(), WIDE_CONE_OFF);
        spec.params
            .insert("wide_cone".into(), ParamValue::Float(50.0));
        let refused = |spec: &StageSpec| {
            matches!(
                Dual::new(&scene, spec),
                Err(CoreError::InvalidParam { key, .. }) if key == "traverse.wide_cone"
            )
        };
        assert!(refused(&spec), "batched final tests");
        spec.params
            .insert("final_tests".into(), ParamValue::Str("inline".into()));
        for objects in ["lbvh", "bvh", "grid"] {
            spec.params
                .insert("objects".into(), ParamValue::Str(objects.into()));
            let t = Dual::new(&scene, &spec).unwrap();
            assert_eq!((t.objects(), t.wide_cone()), (objects, 50.0));
        }
        spec.params
            .insert("objects".into(), ParamValue::Str("meshes".into()));
        assert!(refused(&spec), "meshes");
        let mut t = inline_dual(&scene, "bvh");
        for bad in [-1.0, 181.0, f64::NAN] {
            assert!(t.set_wide_cone(&scene, bad).is_err(), "{bad}");
        }
        t.set_wide_cone(&scene, 10.0).unwrap();
        t.set_inline(&scene, false);
        assert_eq!(t.wide_cone(), WIDE_CONE_OFF, "batched tests drop it");
    }

    /// The spec of `dual` with every default, then `sets` (`key=value`).
    fn dual_spec(sets: &[(&str, ParamValue)]) -> StageSpec {
        let mut spec = info().defaults();
        for (k, v) in sets {
            spec.params.insert(k.to_string(), v.clone());
        }
        spec
    }

    /// Every node of `tree` contains the sphere and the box of every triangle below it, on
    /// `scene` (in `f64` for the spheres).
    fn check_tree_bounds(tree: &Lbvh, scene: &Scene, what: &str) {
        for (i, node) in tree.inner.iter().enumerate() {
            let mut below = Vec::new();
            tree.triangles_below(i as u32, &mut below);
            let c = node.sphere.center.as_dvec3();
            for &t in &below {
                let s = &scene.tri_spheres[t as usize];
                let d = s.center.as_dvec3().distance(c) + s.radius as f64;
                assert!(
                    d <= node.sphere.radius as f64,
                    "{what}: node {i}, triangle {t}"
                );
                let bx = triangle_box(scene.triangle(t as usize));
                assert_eq!(node.bx.union(bx), node.bx, "{what}: node {i}, triangle {t}");
            }
        }
    }

    /// `update = refit`: over the frames of a moving scene, each refit keeps the object
    /// side's topology, bounds every moved triangle again and finds the brute-force hits, with
    /// batched and inline final tests and with every lowest node wide (then every ray goes
    /// through the refitted 8-wide BVH); a refit of a refit works on; `rebuild` offers none.
    #[test]
    fn refitted_object_sides_keep_their_topology_and_give_the_brute_force_hits() {
        let (anim, _) = crsh_scene::load_animated("cornell-mirrors-animated").unwrap();
        let first = Arc::new(anim.scene().clone());
        let brute_of = |s: &Scene| BruteForce::with_test(s, TestKind::Watertight);
        let inline = ("final_tests", ParamValue::Str("inline".into()));
        let configs: Vec<(&str, Vec<(&str, ParamValue)>)> = vec![
            ("batched", vec![]),
            ("inline", vec![inline.clone()]),
            (
                "inline, all wide",
                vec![inline.clone(), ("wide_cone", ParamValue::Float(0.0))],
            ),
        ];
        for objects in ["lbvh", "bvh"] {
            for (name, sets) in &configs {
                let mut sets = sets.clone();
                sets.push(("objects", ParamValue::Str(objects.into())));
                let rebuild = Dual::new(&first, &dual_spec(&sets)).unwrap();
                assert!(!rebuild.refits() && rebuild.refitted(&first).is_none());
                sets.push(("update", ParamValue::Str("refit".into())));
                let mut trav = Dual::new(&first, &dual_spec(&sets)).unwrap();
                assert!(trav.refits());
                let mut scene = anim.scene().clone();
                for frame in [3, 7, 11] {
                    let what = format!("{objects} {name} frame {frame}");
                    anim.update(&mut scene, frame, true).unwrap();
                    let moved = Arc::new(scene.clone());
                    let next = trav.refitted(&moved).expect("a refit");
                    let (old, new) = (trav.lbvh().unwrap(), next.lbvh().unwrap());
                    // The same topology and leaves; the moved triangles' bounds are new.
                    let children =
                        |t: &Lbvh| t.inner.iter().map(|n| n.children).collect::<Vec<_>>();
                    assert_eq!(children(new), children(old), "{what}");
                    assert_eq!(new.leaf_tris, old.leaf_tris, "{what}");
                    assert!(new.leaves != old.leaves, "{what}: nothing moved");
                    check_tree_bounds(new, &moved, &what);
                    assert_eq!(
                        (
                            next.objects(),
                            next.wide_cone(),
                            next.inline(),
                            next.refits()
                        ),
                        (objects, trav.wide_cone(), trav.inline(), true),
                        "{what}"
                    );
                    let brute = brute_of(&moved);
                    let rays = test_rays(&moved, 70 + u64::from(frame), 400);
                    let h = build(&rays, (0..rays.len() as u32).collect(), 8, 2);
                    for mode in [HitMode::Closest, HitMode::Any] {
                        let want = reference(&brute, &rays, mode);
                        let got = if next.inline() {
                            let miss = vec![Hit::MISS; rays.len()];
                            let (hits, _, report) =
                                trace_inline(&next, &rays, &h, mode, brute.triangles(), &miss);
                            if next.wide_cone() == 0.0 {
                                assert_eq!(report.wide_rays, rays.len() as u64, "{what}");
                            }
                            hits
                        } else {
                            trace(&next, &brute, &rays, &h, mode).0
                        };
                        assert_same(&got, &want, mode, &format!("{what} {mode:?}"));
                    }
                    trav = next;
                }
            }
        }
        // Refused where the object side follows the positions, and a bad value.
        for objects in ["grid", "meshes"] {
            let spec = dual_spec(&[
                ("objects", ParamValue::Str(objects.into())),
                ("update", ParamValue::Str("refit".into())),
            ]);
            assert!(
                matches!(Dual::new(&first, &spec), Err(CoreError::InvalidParam { key, .. }) if key == "traverse.update"),
                "{objects}"
            );
            let mut t = Dual::with_options(&first, objects, 64.0).unwrap();
            assert!(t.set_refit(true).is_err(), "{objects}");
            t.set_refit(false).unwrap();
        }
        let spec = dual_spec(&[("update", ParamValue::Str("sometimes".into()))]);
        assert!(Dual::new(&first, &spec).is_err());
        // Another triangle count: no refit (the registry builds anew).
        let mut t = Dual::with_options(&first, "lbvh", 64.0).unwrap();
        t.set_refit(true).unwrap();
        assert!(t.refitted(&Arc::new(soup(5, 30))).is_none());
        t.set_refit(false).unwrap();
        assert!(t.refitted(&first).is_none());
    }

    /// Through the registry: a rebuild of a `dual_screen_bvh` pipeline with
    /// `traverse.update = refit` refits the traverser (`StageBuild::refit`), a rebuild with
    /// another traverse spec builds it anew.
    #[test]
    fn registry_rebuilds_refit_the_dual_traverser() {
        let registry = Registry::<Cpu>::builtin();
        let (anim, _) = crsh_scene::load_animated("cornell-mirrors-animated").unwrap();
        let first = Arc::new(anim.scene().clone());
        let size = FrameSize::new(16, 16).unwrap();
        let mut cfg = registry.preset("dual_screen_bvh").unwrap();
        cfg.set("traverse.update=refit").unwrap();
        let mut pipeline = registry
            .build(&StageContext::new(&Cpu, &first, size), &cfg)
            .unwrap();
        let traverse_build = |p: &crsh_core::Pipeline<Cpu>| {
            p.builds
                .iter()
                .find(|b| b.slot == StageKind::Traverse.key())
                .map(|b| b.refit)
        };
        assert_eq!(traverse_build(&pipeline), Some(false));
        let mut scene = anim.scene().clone();
        for frame in [2, 5] {
            anim.update(&mut scene, frame, true).unwrap();
            let moved = Arc::new(scene.clone());
            pipeline = registry
                .rebuild(&StageContext::new(&Cpu, &moved, size), &pipeline)
                .unwrap();
            assert_eq!(traverse_build(&pipeline), Some(true), "frame {frame}");
        }
        let mut cfg = registry.preset("dual_screen_bvh").unwrap();
        cfg.set("traverse.update=rebuild").unwrap();
        let p = registry
            .build(&StageContext::new(&Cpu, &first, size), &cfg)
            .unwrap();
        let again = registry
            .rebuild(&StageContext::new(&Cpu, &first, size), &p)
            .unwrap();
        assert_eq!(traverse_build(&again), Some(false));
    }

    #[test]
    fn tasks_start_at_the_highest_level_with_enough_nodes_and_give_the_same_hits() {
        let scene = Arc::new(rooms(31, Vec3::ZERO));
        let rays = test_rays(&scene, 32, 700);
        let brute = BruteForce::with_test(&scene, TestKind::MollerTrumbore);
        let order: Vec<u32> = shuffled(rays.len(), 33);
        // Tasks at the top (sub 2, 3 levels: 350, 175, 88 nodes), in the middle (sub 2, 4
        // levels: ..., 44 at the top) and at the lowest level (sub 8, 2 levels: 88, 11).
        for (sub, levels, want_level) in [(2u32, 3usize, 2usize), (2, 4, 2), (8, 2, 0)] {
            let h = build(&rays, order.clone(), sub, levels);
            assert_eq!(h.levels.len(), levels);
            assert_eq!(
                task_level(&h.levels),
                want_level,
                "sub {sub} levels {levels}"
            );
            let trav = inline_dual(&scene, "lbvh");
            for mode in [HitMode::Closest, HitMode::Any] {
                let what = format!("sub {sub} levels {levels} {mode:?}");
                let want = reference(&brute, &rays, mode);
                let miss = vec![Hit::MISS; rays.len()];
                let run = || trace_inline(&trav, &rays, &h, mode, brute.triangles(), &miss);
                let (hits, stats, report) = crate::with_threads(1, run).unwrap();
                assert_same(&hits, &want, mode, &what);
                let three = crate::with_threads(3, run).unwrap();
                assert!(
                    three.0 == hits && three.1 == stats && three.2 == report,
                    "{what}"
                );
                // No pair is tested above the task level.
                let top = stats.levels.iter().filter(|l| l.tests > 0).map(|l| l.level);
                assert_eq!(top.max(), Some(want_level as u32 + 1), "{what}");
            }
        }
        assert_eq!(task_level::<u8>(&[]), 0);
        assert_eq!(task_level(&[vec![0u8; 10]]), 0);
        assert_eq!(task_level(&[vec![0u8; 640], vec![0; 64], vec![0; 4]]), 1);
    }

    #[test]
    fn lowest_nodes_of_varied_sizes_give_the_brute_force_hits() {
        // Leaf offsets (tile hierarchies): lowest nodes of 1 to 32 leaves, so the segments
        // and boxes are gathered node range by node range of unequal lengths.
        use crate::traverse::crsh::tests::{build_with_offsets, random_offsets};
        let scene = Arc::new(clustered(71, 6, 30));
        let brute = BruteForce::from_scene(&scene);
        let rays = test_rays(&scene, 72, 300);
        let refs = [HitMode::Closest, HitMode::Any].map(|m| reference(&brute, &rays, m));
        let offsets = random_offsets(&mut TestRng(73), rays.len(), 32);
        assert!(offsets.windows(2).any(|w| w[1] - w[0] > 16));
        for (sub, levels) in [(4u32, 1usize), (4, 2), (3, 3)] {
            let order = shuffled(rays.len(), 74);
            let h = build_with_offsets(&rays, order, offsets.clone(), sub, levels);
            // Each leaf's segment is its ray's, each lowest node's box holds its rays' boxes
            // and each upper node's its children's.
            let bounds = trav_bounds(&inline_dual(&scene, "lbvh"));
            let (segments, boxes) = leaf_segments_and_boxes(&rays, &h, &bounds);
            let seg_of = |leaf: usize| Segment::of(&rays[h.order[leaf] as usize]);
            assert!((0..rays.len()).all(|l| segments[l] == seg_of(l)));
            let inside = |a: Aabb, b: Aabb| {
                a.is_empty() || (a.min.cmpge(b.min).all() && a.max.cmple(b.max).all())
            };
            for (n, b) in boxes[0].iter().enumerate() {
                for l in lowest_node_leaves(n, sub, h.leaf_offsets.as_deref(), rays.len()) {
                    assert!(inside(segment_box(&rays[h.order[l] as usize], &bounds), *b));
                }
            }
            for l in 1..boxes.len() {
                for (n, b) in boxes[l].iter().enumerate() {
                    let children = (n * sub as usize..(n + 1) * sub as usize)
                        .filter_map(|c| boxes[l - 1].get(c));
                    assert!(children.clone().count() > 0);
                    assert!(children.copied().all(|c| inside(c, *b)));
                }
            }
            let batched = Dual::with_options(&scene, "lbvh", 64.0).unwrap();
            let inline = inline_dual(&scene, "lbvh");
            for (mode, want) in [HitMode::Closest, HitMode::Any].iter().zip(&refs) {
                let what = format!("sub {sub} levels {levels} {mode:?}");
                let run = || trace(&batched, &brute, &rays, &h, *mode);
                let (hits, batches, ..) = crate::with_threads(1, run).unwrap();
                assert_same(&hits, want, *mode, &what);
                assert_eq!(crate::with_threads(3, run).unwrap().1, batches, "{what}");
                let miss = vec![Hit::MISS; rays.len()];
                let run = || trace_inline(&inline, &rays, &h, *mode, brute.triangles(), &miss);
                let (hits, stats, _) = crate::with_threads(1, run).unwrap();
                assert_same(&hits, want, *mode, &what);
                let three = crate::with_threads(3, run).unwrap();
                assert_eq!((three.0, three.1), (hits, stats), "{what}");
            }
        }
    }

    #[test]
    fn inline_final_tests_without_boxes_or_single_rays_stay_exact() {
        let scene = Arc::new(rooms(5, Vec3::new(3.0, -2.0, 1.0)));
        let brute = BruteForce::from_scene(&scene);
        let rays = room_rays(&scene, 6, 400, Vec3::new(3.0, -2.0, 1.0));
        let h = build(&rays, shuffled(rays.len(), 2), 8, 2);
        for (boxes, single) in [(false, false), (true, false), (false, true)] {
            let mut trav = inline_dual(&scene, "lbvh");
            trav.set_box_test(boxes);
            trav.set_single_rays(single);
            for mode in [HitMode::Closest, HitMode::Any] {
                let want = reference(&brute, &rays, mode);
                let miss = vec![Hit::MISS; rays.len()];
                let (hits, ..) = trace_inline(&trav, &rays, &h, mode, brute.triangles(), &miss);
                assert_same(
                    &hits,
                    &want,
                    mode,
                    &format!("boxes {boxes} single {single}"),
                );
            }
        }
    }

    #[test]
    fn inline_final_tests_merge_into_the_hits_they_are_given() {
        let scene = Arc::new(clustered(8, 5, 25));
        let brute = BruteForce::from_scene(&scene);
        let rays = test_rays(&scene, 3, 200);
        let h = build(&rays, shuffled(rays.len(), 4), 8, 2);
        let trav = inline_dual(&scene, "lbvh");
        for mode in [HitMode::Closest, HitMode::Any] {
            // Every third ray starts with a hit: a near one on triangle 0 (kept by either
            // mode), every other third with a far one (closest-hit replaces it when the scene
            // has a nearer hit).
            let start: Vec<Hit> = (0..rays.len())
                .map(|i| match i % 3 {
                    0 => Hit {
                        t: rays[i].t_min.max(0.0) + 1e-3,
                        tri: 0,
                        u: 0.25,
                        v: 0.25,
                    },
                    1 => Hit {
                        t: 1e30,
                        tri: 1,
                        u: 0.5,
                        v: 0.5,
                    },
                    _ => Hit::MISS,
                })
                .collect();
            let mut want = start.clone();
            brute
                .intersect(
                    &Cpu,
                    &rays,
                    Query::Scene,
                    mode,
                    &mut want,
                    &mut Stats::default(),
                )
                .unwrap();
            let (got, stats, _) = trace_inline(&trav, &rays, &h, mode, brute.triangles(), &start);
            assert_same(&got, &want, mode, &format!("{mode:?}"));
            if mode == HitMode::Any {
                // Rays that start hit keep their hit and cost no final test.
                for i in (0..rays.len()).filter(|i| i % 3 != 2) {
                    assert_eq!(got[i], start[i], "ray {i}");
                }
                let fresh = vec![Hit::MISS; rays.len()];
                let (_, all, _) = trace_inline(&trav, &rays, &h, mode, brute.triangles(), &fresh);
                let sum = |s: &Stats| s.tests.bounds + s.tests.ray_triangle;
                assert!(sum(&stats) < sum(&all));
            }
        }
    }

    #[test]
    fn any_hit_rays_leave_the_inline_traversal_at_their_first_hit() {
        // A wall of two triangles in front of a cloud of 400 small triangles: shadow rays
        // through the wall into the cloud. Batched, every ray's node meets the cloud's
        // triangles; inline, a ray stops at the wall when the traversal meets it first, and
        // a node whose rays all stopped is not tested again.
        let mut positions = vec![
            Vec3::new(-5.0, -5.0, 0.0),
            Vec3::new(5.0, -5.0, 0.0),
            Vec3::new(5.0, 5.0, 0.0),
            Vec3::new(-5.0, 5.0, 0.0),
        ];
        let mut indices = vec![[0, 1, 2], [0, 2, 3]];
        let mut rng = TestRng(77);
        for _ in 0..400 {
            let c = rng.vec3(-2.0, 2.0) - Vec3::new(0.0, 0.0, 4.0);
            let base = positions.len() as u32;
            positions.extend([c, c + rng.vec3(-0.1, 0.1), c + rng.vec3(-0.1, 0.1)]);
            indices.push([base, base + 1, base + 2]);
        }
        let normals = vec![Vec3::Z; positions.len()];
        let scene = Arc::new(crate::surface::tests::raw_scene(
            positions, normals, indices,
        ));
        let rays: Vec<Ray> = (0..512)
            .map(|i| {
                let x = (i % 32) as f32 / 16.0 - 1.0;
                let y = (i / 32) as f32 / 8.0 - 1.0;
                let dir = Vec3::new(x * 0.2, y * 0.2, -1.0).normalize();
                test_ray(Vec3::new(x, y, 1.0), dir, 0.0, 8.0, i)
            })
            .collect();
        let h = build(&rays, (0..rays.len() as u32).collect(), 8, 2);
        let brute = BruteForce::from_scene(&scene);
        let want = reference(&brute, &rays, HitMode::Any);
        assert!(want.iter().all(Hit::is_hit), "the wall occludes every ray");
        let miss = vec![Hit::MISS; rays.len()];
        let trav = inline_dual(&scene, "lbvh");
        let (got, inline, _) =
            trace_inline(&trav, &rays, &h, HitMode::Any, brute.triangles(), &miss);
        assert_same(&got, &want, HitMode::Any, "inline");
        let batched = Dual::with_options(&scene, "lbvh", 64.0).unwrap();
        let (hits, _, stats, _) = trace(&batched, &brute, &rays, &h, HitMode::Any);
        assert_same(&hits, &want, HitMode::Any, "batched");
        assert!(
            (inline.tests.bounds + inline.tests.ray_triangle) * 2
                < stats.tests.bounds + stats.tests.ray_triangle,
            "inline {:?} against batched {:?}",
            inline.tests,
            stats.tests
        );
    }

    /// `trav`'s inline final tests of `rays` (as shadow rays, `mode`) over `h` with `tris`, from
    /// `n` misses: what [`Dual::trace_with_report`] answers.
    fn inline_result(
        trav: &Dual,
        rays: &[Ray],
        h: &RayHierarchy<Cpu>,
        mode: HitMode,
        tris: &AnyTriangleSet,
        n: usize,
    ) -> Result<Option<DualReport>> {
        let mut hits = vec![Hit::MISS; n];
        trav.trace_with_report(
            rays,
            RayKind::Shadow,
            mode,
            tris,
            h,
            &mut hits,
            &mut Stats::default(),
        )
    }

    #[test]
    fn inline_final_tests_decline_what_they_do_not_run() {
        let scene = Arc::new(soup(5, 60));
        let rays = test_rays(&scene, 8, 130);
        let n = rays.len();
        let tris = BruteForce::from_scene(&scene).triangles().clone();
        let h = build(&rays, (0..n as u32).collect(), 8, 2);
        let run = |trav: &Dual, h: &RayHierarchy<Cpu>, mode: HitMode| {
            inline_result(trav, &rays, h, mode, &tris, n).map(|r| r.is_some())
        };
        // Batched (the default), `meshes`, edge-width queries, lowest nodes of 64 rays.
        let batched = Dual::with_options(&scene, "lbvh", 64.0).unwrap();
        assert!(!batched.inline());
        assert!(!run(&batched, &h, HitMode::Any).unwrap());
        let mut meshes = Dual::with_options(&scene, "meshes", 64.0).unwrap();
        meshes.set_inline(&scene, true);
        assert!(!meshes.inline());
        assert!(!run(&meshes, &h, HitMode::Any).unwrap());
        let trav = inline_dual(&scene, "lbvh");
        let edge = HitMode::EdgeWidth(crsh_core::edge_width::EdgePairing::Any);
        assert!(!run(&trav, &h, edge).unwrap());
        let wide = build(&rays, (0..n as u32).collect(), 64, 1);
        assert!(!run(&trav, &wide, HitMode::Any).unwrap());
        assert!(run(&trav, &h, HitMode::Closest).unwrap());
        // Bad input is an error, as the intersector's.
        let mut bad = rays.clone();
        bad[17].dir = Vec3::ZERO;
        let err = inline_result(&trav, &bad, &h, HitMode::Any, &tris, n).unwrap_err();
        assert!(err.to_string().contains("ray 17"), "{err}");
        // The tasks check the rays they read; the error names the batch's first invalid ray,
        // whichever task met one.
        let mut bad = rays.clone();
        bad[120].t_min = f32::NAN;
        bad[40].origin.y = f32::INFINITY;
        let shuffled_h = build(&rays, shuffled(n, 9), 8, 2);
        for h in [&h, &shuffled_h] {
            for mode in [HitMode::Any, HitMode::Closest] {
                let err = inline_result(&trav, &bad, h, mode, &tris, n).unwrap_err();
                assert!(err.to_string().contains("ray 40 "), "{err}");
            }
        }
        // An order that is not a permutation of the rays is an error, not a panic.
        let mut dup: Vec<u32> = (0..n as u32).collect();
        dup[5] = dup[6];
        let dup = build(&rays, dup, 8, 2);
        assert!(run(&trav, &dup, HitMode::Any).is_err());
        // As are hits of another length.
        assert!(inline_result(&trav, &rays, &h, HitMode::Any, &tris, 3).is_err());
    }

    #[test]
    fn frames_with_inline_final_tests_equal_brute_force_frames() {
        for (name, scene, want) in brute_frames() {
            for (sub, depth, objects, test) in [
                (8, 2, "lbvh", "mt"),
                (16, 3, "lbvh", "watertight"),
                (4, 2, "grid", "mt"),
            ] {
                let sets = vec![
                    "traverse.kind=dual".to_string(),
                    "traverse.final_tests=inline".to_string(),
                    format!("traverse.objects={objects}"),
                    format!("hierarchy.subdivision={sub}"),
                    format!("hierarchy.depth={depth}"),
                    format!("intersect.test={test}"),
                ];
                let what = format!("{name} {sets:?}");
                let got = checked_frame(&scene, &sets, &what);
                if test == "mt" {
                    assert_eq!(got.image, want.image, "{what}");
                }
                // One stage: the final tests are part of the traversal.
                assert!(got.stats.timings_ms.contains_key("traversal"), "{what}");
                assert!(!got.stats.timings_ms.contains_key("final_tests"), "{what}");
                assert!(got.stats.tests.ray_triangle > 0, "{what}");
            }
        }
    }

    /// An intersector that names its test but does not share its triangles (`as_any` is
    /// `None`): `brute` behind an opaque wrapper.
    struct Opaque(BruteForce);

    impl Intersector<Cpu> for Opaque {
        fn name(&self) -> &str {
            "opaque"
        }

        fn candidate_test(&self) -> Option<&str> {
            self.0.candidate_test()
        }

        fn intersect(
            &self,
            backend: &Cpu,
            rays: &Vec<Ray>,
            query: Query<'_, Cpu>,
            mode: HitMode,
            hits: &mut Vec<Hit>,
            stats: &mut Stats,
        ) -> Result<()> {
            self.0.intersect(backend, rays, query, mode, hits, stats)
        }
    }

    #[test]
    fn inline_final_tests_use_the_intersectors_test_and_brutes_triangles() {
        let scene = Arc::new(clustered(12, 5, 25));
        let rays = test_rays(&scene, 5, 200);
        let h = build(&rays, shuffled(rays.len(), 3), 8, 2);
        let trav = inline_dual(&scene, "lbvh");
        let sets = trav.inline.as_ref().unwrap();
        for test in [TestKind::Watertight, TestKind::Projected] {
            let brute = BruteForce::with_test(&scene, test);
            let want = reference(&brute, &rays, HitMode::Closest);
            let trace_with = |isect: &dyn Intersector<Cpu>| {
                let mut hits = vec![Hit::MISS; rays.len()];
                let mut stats = Stats::default();
                trav.trace(
                    &Cpu,
                    &rays,
                    RayKind::Reflection,
                    HitMode::Closest,
                    isect,
                    &h,
                    &mut hits,
                    &mut stats,
                )
                .expect("inline")
                .unwrap();
                hits
            };
            // `brute` shares its prepared triangles: the stage prepares none of its own.
            let before = sets.prepared();
            assert_same(&trace_with(&brute), &want, HitMode::Closest, "brute");
            assert_eq!(sets.prepared(), before, "{test:?}");
            // An opaque intersector: the stage prepares the test it names, once.
            let opaque = Opaque(BruteForce::with_test(&scene, test));
            assert_same(&trace_with(&opaque), &want, HitMode::Closest, "opaque");
            assert_same(
                &trace_with(&opaque),
                &want,
                HitMode::Closest,
                "opaque again",
            );
            assert_eq!(sets.prepared(), before + 1, "{test:?}");
        }
        // Triangles of a smaller scene are an error, not an out-of-range read.
        let small = BruteForce::from_scene(&soup(2, 10));
        let err = inline_result(
            &trav,
            &rays,
            &h,
            HitMode::Any,
            small.triangles(),
            rays.len(),
        )
        .unwrap_err();
        assert!(err.to_string().contains("prepared"), "{err}");
    }
}
