//! The stage traits of seed 000's pipeline (fig. 3.1).
//!
//! Each trait is generic over a [`Backend`] so a stage variant is written once per backend
//! and the frame driver ([`crate::render_frame`]) never sees where the data lives. Stage
//! objects are built by a [`crate::Registry`] from a [`crate::PipelineConfig`] and a
//! [`crate::StageContext`] (the backend, the scene, the frame size); a stage keeps what it needs
//! of them (triangles, BVH, materials, camera, lights, image width), so the methods take only
//! the per-batch buffers. Every method feeds [`Stats`] with the work it
//! did (tests, levels); the driver records wall time per stage.

use bytemuck::{Pod, Zeroable};

use crate::backend::Backend;
use crate::bounds::SphereCone;
use crate::error::Result;
use crate::ray::{Hit, HitMode, Ray, RayKind, Surface};
use crate::registry::StageContext;
use crate::stats::Stats;

/// Stage 1: primary visibility. Rasterization in the thesis (§3.1), or ray casting.
///
/// Writes the G-buffer: one [`Surface`] per pixel in row-major order (`y * width + x`, `y = 0`
/// the top row), with [`crate::NO_HIT`] where the background is seen.
pub trait PrimaryVisibility<B: Backend>: Send + Sync {
    /// Variant name (`raster`, `raycast`).
    fn name(&self) -> &str;
    /// Whether this variant traces camera rays through an intersector (ray casting) rather
    /// than rasterizing. The driver then counts the camera rays as traced work: in
    /// [`Stats::traced_rays`], in `tests.brute_force`, and with the stage's time as the
    /// primary kind's trace time.
    fn casts_rays(&self) -> bool {
        false
    }
    /// Renders the G-buffer at `width × height`.
    fn gbuffer(
        &self,
        backend: &B,
        width: u32,
        height: u32,
        stats: &mut Stats,
    ) -> Result<B::Buffer<Surface>>;
    /// [`PrimaryVisibility::gbuffer`] in a pipeline whose intersector is `intersector`: what
    /// the frame driver calls. A ray-casting variant may trace its camera rays with it (seed
    /// 003's coherent traversals of camera rays are the intersector's); the default ignores
    /// it.
    fn gbuffer_with(
        &self,
        backend: &B,
        width: u32,
        height: u32,
        intersector: &dyn Intersector<B>,
        stats: &mut Stats,
    ) -> Result<B::Buffer<Surface>> {
        let _ = intersector;
        self.gbuffer(backend, width, height, stats)
    }
}

/// Secondary ray creation (seed 000 §3.2.3, eq. 3.1-3.7; seed 001's AO and diffuse rays).
///
/// A variant names the kinds it makes: at every path vertex the driver asks for one batch of
/// [`RayGen::visibility_kind`] (any hit; [`Shader::shade_direct`] turns them into light), then
/// one batch per [`RayGen::bounce_kinds`] entry (nearest hit; [`Shader::resolve`] turns them
/// into the next vertices), up to the frame's bounce depth.
pub trait RayGen<B: Backend>: Send + Sync {
    /// Variant name.
    fn name(&self) -> &str;
    /// The any-hit kind shaded at every vertex: shadow rays (the default) or ambient-occlusion
    /// rays.
    fn visibility_kind(&self) -> RayKind {
        RayKind::Shadow
    }
    /// The hit query the driver traces the [`RayGen::visibility_kind`] batch with:
    /// [`HitMode::Any`] (the default: binary visibility), or [`HitMode::EdgeWidth`] for
    /// edge-width soft shadows (seed 003 §5; the `whitted` generator with `shadow =
    /// edge_width`). Never [`HitMode::Closest`].
    fn visibility_mode(&self) -> HitMode {
        HitMode::Any
    }
    /// The nearest-hit kinds that continue paths, in batch order: reflection and refraction
    /// (the default, Whitted), diffuse bounces, or none (paths end at the first vertex).
    fn bounce_kinds(&self) -> &[RayKind] {
        &[RayKind::Reflection, RayKind::Refraction]
    }
    /// Bytes of the tables the generator keeps for the scene (seed 001's hemisphere sets);
    /// 0 by default. Reported with the stage's build ([`crate::StageBuild::bytes`]).
    fn table_bytes(&self) -> u64 {
        0
    }
    /// The rays of one `kind` spawned by `surfaces`, compacted (no empty slots), in surface
    /// order; shadow rays light-major (all rays of light 0 in surface order, then light 1, ...).
    /// `Ray::source` indexes `surfaces`.
    fn generate(
        &self,
        backend: &B,
        surfaces: &B::Buffer<Surface>,
        kind: RayKind,
        stats: &mut Stats,
    ) -> Result<B::Buffer<Ray>>;
}

/// Ray indexing (seed 000 §3.2.3, figs 3.8-3.9): one sort key per ray.
pub trait Hasher<B: Backend>: Send + Sync {
    /// Variant name.
    fn name(&self) -> &str;
    /// Significant low bits of the keys this hasher writes (≤ 64); sorters may sort only these.
    fn key_bits(&self) -> u32;
    /// One key per ray of the batch `rays`, same order; every ray of a batch is of `kind`
    /// (hashers with per-kind layouts, such as the thesis's, pick the layout by it).
    fn hash(
        &self,
        backend: &B,
        rays: &B::Buffer<Ray>,
        kind: RayKind,
        stats: &mut Stats,
    ) -> Result<B::Buffer<u64>>;
}

/// Ray sorting (compress / sort / decompress, seed 000 §3.2.4-3.2.6).
pub trait Sorter<B: Backend>: Send + Sync {
    /// Variant name.
    fn name(&self) -> &str;
    /// The permutation that orders rays by key, stably: `order[i]` is the index of the ray
    /// that goes to position `i`.
    fn sort(
        &self,
        backend: &B,
        keys: &B::Buffer<u64>,
        key_bits: u32,
        stats: &mut Stats,
    ) -> Result<B::Buffer<u32>>;
}

/// A bottom-up ray-space hierarchy over one batch of rays (seed 000 §3.2.7).
pub struct RayHierarchy<B: Backend> {
    /// Rays in hierarchy order: leaf `i` is ray `order[i]` of the batch.
    pub order: B::Buffer<u32>,
    /// Node levels, lowest first: `levels[0]` groups rays into nodes (`subdivision` leaves
    /// per node, or the ranges of [`RayHierarchy::leaf_offsets`]), each higher level groups
    /// `subdivision` nodes of the level below. The last entry is the top level.
    ///
    /// A node bounds every point its rays reach: with sphere `(c, r)` and cone `(a, α)`, each
    /// point `o + t·d` of a ray in its interval (`t ≥ max(0, t_min)`) lies in the sphere plus
    /// the cone of apex `c` (`c + v + s·u`, `|v| ≤ r`, `s ≥ 0`, `angle(u, a) ≤ α`). A sphere-cone
    /// (origins in the sphere, directions in the cone, seed 000 §3.2.7) is one such node; an
    /// apex cone containing whole ray segments (seed 004 §4, sphere radius 0 at the apex) is
    /// another. Traversals may rely on nothing else.
    pub levels: Vec<B::Buffer<SphereCone>>,
    /// Children per node of the levels above `levels[0]`, and leaves per `levels[0]` node when
    /// [`RayHierarchy::leaf_offsets`] is `None`.
    pub subdivision: u32,
    /// Variable-size lowest nodes: `levels[0]` node `i` holds the leaves
    /// `leaf_offsets[i] .. leaf_offsets[i + 1]` (positions in `order`), so the buffer has
    /// `levels[0].len() + 1` non-decreasing entries from 0 to the ray count. `None`: node `i`
    /// holds `i·subdivision .. min((i + 1)·subdivision, rays)` (the fixed groups of seed 000).
    /// Seed 004's tile cones need it: after compaction a screen tile holds any number of rays.
    pub leaf_offsets: Option<B::Buffer<u32>>,
    /// Per level (indexed like `levels`), per node: an upper bound on the distance from the
    /// node's sphere centre to any point its rays reach within their `(t_min, t_max)`
    /// (`f32::INFINITY` when a ray is unbounded). Lets traversal cull geometry beyond the
    /// end of finite rays, such as shadow segments. Empty: no bound is known.
    pub reach: Vec<B::Buffer<f32>>,
}

/// The leaves (positions in [`RayHierarchy::order`]) of node `node` of `levels[0]` in a
/// hierarchy over `leaves` rays: `leaf_offsets[node] .. leaf_offsets[node + 1]` when the
/// hierarchy has [`RayHierarchy::leaf_offsets`], else the fixed group
/// `node·subdivision .. min((node + 1)·subdivision, leaves)`.
///
/// The one definition every consumer that maps a lowest node to its rays uses. It never
/// panics: both ends are clamped to `leaves`, the end to at least the start, and a node past
/// the end of the offsets is empty, so offsets that [`check_leaf_offsets`] would refuse give
/// wrong ranges, not out-of-bounds slices. Check the offsets once per hierarchy for an error.
pub fn lowest_node_leaves(
    node: usize,
    subdivision: u32,
    leaf_offsets: Option<&[u32]>,
    leaves: usize,
) -> std::ops::Range<usize> {
    let (start, end) = match leaf_offsets {
        Some(offsets) => (
            offsets.get(node).map_or(leaves, |&o| o as usize),
            offsets
                .get(node.saturating_add(1))
                .map_or(leaves, |&o| o as usize),
        ),
        None => {
            let s = subdivision as usize;
            (
                node.saturating_mul(s),
                node.saturating_add(1).saturating_mul(s),
            )
        }
    };
    let start = start.min(leaves);
    start..end.clamp(start, leaves)
}

/// Checks [`RayHierarchy::leaf_offsets`] against a lowest level of `nodes` nodes over
/// `leaves` rays: `nodes + 1` entries, the first 0, the last `leaves`, non-decreasing.
///
/// # Errors
/// [`CoreError::InvalidInput`](crate::CoreError::InvalidInput) naming the first violation.
pub fn check_leaf_offsets(offsets: &[u32], nodes: usize, leaves: usize) -> Result<()> {
    let bad = |what: String| {
        Err(crate::CoreError::InvalidInput(format!(
            "hierarchy leaf offsets {what}"
        )))
    };
    if offsets.len() != nodes.saturating_add(1) {
        return bad(format!(
            "have {} entries for {nodes} lowest nodes (expected {})",
            offsets.len(),
            nodes.saturating_add(1)
        ));
    }
    if offsets[0] != 0 {
        return bad(format!("start at {}, not 0", offsets[0]));
    }
    let last = offsets[nodes] as usize;
    if last != leaves {
        return bad(format!("end at {last}, not at the ray count {leaves}"));
    }
    if let Some(i) = offsets.windows(2).position(|w| w[1] < w[0]) {
        return bad(format!(
            "decrease at node {i} ({} then {})",
            offsets[i],
            offsets[i + 1]
        ));
    }
    Ok(())
}

/// Hierarchy creation (seed 000 §3.2.7, eq. 3.8-3.15).
pub trait HierarchyBuilder<B: Backend>: Send + Sync {
    /// Variant name.
    fn name(&self) -> &str;
    /// Builds the hierarchy over `rays` taken in `order`.
    fn build(
        &self,
        backend: &B,
        rays: &B::Buffer<Ray>,
        order: B::Buffer<u32>,
        stats: &mut Stats,
    ) -> Result<RayHierarchy<B>>;
}

/// A (lowest-level node, triangle) pair that survived traversal (8 bytes).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, Pod, Zeroable)]
pub struct Candidate {
    /// Node index in `levels[0]`.
    pub node: u32,
    /// Triangle id in scene order.
    pub tri: u32,
}

/// One batch of candidates; a traverser may emit several (triangle batching under a memory
/// budget, §3.2.8) and the intersector merges their hits.
pub struct CandidateBatch<B: Backend> {
    /// The surviving pairs.
    pub pairs: B::Buffer<Candidate>,
    /// Optionally, per pair, which of its node's rays it is for: bit `k` is the node's `k`-th
    /// leaf ([`lowest_node_leaves`]), [`ALL_LANES`] every ray of the node (whatever their
    /// number). A traverser that culls single rays (the CPU `dual`'s `single_rays`) sends the
    /// rays that reached the triangle, and the intersector tests only those; a ray left out
    /// must be one that cannot hit the triangle. A pair whose node has more than 32 rays must
    /// say [`ALL_LANES`]; a mask without a bit for any of its node's rays is allowed (nothing
    /// tested). `None`: every pair is for all of its node's rays.
    pub lanes: Option<B::Buffer<u32>>,
}

/// The lane mask of a candidate for every ray of its node ([`CandidateBatch::lanes`]).
pub const ALL_LANES: u32 = u32::MAX;

impl<B: Backend> CandidateBatch<B> {
    /// A batch whose pairs are for all rays of their nodes.
    pub fn new(pairs: B::Buffer<Candidate>) -> CandidateBatch<B> {
        CandidateBatch { pairs, lanes: None }
    }

    /// A batch with a lane mask per pair (see [`CandidateBatch::lanes`]).
    pub fn with_lanes(pairs: B::Buffer<Candidate>, lanes: B::Buffer<u32>) -> CandidateBatch<B> {
        CandidateBatch {
            pairs,
            lanes: Some(lanes),
        }
    }
}

/// Top-down hierarchy traversal against mesh and triangle bounding spheres (§3.2.8, eq. 3.16).
pub trait Traverser<B: Backend>: Send + Sync {
    /// Variant name.
    fn name(&self) -> &str;
    /// Traverses `hierarchy` over `rays` of `kind`, handing each candidate batch to `sink`
    /// (with the stats, so the final tests can count) as soon as it is complete, so that memory
    /// stays within the variant's budget.
    fn traverse(
        &self,
        backend: &B,
        rays: &B::Buffer<Ray>,
        kind: RayKind,
        hierarchy: &RayHierarchy<B>,
        sink: &mut dyn FnMut(CandidateBatch<B>, &mut Stats) -> Result<()>,
        stats: &mut Stats,
    ) -> Result<()>;
    /// Traverses `hierarchy` over `rays` of `kind` and runs the final tests itself, with the
    /// ray-triangle test of the pipeline's `intersector` ([`Intersector::candidate_test`];
    /// its prepared triangles where the traverser knows the variant,
    /// [`Intersector::as_any`]), merging each ray's hit into `hits` as
    /// [`Intersector::intersect`] merges them (query `mode`). A traverser that tests pairs as
    /// soon as it finds them can drop an any-hit ray at its first hit and shorten a
    /// closest-hit ray's segment as it goes. `None` (the default) when the variant, or this
    /// configuration of it, does not: the pipeline then calls [`Traverser::traverse`] and the
    /// intersector's final tests.
    #[allow(clippy::too_many_arguments)]
    fn trace(
        &self,
        backend: &B,
        rays: &B::Buffer<Ray>,
        kind: RayKind,
        mode: HitMode,
        intersector: &dyn Intersector<B>,
        hierarchy: &RayHierarchy<B>,
        hits: &mut B::Buffer<Hit>,
        stats: &mut Stats,
    ) -> Option<Result<()>> {
        let _ = (
            backend,
            rays,
            kind,
            mode,
            intersector,
            hierarchy,
            hits,
            stats,
        );
        None
    }
    /// For a scene whose triangles moved (`ctx.scene`: the same triangles, new positions), a
    /// traverser that reuses this one's work instead of building anew, e.g. an object
    /// hierarchy whose bounds are recomputed over its kept topology; `None` (the default) when
    /// the variant has nothing to reuse, and [`crate::Registry::rebuild`] constructs it again.
    /// As for [`Intersector::refit`], the result must find the same hits as a fresh build.
    fn refit(&self, ctx: &StageContext<'_, B>) -> Option<Result<Box<dyn Traverser<B>>>> {
        let _ = ctx;
        None
    }
}

/// What an intersector tests each ray against.
pub enum Query<'a, B: Backend> {
    /// The whole scene (brute force, object BVH).
    Scene,
    /// Only the triangles paired with each ray's lowest hierarchy node (§3.2.9).
    Candidates {
        /// The hierarchy whose `levels[0]` the candidate nodes index.
        hierarchy: &'a RayHierarchy<B>,
        /// The pairs to test.
        batch: &'a CandidateBatch<B>,
    },
}

impl<B: Backend> Query<'_, B> {
    /// `Ok` for [`Query::Scene`]; for [`Query::Candidates`] the error of intersector `variant`,
    /// which tests the whole scene only (an object BVH, grid or kd-tree, the f64 reference):
    /// every such intersector refuses candidate queries with this one message, on either
    /// backend.
    pub fn whole_scene_only(&self, variant: &str) -> Result<()> {
        match self {
            Query::Scene => Ok(()),
            Query::Candidates { .. } => Err(crate::CoreError::Unsupported {
                stage: "intersect",
                variant: variant.into(),
                what: "candidate queries (it tests the whole scene: use it in a pipeline \
                       without a ray-space hierarchy, or as the --reference)"
                    .into(),
            }),
        }
    }
}

/// Exact ray-triangle intersection (§3.2.9).
pub trait Intersector<B: Backend>: Send + Sync {
    /// Variant name (`brute`, `bvh`, ...).
    fn name(&self) -> &str;
    /// Whether it answers [`Query::Candidates`], i.e. can run the final tests of a ray-space
    /// hierarchy; variants that only test the whole scene say `false`, and pipelines that
    /// pair them with a hierarchy are rejected when they are built.
    fn supports_candidates(&self) -> bool {
        true
    }
    /// The exact ray-triangle test this intersector runs on candidate pairs, by its `test`
    /// parameter's name (`mt`, `watertight`, `projected`), so that a traverser that runs the
    /// final tests itself ([`Traverser::trace`]) runs the same one; `None` (the default) when
    /// it names none, and the pipeline leaves the final tests to [`Intersector::intersect`].
    fn candidate_test(&self) -> Option<&str> {
        None
    }
    /// The variant itself, for a stage of the same backend that can use its prepared data
    /// (a traverser running the final tests inline reuses `brute`'s prepared triangles instead
    /// of preparing them again); `None` (the default) keeps it opaque.
    fn as_any(&self) -> Option<&dyn std::any::Any> {
        None
    }
    /// For a scene whose triangles moved (`ctx.scene`: the same triangles, new positions), an
    /// intersector that reuses this one's work instead of building anew, e.g. a BVH whose
    /// boxes are refitted over its kept topology; `None` (the default) when the variant has
    /// nothing to reuse, and [`crate::Registry::rebuild`] constructs it again. The result must
    /// answer queries exactly as a fresh build would (the same hits), however its speed
    /// degrades.
    fn refit(&self, ctx: &StageContext<'_, B>) -> Option<Result<Box<dyn Intersector<B>>>> {
        let _ = ctx;
        None
    }
    /// Tests `rays` as `query` says and merges the results into `hits` (one per ray, same
    /// order; pass a buffer of [`Hit::MISS`] to start): for [`HitMode::Closest`] a hit replaces
    /// the stored one when [`Hit::closer_than`] says so; for [`HitMode::Any`] any hit may be
    /// stored. Merging lets candidate batches arrive one at a time.
    fn intersect(
        &self,
        backend: &B,
        rays: &B::Buffer<Ray>,
        query: Query<'_, B>,
        mode: HitMode,
        hits: &mut B::Buffer<Hit>,
        stats: &mut Stats,
    ) -> Result<()>;
}

/// Shading (seed 000 eq. 3.17-3.19): Phong direct light and path-vertex resolution.
///
/// The image is linear HDR RGBA, one `[f32; 4]` per pixel, accumulated across batches.
pub trait Shader<B: Backend>: Send + Sync {
    /// Variant name.
    fn name(&self) -> &str;
    /// Whether [`Shader::shade_direct`] understands rays of `kind` (the ray generator's
    /// [`RayGen::visibility_kind`]): shadow rays by default.
    fn shades(&self, kind: RayKind) -> bool {
        kind == RayKind::Shadow
    }
    /// Adds the direct light at `surfaces` (and the background where a surface is a miss) to
    /// `image`, with each light's visibility taken from the shadow rays and their hits
    /// (`shadow_rays[i].source` indexes `surfaces`), traced with `mode` (the ray generator's
    /// [`RayGen::visibility_mode`]: [`HitMode::Any`] hits are binary, [`HitMode::EdgeWidth`]
    /// hits carry an occlusion). A shader that cannot use `mode` returns
    /// [`crate::CoreError::Unsupported`].
    #[allow(clippy::too_many_arguments)]
    fn shade_direct(
        &self,
        backend: &B,
        surfaces: &B::Buffer<Surface>,
        shadow_rays: &B::Buffer<Ray>,
        shadow_hits: &B::Buffer<Hit>,
        mode: HitMode,
        image: &mut B::Buffer<[f32; 4]>,
        stats: &mut Stats,
    ) -> Result<()>;
    /// Turns the reflection or refraction `rays` and their nearest `hits` into the next path
    /// vertices (barycentric normal interpolation, eq. 3.17-3.18); misses become background
    /// records that [`Shader::shade_direct`] shades.
    fn resolve(
        &self,
        backend: &B,
        rays: &B::Buffer<Ray>,
        hits: &B::Buffer<Hit>,
        stats: &mut Stats,
    ) -> Result<B::Buffer<Surface>>;
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lowest_node_leaves_fixed_groups_and_offsets() {
        // Fixed groups of 4 over 10 leaves: the last is partial, past the end empty.
        assert_eq!(lowest_node_leaves(0, 4, None, 10), 0..4);
        assert_eq!(lowest_node_leaves(2, 4, None, 10), 8..10);
        assert_eq!(lowest_node_leaves(3, 4, None, 10), 10..10);
        assert_eq!(lowest_node_leaves(usize::MAX, 4, None, 10), 10..10);
        // Offsets: variable sizes, empty nodes allowed.
        let offsets = [0, 3, 3, 7, 10];
        let ranges: Vec<_> = (0..4)
            .map(|k| lowest_node_leaves(k, 4, Some(&offsets), 10))
            .collect();
        assert_eq!(ranges, [0..3, 3..3, 3..7, 7..10]);
        assert_eq!(lowest_node_leaves(4, 4, Some(&offsets), 10), 10..10);
        // Bad offsets give clamped ranges, never a panic.
        assert_eq!(lowest_node_leaves(0, 4, Some(&[5, 2]), 10), 5..5);
        assert_eq!(lowest_node_leaves(0, 4, Some(&[0, 99]), 10), 0..10);
    }

    #[test]
    fn leaf_offsets_are_checked() {
        assert!(check_leaf_offsets(&[0, 3, 3, 7, 10], 4, 10).is_ok());
        assert!(check_leaf_offsets(&[0], 0, 0).is_ok());
        for (offsets, nodes, leaves) in [
            (&[0u32, 3, 10][..], 3, 10), // too short
            (&[1, 3, 10], 2, 10),        // does not start at 0
            (&[0, 3, 9], 2, 10),         // does not end at the ray count
            (&[0, 3, 11], 2, 10),        // past the ray count
            (&[0, 5, 4, 10], 3, 10),     // decreasing
            (&[], 0, 0),                 // no entry at all
        ] {
            let r = check_leaf_offsets(offsets, nodes, leaves);
            assert!(
                matches!(r, Err(crate::CoreError::InvalidInput(_))),
                "{offsets:?}: {r:?}"
            );
        }
    }
}
