//! `brute`: every ray against every triangle, the exact reference intersector.
//!
//! # Scene queries
//!
//! Rays are processed in packets of [`PACKET`] (rayon over packets); each packet sweeps the
//! scene's triangles in [`TriangleBlock`]s of [`LANES`], so a block is loaded once per packet
//! rather than once per ray, and the per-lane test vectorizes (Möller-Trumbore's
//! structure-of-arrays blocks do; the other tests run lane by lane).
//!
//! The ray-triangle test is the `test` parameter (`mt`, `watertight`, `projected`, see
//! [`crate::triangle`]): the triangles are prepared for it once, and each query is dispatched
//! to the loops of that test once, so every loop below is monomorphic.
//! Nothing is allocated per ray. Each ray's result depends only on the ray and the scene, so
//! the output is the same for any thread count.
//!
//! - [`HitMode::Closest`]: every triangle is tested; a hit replaces the stored one when
//!   [`Hit::closer_than`] says so (smaller `t`, then lower triangle id), so the answer does not
//!   depend on the order of the tests. Counts `triangles` tests per ray.
//! - [`HitMode::Any`]: a ray whose stored hit is already a hit is skipped (0 tests). Otherwise
//!   the sweep stops after the first block with a hit and stores that block's lowest-id hit;
//!   the count is the tests actually computed: all lanes of every block swept, i.e.
//!   `min(LANES·blocks_swept, triangles)` (padding lanes of the last block are not counted).
//!
//! - [`HitMode::EdgeWidth`] (seed 003 §5, eq. 5.1): the reference of the edge-width
//!   occlusion. Every triangle is tested; all crossings of the segment are gathered, sorted
//!   and paired ([`crsh_core::edge_width`]), with `R` the radius of the scene light
//!   [`Ray::light`]. The stored hit is replaced. Counts `triangles` tests per ray. Candidate
//!   queries do not answer it ([`CoreError::Unsupported`]): a ray's crossings would arrive
//!   split over batches.
//!
//! # Candidate queries
//!
//! [`Query::Candidates`] tests only the listed (node, triangle) pairs: node `n` of
//! `hierarchy.levels[0]` covers the leaves [`crsh_core::lowest_node_leaves`] gives
//! (`leaf_offsets[n] .. leaf_offsets[n+1]` when the hierarchy has
//! [`RayHierarchy::leaf_offsets`], else `n·subdivision .. min((n+1)·subdivision, rays)`),
//! whose rays are `hierarchy.order[leaf]`. Pairs are sorted and de-duplicated first, so the
//! result does not depend on their order; per ray the triangles are tested in increasing id
//! order with the same merge rules as above (any-hit: the lowest-id hit, stop at the first).
//!
//! A batch with [`CandidateBatch::lanes`] names, per pair, the rays of the node it is for (a
//! traverser that culled single rays, the `dual` traverser's `single_rays`): only those are
//! tested and counted, a repeated pair is for the union of its masks, and a packet skips a
//! triangle none of its live rays needs. A mask other than [`ALL_LANES`] on a node of more
//! than 32 rays, or a mask array of another length than the pairs', is an error.
//!
//! Work is per node (rayon over the nodes of the batch): the node's rays (up to [`LANES`] at
//! a time) sit in the lanes of a [`RayPacket`] and each candidate triangle is loaded once and
//! tested against all of them, with the same per-lane arithmetic as the scalar test. Pairs
//! that arrive strictly increasing, as the `crsh` traverser emits them, are used in place
//! (one parallel scan checks that and the ranges); others are copied and sorted.
//! Each (ray, triangle) test performed is counted, and also recorded as the hierarchy's
//! level-0 entry of [`Stats::levels`] (`Stats::add_level(kind, 0, tests, hits)`, the kind
//! taken from the rays, `hits` the tests that found an intersection): the final-test row of
//! seed 000's tables 4.1-4.24.
//!
//! # Errors
//!
//! [`CoreError::InvalidInput`] when `hits` and `rays` differ in length, a ray is not valid
//! ([`Ray::is_valid`]: NaN / infinite origin or direction, zero direction, NaN interval), or
//! a candidate batch is inconsistent (node or triangle out of range, `order` not a
//! permutation of the rays, zero subdivision without leaf offsets, no level, leaf offsets
//! refused by [`crsh_core::check_leaf_offsets`]: checked on every batch, O(nodes)).
//!
//! The traverser sends many candidate batches per hierarchy, and its batches shrink as rays
//! grow, so checking all of `order` and every ray per batch would make a traversal
//! O(rays²). Instead the intersector keeps a copy of the last `order` it found to be a
//! permutation (a batch whose `order` equals it, a sequential compare, skips the bit-set
//! check), and remembers the buffers (addresses and lengths of the rays and the hierarchy)
//! whose rays it last validated, so the later batches of the same traversal skip that scan of
//! 64-byte rays. The rays a batch tests are checked every time, so a ray made invalid in
//! place after validation is an error as soon as a batch would test it (one that no batch
//! tests cannot change any result).

use std::sync::{Arc, Mutex};

use crsh_core::edge_width::{Crossing, EdgePairing, EdgeWidthLights};
use crsh_core::{
    check_leaf_offsets, lowest_node_leaves, Candidate, CandidateBatch, CoreError, Hit, HitMode,
    Intersector, ParamInfo, Query, Ray, RayHierarchy, RayKind, Registry, Result, StageKind,
    StageSpec, StageVariantInfo, Stats, ALL_LANES,
};
use crsh_scene::Scene;
use rayon::prelude::*;

use crate::backend::Cpu;
use crate::triangle::{AnyTriangleSet, TestKind, TriangleSet, TriangleTest, LANES};

#[cfg(doc)]
use crate::triangle::{RayPacket, TriangleBlock};

/// Rays per packet in scene queries.
pub const PACKET: usize = 16;

/// The brute-force intersector (variant `brute`; parameter `test`).
#[derive(Debug)]
pub struct BruteForce {
    tris: AnyTriangleSet,
    /// The scene lights' radii (the `R` of edge-width queries) and shared vertices.
    lights: EdgeWidthLights,
    /// What the candidate queries last validated.
    validated: Mutex<Validated>,
}

impl Clone for BruteForce {
    /// A copy with the same triangles and nothing validated yet.
    fn clone(&self) -> BruteForce {
        BruteForce {
            tris: self.tris.clone(),
            lights: self.lights.clone(),
            validated: Mutex::default(),
        }
    }
}

/// What the candidate queries last validated, so the next batches of the same traversal
/// skip the O(rays) checks.
#[derive(Debug, Default)]
struct Validated {
    /// The buffers whose rays were all valid.
    rays: Option<RaysKey>,
    /// The last `order` found to be a permutation of its length.
    order: Option<Vec<u32>>,
}

/// Identifies the buffers of a candidate query (addresses and lengths).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct RaysKey {
    rays: usize,
    n_rays: usize,
    order: usize,
    order_len: usize,
    level0: usize,
    nodes: usize,
    subdivision: u32,
    /// Address and length of the leaf offsets, if any.
    leaf_offsets: Option<(usize, usize)>,
}

/// The catalogue entry of the `brute` intersector.
pub fn info() -> StageVariantInfo {
    StageVariantInfo::new(
        StageKind::Intersect,
        "brute",
        "every ray against every triangle: the exact reference, N×M tests (§3.2.9); under a \
         hierarchy, only the candidate pairs that survived traversal",
    )
    .param(ParamInfo::choice(
        "test",
        "mt",
        crate::triangle::TEST_NAMES,
        "ray-triangle test: `mt` Möller-Trumbore (f32), `watertight` Woop, Benthin and Wald \
         2013 (no ray slips through shared edges), `projected` RTTest's projected \
         barycentrics (seed 003 §4.2)",
    ))
}

/// Registers `brute` ([`info`], [`BruteForce::new`]).
pub fn register(registry: &mut Registry<Cpu>) -> Result<()> {
    registry.add_intersector(info(), |ctx, spec| {
        Ok(Box::new(BruteForce::new(ctx.scene, spec)?))
    })?;
    Ok(())
}

impl BruteForce {
    /// Prepares the triangles of `scene` for the ray-triangle test of `spec.test`.
    pub fn new(scene: &Arc<Scene>, spec: &StageSpec) -> Result<BruteForce, CoreError> {
        Ok(BruteForce::with_test(scene, test_kind(spec, "brute")?))
    }

    /// Prepares the triangles of `scene` for Möller-Trumbore (the default test).
    pub fn from_scene(scene: &Scene) -> BruteForce {
        BruteForce::with_test(scene, TestKind::MollerTrumbore)
    }

    /// Prepares the triangles of `scene` for test `kind`.
    pub fn with_test(scene: &Scene, kind: TestKind) -> BruteForce {
        BruteForce {
            tris: AnyTriangleSet::new(scene, kind),
            lights: edge_width_lights(scene),
            validated: Mutex::default(),
        }
    }

    /// The prepared triangles.
    pub fn triangles(&self) -> &AnyTriangleSet {
        &self.tris
    }

    /// The ray-triangle test in use.
    pub fn test(&self) -> TestKind {
        self.tris.kind()
    }
}

/// The `test` parameter of intersector `variant`'s `spec`.
pub(crate) fn test_kind(spec: &StageSpec, variant: &str) -> Result<TestKind> {
    let name = spec.str("test")?;
    TestKind::from_name(name).ok_or_else(|| CoreError::InvalidParam {
        key: format!("{variant}.test"),
        reason: format!(
            "`{name}` is not one of {}",
            crate::triangle::TEST_NAMES.join(", ")
        ),
    })
}

/// Edge-width answers ([`HitMode::EdgeWidth`]) for one packet of rays with test `T`: every
/// crossing of each segment, sorted and paired by [`crsh_core::edge_width::edge_width_hit`]
/// with the radius of the ray's light. Returns the tests performed (every triangle, per ray).
fn edge_width_packet<T: TriangleTest>(
    set: &TriangleSet<T>,
    rays: &[Ray],
    hits: &mut [Hit],
    lights: &EdgeWidthLights,
    pairing: EdgePairing,
) -> u64 {
    let mut crossings = Vec::new();
    for (ray, hit) in rays.iter().zip(hits.iter_mut()) {
        crossings.clear();
        let pre = T::ray_of(ray);
        for (k, block) in set.blocks().iter().enumerate() {
            let bh = T::test_block(block, &pre, ray.t_min, ray.t_max);
            for l in 0..LANES {
                if bh.t[l] < f32::INFINITY {
                    crossings.push(Crossing {
                        t: bh.t[l],
                        tri: (k * LANES + l) as u32,
                    });
                }
            }
        }
        *hit = lights.hit(ray, pairing, &mut crossings);
    }
    (set.len() * rays.len()) as u64
}

/// What the CPU intersectors keep of `scene` to answer edge-width queries: its lights' radii
/// and its triangles' shared vertices.
pub(crate) fn edge_width_lights(scene: &Scene) -> EdgeWidthLights {
    EdgeWidthLights::new(
        scene.lights.iter().map(|l| l.radius).collect(),
        &scene.positions,
        &scene.indices,
    )
}

/// Scene query for one packet (`rays.len() <= PACKET`) with test `T`; returns the tests
/// performed.
fn scene_packet<T: TriangleTest>(
    set: &TriangleSet<T>,
    rays: &[Ray],
    hits: &mut [Hit],
    mode: HitMode,
) -> u64 {
    let n = set.len();
    let blocks = set.blocks();
    let mut pre = [T::ray(Default::default(), Default::default()); PACKET];
    let mut best = [Hit::MISS; PACKET];
    let mut active = [false; PACKET];
    let count = rays.len();
    for i in 0..count {
        pre[i] = T::ray_of(&rays[i]);
        best[i] = hits[i];
        active[i] = mode == HitMode::Closest || !hits[i].is_hit();
    }
    let mut tests = 0u64;
    match mode {
        HitMode::Closest => {
            for (k, block) in blocks.iter().enumerate() {
                for i in 0..count {
                    let bh = T::test_block(block, &pre[i], rays[i].t_min, rays[i].t_max);
                    let m = bh.t.iter().fold(f32::INFINITY, |a, &b| a.min(b));
                    if m < f32::INFINITY && m <= best[i].t {
                        for l in 0..LANES {
                            let cand = Hit {
                                t: bh.t[l],
                                tri: (k * LANES + l) as u32,
                                u: bh.u[l],
                                v: bh.v[l],
                            };
                            if cand.t < f32::INFINITY && cand.closer_than(&best[i]) {
                                best[i] = cand;
                            }
                        }
                    }
                }
            }
            tests = (n * count) as u64;
        }
        // Edge-width queries are answered by `edge_width_packet`, never here.
        HitMode::Any | HitMode::EdgeWidth(_) => {
            let mut remaining = active[..count].iter().filter(|&&a| a).count();
            for (k, block) in blocks.iter().enumerate() {
                if remaining == 0 {
                    break;
                }
                for i in 0..count {
                    if !active[i] {
                        continue;
                    }
                    let bh = T::test_block(block, &pre[i], rays[i].t_min, rays[i].t_max);
                    if let Some(l) = (0..LANES).find(|&l| bh.t[l] < f32::INFINITY) {
                        best[i] = Hit {
                            t: bh.t[l],
                            tri: (k * LANES + l) as u32,
                            u: bh.u[l],
                            v: bh.v[l],
                        };
                        active[i] = false;
                        remaining -= 1;
                        tests += ((k + 1) * LANES).min(n) as u64;
                    }
                }
            }
            tests += (remaining * n) as u64;
        }
    }
    hits[..count].copy_from_slice(&best[..count]);
    tests
}

impl BruteForce {
    /// Candidate query with test `T` on `set` (this intersector's triangles): see the module
    /// doc.
    fn candidates<T: TriangleTest>(
        &self,
        set: &TriangleSet<T>,
        rays: &[Ray],
        hierarchy: &RayHierarchy<Cpu>,
        batch: &CandidateBatch<Cpu>,
        mode: HitMode,
        hits: &mut [Hit],
    ) -> Result<(u64, u64)> {
        let pairs = batch.pairs.as_slice();
        let lanes = batch.lanes.as_deref();
        if let Some(l) = lanes {
            if l.len() != pairs.len() {
                return Err(CoreError::InvalidInput(format!(
                    "{} lane masks for {} candidate pairs",
                    l.len(),
                    pairs.len()
                )));
            }
        }
        if pairs.is_empty() {
            check_rays(rays)?;
            return Ok((0, 0));
        }
        let n_rays = rays.len();
        let sub = hierarchy.subdivision as usize;
        let offsets = hierarchy.leaf_offsets.as_deref();
        if sub == 0 && offsets.is_none() {
            return Err(CoreError::InvalidInput("hierarchy subdivision is 0".into()));
        }
        let Some(level0) = hierarchy.levels.first() else {
            return Err(CoreError::InvalidInput("hierarchy has no levels".into()));
        };
        let order = &hierarchy.order;
        let n_nodes = level0.len();
        if let Some(offsets) = offsets {
            // O(nodes), cheaper than the order compare below: checked on every batch, so
            // offsets changed in place are caught too.
            check_leaf_offsets(offsets, n_nodes, n_rays)?;
        }
        let key = RaysKey {
            rays: rays.as_ptr() as usize,
            n_rays,
            order: order.as_ptr() as usize,
            order_len: order.len(),
            level0: level0.as_ptr() as usize,
            nodes: n_nodes,
            subdivision: hierarchy.subdivision,
            leaf_offsets: offsets.map(|o| (o.as_ptr() as usize, o.len())),
        };
        // The O(rays) checks, skipped when this traversal's earlier batches did them (see the
        // module doc); the rays a batch tests are checked below anyway.
        let mut validated = self
            .validated
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        if validated.order.as_deref() != Some(order.as_slice()) || order.len() != n_rays {
            check_permutation(order, n_rays)?;
            let copy = validated.order.get_or_insert_with(Vec::new);
            copy.clear();
            copy.extend_from_slice(order);
        }
        if validated.rays != Some(key) {
            validated.rays = None;
            check_rays(rays)?;
            validated.rays = Some(key);
        }
        drop(validated);
        let n_tris = set.len();
        // One parallel pass: every pair in range, and whether the pairs are already strictly
        // increasing (sorted, no duplicates), as the traversal emits them.
        let (in_range, increasing) = scan_pairs(pairs, n_nodes, n_tris);
        if !in_range {
            let bad = pairs
                .iter()
                .find(|c| c.node as usize >= n_nodes || c.tri as usize >= n_tris)
                .expect("the scan found one");
            return Err(CoreError::InvalidInput(format!(
                "candidate (node {}, triangle {}) out of range ({} nodes, {} triangles)",
                bad.node, bad.tri, n_nodes, n_tris
            )));
        }
        let owned: Vec<Candidate>;
        let owned_lanes: Vec<u32>;
        let (sorted, lanes): (&[Candidate], Option<&[u32]>) = if increasing {
            (pairs, lanes)
        } else if let Some(lanes) = lanes {
            (owned, owned_lanes) = sort_with_lanes(pairs, lanes);
            (&owned, Some(&owned_lanes))
        } else {
            owned = sort_pairs(pairs);
            (&owned, None)
        };
        let groups = node_runs(sorted, hierarchy.subdivision, offsets, n_rays);
        if let Some(lanes) = lanes {
            // A node of more than 32 rays has no mask but "all of them".
            for g in groups.iter().filter(|g| g.leaves > 32) {
                if let Some(&m) = lanes[g.pairs.clone()].iter().find(|&&m| m != ALL_LANES) {
                    return Err(CoreError::InvalidInput(format!(
                        "candidate of hierarchy node {} has lane mask {m:#x}, but the node \
                         has {} rays (more than 32: only the all-rays mask)",
                        sorted[g.pairs.start].node, g.leaves
                    )));
                }
            }
        }

        // Each active node gets one slot of `local` per leaf (`groups[i].slot ..`): its rays'
        // current hits are gathered, updated in parallel, and scattered back.
        let slots = groups.last().map_or(0, |g| g.slot + g.leaves);
        let mut local = vec![Hit::MISS; slots];
        let mut outs: Vec<&mut [Hit]> = Vec::with_capacity(groups.len());
        let mut rest = local.as_mut_slice();
        for g in &groups {
            let (out, tail) = rest.split_at_mut(g.leaves);
            outs.push(out);
            rest = tail;
        }
        let tris = set.triangles();
        let current: &[Hit] = hits;
        // The rays a node tests and its order entries are checked as they are read (cheap,
        // and it keeps bad input an error even if the buffers were changed in place since
        // they were validated); `bad` is the first node that failed.
        let (tests, found, bad) = groups
            .par_iter()
            .enumerate()
            .zip(outs.into_par_iter())
            .map(|((gi, g), out)| {
                let leaves = &order[g.first_leaf..g.first_leaf + g.leaves];
                let usable = leaves.iter().all(|&r| rays[r as usize].is_valid());
                if !usable {
                    return (0, 0, gi);
                }
                let node_pairs = &sorted[g.pairs.clone()];
                let node_lanes = lanes.map(|l| &l[g.pairs.clone()]);
                for (slot, &r) in out.iter_mut().zip(leaves) {
                    *slot = current[r as usize];
                }
                let mut tests = 0u64;
                let mut found = 0u64;
                for (k, (ids, best)) in leaves.chunks(LANES).zip(out.chunks_mut(LANES)).enumerate()
                {
                    let (t, f) = node_packet::<T>(
                        rays,
                        ids,
                        node_pairs,
                        node_lanes.map(|l| (l, k * LANES)),
                        tris,
                        mode,
                        best,
                    );
                    tests += t;
                    found += f;
                }
                (tests, found, usize::MAX)
            })
            .reduce(
                || (0, 0, usize::MAX),
                |a, b| (a.0 + b.0, a.1 + b.1, a.2.min(b.2)),
            );
        if bad != usize::MAX {
            // A ray changed in place since it was validated: report it as `check_rays` does.
            self.validated
                .lock()
                .unwrap_or_else(std::sync::PoisonError::into_inner)
                .rays = None;
            check_rays(rays)?;
            return Err(CoreError::InvalidInput(format!(
                "hierarchy node {} has an unusable ray",
                sorted[groups[bad].pairs.start].node
            )));
        }
        for g in &groups {
            let out = &local[g.slot..g.slot + g.leaves];
            for (&r, h) in order[g.first_leaf..g.first_leaf + g.leaves].iter().zip(out) {
                hits[r as usize] = *h;
            }
        }
        Ok((tests, found))
    }
}

/// A run of candidate pairs that share a node with rays: the pairs' range in the sorted
/// array, the node's leaves, and where its rays' hits sit in the gathered array.
struct NodeRun {
    pairs: std::ops::Range<usize>,
    first_leaf: usize,
    leaves: usize,
    slot: usize,
}

/// Splits the sorted pairs into runs of one node each (leaves by
/// [`crsh_core::lowest_node_leaves`]), skipping nodes without leaves.
fn node_runs(
    sorted: &[Candidate],
    subdivision: u32,
    offsets: Option<&[u32]>,
    n_rays: usize,
) -> Vec<NodeRun> {
    let mut runs = Vec::new();
    let mut start = 0;
    let mut slot = 0;
    while start < sorted.len() {
        let node = sorted[start].node;
        let end = start + sorted[start..].partition_point(|c| c.node == node);
        let leaves = lowest_node_leaves(node as usize, subdivision, offsets, n_rays);
        if !leaves.is_empty() {
            runs.push(NodeRun {
                pairs: start..end,
                first_leaf: leaves.start,
                leaves: leaves.len(),
                slot,
            });
            slot += leaves.len();
        }
        start = end;
    }
    runs
}

/// Tests the rays `ids` (at most [`LANES`] of one node) against the node's triangles, in
/// increasing triangle order, merging into `best` (their current hits) with the module doc's
/// rules; returns `(tests, hits found)`. Each triangle is loaded once for all the rays, which
/// sit in the lanes of a [`RayPacket`]; per ray the decisions and counts are those of testing
/// the triangles one after the other (any-hit: the lowest-id hit, then the ray stops).
/// With `lanes` (the pairs' masks, and the node leaf of `ids[0]`), a pair tests only the rays
/// its mask names, and a triangle no live ray of the packet needs is skipped.
fn node_packet<T: TriangleTest>(
    rays: &[Ray],
    ids: &[u32],
    node_pairs: &[Candidate],
    lanes: Option<(&[u32], usize)>,
    tris: &[T::Tri],
    mode: HitMode,
    best: &mut [Hit],
) -> (u64, u64) {
    let mut packet = T::empty_packet();
    let mut active = 0u32;
    for (l, &r) in ids.iter().enumerate() {
        if mode == HitMode::Any && best[l].is_hit() {
            continue;
        }
        T::set_lane(&mut packet, l, &rays[r as usize]);
        active |= 1 << l;
    }
    let mut tests = 0u64;
    let mut found = 0u64;
    for (j, c) in node_pairs.iter().enumerate() {
        if active == 0 {
            break;
        }
        let want = match lanes {
            // `first` < 32 here: a node of more than 32 rays has only all-rays masks.
            Some((l, first)) if l[j] != ALL_LANES => active & (l[j] >> first),
            _ => active,
        };
        if want == 0 {
            continue;
        }
        tests += want.count_ones() as u64;
        let (mask, bh) = T::test_packet(&packet, &tris[c.tri as usize]);
        let mut hit = mask & want;
        found += hit.count_ones() as u64;
        while hit != 0 {
            let l = hit.trailing_zeros() as usize;
            hit &= hit - 1;
            let h = Hit {
                t: bh.t[l],
                tri: c.tri,
                u: bh.u[l],
                v: bh.v[l],
            };
            match mode {
                // Edge-width queries never reach candidate tests (refused in `intersect`).
                HitMode::Any | HitMode::EdgeWidth(_) => {
                    best[l] = h;
                    active &= !(1 << l);
                }
                HitMode::Closest => {
                    if h.closer_than(&best[l]) {
                        best[l] = h;
                    }
                }
            }
        }
    }
    (tests, found)
}

/// `pairs` sorted and de-duplicated: the order the candidate query works in.
pub fn sort_pairs(pairs: &[Candidate]) -> Vec<Candidate> {
    let mut v = pairs.to_vec();
    v.par_sort_unstable();
    v.dedup();
    v
}

/// `pairs` sorted with their lane masks, a repeated pair merged into one for the union of its
/// masks ([`CandidateBatch::lanes`]): the order the candidate query works in.
pub fn sort_with_lanes(pairs: &[Candidate], lanes: &[u32]) -> (Vec<Candidate>, Vec<u32>) {
    let mut v: Vec<(Candidate, u32)> = pairs.iter().copied().zip(lanes.iter().copied()).collect();
    v.par_sort_unstable_by_key(|e| e.0);
    merge_repeats(&mut v);
    v.into_iter().unzip()
}

/// Merges the repeats of a candidate in `v` (sorted by candidate) into one, for the union of
/// their lane masks ([`CandidateBatch::lanes`]).
pub(crate) fn merge_repeats(v: &mut Vec<(Candidate, u32)>) {
    v.dedup_by(|next, kept| {
        let same = next.0 == kept.0;
        if same {
            kept.1 |= next.1;
        }
        same
    });
}

/// Whether every pair is in range, and whether the pairs are strictly increasing.
fn scan_pairs(pairs: &[Candidate], n_nodes: usize, n_tris: usize) -> (bool, bool) {
    pairs
        .par_chunks(crate::SCAN_CHUNK)
        .enumerate()
        .map(|(k, chunk)| {
            let in_range = chunk
                .iter()
                .all(|c| (c.node as usize) < n_nodes && (c.tri as usize) < n_tris);
            // Include the boundary with the previous chunk.
            let from = (k * crate::SCAN_CHUNK).saturating_sub(1);
            let window = &pairs[from..k * crate::SCAN_CHUNK + chunk.len()];
            let increasing = window.windows(2).all(|w| w[0] < w[1]);
            (in_range, increasing)
        })
        .reduce(|| (true, true), |a, b| (a.0 && b.0, a.1 && b.1))
}

/// Checks that `hits` matches `rays` and every ray is valid.
pub(crate) fn check_batch(rays: &[Ray], hits: &[Hit]) -> Result<()> {
    crsh_core::ray::check_hits_per_ray("rays", rays.len(), hits.len())?;
    check_rays(rays)
}

/// Checks that every ray is valid ([`Ray::is_valid`]).
fn check_rays(rays: &[Ray]) -> Result<()> {
    if let Some(i) = crate::position_first(rays, |r| !r.is_valid()) {
        return Err(CoreError::InvalidInput(format!(
            "ray {i} is not valid (non-finite or zero direction, or NaN interval): {:?}",
            rays[i]
        )));
    }
    Ok(())
}

/// Checks that `order` is a permutation of `0..n`.
pub(crate) fn check_permutation(order: &[u32], n: usize) -> Result<()> {
    if order.len() != n {
        return Err(CoreError::InvalidInput(format!(
            "hierarchy order has {} entries for {n} rays",
            order.len()
        )));
    }
    match crate::first_repeat(order, n) {
        Some(at) => Err(CoreError::InvalidInput(format!(
            "hierarchy order is not a permutation of the rays (entry {})",
            order[at]
        ))),
        None => Ok(()),
    }
}

impl Intersector<Cpu> for BruteForce {
    fn name(&self) -> &str {
        "brute"
    }

    fn candidate_test(&self) -> Option<&str> {
        Some(self.tris.kind().name())
    }

    fn as_any(&self) -> Option<&dyn std::any::Any> {
        Some(self)
    }

    fn intersect(
        &self,
        _backend: &Cpu,
        rays: &Vec<Ray>,
        query: Query<'_, Cpu>,
        mode: HitMode,
        hits: &mut Vec<Hit>,
        stats: &mut Stats,
    ) -> Result<()> {
        crsh_core::ray::check_hits_per_ray("rays", rays.len(), hits.len())?;
        if mode.is_edge_width() {
            if let Query::Candidates { .. } = query {
                return Err(CoreError::Unsupported {
                    stage: "intersect",
                    variant: "brute".into(),
                    what: "edge-width queries on candidate pairs (a ray's crossings would be \
                           split over batches); use a whole-scene query"
                        .into(),
                });
            }
            check_rays(rays)?;
            self.lights.check(rays)?;
            let HitMode::EdgeWidth(pairing) = mode else {
                unreachable!("an edge-width mode")
            };
            fn sweep_edges<T: TriangleTest>(
                set: &TriangleSet<T>,
                rays: &[Ray],
                hits: &mut [Hit],
                lights: &EdgeWidthLights,
                pairing: EdgePairing,
            ) -> u64 {
                rays.par_chunks(PACKET)
                    .zip(hits.par_chunks_mut(PACKET))
                    .map(|(r, h)| edge_width_packet(set, r, h, lights, pairing))
                    .sum()
            }
            let tests = match &self.tris {
                AnyTriangleSet::MollerTrumbore(s) => {
                    sweep_edges(s, rays, hits, &self.lights, pairing)
                }
                AnyTriangleSet::Watertight(s) => sweep_edges(s, rays, hits, &self.lights, pairing),
                AnyTriangleSet::Projected(s) => sweep_edges(s, rays, hits, &self.lights, pairing),
            };
            stats.add_ray_triangle(tests);
            return Ok(());
        }
        let tests = match query {
            Query::Scene => {
                check_rays(rays)?;
                fn sweep<T: TriangleTest>(
                    set: &TriangleSet<T>,
                    rays: &[Ray],
                    hits: &mut [Hit],
                    mode: HitMode,
                ) -> u64 {
                    rays.par_chunks(PACKET)
                        .zip(hits.par_chunks_mut(PACKET))
                        .map(|(r, h)| scene_packet(set, r, h, mode))
                        .sum()
                }
                match &self.tris {
                    AnyTriangleSet::MollerTrumbore(s) => sweep(s, rays, hits, mode),
                    AnyTriangleSet::Watertight(s) => sweep(s, rays, hits, mode),
                    AnyTriangleSet::Projected(s) => sweep(s, rays, hits, mode),
                }
            }
            Query::Candidates { hierarchy, batch } => {
                let (tests, found) = match &self.tris {
                    AnyTriangleSet::MollerTrumbore(s) => {
                        self.candidates(s, rays, hierarchy, batch, mode, hits)?
                    }
                    AnyTriangleSet::Watertight(s) => {
                        self.candidates(s, rays, hierarchy, batch, mode, hits)?
                    }
                    AnyTriangleSet::Projected(s) => {
                        self.candidates(s, rays, hierarchy, batch, mode, hits)?
                    }
                };
                if !batch.pairs.is_empty() {
                    let kind = RayKind::from_u32(rays[0].kind).ok_or_else(|| {
                        CoreError::InvalidInput(format!(
                            "ray 0 has an unknown kind {}",
                            rays[0].kind
                        ))
                    })?;
                    stats.add_level(kind, 0, tests, found);
                }
                tests
            }
        };
        stats.add_ray_triangle(tests);
        Ok(())
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::surface::tests::raw_scene;
    use crate::triangle::tests::TestRng;
    use crsh_core::glam::Vec3;
    use crsh_core::SphereCone;

    /// A random triangle soup in `[-1, 1]³` with a few degenerate and duplicated triangles
    /// (exact ties).
    pub(crate) fn soup(seed: u64, n: usize) -> Scene {
        let mut rng = TestRng(seed);
        let mut positions = Vec::new();
        let mut indices = Vec::new();
        for i in 0..n {
            let a = rng.vec3(-1.0, 1.0);
            let size = if i % 10 == 0 { 0.8 } else { 0.25 };
            let (b, c) = match i % 37 {
                5 => (a, a + Vec3::X * 0.1),                 // degenerate
                6 => (a + Vec3::Y * 0.1, a + Vec3::Y * 0.2), // collinear
                _ => (a + rng.vec3(-size, size), a + rng.vec3(-size, size)),
            };
            let base = positions.len() as u32;
            positions.extend([a, b, c]);
            indices.push([base, base + 1, base + 2]);
            if i % 23 == 0 {
                // The same triangle again (reversed winding): exact t ties.
                indices.push([base, base + 2, base + 1]);
            }
        }
        let normals = vec![Vec3::Z; positions.len()];
        raw_scene(positions, normals, indices)
    }

    /// Random rays: from outside, from on a surface (origin on a triangle, small `t_min`),
    /// grazing along a triangle's plane, and short shadow-like segments.
    pub(crate) fn random_rays(scene: &Scene, seed: u64, n: usize) -> Vec<Ray> {
        let mut rng = TestRng(seed);
        (0..n)
            .map(|i| {
                let tri = scene.triangle(rng.next_u64() as usize % scene.triangle_count());
                let (u, v) = (rng.f32() * 0.5, rng.f32() * 0.5);
                let on = tri[0] + (tri[1] - tri[0]) * u + (tri[2] - tri[0]) * v;
                let (origin, dir, t_min, t_max) = match i % 4 {
                    0 => {
                        let o = rng.vec3(-2.0, 2.0);
                        (o, (on - o).normalize_or(Vec3::X), 0.0, f32::INFINITY)
                    }
                    1 => (on, rng.unit(), 1e-4, f32::INFINITY),
                    2 => {
                        let dir = (tri[1] - tri[0]).normalize_or(Vec3::X);
                        (on - dir, dir, 0.0, f32::INFINITY)
                    }
                    _ => {
                        let o = rng.vec3(-2.0, 2.0);
                        let d = on - o;
                        (
                            o,
                            d.normalize_or(Vec3::X),
                            0.0,
                            d.length() * rng.range(0.5, 1.5),
                        )
                    }
                };
                test_ray(origin, dir, t_min, t_max, i)
            })
            .collect()
    }

    /// A reflection ray with the interval `(t_min, t_max)`, pixel and source `i`.
    pub(crate) fn test_ray(origin: Vec3, dir: Vec3, t_min: f32, t_max: f32, i: usize) -> Ray {
        Ray {
            pixel: i as u32,
            source: i as u32,
            ..Ray::new(RayKind::Reflection, origin, dir, t_min, t_max)
        }
    }

    /// The obvious scalar reference: every triangle, one at a time, with `set`'s test.
    fn naive(set: &AnyTriangleSet, ray: &Ray, mode: HitMode) -> Hit {
        match set {
            AnyTriangleSet::MollerTrumbore(s) => naive_with(s, ray, mode),
            AnyTriangleSet::Watertight(s) => naive_with(s, ray, mode),
            AnyTriangleSet::Projected(s) => naive_with(s, ray, mode),
        }
    }

    fn naive_with<T: TriangleTest>(set: &TriangleSet<T>, ray: &Ray, mode: HitMode) -> Hit {
        let r = T::ray_of(ray);
        let mut best = Hit::MISS;
        for (i, t) in set.triangles().iter().enumerate() {
            if let Some(h) = T::hit(t, &r, ray.t_min, ray.t_max, i as u32) {
                if mode == HitMode::Any {
                    return h;
                }
                if h.closer_than(&best) {
                    best = h;
                }
            }
        }
        best
    }

    fn run(b: &BruteForce, rays: &Vec<Ray>, q: Query<'_, Cpu>, mode: HitMode) -> (Vec<Hit>, Stats) {
        let mut hits = vec![Hit::MISS; rays.len()];
        let mut stats = Stats::default();
        b.intersect(&Cpu, rays, q, mode, &mut hits, &mut stats)
            .unwrap();
        (hits, stats)
    }

    #[test]
    fn scene_query_matches_naive_loop() {
        for kind in TestKind::ALL {
            scene_query_matches_naive_loop_with(kind);
        }
    }

    fn scene_query_matches_naive_loop_with(kind: TestKind) {
        let scene = soup(1, 300);
        let b = BruteForce::with_test(&scene, kind);
        assert_eq!(b.test(), kind);
        let rays = random_rays(&scene, 2, 403);
        let (closest, stats) = run(&b, &rays, Query::Scene, HitMode::Closest);
        assert_eq!(
            stats.tests.ray_triangle,
            (rays.len() * b.triangles().len()) as u64
        );
        let mut n_hits = 0;
        for (ray, h) in rays.iter().zip(&closest) {
            let want = naive(&b.tris, ray, HitMode::Closest);
            assert_eq!(h, &want);
            n_hits += h.is_hit() as usize;
        }
        assert!(n_hits > rays.len() / 3, "{n_hits}");
        let (any, stats) = run(&b, &rays, Query::Scene, HitMode::Any);
        for (ray, h) in rays.iter().zip(&any) {
            let want = naive(&b.tris, ray, HitMode::Any);
            // Both report the lowest-id hit (the first block with a hit, its lowest lane).
            assert_eq!(h, &want);
        }
        assert!(stats.tests.ray_triangle < (rays.len() * b.triangles().len()) as u64);
    }

    #[test]
    fn ties_go_to_the_lower_id() {
        // Two copies of one quad: every hit is a tie.
        let p = vec![Vec3::ZERO, Vec3::X, Vec3::Y, Vec3::new(1.0, 1.0, 0.0)];
        let scene = raw_scene(
            p.clone(),
            vec![Vec3::Z; 4],
            vec![[3, 2, 1], [0, 1, 2], [1, 2, 3], [0, 1, 2]],
        );
        let b = BruteForce::from_scene(&scene);
        let ray = |x: f32, y: f32| Ray {
            origin: Vec3::new(x, y, 1.0),
            t_min: 0.0,
            dir: -Vec3::Z,
            t_max: f32::INFINITY,
            throughput: Vec3::ONE,
            kind: 0,
            pixel: 0,
            light: u32::MAX,
            depth: 0,
            source: 0,
        };
        let rays = vec![ray(0.2, 0.2), ray(0.8, 0.8)];
        let (hits, _) = run(&b, &rays, Query::Scene, HitMode::Closest);
        assert_eq!(hits[0].tri, 1);
        assert_eq!(hits[1].tri, 0);
    }

    #[test]
    fn merges_into_existing_hits() {
        let scene = soup(4, 100);
        let b = BruteForce::from_scene(&scene);
        let rays = random_rays(&scene, 5, 64);
        let (fresh, _) = run(&b, &rays, Query::Scene, HitMode::Closest);
        // A stored hit closer than anything: kept.
        let mut hits = vec![
            Hit {
                t: -1.0,
                tri: 12345,
                u: 0.0,
                v: 0.0
            };
            rays.len()
        ];
        b.intersect(
            &Cpu,
            &rays,
            Query::Scene,
            HitMode::Closest,
            &mut hits,
            &mut Stats::default(),
        )
        .unwrap();
        assert!(hits.iter().all(|h| h.tri == 12345));
        // Any-hit: rays already hit are skipped and cost nothing.
        let mut hits = fresh.clone();
        let mut stats = Stats::default();
        b.intersect(
            &Cpu,
            &rays,
            Query::Scene,
            HitMode::Any,
            &mut hits,
            &mut stats,
        )
        .unwrap();
        assert_eq!(hits, fresh);
        let misses = fresh.iter().filter(|h| !h.is_hit()).count();
        assert_eq!(
            stats.tests.ray_triangle,
            (misses * b.triangles().len()) as u64
        );
    }

    fn hierarchy(order: Vec<u32>, sub: u32) -> RayHierarchy<Cpu> {
        let nodes = order.len().div_ceil(sub as usize);
        RayHierarchy {
            leaf_offsets: None,
            order,
            levels: vec![vec![<SphereCone as bytemuck::Zeroable>::zeroed(); nodes]],
            subdivision: sub,
            reach: vec![],
        }
    }

    #[test]
    fn candidates_with_all_pairs_equal_scene_query() {
        let scene = soup(6, 120);
        let b = BruteForce::from_scene(&scene);
        let rays = random_rays(&scene, 7, 101);
        let mut rng = TestRng(8);
        // A shuffled order and subdivision 4 (the last node is partial).
        let mut order: Vec<u32> = (0..rays.len() as u32).collect();
        for i in (1..order.len()).rev() {
            order.swap(i, rng.next_u64() as usize % (i + 1));
        }
        let h = hierarchy(order, 4);
        let nodes = h.levels[0].len() as u32;
        let mut pairs: Vec<Candidate> = (0..nodes)
            .flat_map(|node| {
                (0..b.triangles().len() as u32).map(move |tri| Candidate { node, tri })
            })
            .collect();
        // Shuffle the pairs and split them into two batches: same result.
        for i in (1..pairs.len()).rev() {
            pairs.swap(i, rng.next_u64() as usize % (i + 1));
        }
        let half = pairs.len() / 2;
        for mode in [HitMode::Closest, HitMode::Any] {
            let (want, _) = run(&b, &rays, Query::Scene, mode);
            let mut hits = vec![Hit::MISS; rays.len()];
            let mut stats = Stats::default();
            for part in [&pairs[..half], &pairs[half..]] {
                let batch = CandidateBatch::<Cpu>::new(part.to_vec());
                let q = Query::Candidates {
                    hierarchy: &h,
                    batch: &batch,
                };
                b.intersect(&Cpu, &rays, q, mode, &mut hits, &mut stats)
                    .unwrap();
            }
            match mode {
                HitMode::Closest => {
                    assert_eq!(hits, want);
                    assert_eq!(
                        stats.tests.ray_triangle,
                        (rays.len() * b.triangles().len()) as u64
                    );
                }
                HitMode::Any | HitMode::EdgeWidth(_) => {
                    for (g, w) in hits.iter().zip(&want) {
                        assert_eq!(g.is_hit(), w.is_hit());
                    }
                }
            }
        }
    }

    #[test]
    fn candidates_test_only_listed_pairs() {
        let scene = soup(9, 50);
        let b = BruteForce::from_scene(&scene);
        let rays = random_rays(&scene, 10, 20);
        let h = hierarchy((0..20).rev().collect(), 8);
        // Node 2 covers leaves 16..20, i.e. rays 3, 2, 1, 0.
        let pairs = vec![
            Candidate { node: 2, tri: 7 },
            Candidate { node: 2, tri: 3 },
            Candidate { node: 2, tri: 7 },
        ];
        let batch = CandidateBatch::<Cpu>::new(pairs);
        let mut hits = vec![Hit::MISS; rays.len()];
        let mut stats = Stats::default();
        b.intersect(
            &Cpu,
            &rays,
            Query::Candidates {
                hierarchy: &h,
                batch: &batch,
            },
            HitMode::Closest,
            &mut hits,
            &mut stats,
        )
        .unwrap();
        assert_eq!(stats.tests.ray_triangle, 8, "4 rays x 2 distinct triangles");
        // The final tests are the hierarchy's level-0 row: 8 tests, as many hits as found.
        assert_eq!(stats.levels.len(), 1);
        let row = &stats.levels[0];
        assert_eq!(
            (row.ray_kind.as_str(), row.level, row.tests),
            ("reflection", 0, 8)
        );
        assert_eq!(row.hits + row.misses, 8);
        let AnyTriangleSet::MollerTrumbore(set) = &b.tris else {
            panic!("from_scene prepares for Möller-Trumbore");
        };
        for (i, (ray, hit)) in rays.iter().zip(&hits).enumerate() {
            let r = crate::triangle::RayPre::of(ray);
            let mut want = Hit::MISS;
            if i < 4 {
                for tri in [3u32, 7] {
                    if let Some(x) =
                        set.triangles()[tri as usize].hit(&r, ray.t_min, ray.t_max, tri)
                    {
                        if x.closer_than(&want) {
                            want = x;
                        }
                    }
                }
            }
            assert_eq!(hit, &want, "ray {i}");
        }
    }

    /// The candidate query written the obvious way: pairs sorted and de-duplicated (a
    /// repeated pair for the union of its lane masks), then per ray of each node, the
    /// triangles whose mask names the ray, one at a time; returns the (tests, hits found)
    /// counts.
    fn naive_candidates(
        set: &AnyTriangleSet,
        rays: &[Ray],
        h: &RayHierarchy<Cpu>,
        pairs: &[Candidate],
        lanes: Option<&[u32]>,
        mode: HitMode,
        hits: &mut [Hit],
    ) -> (u64, u64) {
        match set {
            AnyTriangleSet::MollerTrumbore(s) => {
                naive_candidates_with(s, rays, h, pairs, lanes, mode, hits)
            }
            AnyTriangleSet::Watertight(s) => {
                naive_candidates_with(s, rays, h, pairs, lanes, mode, hits)
            }
            AnyTriangleSet::Projected(s) => {
                naive_candidates_with(s, rays, h, pairs, lanes, mode, hits)
            }
        }
    }

    fn naive_candidates_with<T: TriangleTest>(
        set: &TriangleSet<T>,
        rays: &[Ray],
        h: &RayHierarchy<Cpu>,
        pairs: &[Candidate],
        lanes: Option<&[u32]>,
        mode: HitMode,
        hits: &mut [Hit],
    ) -> (u64, u64) {
        let mut merged: std::collections::BTreeMap<Candidate, u32> = Default::default();
        for (i, c) in pairs.iter().enumerate() {
            *merged.entry(*c).or_insert(0) |= lanes.map_or(ALL_LANES, |l| l[i]);
        }
        let (mut tests, mut found) = (0, 0);
        for node in 0..h.levels[0].len() {
            let tris: Vec<(u32, u32)> = merged
                .iter()
                .filter(|(c, _)| c.node as usize == node)
                .map(|(c, m)| (c.tri, *m))
                .collect();
            let leaves =
                lowest_node_leaves(node, h.subdivision, h.leaf_offsets.as_deref(), rays.len());
            for (k, &r) in h.order[leaves].iter().enumerate() {
                let ray = &rays[r as usize];
                let best = &mut hits[r as usize];
                if mode == HitMode::Any && best.is_hit() {
                    continue;
                }
                for &(tri, m) in &tris {
                    if m != ALL_LANES && (k >= 32 || m & (1 << k) == 0) {
                        continue;
                    }
                    tests += 1;
                    let pre = T::ray_of(ray);
                    if let Some(x) = T::hit(
                        &set.triangles()[tri as usize],
                        &pre,
                        ray.t_min,
                        ray.t_max,
                        tri,
                    ) {
                        found += 1;
                        if mode == HitMode::Any {
                            *best = x;
                            break;
                        }
                        if x.closer_than(best) {
                            *best = x;
                        }
                    }
                }
            }
        }
        (tests, found)
    }

    #[test]
    fn candidates_match_the_naive_loop_exactly() {
        for kind in TestKind::ALL {
            candidates_match_the_naive_loop_exactly_with(kind);
        }
    }

    fn candidates_match_the_naive_loop_exactly_with(kind: TestKind) {
        let scene = soup(21, 90);
        let b = BruteForce::with_test(&scene, kind);
        let rays = random_rays(&scene, 22, 157);
        let mut rng = TestRng(23);
        let mut order: Vec<u32> = (0..rays.len() as u32).collect();
        for i in (1..order.len()).rev() {
            order.swap(i, rng.next_u64() as usize % (i + 1));
        }
        // Subdivisions below, at and above LANES (nodes of several packets), partial last node.
        for sub in [1u32, 3, 8, 11, 20] {
            let h = hierarchy(order.clone(), sub);
            let nodes = h.levels[0].len() as u32;
            // A random half of the pairs, in two batches: the first sorted as the traverser
            // emits them, the second shuffled with duplicates.
            let mut pairs: Vec<Candidate> = (0..nodes)
                .flat_map(|node| {
                    (0..b.triangles().len() as u32).map(move |tri| Candidate { node, tri })
                })
                .filter(|_| rng.next_u64() & 1 == 0)
                .collect();
            let half = pairs.len() / 2;
            let mut second = pairs.split_off(half);
            second.extend_from_within(..second.len() / 5);
            for i in (1..second.len()).rev() {
                second.swap(i, rng.next_u64() as usize % (i + 1));
            }
            // Lane masks for both batches: all rays, none, or random rays of the node.
            let mut masks = |n: usize| -> Vec<u32> {
                (0..n)
                    .map(|_| match rng.next_u64() % 4 {
                        0 => ALL_LANES,
                        1 => 0,
                        _ => rng.next_u64() as u32,
                    })
                    .collect()
            };
            let lanes = [masks(pairs.len()), masks(second.len())];
            for (mode, masked) in [
                (HitMode::Closest, false),
                (HitMode::Any, false),
                (HitMode::Closest, true),
                (HitMode::Any, true),
            ] {
                // Start from some stored hits (closer than anything, or misses).
                let start: Vec<Hit> = (0..rays.len())
                    .map(|i| match i % 9 {
                        0 => Hit {
                            t: 1e-3,
                            tri: 5,
                            u: 0.1,
                            v: 0.1,
                        },
                        _ => Hit::MISS,
                    })
                    .collect();
                let mut want = start.clone();
                let mut got = start.clone();
                let mut stats = Stats::default();
                let mut counts = (0, 0);
                for (part, l) in [&pairs, &second].into_iter().zip(&lanes) {
                    let l = masked.then_some(l.as_slice());
                    let c = naive_candidates(&b.tris, &rays, &h, part, l, mode, &mut want);
                    counts = (counts.0 + c.0, counts.1 + c.1);
                    let batch = match l {
                        Some(l) => CandidateBatch::<Cpu>::with_lanes(part.to_vec(), l.to_vec()),
                        None => CandidateBatch::<Cpu>::new(part.to_vec()),
                    };
                    let q = Query::Candidates {
                        hierarchy: &h,
                        batch: &batch,
                    };
                    b.intersect(&Cpu, &rays, q, mode, &mut got, &mut stats)
                        .unwrap();
                }
                let what = format!("{kind:?} sub {sub} {mode:?} masked {masked}");
                assert_eq!(got, want, "{what}");
                assert_eq!(stats.tests.ray_triangle, counts.0, "{what}");
                let found: u64 = stats.levels.iter().map(|r| r.hits).sum();
                assert_eq!(found, counts.1, "{what}");
                assert!(counts.1 > 0, "{what}: no hits, not a test");
            }
        }
    }

    #[test]
    fn lane_masks_that_do_not_fit_are_errors() {
        let scene = soup(31, 40);
        let b = BruteForce::from_scene(&scene);
        let rays = random_rays(&scene, 32, 80);
        // Nodes of 40 rays: more than a mask holds.
        let h = hierarchy((0..80).collect(), 40);
        let pairs = vec![Candidate { node: 0, tri: 3 }, Candidate { node: 1, tri: 5 }];
        let run = |lanes: Vec<u32>| {
            let batch = CandidateBatch::<Cpu>::with_lanes(pairs.clone(), lanes);
            let mut hits = vec![Hit::MISS; rays.len()];
            let mut stats = Stats::default();
            let q = Query::Candidates {
                hierarchy: &h,
                batch: &batch,
            };
            b.intersect(&Cpu, &rays, q, HitMode::Closest, &mut hits, &mut stats)
                .map(|()| stats.tests.ray_triangle)
        };
        assert_eq!(run(vec![ALL_LANES, ALL_LANES]).unwrap(), 80);
        let err = run(vec![ALL_LANES, 1]).unwrap_err().to_string();
        assert!(err.contains("node 1") && err.contains("40 rays"), "{err}");
        let err = run(vec![ALL_LANES]).unwrap_err().to_string();
        assert!(err.contains("1 lane masks for 2"), "{err}");
    }

    /// A one-level hierarchy with variable-size lowest nodes: `offsets` over `order`.
    fn hierarchy_with_offsets(order: Vec<u32>, offsets: Vec<u32>) -> RayHierarchy<Cpu> {
        let nodes = offsets.len().saturating_sub(1);
        RayHierarchy {
            leaf_offsets: Some(offsets),
            order,
            levels: vec![vec![<SphereCone as bytemuck::Zeroable>::zeroed(); nodes]],
            subdivision: 256,
            reach: vec![],
        }
    }

    /// Random cut points over `n` leaves: nodes of 0 to 40 leaves (empty ones included, some
    /// above `LANES`, so a node spans several packets).
    fn random_offsets(rng: &mut TestRng, n: usize) -> Vec<u32> {
        let mut offsets = vec![0u32];
        let mut at = 0usize;
        while at < n {
            let size = match rng.next_u64() % 5 {
                0 => 0,
                1 => 1,
                2 => 17 + (rng.next_u64() % 24) as usize,
                _ => 1 + (rng.next_u64() % 9) as usize,
            };
            at = (at + size).min(n);
            offsets.push(at as u32);
        }
        offsets
    }

    #[test]
    fn candidates_with_leaf_offsets_agree_with_brute_force() {
        for kind in TestKind::ALL {
            let scene = soup(31, 90);
            let b = BruteForce::with_test(&scene, kind);
            let rays = random_rays(&scene, 32, 157);
            let mut rng = TestRng(33);
            let mut order: Vec<u32> = (0..rays.len() as u32).collect();
            for i in (1..order.len()).rev() {
                order.swap(i, rng.next_u64() as usize % (i + 1));
            }
            let offsets = random_offsets(&mut rng, rays.len());
            let h = hierarchy_with_offsets(order, offsets);
            let nodes = h.levels[0].len() as u32;
            let all: Vec<Candidate> = (0..nodes)
                .flat_map(|node| {
                    (0..b.triangles().len() as u32).map(move |tri| Candidate { node, tri })
                })
                .collect();
            // Every pair: the scene query's answer, N×M tests.
            let (want, _) = run(&b, &rays, Query::Scene, HitMode::Closest);
            let batch = CandidateBatch::<Cpu>::new(all.clone());
            let q = Query::Candidates {
                hierarchy: &h,
                batch: &batch,
            };
            let (got, stats) = run(&b, &rays, q, HitMode::Closest);
            assert_eq!(got, want, "{kind:?}");
            assert_eq!(
                stats.tests.ray_triangle,
                (rays.len() * b.triangles().len()) as u64
            );
            // A random half of the pairs, shuffled: the naive per-node loop over the offsets.
            let mut half: Vec<Candidate> = all
                .into_iter()
                .filter(|_| rng.next_u64() & 1 == 0)
                .collect();
            for i in (1..half.len()).rev() {
                half.swap(i, rng.next_u64() as usize % (i + 1));
            }
            for mode in [HitMode::Closest, HitMode::Any] {
                let mut want = vec![Hit::MISS; rays.len()];
                let counts = naive_candidates(&b.tris, &rays, &h, &half, None, mode, &mut want);
                let batch = CandidateBatch::<Cpu>::new(half.clone());
                let q = Query::Candidates {
                    hierarchy: &h,
                    batch: &batch,
                };
                let (got, stats) = run(&b, &rays, q, mode);
                assert_eq!(got, want, "{kind:?} {mode:?}");
                assert_eq!(stats.tests.ray_triangle, counts.0, "{kind:?} {mode:?}");
                assert!(counts.1 > 0);
            }
        }
    }

    #[test]
    fn bad_leaf_offsets_are_refused() {
        let scene = soup(34, 10);
        let b = BruteForce::from_scene(&scene);
        let rays = random_rays(&scene, 35, 8);
        let order: Vec<u32> = (0..8).collect();
        let ok = hierarchy_with_offsets(order.clone(), vec![0, 3, 3, 8]);
        let cases = [
            ok,
            // Wrong length for the level (3 nodes, 3 offsets).
            RayHierarchy {
                leaf_offsets: Some(vec![0, 3, 8]),
                ..hierarchy_with_offsets(order.clone(), vec![0, 3, 3, 8])
            },
            hierarchy_with_offsets(order.clone(), vec![1, 3, 3, 8]),
            hierarchy_with_offsets(order.clone(), vec![0, 3, 3, 7]),
            hierarchy_with_offsets(order.clone(), vec![0, 3, 3, 9]),
            hierarchy_with_offsets(order.clone(), vec![0, 4, 3, 8]),
            hierarchy_with_offsets(order.clone(), vec![0, u32::MAX, 3, 8]),
        ];
        for (i, h) in cases.iter().enumerate() {
            let batch = CandidateBatch::<Cpu>::new(vec![
                Candidate { node: 0, tri: 0 },
                Candidate { node: 2, tri: 1 },
            ]);
            let mut hits = vec![Hit::MISS; rays.len()];
            let r = b.intersect(
                &Cpu,
                &rays,
                Query::Candidates {
                    hierarchy: h,
                    batch: &batch,
                },
                HitMode::Closest,
                &mut hits,
                &mut Stats::default(),
            );
            if i == 0 {
                r.unwrap();
            } else {
                assert!(
                    matches!(r, Err(CoreError::InvalidInput(_))),
                    "case {i}: {r:?}"
                );
            }
        }
    }

    #[test]
    fn bad_input_is_an_error() {
        let scene = soup(11, 10);
        let b = BruteForce::from_scene(&scene);
        let mut rays = random_rays(&scene, 12, 8);
        let mut hits = vec![Hit::MISS; 7];
        assert!(b
            .intersect(
                &Cpu,
                &rays,
                Query::Scene,
                HitMode::Closest,
                &mut hits,
                &mut Stats::default()
            )
            .is_err());
        let mut hits = vec![Hit::MISS; 8];
        rays[3].dir = Vec3::new(f32::NAN, 0.0, 1.0);
        assert!(b
            .intersect(
                &Cpu,
                &rays,
                Query::Scene,
                HitMode::Closest,
                &mut hits,
                &mut Stats::default()
            )
            .is_err());
        rays[3].dir = Vec3::ZERO;
        assert!(b
            .intersect(
                &Cpu,
                &rays,
                Query::Scene,
                HitMode::Any,
                &mut hits,
                &mut Stats::default()
            )
            .is_err());
        let rays = random_rays(&scene, 12, 8);
        let cases: Vec<(RayHierarchy<Cpu>, Vec<Candidate>)> = vec![
            (
                hierarchy((0..8).collect(), 4),
                vec![Candidate { node: 2, tri: 0 }],
            ),
            (
                hierarchy((0..8).collect(), 4),
                vec![Candidate { node: 0, tri: 99 }],
            ),
            (
                hierarchy(vec![0, 1, 2, 3, 4, 5, 6, 6], 4),
                vec![Candidate { node: 0, tri: 0 }],
            ),
            (
                hierarchy((0..7).collect(), 4),
                vec![Candidate { node: 0, tri: 0 }],
            ),
            (
                RayHierarchy {
                    leaf_offsets: None,
                    order: (0..8).collect(),
                    levels: vec![],
                    subdivision: 4,
                    reach: vec![],
                },
                vec![Candidate { node: 0, tri: 0 }],
            ),
            (
                RayHierarchy {
                    leaf_offsets: None,
                    order: (0..8).collect(),
                    levels: vec![vec![<SphereCone as bytemuck::Zeroable>::zeroed(); 2]],
                    subdivision: 0,
                    reach: vec![],
                },
                vec![Candidate { node: 0, tri: 0 }],
            ),
        ];
        for (h, pairs) in cases {
            let batch = CandidateBatch::<Cpu>::new(pairs);
            let r = b.intersect(
                &Cpu,
                &rays,
                Query::Candidates {
                    hierarchy: &h,
                    batch: &batch,
                },
                HitMode::Closest,
                &mut hits,
                &mut Stats::default(),
            );
            assert!(matches!(r, Err(CoreError::InvalidInput(_))), "{r:?}");
        }
    }

    #[test]
    fn rays_changed_in_place_between_batches_are_caught() {
        let scene = soup(15, 40);
        let b = BruteForce::from_scene(&scene);
        let mut rays = random_rays(&scene, 16, 16);
        let h = hierarchy((0..16).rev().collect(), 4);
        let batch = |node: u32| {
            CandidateBatch::<Cpu>::new((0..40).map(|tri| Candidate { node, tri }).collect())
        };
        let mut hits = vec![Hit::MISS; rays.len()];
        let mut go = |rays: &Vec<Ray>, node: u32| {
            let batch = batch(node);
            let q = Query::Candidates {
                hierarchy: &h,
                batch: &batch,
            };
            b.intersect(
                &Cpu,
                rays,
                q,
                HitMode::Closest,
                &mut hits,
                &mut Stats::default(),
            )
        };
        go(&rays, 0).unwrap();
        // Ray 15 is leaf 0, in node 0: the next batch of node 1 does not test it, node 0's does.
        rays[15].origin.x = f32::NAN;
        go(&rays, 1).unwrap();
        let r = go(&rays, 0);
        assert!(matches!(r, Err(CoreError::InvalidInput(_))), "{r:?}");
        // And a fresh traversal (a new hierarchy) checks every ray up front.
        let h2 = hierarchy((0..16).collect(), 4);
        let batch = batch(0);
        let q = Query::Candidates {
            hierarchy: &h2,
            batch: &batch,
        };
        let r = b.intersect(
            &Cpu,
            &rays,
            q,
            HitMode::Closest,
            &mut hits,
            &mut Stats::default(),
        );
        assert!(matches!(r, Err(CoreError::InvalidInput(_))), "{r:?}");
    }

    #[test]
    fn order_changed_in_place_between_batches_is_caught() {
        let scene = soup(17, 30);
        let b = BruteForce::from_scene(&scene);
        let rays = random_rays(&scene, 18, 12);
        let mut h = hierarchy((0..12).collect(), 4);
        let batch = CandidateBatch::<Cpu>::new(vec![Candidate { node: 0, tri: 1 }]);
        let mut hits = vec![Hit::MISS; rays.len()];
        for (i, want_ok) in [(11, true), (10, false), (11, true)] {
            // Leaf 11 (outside node 0) names ray 11, then ray 10 twice, then 11 again.
            h.order[11] = i;
            let q = Query::Candidates {
                hierarchy: &h,
                batch: &batch,
            };
            let r = b.intersect(
                &Cpu,
                &rays,
                q,
                HitMode::Closest,
                &mut hits,
                &mut Stats::default(),
            );
            assert_eq!(r.is_ok(), want_ok, "order[11] = {i}: {r:?}");
        }
    }

    #[test]
    fn same_result_for_any_thread_count() {
        let scene = soup(13, 200);
        let b = BruteForce::from_scene(&scene);
        let rays = random_rays(&scene, 14, 300);
        for mode in [HitMode::Closest, HitMode::Any] {
            let a = crate::with_threads(1, || run(&b, &rays, Query::Scene, mode)).unwrap();
            let c = crate::with_threads(3, || run(&b, &rays, Query::Scene, mode)).unwrap();
            assert_eq!(a.0, c.0);
            assert_eq!(a.1.tests, c.1.tests);
        }
    }
}
