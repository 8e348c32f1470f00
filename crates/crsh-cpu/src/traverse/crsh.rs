//! `crsh`: top-down traversal of the coherent ray-space hierarchy (seed 000 §3.2.8, eq. 3.16).
//!
//! # Algorithm
//!
//! The triangles are processed in batches of contiguous ids (see *Memory bound*). For each
//! batch:
//!
//! 1. **Mesh culling** (parameter `mesh_culling`, the thesis's default; RAH turns it off).
//!    Once per traversal, every top-level node is tested against every mesh's bounding sphere
//!    (`Scene::meshes[i].sphere`); a top node keeps the triangles of the meshes it may hit.
//!    Without mesh culling every triangle is kept for every top node.
//! 2. **Top level.** Each kept (top node, triangle) pair is tested against the triangle's
//!    bounding sphere (`Scene::tri_spheres`): "if a triangle does not intersect the root node
//!    [...] no ray in the scene will intersect it" (§3.2.8). The survivors form the top
//!    level's candidate array.
//! 3. **Descent.** Level by level, each surviving (node, triangle) pair of level `L` is tested
//!    for each existing child of the node at level `L-1` (children `n·s .. (n+1)·s`, clamped
//!    to the level's length) against the triangle's sphere; the survivors are written,
//!    compacted, as the next level's array (stream compaction, §3.2.8). Pairs stay sorted by
//!    `(node, triangle)` at every level: the work is split into chunks of whole node runs
//!    (rayon over chunks), each chunk writes its survivors child by child, and the chunks are
//!    concatenated in order — so the output does not depend on the thread count.
//! 4. The pairs that survive the lowest node level (`levels[0]`) are handed to the sink as one
//!    [`CandidateBatch`] before the next triangle batch starts; the intersector merges hits
//!    across batches with [`crsh_core::Hit::closer_than`], so results do not depend on
//!    batching.
//!
//! # The node-sphere test (eq. 3.16, conservative)
//!
//! A node bounds its rays' origins by the sphere `(c, r)` and their directions by the cone
//! `(a, α)`. Seed 000's eq. 3.16 (after Roger et al.) enlarges the triangle's sphere by the
//! node's radius and shrinks the node to a cone with apex `c`. [`NodeBound::may_hit`]
//! implements that idea in a form that provably never culls an intersecting pair:
//!
//! - Let a ray have origin `o` with `|o − c| ≤ r` and unit direction `d` with
//!   `angle(a, d) ≤ α`, and let it hit the sphere `(P, R)` at `o + t·d`, `t ≥ 0`. Then the
//!   point `c + t·d = (o + t·d) − (o − c)` is within `R + r` of `P`: **the half-line from `c`
//!   along `d` hits the sphere `(P, ρ)`, `ρ = R + r`.**
//! - If `|P − c| ≤ ρ` the test passes. Otherwise, with `D = |P − c|`, a half-line from `c`
//!   along `d` hits `(P, ρ)` iff `angle(d, P − c) ≤ β = asin(ρ / D)`, and by the triangle
//!   inequality for angles `angle(a, P − c) ≤ α + β`. **So the pair can intersect only if
//!   `angle(a, P − c) ≤ α + β`**, which is the test.
//! - It is evaluated without trigonometry: when `α + β ≥ π` every direction passes. For
//!   `α ≤ π/2` that cannot happen with `D > ρ` (`β < π/2`); for `α > π/2` it happens iff
//!   `β ≥ π − α`, i.e. iff `ρ ≥ D·sin α` (both angles lie in `[0, π/2]`). Else both
//!   `angle(a, P − c)` and `α + β` lie in `[0, π)`, where `cos` is decreasing, and the test is
//!   `a·(P − c) ≥ D·cos(α + β) = cos α·√(D² − ρ²) − sin α·ρ`. Wide cones (`α ≥ π/2`) thus
//!   pass spheres in front of and behind the apex correctly.
//! - Rays are treated as infinite half-lines from their origin: `t_min` and `t_max` are
//!   ignored, which only keeps more pairs.
//! - Floating point: the test runs in `f64` on the `f32` inputs, with the margins
//!   `ρ' = ρ·(1 + `[`REL_MARGIN`]`) + `[`ABS_MARGIN`]`·max(1, |c|∞, |P|∞)` and
//!   `α' = α + `[`ANGLE_MARGIN`]` on top, so rounding in the bounds and in the ray-triangle
//!   test (hits a hair outside a triangle) cannot cause a false cull.
//!
//! # Counters
//!
//! Every node-sphere and node-mesh test counts in [`Stats::add_bounds`]. Per-level counters
//! use the thesis numbering ([`crsh_core::LevelStats`]): `levels[i]` is level `i + 1`, so the
//! top is level `levels.len()` and the lowest node level is 1; the **mesh-culling tests are
//! counted apart, in [`Stats::mesh_culling`]** (tests = top nodes × meshes, hits = the
//! (node, mesh) pairs kept), so level numbers mean the same whatever the batch; the final
//! ray-triangle tests are level 0, recorded by the intersector. Together the rows account for
//! every test. At every level `tests = hits + misses`, and within a triangle batch the tests
//! at level `L < top` are the survivors at `L + 1` times their existing children; the tests of
//! a batch abandoned under the memory budget (see below) count too, at the levels where they
//! were done, so with retries a level can show more tests than that product.
//!
//! # Memory bound
//!
//! The candidate arrays (8-byte [`Candidate`] pairs) of a batch of `B` triangles hold at most
//! `nodes_at_level × B` pairs per level; while a level is computed its input and output arrays
//! are alive, and the last level is concatenated into one batch for the sink. Sizing `B` from
//! the lowest level's node count alone (`2 × nodes(levels[0]) × B × 8` bytes) would be safe but
//! far too pessimistic (a 1920×1080 batch with subdivision 8 would get 16-triangle batches, so
//! thousands of sink calls), so the bound is enforced level by level instead:
//!
//! - `B` starts at the largest count whose top-level worst case `2 × nodes(top) × B × 8` bytes
//!   fits `candidate_budget_mb` (MiB, 2²⁰ bytes), at least one triangle
//!   ([`Crsh::batch_triangles`]).
//! - Before each lower level is computed, its worst case is known exactly from the pairs in
//!   hand: `input + pairs × subdivision × 8` bytes (for the last level also
//!   `2 × pairs × subdivision × 8`, the concatenation). If that exceeds the budget and the batch
//!   has more than one triangle, the batch is abandoned and retried with
//!   `min(B / 2, B × budget / needed)` triangles ([`TraversalReport::retries`]; the bounds tests
//!   already done count in [`Stats::add_bounds`], the level rows only come from completed
//!   batches, so the row identities below hold). After a batch whose checked worst cases all
//!   stayed within half the budget, `B` doubles again (up to the start value).
//! - So the live candidate arrays never exceed the budget, except for one-triangle batches,
//!   which always proceed (their arrays are at most `2 × nodes(levels[0]) × 8` bytes).
//!   [`Crsh::traverse_with_report`] returns the peak actually reached
//!   ([`TraversalReport::peak_candidate_bytes`], from the arrays' capacities after
//!   compaction), so the bound is testable. The batch sizes depend only on the counts, never on
//!   the thread count.
//!
//! # Errors
//!
//! [`CoreError::InvalidParam`] for a budget that is not a finite positive number;
//! [`CoreError::InvalidInput`] for an inconsistent hierarchy: zero subdivision where it is
//! used, no level, `order` of the wrong length, a level whose length is not
//! `⌈below / subdivision⌉` (`levels[0]` over the rays; with [`RayHierarchy::leaf_offsets`]
//! `levels[0]` has `offsets − 1` nodes instead and the offsets must pass
//! [`crsh_core::check_leaf_offsets`]), or a node with a non-finite or negative radius or
//! half-angle, or a cone axis that cannot be normalized.
//!
//! # Apex cones (seed 004)
//!
//! A hierarchy of seed 004's tile cones ([`crate::hierarchy::tile_cone`]) has one level of
//! variable-size nodes ([`RayHierarchy::leaf_offsets`]), each a [`SphereCone`] of sphere
//! radius 0 at the cone's apex. The traversal needs nothing else: it only emits
//! (node, triangle) pairs, and the intersector maps nodes to rays. With `r = 0`,
//! [`NodeBound::may_hit`] is exactly the paper's cone-sphere test (§4, *the cone intersects
//! the sphere if φ > arccos((v − a)·x) − arcsin(r / |v − a|)*) with the direction to the
//! sphere centre normalized, a sphere containing the apex counted as a hit, and every sphere
//! passing once `φ + arcsin(r / |v − a|) ≥ π` (the derivation above, with margins); a
//! half-angle of π (the builder's "wider than a hemisphere") passes every sphere, within the
//! reach.

use std::sync::Arc;

use crsh_core::glam::DVec3;
use crsh_core::{
    check_leaf_offsets, Candidate, CandidateBatch, CoreError, ParamInfo, Ray, RayHierarchy,
    RayKind, Registry, Result, Sphere, SphereCone, StageKind, StageSpec, StageVariantInfo, Stats,
    Traverser,
};
use crsh_scene::Scene;
use rayon::prelude::*;

use crate::backend::Cpu;

/// Relative enlargement of the combined radius `R + r` in [`NodeBound::may_hit`].
pub const REL_MARGIN: f64 = 1e-4;
/// Absolute enlargement of the combined radius, times `max(1, |c|∞, |P|∞)`.
pub const ABS_MARGIN: f64 = 1e-5;
/// Enlargement of every node cone's half-angle, radians.
pub const ANGLE_MARGIN: f64 = 1e-4;
/// Target number of pairs per chunk of a candidate array (chunks hold whole node runs, so
/// a chunk may exceed it by one child's triangles).
const CHUNK: usize = 1 << 14;
/// Bytes per candidate pair.
const PAIR_BYTES: u64 = std::mem::size_of::<Candidate>() as u64;

/// The catalogue entry of the `crsh` traverser.
pub fn info() -> StageVariantInfo {
    StageVariantInfo::new(
        StageKind::Traverse,
        "crsh",
        "top-down sphere-cone hierarchy traversal against mesh and triangle bounding \
         spheres with per-level stream compaction and triangle batches, seed 000 §3.2.8 \
         eq. 3.16 (conservative enlarge-the-sphere test)",
    )
    .param(ParamInfo::bool(
        "mesh_culling",
        true,
        "test the top nodes against whole-mesh bounding spheres first (thesis); false: \
         every triangle is a candidate of every top node (RAH)",
    ))
    .param(
        ParamInfo::float(
            "candidate_budget_mb",
            64.0,
            "memory bound of the candidate arrays in MiB (> 0); triangle batches shrink \
             (down to 1 triangle) so that no level's worst case exceeds it",
        )
        .range(1.0 / 1024.0, 1024.0 * 1024.0),
    )
}

/// Registers `crsh` ([`info`], [`Crsh::new`]).
pub fn register(registry: &mut Registry<Cpu>) -> Result<()> {
    registry.add_traverser(info(), |ctx, spec| {
        Ok(Box::new(Crsh::new(ctx.scene, spec)?))
    })?;
    Ok(())
}

/// A hierarchy node prepared for [`NodeBound::may_hit`] (`f64`, margins applied).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NodeBound {
    center: DVec3,
    radius: f64,
    axis: DVec3,
    cos_a: f64,
    sin_a: f64,
    /// The cone (with margin) covers every direction.
    all: bool,
    /// Upper bound on the distance from `center` to any point the node's rays reach
    /// ([`RayHierarchy::reach`]; infinite when unknown).
    reach: f64,
    /// `max(1, |c|∞)`.
    scale: f64,
}

impl NodeBound {
    /// Prepares `node`; errors on a non-finite or negative radius or half-angle, or an axis
    /// that cannot be normalized while the cone is not the whole sphere of directions.
    pub fn new(node: &SphereCone) -> Result<NodeBound> {
        let s = node.sphere;
        let c = node.cone;
        let bad = |what: &str| {
            Err(CoreError::InvalidInput(format!(
                "hierarchy node has {what}: {node:?}"
            )))
        };
        if !s.center.is_finite() || !s.radius.is_finite() || s.radius < 0.0 {
            return bad("a non-finite or negative sphere");
        }
        if !c.half_angle.is_finite() || c.half_angle < 0.0 || !c.axis.is_finite() {
            return bad("a non-finite or negative cone");
        }
        let alpha = c.half_angle as f64 + ANGLE_MARGIN;
        let center = s.center.as_dvec3();
        let scale = center.abs().max_element().max(1.0);
        if alpha >= std::f64::consts::PI {
            return Ok(NodeBound {
                center,
                radius: s.radius as f64,
                axis: DVec3::X,
                cos_a: -1.0,
                sin_a: 0.0,
                all: true,
                scale,
                reach: f64::INFINITY,
            });
        }
        let axis = c.axis.as_dvec3();
        let len = axis.length();
        if len < 1e-12 {
            return bad("a zero cone axis");
        }
        Ok(NodeBound {
            center,
            radius: s.radius as f64,
            axis: axis / len,
            cos_a: alpha.cos(),
            sin_a: alpha.sin(),
            all: false,
            scale,
            reach: f64::INFINITY,
        })
    }

    /// This bound, also culling spheres farther than `reach` from the node's centre: no ray
    /// of the node gets that far within its interval. A non-finite or negative `reach` leaves
    /// the bound unlimited.
    pub fn with_reach(mut self, reach: f32) -> NodeBound {
        if reach.is_finite() && reach >= 0.0 {
            self.reach = reach as f64;
        }
        self
    }

    /// Whether some ray of the node (origin in its sphere, direction in its cone, as an
    /// infinite half-line) may hit `sphere`. Never false when one does (see the module doc
    /// for the derivation from eq. 3.16).
    #[inline]
    pub fn may_hit(&self, sphere: &Sphere) -> bool {
        let v = sphere.center.as_dvec3() - self.center;
        self.may_hit_at(sphere, v, v.length_squared())
    }

    /// [`NodeBound::may_hit`] and, when it holds, [`NodeBound::spreads_wider_than`] for the same
    /// sphere: `None` when no ray of the node may hit `sphere`, else whether the node's rays
    /// spread wider than it. The two share the distance to the sphere's centre ([`super::dual`]
    /// asks both of every pair that passes); the answers are the two methods' own.
    #[inline]
    pub fn hit_and_spread(&self, sphere: &Sphere) -> Option<bool> {
        let v = sphere.center.as_dvec3() - self.center;
        let d2 = v.length_squared();
        self.may_hit_at(sphere, v, d2)
            .then(|| self.spreads_at(sphere, d2))
    }

    /// [`NodeBound::may_hit`] with `v = centre(sphere) − centre` and `d2 = |v|²` given.
    #[inline]
    fn may_hit_at(&self, sphere: &Sphere, v: DVec3, d2: f64) -> bool {
        let p = sphere.center.as_dvec3();
        let scale = self.scale.max(p.abs().max_element());
        let rho = (sphere.radius as f64 + self.radius) * (1.0 + REL_MARGIN) + ABS_MARGIN * scale;
        if self.reach.is_finite() {
            // Every point a ray of the node reaches is within `reach` of the centre; the
            // sphere is within `radius ≤ rho` of its centre.
            let limit = (self.reach + rho) * (1.0 + REL_MARGIN) + ABS_MARGIN * scale;
            if d2 > limit * limit {
                return false;
            }
        }
        if self.all {
            return true;
        }
        let rho2 = rho * rho;
        if d2 <= rho2 {
            return true;
        }
        if self.cos_a < 0.0 && rho * rho >= d2 * self.sin_a * self.sin_a {
            // α > π/2 and ρ ≥ D·sin α: α + β ≥ π, every direction may hit.
            return true;
        }
        self.axis.dot(v) >= self.cos_a * (d2 - rho2).sqrt() - self.sin_a * rho
    }

    /// How far `p` lies along the node's axis from its centre, `(p − c)·a`: an ordering key
    /// only ([`super::dual`] visits the nearer of two object nodes first when it tests pairs
    /// inline), not a bound.
    #[inline]
    pub fn along_axis(&self, p: crsh_core::glam::Vec3) -> f64 {
        (p.as_dvec3() - self.center).dot(self.axis)
    }

    /// Whether the node's rays spread wider at `sphere`'s centre than `sphere`'s radius `R`:
    /// `r + D·sin α > R` with `D` the distance from the node's centre to the sphere's centre
    /// (`r + D > R` when the cone is a hemisphere or wider), evaluated without a square root.
    /// `r + D·sin α` is the radius of a ball around the axis point at distance `D` that every
    /// ray of the node crossing that distance passes through. A size comparison only (margins
    /// included, not a bound the traversal relies on): [`super::dual`] uses it to choose which
    /// side of a (ray node, object node) pair to descend.
    #[inline]
    pub fn spreads_wider_than(&self, sphere: &Sphere) -> bool {
        self.spreads_at(
            sphere,
            (sphere.center.as_dvec3() - self.center).length_squared(),
        )
    }

    /// [`NodeBound::spreads_wider_than`] with `d2`, the squared distance between the centres,
    /// given.
    #[inline]
    fn spreads_at(&self, sphere: &Sphere, d2: f64) -> bool {
        let room = sphere.radius as f64 - self.radius;
        if room < 0.0 {
            return true;
        }
        let sin2 = if self.all || self.cos_a <= 0.0 {
            1.0
        } else {
            self.sin_a * self.sin_a
        };
        d2 * sin2 > room * room
    }
}

/// Checks a hierarchy's shape for a traversal of `n_rays` rays (shared by the backends): at
/// least one level, `order_len == n_rays`, level `i` holding `⌈below / subdivision⌉` nodes
/// with a non-zero `subdivision`, and reach bounds either absent or shaped like the levels.
/// With [`RayHierarchy::leaf_offsets`] of `offsets_len` entries (`None`: no offsets),
/// `levels[0]` must hold `offsets_len − 1` nodes (whatever `subdivision` says) and
/// `subdivision` must be non-zero only when there are levels above it. The offsets' contents
/// are checked apart ([`crsh_core::check_leaf_offsets`]).
pub fn check_shape(
    n_rays: usize,
    subdivision: u32,
    order_len: usize,
    level_lens: &[usize],
    reach_lens: &[usize],
    offsets_len: Option<usize>,
) -> Result<()> {
    let sub = subdivision as usize;
    if sub == 0 && (offsets_len.is_none() || level_lens.len() > 1) {
        return Err(CoreError::InvalidInput("hierarchy subdivision is 0".into()));
    }
    if level_lens.is_empty() {
        return Err(CoreError::InvalidInput("hierarchy has no levels".into()));
    }
    if order_len != n_rays {
        return Err(CoreError::InvalidInput(format!(
            "hierarchy order has {order_len} entries for {n_rays} rays"
        )));
    }
    let mut below = n_rays;
    for (i, &len) in level_lens.iter().enumerate() {
        let want = match offsets_len {
            Some(0) if i == 0 => {
                return Err(CoreError::InvalidInput(
                    "hierarchy leaf offsets are empty (need nodes + 1 entries)".into(),
                ))
            }
            Some(o) if i == 0 => o - 1,
            _ => below.div_ceil(sub),
        };
        if len != want {
            if let (0, Some(o)) = (i, offsets_len) {
                return Err(CoreError::InvalidInput(format!(
                    "hierarchy level 0 has {len} nodes but {o} leaf offsets (nodes + 1 expected)"
                )));
            }
            return Err(CoreError::InvalidInput(format!(
                "hierarchy level {i} has {len} nodes, expected {want} (⌈{below} / {sub}⌉)"
            )));
        }
        below = want;
    }
    if !reach_lens.is_empty() && reach_lens != level_lens {
        return Err(CoreError::InvalidInput(
            "hierarchy reach bounds do not match its levels".into(),
        ));
    }
    Ok(())
}

/// The candidate budget `candidate_budget_mb` (MiB, 2²⁰ bytes) in bytes; an error unless it is
/// a finite positive number. Shared by the traversers of this module and [`super::dual`].
pub fn budget_bytes(budget_mb: f64) -> Result<u64> {
    if !(budget_mb.is_finite() && budget_mb > 0.0) {
        return Err(CoreError::InvalidParam {
            key: "traverse.candidate_budget_mb".into(),
            reason: format!("{budget_mb} is not a positive number of MiB"),
        });
    }
    Ok((budget_mb * (1u64 << 20) as f64).min(u64::MAX as f64) as u64)
}

/// Checks a hierarchy's shape for a traversal of `n_rays` rays ([`check_shape`],
/// [`crsh_core::check_leaf_offsets`]) and prepares its nodes for [`NodeBound::may_hit`],
/// lowest level first, with their reach bounds where the hierarchy has them. Shared by `crsh`
/// and [`super::dual`].
pub fn prepare_nodes(n_rays: usize, h: &RayHierarchy<Cpu>) -> Result<Vec<Vec<NodeBound>>> {
    let level_lens: Vec<usize> = h.levels.iter().map(Vec::len).collect();
    let reach_lens: Vec<usize> = h.reach.iter().map(Vec::len).collect();
    check_shape(
        n_rays,
        h.subdivision,
        h.order.len(),
        &level_lens,
        &reach_lens,
        h.leaf_offsets.as_ref().map(Vec::len),
    )?;
    if let Some(offsets) = &h.leaf_offsets {
        check_leaf_offsets(offsets, level_lens[0], n_rays)?;
    }
    h.levels
        .iter()
        .enumerate()
        .map(|(i, l)| {
            l.par_iter()
                .enumerate()
                .map(|(n, node)| {
                    let b = NodeBound::new(node)?;
                    Ok(match h.reach.get(i) {
                        Some(r) => b.with_reach(r[n]),
                        None => b,
                    })
                })
                .collect()
        })
        .collect()
}

/// What one traversal did, for tests and tuning.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct TraversalReport {
    /// Triangles in the largest batch completed.
    pub batch_triangles: usize,
    /// Triangle batches completed (each handed its candidates to the sink).
    pub batches: usize,
    /// Batches abandoned because a level's worst case would have exceeded the budget (and
    /// retried with fewer triangles).
    pub retries: usize,
    /// The budget in bytes the batch size was chosen for.
    pub budget_bytes: u64,
    /// Largest total size, in bytes, of the candidate arrays alive at once (input and output
    /// of a level, or the last level and its concatenation).
    pub peak_candidate_bytes: u64,
    /// Candidate pairs handed to the sink, over all batches.
    pub candidates: u64,
}

/// The `crsh` traverser (see the module doc).
#[derive(Clone, Debug)]
pub struct Crsh {
    scene: Arc<Scene>,
    mesh_culling: bool,
    budget_bytes: u64,
}

/// One level's candidate array: chunks of whole node runs, in `(node, triangle)` order.
type Chunks = Vec<Vec<Candidate>>;

fn bytes(chunks: &Chunks) -> u64 {
    chunks.iter().map(|c| c.capacity() as u64).sum::<u64>() * PAIR_BYTES
}

fn pairs(chunks: &Chunks) -> u64 {
    chunks.iter().map(|c| c.len() as u64).sum()
}

impl Crsh {
    /// The traverser over `scene` with `spec`'s `mesh_culling` and `candidate_budget_mb`.
    pub fn new(scene: &Arc<Scene>, spec: &StageSpec) -> Result<Crsh, CoreError> {
        let mesh_culling = spec.bool("mesh_culling")?;
        let mb = spec.f64("candidate_budget_mb")?;
        Crsh::with_options(scene, mesh_culling, mb)
    }

    /// The traverser with explicit options (`budget_mb` in MiB, finite and > 0).
    pub fn with_options(scene: &Arc<Scene>, mesh_culling: bool, budget_mb: f64) -> Result<Crsh> {
        Ok(Crsh {
            scene: Arc::clone(scene),
            mesh_culling,
            budget_bytes: budget_bytes(budget_mb)?,
        })
    }

    /// Whether whole meshes are culled at the top level.
    pub fn mesh_culling(&self) -> bool {
        self.mesh_culling
    }

    /// The candidate-array budget in bytes.
    pub fn budget_bytes(&self) -> u64 {
        self.budget_bytes
    }

    /// The largest triangle batch for a hierarchy with `top_nodes` top-level nodes: the
    /// largest count whose top-level worst case `2 × top_nodes × count × 8` bytes (the
    /// array, and its concatenation when the top is the only level) fits the budget, at
    /// least 1, at most the scene's triangle count. Lower levels are checked as they come.
    pub fn batch_triangles(&self, top_nodes: usize) -> usize {
        let per_tri = 2 * PAIR_BYTES * top_nodes.max(1) as u64;
        let n = (self.budget_bytes / per_tri).max(1);
        (n.min(self.scene.triangle_count().max(1) as u64)) as usize
    }

    /// [`Traverser::traverse`], returning what it did (batch size, peak candidate bytes).
    pub fn traverse_with_report(
        &self,
        rays: &[Ray],
        kind: RayKind,
        hierarchy: &RayHierarchy<Cpu>,
        sink: &mut dyn FnMut(CandidateBatch<Cpu>, &mut Stats) -> Result<()>,
        stats: &mut Stats,
    ) -> Result<TraversalReport> {
        let mut report = TraversalReport {
            budget_bytes: self.budget_bytes,
            ..Default::default()
        };
        let n_rays = rays.len();
        let n_tris = self.scene.triangle_count();
        if n_rays == 0 {
            return Ok(report);
        }
        let nodes = prepare_nodes(n_rays, hierarchy)?;
        if n_tris == 0 {
            return Ok(report);
        }
        let sub = hierarchy.subdivision as usize;
        let top = nodes.last().expect("checked non-empty");
        let meshes = &self.scene.meshes;

        // Mesh culling, once: keep[node * meshes + m].
        let keep: Vec<bool> = if self.mesh_culling {
            let keep: Vec<bool> = top
                .par_iter()
                .flat_map_iter(|nb| meshes.iter().map(move |m| nb.may_hit(&m.sphere)))
                .collect();
            let tests = keep.len() as u64;
            let kept = keep.iter().filter(|&&k| k).count() as u64;
            stats.add_bounds(tests);
            stats.add_mesh_culling(kind, tests, kept);
            keep
        } else {
            Vec::new()
        };

        let ctx = BatchContext {
            nodes: &nodes,
            sub,
            keep: &keep,
            kind,
        };
        let max_batch = self.batch_triangles(top.len());
        let mut batch = max_batch;
        let mut t0 = 0usize;
        while t0 < n_tris {
            let t1 = (t0 + batch).min(n_tris);
            match self.run_batch(&ctx, t0, t1)? {
                BatchOutcome::Aborted { needed, local } => {
                    // The tests done before the batch was abandoned were done: they count,
                    // at their levels, so that the level rows account for every test.
                    stats.add_bounds(local.tests.bounds);
                    for row in &local.levels {
                        stats.add_level(kind, row.level, row.tests, row.hits);
                    }
                    report.retries += 1;
                    let scaled = (batch as f64 * self.budget_bytes as f64 / needed as f64) as usize;
                    batch = scaled.min(batch / 2).max(1);
                }
                BatchOutcome::Done {
                    pairs,
                    local,
                    peak,
                    worst,
                } => {
                    stats.add_bounds(local.tests.bounds);
                    for row in &local.levels {
                        stats.add_level(kind, row.level, row.tests, row.hits);
                    }
                    report.batches += 1;
                    report.batch_triangles = report.batch_triangles.max(t1 - t0);
                    report.peak_candidate_bytes = report.peak_candidate_bytes.max(peak);
                    if !pairs.is_empty() {
                        report.candidates += pairs.len() as u64;
                        sink(CandidateBatch::new(pairs), stats)?;
                    }
                    if worst <= self.budget_bytes / 2 {
                        batch = (batch * 2).min(max_batch);
                    }
                    t0 = t1;
                }
            }
        }
        Ok(report)
    }
}

/// What [`Crsh::run_batch`] needs besides the triangle range.
struct BatchContext<'a> {
    nodes: &'a [Vec<NodeBound>],
    sub: usize,
    keep: &'a [bool],
    kind: RayKind,
}

/// The result of one triangle batch.
enum BatchOutcome {
    /// The final candidates, the batch's counters, its peak candidate bytes and the largest
    /// worst case checked against the budget.
    Done {
        pairs: Vec<Candidate>,
        local: Box<Stats>,
        peak: u64,
        worst: u64,
    },
    /// A level's worst case would exceed the budget: `needed` bytes; `local` holds the tests
    /// done before the batch was abandoned.
    Aborted { needed: u64, local: Box<Stats> },
}

impl Crsh {
    /// Traverses all levels for the triangles `t0..t1`. Before each level is computed, its
    /// worst case (input pairs × subdivision, doubled at the last level for the
    /// concatenation) is checked against the budget; a batch of more than one triangle that
    /// would exceed it is abandoned so the caller retries with a smaller batch.
    fn run_batch(&self, ctx: &BatchContext<'_>, t0: usize, t1: usize) -> Result<BatchOutcome> {
        let nodes = ctx.nodes;
        let sub = ctx.sub;
        let kind = ctx.kind;
        let top = nodes.last().expect("checked non-empty");
        let top_level = nodes.len() as u32;
        let tri_spheres = &self.scene.tri_spheres;
        let meshes = &self.scene.meshes;
        let keep = ctx.keep;
        let mut local = Stats::default();
        let mut peak = 0u64;
        let mut worst = 0u64;
        // Triangle ranges of this batch, with their mesh (None without mesh culling).
        let ranges: Vec<(Option<usize>, usize, usize)> = if self.mesh_culling {
            meshes
                .iter()
                .enumerate()
                .filter_map(|(i, m)| {
                    let a = (m.first_tri as usize).max(t0);
                    let b = (m.first_tri as usize + m.tri_count as usize).min(t1);
                    (a < b).then_some((Some(i), a, b))
                })
                .collect()
        } else {
            vec![(None, t0, t1)]
        };
        // Top level: each top node against the kept triangles' spheres.
        let results: Vec<(Vec<Candidate>, u64)> = top
            .par_iter()
            .enumerate()
            .map(|(n, nb)| {
                let mut out = Vec::new();
                let mut tests = 0u64;
                for &(mesh, a, b) in &ranges {
                    if let Some(m) = mesh {
                        if !keep[n * meshes.len() + m] {
                            continue;
                        }
                    }
                    tests += (b - a) as u64;
                    for (tri, sphere) in (a..b).zip(&tri_spheres[a..b]) {
                        if nb.may_hit(sphere) {
                            out.push(Candidate {
                                node: n as u32,
                                tri: tri as u32,
                            });
                        }
                    }
                }
                out.shrink_to_fit();
                (out, tests)
            })
            .collect();
        let tests: u64 = results.iter().map(|r| r.1).sum();
        let mut level: Chunks = results
            .into_iter()
            .map(|r| r.0)
            .filter(|c| !c.is_empty())
            .collect();
        local.add_bounds(tests);
        local.add_level(kind, top_level, tests, pairs(&level));
        peak = peak.max(bytes(&level));

        // Descent: level index li (thesis li + 1) to li - 1.
        for li in (1..nodes.len()).rev() {
            let worst_out = pairs(&level) * sub as u64 * PAIR_BYTES;
            let needed = if li == 1 {
                (bytes(&level) + worst_out).max(2 * worst_out)
            } else {
                bytes(&level) + worst_out
            };
            worst = worst.max(needed);
            if needed > self.budget_bytes && t1 - t0 > 1 {
                return Ok(BatchOutcome::Aborted {
                    needed,
                    local: Box::new(local),
                });
            }
            let children = &nodes[li - 1];
            let results: Vec<(Chunks, u64)> = level
                .par_iter()
                .map(|chunk| descend(chunk, children, sub, tri_spheres))
                .collect();
            let tests: u64 = results.iter().map(|r| r.1).sum();
            let next: Chunks = results.into_iter().flat_map(|r| r.0).collect();
            local.add_bounds(tests);
            local.add_level(kind, li as u32, tests, pairs(&next));
            peak = peak.max(bytes(&level) + bytes(&next));
            level = next;
        }

        // Final candidates of this batch: one contiguous array for the sink.
        let total = pairs(&level) as usize;
        let mut flat = Vec::with_capacity(total);
        for c in &level {
            flat.extend_from_slice(c);
        }
        peak = peak.max(bytes(&level) + flat.capacity() as u64 * PAIR_BYTES);
        Ok(BatchOutcome::Done {
            pairs: flat,
            local: Box::new(local),
            peak,
            worst,
        })
    }
}

/// Tests every pair of `chunk` (whole node runs of level `L`, sorted) against each existing
/// child at level `L-1`; returns the survivors as chunks of whole child runs, sorted, and the
/// number of tests.
fn descend(
    chunk: &[Candidate],
    children: &[NodeBound],
    sub: usize,
    tri_spheres: &[Sphere],
) -> (Chunks, u64) {
    let mut out: Chunks = Vec::new();
    let mut cur: Vec<Candidate> = Vec::new();
    let mut tests = 0u64;
    let mut start = 0;
    while start < chunk.len() {
        let node = chunk[start].node as usize;
        let mut end = start + 1;
        while end < chunk.len() && chunk[end].node as usize == node {
            end += 1;
        }
        let run = &chunk[start..end];
        let first = (node * sub).min(children.len());
        let last = ((node + 1) * sub).min(children.len());
        for (c, nb) in children[first..last].iter().enumerate() {
            let child = (first + c) as u32;
            tests += run.len() as u64;
            for p in run {
                if nb.may_hit(&tri_spheres[p.tri as usize]) {
                    cur.push(Candidate {
                        node: child,
                        tri: p.tri,
                    });
                }
            }
            if cur.len() >= CHUNK {
                cur.shrink_to_fit();
                out.push(std::mem::take(&mut cur));
            }
        }
        start = end;
    }
    if !cur.is_empty() {
        cur.shrink_to_fit();
        out.push(cur);
    }
    (out, tests)
}

impl Traverser<Cpu> for Crsh {
    fn name(&self) -> &str {
        "crsh"
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
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::intersect::brute::tests::{random_rays, soup, test_ray};
    use crate::intersect::brute::BruteForce;
    use crate::triangle::tests::TestRng;
    use crsh_core::glam::Vec3;
    use crsh_core::ParamValue;
    use crsh_core::{Cone, Hit, HitMode, Intersector, LevelStats, Query};
    use crsh_scene::bounding::min_sphere;
    use crsh_scene::{Camera, Material, SceneBuilder};

    /// `meshes` clusters of random triangles, one mesh each, spread over `[-4, 4]³`, so that
    /// mesh culling has something to cull.
    pub(crate) fn clustered(seed: u64, meshes: usize, per_mesh: usize) -> Scene {
        let mut rng = TestRng(seed);
        let mut b = SceneBuilder::new("clusters");
        let m = b.material(Material::default());
        b.camera(Camera {
            eye: Vec3::new(0.0, 0.0, 10.0),
            target: Vec3::ZERO,
            up: Vec3::Y,
            vfov_deg: 45.0,
            aspect: None,
        });
        for k in 0..meshes {
            let centre = rng.vec3(-4.0, 4.0);
            let mut positions = Vec::new();
            let mut indices = Vec::new();
            for i in 0..per_mesh {
                let a = centre + rng.vec3(-0.8, 0.8);
                let base = positions.len() as u32;
                positions.extend([a, a + rng.vec3(-0.4, 0.4), a + rng.vec3(-0.4, 0.4)]);
                indices.push([base, base + 1, base + 2]);
                if i % 11 == 0 {
                    // Exact ties.
                    indices.push([base, base + 2, base + 1]);
                }
            }
            b.mesh(format!("cluster{k}"), &positions, None, &indices, m);
        }
        b.build("clustered test scene").unwrap()
    }

    /// The brute-force test rays (outside, on surfaces, grazing, segments) plus coherent
    /// bundles: origins in a small ball, directions in a narrow cone, towards the scene.
    pub(crate) fn test_rays(scene: &Scene, seed: u64, n: usize) -> Vec<Ray> {
        let mut rays = random_rays(scene, seed, n / 2);
        let mut rng = TestRng(seed ^ 0x9e37);
        let target = scene.bounds.center();
        while rays.len() < n {
            let o = rng.vec3(-6.0, 6.0);
            let axis = (target + rng.vec3(-2.0, 2.0) - o).normalize_or(Vec3::X);
            for _ in 0..16.min(n - rays.len()) {
                let origin = o + rng.vec3(-0.05, 0.05);
                let dir = (axis + rng.vec3(-0.1, 0.1)).normalize_or(Vec3::X);
                let t_max = if rng.f32() < 0.3 {
                    rng.range(1.0, 8.0)
                } else {
                    f32::INFINITY
                };
                rays.push(test_ray(origin, dir, 0.0, t_max, rays.len()));
            }
        }
        rays
    }

    /// A correct (not tight) sphere-cone of some rays: the minimal sphere of the origins
    /// (rounded up) and a cone about the mean direction with the largest angle.
    pub(crate) fn bound(rays: &[Ray]) -> SphereCone {
        let origins: Vec<Vec3> = rays.iter().map(|r| r.origin).collect();
        let s = min_sphere(&origins);
        let c = s.center.as_dvec3();
        let far = origins
            .iter()
            .map(|o| o.as_dvec3().distance(c))
            .fold(s.radius as f64, f64::max);
        let dirs: Vec<DVec3> = rays.iter().map(|r| r.dir.as_dvec3().normalize()).collect();
        let mean: DVec3 = dirs.iter().sum();
        let (axis, angle) = if mean.length() < 1e-9 {
            (DVec3::X, std::f64::consts::PI)
        } else {
            let a = mean.normalize();
            let ang = dirs
                .iter()
                .map(|d| a.dot(*d).clamp(-1.0, 1.0).acos())
                .fold(0.0, f64::max);
            (a, (ang * (1.0 + 1e-6) + 1e-6).min(std::f64::consts::PI))
        };
        SphereCone {
            sphere: Sphere::new(s.center, (far * (1.0 + 1e-6)) as f32),
            cone: Cone {
                axis: axis.as_vec3(),
                half_angle: angle as f32,
            },
        }
    }

    /// A test-only bottom-up builder: node `n` of level `i` bounds the rays of leaves
    /// `n·s^(i+1) .. (n+1)·s^(i+1)` of `order`, computed directly from the rays.
    pub(crate) fn build(
        rays: &[Ray],
        order: Vec<u32>,
        sub: u32,
        levels: usize,
    ) -> RayHierarchy<Cpu> {
        let s = sub as usize;
        let mut out = Vec::new();
        let mut span = s;
        let mut count = rays.len().div_ceil(s);
        for _ in 0..levels {
            let level: Vec<SphereCone> = (0..count)
                .map(|n| {
                    let leaves = &order[n * span..((n + 1) * span).min(order.len())];
                    let rs: Vec<Ray> = leaves.iter().map(|&r| rays[r as usize]).collect();
                    bound(&rs)
                })
                .collect();
            out.push(level);
            span *= s;
            count = count.div_ceil(s);
        }
        RayHierarchy {
            leaf_offsets: None,
            order,
            levels: out,
            subdivision: sub,
            reach: vec![],
        }
    }

    pub(crate) fn shuffled(n: usize, seed: u64) -> Vec<u32> {
        let mut rng = TestRng(seed);
        let mut order: Vec<u32> = (0..n as u32).collect();
        for i in (1..n).rev() {
            order.swap(i, rng.next_u64() as usize % (i + 1));
        }
        order
    }

    /// Runs `traverse` (a traversal of `rays` over `h` for the ray kind it is given, handing
    /// its batches to the sink it is given) with brute-force candidate tests in `mode`;
    /// returns the hits, the batches' pairs, the stats and what `traverse` returned. Shared
    /// by the tests of every traverser.
    pub(crate) fn trace_with<R>(
        brute: &BruteForce,
        rays: &Vec<Ray>,
        h: &RayHierarchy<Cpu>,
        mode: HitMode,
        traverse: impl FnOnce(
            RayKind,
            &mut dyn FnMut(CandidateBatch<Cpu>, &mut Stats) -> Result<()>,
            &mut Stats,
        ) -> Result<R>,
    ) -> (Vec<Hit>, Vec<Vec<Candidate>>, Stats, R) {
        let kind = if mode == HitMode::Any {
            RayKind::Shadow
        } else {
            RayKind::Reflection
        };
        let mut hits = vec![Hit::MISS; rays.len()];
        let mut batches = Vec::new();
        let mut stats = Stats::default();
        let report = traverse(
            kind,
            &mut |batch, stats| {
                let q = Query::Candidates {
                    hierarchy: h,
                    batch: &batch,
                };
                brute.intersect(&Cpu, rays, q, mode, &mut hits, stats)?;
                batches.push(batch.pairs);
                Ok(())
            },
            &mut stats,
        )
        .unwrap();
        (hits, batches, stats, report)
    }

    /// [`trace_with`] for the `crsh` traverser `trav`.
    fn trace(
        trav: &Crsh,
        brute: &BruteForce,
        rays: &Vec<Ray>,
        h: &RayHierarchy<Cpu>,
        mode: HitMode,
    ) -> (Vec<Hit>, Vec<Vec<Candidate>>, Stats, TraversalReport) {
        trace_with(brute, rays, h, mode, |kind, sink, stats| {
            trav.traverse_with_report(rays, kind, h, sink, stats)
        })
    }

    pub(crate) fn reference(brute: &BruteForce, rays: &Vec<Ray>, mode: HitMode) -> Vec<Hit> {
        let mut hits = vec![Hit::MISS; rays.len()];
        brute
            .intersect(
                &Cpu,
                rays,
                Query::Scene,
                mode,
                &mut hits,
                &mut Stats::default(),
            )
            .unwrap();
        hits
    }

    pub(crate) fn assert_same(got: &[Hit], want: &[Hit], mode: HitMode, what: &str) {
        for (i, (g, w)) in got.iter().zip(want).enumerate() {
            match mode {
                HitMode::Closest => assert_eq!(g, w, "{what}: ray {i}"),
                HitMode::Any | HitMode::EdgeWidth(_) => {
                    assert_eq!(g.is_hit(), w.is_hit(), "{what}: ray {i}")
                }
            }
        }
    }

    #[test]
    fn traversal_gives_the_brute_force_hits() {
        let scenes = [
            (Arc::new(soup(3, 150)), "soup"),
            (Arc::new(clustered(4, 6, 30)), "clusters"),
        ];
        for (si, (scene, name)) in scenes.iter().enumerate() {
            let brute = BruteForce::from_scene(scene);
            let rays = test_rays(scene, 10 + si as u64, 230);
            let refs = [HitMode::Closest, HitMode::Any].map(|m| reference(&brute, &rays, m));
            let mut culled_some = false;
            for (sub, levels) in [(2u32, 3usize), (4, 1), (4, 2), (8, 2), (8, 3)] {
                for (oi, order) in [(0..rays.len() as u32).collect(), shuffled(rays.len(), 5)]
                    .into_iter()
                    .enumerate()
                {
                    let h = build(&rays, order, sub, levels);
                    for culling in [true, false] {
                        let trav = Crsh::with_options(scene, culling, 64.0).unwrap();
                        for (mode, want) in [HitMode::Closest, HitMode::Any].iter().zip(&refs) {
                            let (hits, batches, _, _) = trace(&trav, &brute, &rays, &h, *mode);
                            let what = format!(
                                "{name} sub {sub} levels {levels} order {oi} culling {culling} {mode:?}"
                            );
                            assert_same(&hits, want, *mode, &what);
                            let n: usize = batches.iter().map(Vec::len).sum();
                            culled_some |= n < h.levels[0].len() * scene.triangle_count();
                        }
                    }
                }
            }
            assert!(culled_some, "{name}: the traversal never culled anything");
            assert!(refs[0].iter().filter(|h| h.is_hit()).count() > rays.len() / 4);
        }
    }

    /// A test-only hierarchy with variable-size lowest nodes: node `k` of `levels[0]` bounds
    /// the leaves `offsets[k] .. offsets[k + 1]`, node `n` of level `i > 0` the leaves of its
    /// `sub^i` lowest descendants; every node is the [`bound`] of its rays.
    pub(crate) fn build_with_offsets(
        rays: &[Ray],
        order: Vec<u32>,
        offsets: Vec<u32>,
        sub: u32,
        levels: usize,
    ) -> RayHierarchy<Cpu> {
        let nodes0 = offsets.len() - 1;
        let mut out = Vec::new();
        let mut span = 1usize;
        let mut count = nodes0;
        for _ in 0..levels {
            let level: Vec<SphereCone> = (0..count)
                .map(|n| {
                    let a = offsets[(n * span).min(nodes0)] as usize;
                    let b = offsets[((n + 1) * span).min(nodes0)] as usize;
                    let rs: Vec<Ray> = order[a..b].iter().map(|&r| rays[r as usize]).collect();
                    bound(&rs)
                })
                .collect();
            out.push(level);
            span *= sub as usize;
            count = count.div_ceil(sub as usize);
        }
        RayHierarchy {
            leaf_offsets: Some(offsets),
            order,
            levels: out,
            subdivision: sub,
            reach: vec![],
        }
    }

    /// Cut points over `n` leaves: nodes of 1 to `widest` leaves.
    pub(crate) fn random_offsets(rng: &mut TestRng, n: usize, widest: usize) -> Vec<u32> {
        let mut offsets = vec![0u32];
        let mut at = 0usize;
        while at < n {
            at = (at + 1 + (rng.next_u64() % widest as u64) as usize).min(n);
            offsets.push(at as u32);
        }
        offsets
    }

    #[test]
    fn hierarchies_with_leaf_offsets_give_the_brute_force_hits() {
        let scene = Arc::new(clustered(61, 6, 30));
        let brute = BruteForce::from_scene(&scene);
        let rays = test_rays(&scene, 62, 300);
        let refs = [HitMode::Closest, HitMode::Any].map(|m| reference(&brute, &rays, m));
        let mut rng = TestRng(63);
        let offsets = random_offsets(&mut rng, rays.len(), 40);
        for (sub, levels) in [(4u32, 1usize), (4, 2), (3, 3)] {
            let h = build_with_offsets(
                &rays,
                shuffled(rays.len(), 64),
                offsets.clone(),
                sub,
                levels,
            );
            for culling in [true, false] {
                let trav = Crsh::with_options(&scene, culling, 0.05).unwrap();
                for (mode, want) in [HitMode::Closest, HitMode::Any].iter().zip(&refs) {
                    let (hits, batches, _, _) = trace(&trav, &brute, &rays, &h, *mode);
                    let what = format!("sub {sub} levels {levels} culling {culling} {mode:?}");
                    assert_same(&hits, want, *mode, &what);
                    let n: usize = batches.iter().map(Vec::len).sum();
                    assert!(n < h.levels[0].len() * scene.triangle_count(), "{what}");
                }
            }
        }
    }

    #[test]
    fn hit_and_spread_answers_as_may_hit_and_spreads_wider_than() {
        let mut rng = TestRng(81);
        let (mut hit, mut spread, mut culled) = (0, 0, 0);
        for i in 0..20_000 {
            // Narrow, wide (beyond π/2) and full cones; point and ball origins; some reaches.
            let half_angle = match i % 4 {
                0 => rng.range(0.0, 0.05),
                1 => rng.range(0.0, 1.5),
                2 => rng.range(1.6, 3.1),
                _ => 3.2,
            };
            let node = SphereCone {
                sphere: Sphere::new(rng.vec3(-5.0, 5.0), rng.range(0.0, 2.0) * (i % 3) as f32),
                cone: Cone {
                    axis: rng.unit(),
                    half_angle,
                },
            };
            let mut b = NodeBound::new(&node).unwrap();
            if i % 5 == 0 {
                b = b.with_reach(rng.range(0.0, 10.0));
            }
            let s = Sphere::new(rng.vec3(-10.0, 10.0), rng.range(0.0, 4.0));
            let want = b.may_hit(&s).then(|| b.spreads_wider_than(&s));
            assert_eq!(b.hit_and_spread(&s), want, "{node:?} {s:?}");
            match want {
                Some(true) => spread += 1,
                Some(false) => hit += 1,
                None => culled += 1,
            }
        }
        // Every outcome occurs.
        assert!(
            hit > 100 && spread > 100 && culled > 100,
            "{hit} {spread} {culled}"
        );
    }

    #[test]
    fn apex_cones_of_radius_zero_and_full_cones_are_accepted() {
        let apex = |alpha: f32| {
            NodeBound::new(&SphereCone {
                sphere: Sphere::new(Vec3::ZERO, 0.0),
                cone: Cone {
                    axis: Vec3::Z,
                    half_angle: alpha,
                },
            })
            .unwrap()
        };
        let behind = Sphere::new(Vec3::new(0.0, 0.0, -10.0), 1.0);
        let ahead = Sphere::new(Vec3::new(0.0, 0.0, 10.0), 1.0);
        // The paper's test: φ > arccos((v − a)·x / |v − a|) − arcsin(r / |v − a|).
        assert!(apex(0.0).may_hit(&ahead));
        assert!(!apex(0.0).may_hit(&behind));
        let off = Sphere::new(
            Vec3::new(10.0 * 0.2f32.sin(), 0.0, 10.0 * 0.2f32.cos()),
            1.0,
        );
        // asin(0.1) ≈ 0.1002: needs φ above ≈ 0.0998.
        assert!(apex(0.11).may_hit(&off));
        assert!(!apex(0.09).may_hit(&off));
        // A sphere containing the apex is a hit whatever the direction.
        assert!(apex(0.0).may_hit(&Sphere::new(Vec3::new(0.0, 0.0, -0.5), 1.0)));
        // Half-angle π: every sphere, but still limited by the reach.
        let full = apex(std::f32::consts::PI);
        assert!(full.may_hit(&behind));
        assert!(!full.with_reach(5.0).may_hit(&behind));
        assert!(full.with_reach(9.5).may_hit(&behind));
    }

    /// A uniform direction within the cone `(axis, alpha)`.
    fn dir_in_cone(rng: &mut TestRng, axis: DVec3, alpha: f64) -> DVec3 {
        let (u, v) = axis.any_orthonormal_pair();
        // Uniform in the spherical cap: cos θ uniform in [cos α, 1].
        let cos_t = 1.0 - rng.f32() as f64 * (1.0 - alpha.cos());
        let sin_t = (1.0 - cos_t * cos_t).max(0.0).sqrt();
        let phi = rng.f32() as f64 * std::f64::consts::TAU;
        axis * cos_t + (u * phi.cos() + v * phi.sin()) * sin_t
    }

    /// Whether the half-line `o + t·d`, `t ≥ 0`, meets the sphere `(p, r)` (f64).
    fn half_line_hits(o: DVec3, d: DVec3, p: DVec3, r: f64) -> bool {
        let d = d.normalize();
        let t = (p - o).dot(d).max(0.0);
        (o + d * t).distance(p) <= r
    }

    #[test]
    fn node_test_never_culls_a_sampled_hit() {
        let mut rng = TestRng(77);
        let (mut hit_cases, mut culls) = (0, 0);
        for case in 0..3000 {
            let c = rng.vec3(-3.0, 3.0);
            let r = if case % 5 == 0 {
                0.0
            } else {
                rng.range(0.0, 1.0)
            };
            let axis = rng.unit();
            // Narrow, medium, right-angle and wide cones (up to the whole sphere).
            let alpha = match case % 6 {
                0 => 0.0,
                1 => rng.range(0.0, 0.1),
                2 => rng.range(0.1, 1.2),
                3 => std::f32::consts::FRAC_PI_2,
                4 => rng.range(1.6, 3.0),
                _ => rng.range(0.0, std::f32::consts::PI),
            };
            let node = SphereCone {
                sphere: Sphere::new(c, r),
                cone: Cone {
                    axis,
                    half_angle: alpha,
                },
            };
            let nb = NodeBound::new(&node).unwrap();
            // Half the spheres near the cone's boundary (grazing), half anywhere.
            let centre = if case % 2 == 0 {
                let d = dir_in_cone(
                    &mut rng,
                    axis.as_dvec3(),
                    (alpha as f64 * 1.1 + 0.05).min(3.1),
                );
                c + d.as_vec3() * rng.range(0.5, 5.0)
            } else {
                rng.vec3(-4.0, 4.0)
            };
            let sphere = Sphere::new(centre, rng.range(0.0, 0.8));
            let pass = nb.may_hit(&sphere);
            culls += !pass as usize;
            let (p, pr) = (sphere.center.as_dvec3(), sphere.radius as f64);
            for _ in 0..64 {
                // Origins in the ball (some on its boundary), directions in the cone (some
                // on its boundary).
                let o = c.as_dvec3()
                    + rng.unit().as_dvec3()
                        * r as f64
                        * if rng.f32() < 0.3 {
                            1.0
                        } else {
                            rng.f32() as f64
                        };
                let a = if rng.f32() < 0.3 {
                    alpha as f64
                } else {
                    alpha as f64 * rng.f32() as f64
                };
                let d = dir_in_cone(&mut rng, axis.as_dvec3(), a);
                if half_line_hits(o, d, p, pr) {
                    hit_cases += 1;
                    assert!(
                        pass,
                        "case {case}: {node:?} culls {sphere:?} hit by o {o} d {d}"
                    );
                }
            }
        }
        assert!(
            hit_cases > 1000 && culls > 300,
            "{hit_cases} hits, {culls} culls"
        );
    }

    #[test]
    fn node_test_known_cases() {
        let node = |axis: Vec3, alpha: f32| {
            NodeBound::new(&SphereCone {
                sphere: Sphere::new(Vec3::ZERO, 0.5),
                cone: Cone {
                    axis,
                    half_angle: alpha,
                },
            })
            .unwrap()
        };
        let ahead = Sphere::new(Vec3::new(0.0, 0.0, 10.0), 1.0);
        let behind = Sphere::new(Vec3::new(0.0, 0.0, -10.0), 1.0);
        let side = Sphere::new(Vec3::new(10.0, 0.0, 0.0), 1.0);
        let narrow = node(Vec3::Z, 0.01);
        assert!(narrow.may_hit(&ahead));
        assert!(!narrow.may_hit(&behind));
        assert!(!narrow.may_hit(&side));
        // asin(1.5 / 10) ≈ 0.1506: a cone of 0.05 rad reaches a sphere 0.19 rad off axis.
        let off = Sphere::new(
            Vec3::new(10.0 * 0.19f32.sin(), 0.0, 10.0 * 0.19f32.cos()),
            1.0,
        );
        assert!(node(Vec3::Z, 0.05).may_hit(&off));
        assert!(!node(Vec3::Z, 0.03).may_hit(&off));
        // Right-angle and wide cones: the side passes, behind only when wide enough.
        let half = node(Vec3::Z, std::f32::consts::FRAC_PI_2);
        assert!(half.may_hit(&side));
        assert!(!half.may_hit(&behind));
        let wide = node(Vec3::Z, 3.0);
        assert!(wide.may_hit(&behind), "α + asin(0.15) > π");
        assert!(!node(Vec3::Z, 2.9).may_hit(&behind), "α + asin(0.15) < π");
        // A sphere around the origins always passes.
        assert!(narrow.may_hit(&Sphere::new(Vec3::new(0.0, 0.0, -1.0), 0.6)));
    }

    #[test]
    fn small_budgets_split_batches_and_stay_within_budget() {
        let scene = Arc::new(clustered(8, 4, 25));
        let brute = BruteForce::from_scene(&scene);
        let rays = test_rays(&scene, 9, 150);
        let h = build(&rays, shuffled(rays.len(), 3), 4, 2);
        let lowest = h.levels[0].len() as f64;
        let big = Crsh::with_options(&scene, true, 64.0).unwrap();
        let mib = (1u64 << 20) as f64;
        for mode in [HitMode::Closest, HitMode::Any] {
            let want = reference(&brute, &rays, mode);
            let (h_big, b_big, s_big, r_big) = trace(&big, &brute, &rays, &h, mode);
            assert_eq!((r_big.batches, r_big.retries), (1, 0));
            assert_eq!(r_big.batch_triangles, scene.triangle_count());
            assert_same(&h_big, &want, mode, "big");
            let mut all_big: Vec<Candidate> = b_big.concat();
            all_big.sort_unstable();
            // 1.5 × the one-triangle worst case (tiny), and ten triangles' worth.
            for factor in [1.5, 10.5] {
                let trav = Crsh::with_options(&scene, true, factor * 16.0 * lowest / mib).unwrap();
                let (hits, batches, stats, report) = trace(&trav, &brute, &rays, &h, mode);
                assert!(report.batches > 1 && report.retries > 0, "{report:?}");
                assert!(report.batch_triangles < scene.triangle_count());
                assert!(
                    report.peak_candidate_bytes <= trav.budget_bytes(),
                    "{report:?}"
                );
                assert!(report.peak_candidate_bytes > 0);
                assert_same(&hits, &want, mode, "small budget");
                // The same candidates overall, only split by triangle range.
                let mut all: Vec<Candidate> = batches.concat();
                all.sort_unstable();
                assert_eq!(all, all_big);
                assert_eq!(report.candidates as usize, all.len());
                // The level rows account for every bounds test (mesh culling apart), and
                // per level they hold at least the unbatched tests: the batches partition
                // the triangles, and abandoned attempts add the tests they did.
                let node_rows = |s: &Stats| -> Vec<LevelStats> {
                    s.levels.iter().filter(|l| l.level > 0).cloned().collect()
                };
                let mesh_tests = |s: &Stats| s.mesh_culling.values().map(|c| c.tests).sum::<u64>();
                for st in [&stats, &s_big] {
                    let rows: u64 = node_rows(st).iter().map(|l| l.tests).sum();
                    assert_eq!(rows + mesh_tests(st), st.tests.bounds);
                }
                let (small_rows, big_rows) = (node_rows(&stats), node_rows(&s_big));
                assert_eq!(small_rows.len(), big_rows.len());
                for b in &big_rows {
                    let r = small_rows.iter().find(|r| r.level == b.level).unwrap();
                    assert!(r.tests >= b.tests, "{r:?} vs {b:?}");
                }
                if report.retries == 0 {
                    assert_eq!(small_rows, big_rows);
                }
                assert!(stats.tests.bounds > s_big.tests.bounds);
            }
        }
    }

    #[test]
    fn same_output_for_any_thread_count() {
        let scene = Arc::new(clustered(21, 5, 40));
        let brute = BruteForce::from_scene(&scene);
        let rays = test_rays(&scene, 22, 400);
        let h = build(&rays, shuffled(rays.len(), 23), 4, 3);
        let trav = Crsh::with_options(&scene, true, 0.01).unwrap();
        for mode in [HitMode::Closest, HitMode::Any] {
            let run = || trace(&trav, &brute, &rays, &h, mode);
            let (h1, b1, s1, r1) = crate::with_threads(1, run).unwrap();
            let (h3, b3, s3, r3) = crate::with_threads(3, run).unwrap();
            assert!(r1.batches > 1);
            assert_eq!(h1, h3);
            assert_eq!(b1, b3);
            assert_eq!(s1.levels, s3.levels);
            assert_eq!(s1.tests, s3.tests);
            assert_eq!(r1, r3);
            // Every batch is sorted by (node, triangle) without duplicates.
            for b in &b1 {
                assert!(b.windows(2).all(|w| w[0] < w[1]));
            }
        }
    }

    #[test]
    fn level_counters_follow_the_survivors() {
        let scene = Arc::new(clustered(31, 5, 20));
        let brute = BruteForce::from_scene(&scene);
        // 203 rays: partial nodes at every level.
        let rays = test_rays(&scene, 32, 203);
        for culling in [true, false] {
            let h = build(&rays, shuffled(rays.len(), 33), 4, 3);
            let trav = Crsh::with_options(&scene, culling, 64.0).unwrap();
            let (_, batches, stats, _) = trace(&trav, &brute, &rays, &h, HitMode::Closest);
            let nodes: Vec<Vec<NodeBound>> = h
                .levels
                .iter()
                .map(|l| l.iter().map(|n| NodeBound::new(n).unwrap()).collect())
                .collect();
            let top = nodes.len();
            let row = |level: usize| {
                stats
                    .levels
                    .iter()
                    .find(|l| l.level == level as u32 && l.ray_kind == "reflection")
                    .cloned()
            };
            for l in &stats.levels {
                assert_eq!(l.tests, l.hits + l.misses, "{l:?}");
            }
            // Independent naive traversal: sets of (node, tri) per level.
            let n_tris = scene.triangle_count();
            let mut bounds_tests = 0u64;
            let mut kept: Vec<(usize, usize)> = Vec::new();
            for (n, nb) in nodes[top - 1].iter().enumerate() {
                for (m, mesh) in scene.meshes.iter().enumerate() {
                    if !culling || nb.may_hit(&mesh.sphere) {
                        kept.push((n, m));
                    }
                }
            }
            assert!(row(top + 1).is_none(), "mesh culling is not a level");
            if culling {
                let r = &stats.mesh_culling["reflection"];
                let want = (nodes[top - 1].len() * scene.meshes.len()) as u64;
                assert_eq!((r.tests, r.hits), (want, kept.len() as u64));
                assert_eq!(r.tests, r.hits + r.misses);
                bounds_tests += want;
            } else {
                assert!(stats.mesh_culling.is_empty());
            }
            let mut tests = 0u64;
            let mut culled = 0u64;
            let mut level: Vec<(usize, usize)> = Vec::new();
            for &(n, m) in &kept {
                let mesh = &scene.meshes[m];
                for t in mesh.first_tri as usize..(mesh.first_tri + mesh.tri_count) as usize {
                    tests += 1;
                    if nodes[top - 1][n].may_hit(&scene.tri_spheres[t]) {
                        level.push((n, t));
                    }
                }
            }
            if !culling {
                assert_eq!(tests, (nodes[top - 1].len() * n_tris) as u64);
            }
            let r = row(top).unwrap();
            assert_eq!((r.tests, r.hits), (tests, level.len() as u64));
            bounds_tests += tests;
            for li in (0..top - 1).rev() {
                let mut next = Vec::new();
                let mut tests = 0u64;
                for &(n, t) in &level {
                    let kids = n * 4..((n + 1) * 4).min(nodes[li].len());
                    tests += kids.len() as u64;
                    for (c, child) in kids.clone().zip(&nodes[li][kids]) {
                        if child.may_hit(&scene.tri_spheres[t]) {
                            next.push((c, t));
                        }
                    }
                }
                let r = row(li + 1).unwrap();
                assert_eq!(r.tests, tests, "level {}", li + 1);
                assert_eq!(r.hits, next.len() as u64, "level {}", li + 1);
                culled += r.misses;
                bounds_tests += tests;
                level = next;
            }
            assert!(culled > 0, "the lower levels cull nothing");
            assert_eq!(stats.tests.bounds, bounds_tests);
            let mut got: Vec<(usize, usize)> = batches
                .concat()
                .iter()
                .map(|c| (c.node as usize, c.tri as usize))
                .collect();
            got.sort_unstable();
            level.sort_unstable();
            assert_eq!(got, level);
            // The final tests are level 0 (recorded by the intersector).
            let r0 = row(0).unwrap();
            assert_eq!(r0.tests, stats.tests.ray_triangle);
            assert_eq!(r0.tests, r0.hits + r0.misses);
        }
    }

    #[test]
    fn sphere_cone_builder_hierarchies_give_the_brute_force_hits() {
        use crate::hierarchy::sphere_cone::SphereConeBuilder;
        let scene = Arc::new(clustered(71, 6, 30));
        let brute = BruteForce::from_scene(&scene);
        let rays = test_rays(&scene, 72, 300);
        let refs = [HitMode::Closest, HitMode::Any].map(|m| reference(&brute, &rays, m));
        for (sub, depth) in [(2u32, 3u32), (4, 1), (4, 3), (8, 2)] {
            let builder = SphereConeBuilder::with_params(sub, depth).unwrap();
            let order = shuffled(rays.len(), 73);
            let levels = builder.build_levels(&rays, &order).unwrap();
            let h = RayHierarchy::<Cpu> {
                leaf_offsets: None,
                reach: crate::hierarchy::sphere_cone::reach_levels(&rays, &order, &levels, sub),
                levels,
                order,
                subdivision: sub,
            };
            for culling in [true, false] {
                let trav = Crsh::with_options(&scene, culling, 0.05).unwrap();
                for (mode, want) in [HitMode::Closest, HitMode::Any].iter().zip(&refs) {
                    let (hits, _, _, _) = trace(&trav, &brute, &rays, &h, *mode);
                    let what = format!("sub {sub} depth {depth} culling {culling} {mode:?}");
                    assert_same(&hits, want, *mode, &what);
                }
            }
        }
    }

    #[test]
    fn frames_with_crsh_traversal_equal_brute_force_frames() {
        use crate::hierarchy::sphere_cone::SphereConeBuilder;
        use crsh_core::{render_frame, FrameOptions, FrameSize, PipelineConfig, StageContext};
        let scene = Arc::new(crsh_scene::builtin::build("office-boxes").unwrap());
        let cfg = PipelineConfig::whitted("brute", "brute");
        let registry = Registry::<Cpu>::builtin();
        let ctx = StageContext::new(&Cpu, &scene, FrameSize::new(40, 30).unwrap());
        let opts = FrameOptions::default().with_max_depth(2);
        let plain = registry.build(&ctx, &cfg).unwrap();
        let want = render_frame(&Cpu, &plain, &opts, None, &mut |_| {}).unwrap();
        let reference = BruteForce::from_scene(&scene);
        for (culling, budget_mb) in [(true, 64.0), (false, 0.05)] {
            // A library user's swap: stages the registry did not build go into a built pipeline,
            // and the frame's stats name what ran.
            let mut pipeline = registry.build(&ctx, &cfg).unwrap();
            pipeline.stages.hierarchy =
                Some(Box::new(SphereConeBuilder::with_params(4, 3).unwrap()));
            pipeline.stages.traverser = Some(Box::new(
                Crsh::with_options(&scene, culling, budget_mb).unwrap(),
            ));
            let got = render_frame(&Cpu, &pipeline, &opts, Some(&reference), &mut |_| {}).unwrap();
            assert_eq!(got.stats.stages["hierarchy"], "sphere_cone");
            assert_eq!(got.stats.stages["traverse"], "crsh");
            assert!(!got.stats.stages.contains_key("hash"));
            assert_eq!(got.image, want.image, "culling {culling}");
            let acc = got.stats.accuracy.clone().unwrap();
            assert!(acc.rays > 0);
            assert_eq!(acc.agreeing, acc.rays, "{acc:?}");
            // Fewer ray-triangle tests than brute force, and per-level rows for both kinds.
            let s = &got.stats;
            assert!(s.tests.ray_triangle < s.tests.brute_force, "{:?}", s.tests);
            for kind in ["shadow", "reflection"] {
                assert!(s.levels.iter().any(|l| l.ray_kind == kind && l.level == 0));
                assert!(s.levels.iter().any(|l| l.ray_kind == kind && l.level == 3));
            }
        }
    }

    #[test]
    fn bad_input_is_an_error() {
        let scene = Arc::new(soup(41, 20));
        let rays = random_rays(&scene, 42, 20);
        let trav = Crsh::with_options(&scene, true, 1.0).unwrap();
        let good = build(&rays, (0..20).collect(), 4, 2);
        let mut nan = build(&rays, (0..20).collect(), 4, 2);
        nan.levels[1][0].sphere.radius = f32::NAN;
        let mut zero_axis = build(&rays, (0..20).collect(), 4, 2);
        zero_axis.levels[0][1].cone = Cone {
            axis: Vec3::ZERO,
            half_angle: 0.5,
        };
        let mut negative = build(&rays, (0..20).collect(), 4, 1);
        negative.levels[0][0].cone.half_angle = -0.1;
        let cases = [
            RayHierarchy {
                leaf_offsets: None,
                subdivision: 0,
                ..build(&rays, (0..20).collect(), 4, 1)
            },
            RayHierarchy {
                leaf_offsets: None,
                levels: vec![],
                ..build(&rays, (0..20).collect(), 4, 1)
            },
            RayHierarchy {
                leaf_offsets: None,
                order: (0..19).collect(),
                ..build(&rays, (0..20).collect(), 4, 1)
            },
            RayHierarchy {
                leaf_offsets: None,
                levels: vec![good.levels[0].clone(), good.levels[0].clone()],
                ..build(&rays, (0..20).collect(), 4, 1)
            },
            nan,
            zero_axis,
            negative,
            // Leaf offsets: level 0 not offsets − 1 nodes long, bad contents, no entry.
            RayHierarchy {
                leaf_offsets: Some(vec![0, 10, 20]),
                ..build(&rays, (0..20).collect(), 4, 1)
            },
            RayHierarchy {
                leaf_offsets: Some(vec![0, 5, 4, 15, 20]),
                ..build(&rays, (0..20).collect(), 4, 1)
            },
            RayHierarchy {
                leaf_offsets: Some(vec![0, 5, 10, 15, 19]),
                ..build(&rays, (0..20).collect(), 4, 1)
            },
            RayHierarchy {
                leaf_offsets: Some(vec![]),
                ..build(&rays, (0..20).collect(), 4, 1)
            },
            RayHierarchy {
                leaf_offsets: Some(vec![0, 5, 10, 15, 20]),
                subdivision: 0,
                ..build(&rays, (0..20).collect(), 4, 2)
            },
        ];
        for (i, h) in cases.iter().enumerate() {
            let r = trav.traverse(
                &Cpu,
                &rays,
                RayKind::Reflection,
                h,
                &mut |_, _| Ok(()),
                &mut Stats::default(),
            );
            assert!(
                matches!(r, Err(CoreError::InvalidInput(_))),
                "case {i}: {r:?}"
            );
        }
        // The whole sphere of directions needs no axis.
        let mut all = build(&rays, (0..20).collect(), 4, 1);
        all.levels[0][0].cone = Cone {
            axis: Vec3::ZERO,
            half_angle: std::f32::consts::PI,
        };
        let mut n = 0;
        trav.traverse(
            &Cpu,
            &rays,
            RayKind::Reflection,
            &all,
            &mut |b, _| {
                n += b.pairs.iter().filter(|c| c.node == 0).count();
                Ok(())
            },
            &mut Stats::default(),
        )
        .unwrap();
        assert!(n > 0);
        for mb in [0.0, -1.0, f64::NAN, f64::INFINITY] {
            assert!(matches!(
                Crsh::with_options(&scene, true, mb),
                Err(CoreError::InvalidParam { .. })
            ));
        }
    }

    #[test]
    fn constructor_reads_the_resolved_spec() {
        let scene = Arc::new(soup(51, 10));
        let info = info();
        assert_eq!((info.stage, info.name), (StageKind::Traverse, "crsh"));
        let mut spec = StageSpec::new("crsh");
        for p in &info.params {
            spec.params.insert(p.name.to_string(), p.default.clone());
        }
        let t = Crsh::new(&scene, &spec).unwrap();
        assert!(t.mesh_culling());
        assert_eq!(t.budget_bytes(), 64 << 20);
        assert_eq!(t.name(), "crsh");
        spec.params
            .insert("candidate_budget_mb".into(), ParamValue::Int(0));
        assert!(Crsh::new(&scene, &spec).is_err());
        spec.params
            .insert("candidate_budget_mb".into(), ParamValue::Int(2));
        spec.params
            .insert("mesh_culling".into(), ParamValue::Bool(false));
        let t = Crsh::new(&scene, &spec).unwrap();
        assert!(!t.mesh_culling());
        assert_eq!(t.budget_bytes(), 2 << 20);
        spec.params.remove("mesh_culling");
        assert!(Crsh::new(&scene, &spec).is_err());
    }

    /// How often `trav` calls its sink for a batch without rays (an empty hierarchy); it
    /// must succeed. Shared by the tests of every traverser.
    pub(crate) fn sink_calls_without_rays(trav: &dyn Traverser<Cpu>) -> usize {
        let h = RayHierarchy::<Cpu> {
            leaf_offsets: None,
            order: vec![],
            levels: vec![vec![]],
            subdivision: 4,
            reach: vec![],
        };
        let mut calls = 0;
        trav.traverse(
            &Cpu,
            &Vec::new(),
            RayKind::Shadow,
            &h,
            &mut |_, _| {
                calls += 1;
                Ok(())
            },
            &mut Stats::default(),
        )
        .unwrap();
        calls
    }

    #[test]
    fn empty_rays_call_no_sink() {
        let scene = Arc::new(soup(61, 10));
        let trav = Crsh::with_options(&scene, true, 1.0).unwrap();
        assert_eq!(sink_calls_without_rays(&trav), 0);
    }
}
