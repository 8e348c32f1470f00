//! `brute` on the wgpu backend: every ray against every triangle (whole-scene queries), or
//! against the triangles a ray-space hierarchy paired with its node (candidate queries).
//!
//! The twin is [`crsh_cpu::intersect::brute::BruteForce`], and the results are the CPU's:
//!
//! - The triangles are prepared on the host by the CPU's own code
//!   ([`crsh_cpu::triangle::PreparedTriangle`]: `v0`, `e1`, `e2`, `det_eps`), and
//!   `kernels/mt.wgsl` runs the Möller-Trumbore solve with the same operations in the same
//!   order, so `t`, `u`, `v` agree with the CPU's up to the rounding of the division (WGSL's
//!   `1/x` need not be correctly rounded; lavapipe's is) and contraction into fused
//!   multiply-adds, which a driver may do.
//! - **Whole-scene queries**: one invocation per ray sweeps the triangles in increasing id
//!   order, staged through workgroup memory 256 at a time. Closest hit: [`Hit::closer_than`]
//!   over all of them, merged with the hit already stored. Any hit: a ray whose stored hit is
//!   already a hit is skipped; otherwise its lowest-id hit stops it, which is exactly the hit
//!   the CPU stores (the first 8-wide block with a hit, its lowest lane), and the test count
//!   is the CPU's (`min(8·(block + 1), triangles)`, or every triangle when nothing is hit).
//!   A workgroup stops sweeping as soon as none of its rays is still searching.
//! - **Candidate queries**: one invocation per hierarchy leaf tests its ray against the pairs
//!   of its node (found by binary search in the pairs, which must be strictly increasing by
//!   (node, triangle) as the traversals emit them; pairs that are not are sorted on the host
//!   first), in increasing triangle order, with the CPU's merge rules; every test and every
//!   test that hit are counted (the level-0 row of [`Stats::levels`]). A leaf's node is
//!   `leaf / subdivision` (seed 000's fixed groups) or, when the hierarchy has
//!   [`RayHierarchy::leaf_offsets`] (seed 004's tile cones), the node whose range
//!   `leaf_offsets[k] .. leaf_offsets[k + 1]` holds it (a binary search in the offsets; one
//!   kernel, a uniform flag). The offsets are checked on the device in the pass that checks
//!   the pairs (`levels[0].len() + 1` entries on the host; 0 first, the ray count last,
//!   non-decreasing) and a violation is a [`CoreError::InvalidInput`] naming it.
//!
//! - **Lane masks** ([`crsh_core::CandidateBatch::lanes`], sent by `dual` with single rays): a
//!   pair tests only the rays of its node its mask names (the leaf's lane within its node); a
//!   mask other than all lanes on a node of more than 32 rays, or a mask array of another
//!   length than the pairs', is an error, as on the CPU; unsorted batches are sorted on the
//!   host with their repeats merged into one pair for the union of their masks.
//! - **Windows**: no invocation loops over more than [`SPAN`] triangles (whole-scene queries)
//!   or pairs of its node (candidate queries) in one dispatch; longer sweeps are split into
//!   windows, one dispatch each, merging into the hits the last one left, with the counts
//!   adding up to the CPU's. Mesa's lavapipe silently ends an invocation's loops after 65,535
//!   iterations in all, which cut every sweep past 65,536 triangles before.
//!
//! Rays are bound in chunks of one storage binding for whole-scene queries; candidate queries
//! bind the whole ray buffer (a leaf may name any ray) and fail with
//! [`crate::GpuError::TooLarge`] above the binding limit. Only the Möller-Trumbore test
//! (`test = "mt"`) has a WGSL twin; the other tests are refused as unsupported.

use std::sync::Arc;

use bytemuck::{Pod, Zeroable};
use crsh_core::{
    Candidate, CoreError, Hit, HitMode, Intersector, Query, Ray, RayKind, Registry, Result,
    StageSpec, Stats,
};

#[cfg(doc)]
use crsh_core::RayHierarchy;
use crsh_cpu::intersect::brute::{sort_pairs, sort_with_lanes};
use crsh_cpu::triangle::{PreparedTriangle, TriangleSet};

use crate::adapter::GpuContext;
use crate::backend::{GpuBuffer, Wgpu};
use crate::error::GpuResult;
use crate::kernel::{dispatch_chunks, encoder, submit, uniform, Kernel, Slot};
use crate::scene::GpuScene;

const SHADER: &str = include_str!("brute.wgsl");

/// The most triangles (whole-scene queries) or pairs of one node (candidate queries) one
/// invocation loops over in one dispatch: Mesa's lavapipe ends the loops of an invocation
/// after 65,535 iterations in all (`LP_MAX_TGSI_LOOP_ITERATIONS`, shared by every loop of a
/// shader), silently; a multiple of 256 (the workgroup's triangle tile) and of 8 (the CPU's
/// test blocks, so the any-hit counts add up across windows).
pub const SPAN: u32 = 32_768;

/// Uniform block of `brute.wgsl`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct Params {
    n: u32,
    n_tris: u32,
    any_hit: u32,
    n_pairs: u32,
    subdivision: u32,
    first: u32,
    has_offsets: u32,
    n_nodes: u32,
    n_leaves: u32,
    has_lanes: u32,
    start: u32,
    span: u32,
}

/// The compiled kernels (one per device).
struct BruteKernels {
    kernel: Kernel,
}

impl BruteKernels {
    fn new(ctx: &GpuContext) -> GpuResult<BruteKernels> {
        let source = format!("{}\n{SHADER}", super::MT_WGSL);
        Ok(BruteKernels {
            kernel: Kernel::new(
                ctx,
                "crsh brute",
                &source,
                &["scene_query", "candidates", "check_pairs"],
                &[
                    Slot::Uniform,
                    Slot::Read,
                    Slot::Read,
                    Slot::ReadWrite,
                    Slot::ReadWrite,
                    Slot::Read,
                    Slot::Read,
                    Slot::Read,
                    Slot::Read,
                ],
            )?,
        })
    }
}

/// The GPU brute-force intersector (variant `brute`, parameter `test`, only `mt`).
pub struct BruteForce {
    scene: Arc<GpuScene>,
    tris: GpuBuffer<PreparedTriangle>,
    n_tris: u32,
}

/// Registers the wgpu `brute` under its CPU twin's catalogue entry (same name, parameters,
/// defaults and documentation) (`test` offers `mt` only: the other tests have no WGSL twin).
pub fn register(registry: &mut Registry<Wgpu>) -> Result<()> {
    registry.add_intersector(
        crate::registry::mt_only(crsh_cpu::intersect::brute::info()),
        |ctx, spec| Ok(Box::new(BruteForce::new(ctx.scene, spec)?)),
    )?;
    Ok(())
}

impl BruteForce {
    /// Prepares `scene`'s triangles for the Möller-Trumbore test on the host and uploads them.
    pub fn new(scene: &Arc<GpuScene>, spec: &StageSpec) -> Result<BruteForce> {
        super::require_mt(spec, "brute")?;
        let set: TriangleSet = TriangleSet::new(&scene.scene);
        let n_tris = u32::try_from(set.len()).map_err(|_| {
            CoreError::InvalidInput(format!("{} triangles exceed u32 ids", set.len()))
        })?;
        let tris = GpuBuffer::from_slice(scene.ctx(), "crsh brute triangles", set.triangles())?;
        Ok(BruteForce {
            scene: Arc::clone(scene),
            tris,
            n_tris,
        })
    }

    fn kernels(&self) -> GpuResult<Arc<BruteKernels>> {
        self.scene.ctx().kernel(BruteKernels::new)
    }

    /// Whole-scene query; returns the tests performed.
    fn scene_query(
        &self,
        rays: &GpuBuffer<Ray>,
        any_hit: bool,
        hits: &GpuBuffer<Hit>,
    ) -> Result<u64> {
        let ctx = self.scene.ctx();
        let k = self.kernels()?;
        let counters = GpuBuffer::<u32>::zeroed(ctx, "crsh brute counters", 8)?;
        let dummy = GpuBuffer::<u32>::zeroed(ctx, "crsh brute unused", 4)?;
        // One dispatch per window of SPAN triangles (at least one: it also reports invalid
        // rays), each merging into the hits the previous left.
        for start in (0..self.n_tris.max(1)).step_by(SPAN as usize) {
            dispatch_chunks::<Ray>(
                ctx,
                &k.kernel,
                "crsh brute scene query",
                "scene_query",
                rays.len(),
                |range| {
                    let params = Params {
                        n: range.len() as u32,
                        n_tris: self.n_tris,
                        any_hit: u32::from(any_hit),
                        n_pairs: 0,
                        subdivision: 1,
                        first: range.start as u32,
                        has_offsets: 0,
                        n_nodes: 0,
                        n_leaves: 0,
                        has_lanes: 0,
                        start,
                        span: SPAN,
                    };
                    let u = uniform(ctx, "crsh brute params", &params);
                    k.kernel.bind_group(
                        ctx,
                        &[
                            u.as_entire_binding(),
                            rays.slice_binding(range.clone()),
                            self.tris.binding(),
                            hits.slice_binding(range.clone()),
                            counters.binding(),
                            dummy.binding(),
                            dummy.binding(),
                            dummy.binding(),
                            dummy.binding(),
                        ],
                    )
                },
            )?;
        }
        let c = counters.to_vec(ctx)?;
        check_invalid(c[5])?;
        Ok(u64::from(c[0]) | (u64::from(c[1]) << 32))
    }

    /// Candidate query; returns `(tests, hits found)`, or `None` when the pairs are not
    /// strictly increasing (the caller sorts them). `offsets`: the hierarchy's leaf offsets
    /// (`n_nodes + 1` entries, checked here on the device, reported on the host), or `None`
    /// for fixed groups of `subdivision` leaves.
    #[allow(clippy::too_many_arguments)]
    fn candidate_query(
        &self,
        rays: &GpuBuffer<Ray>,
        order: &GpuBuffer<u32>,
        n_nodes: usize,
        subdivision: u32,
        offsets: Option<&GpuBuffer<u32>>,
        pairs: &GpuBuffer<Candidate>,
        lanes: Option<&GpuBuffer<u32>>,
        any_hit: bool,
        hits: &GpuBuffer<Hit>,
    ) -> Result<Option<(u64, u64)>> {
        let ctx = self.scene.ctx();
        let k = self.kernels()?;
        ctx.check_storage_binding("candidate rays", rays.byte_len())?;
        ctx.check_storage_binding("candidate hits", hits.byte_len())?;
        ctx.check_storage_binding("candidate pairs", pairs.byte_len())?;
        if let Some(o) = offsets {
            ctx.check_storage_binding("hierarchy leaf offsets", o.byte_len())?;
        }
        let counters = GpuBuffer::<u32>::zeroed(ctx, "crsh brute counters", 8)?;
        let dummy = GpuBuffer::<u32>::zeroed(ctx, "crsh brute unused", 4)?;
        // With offsets every leaf belongs to a node (the last offset is the ray count).
        let leaves = match offsets {
            Some(_) => order.len(),
            None => order.len().min(n_nodes * subdivision as usize),
        };
        let params = Params {
            n: leaves as u32,
            n_tris: self.n_tris,
            any_hit: u32::from(any_hit),
            n_pairs: pairs.len() as u32,
            subdivision,
            first: 0,
            has_offsets: u32::from(offsets.is_some()),
            n_nodes: n_nodes as u32,
            n_leaves: order.len() as u32,
            has_lanes: u32::from(lanes.is_some()),
            start: 0,
            span: SPAN,
        };
        let bind = |p: &Params| {
            let u = uniform(ctx, "crsh brute params", p);
            k.kernel.bind_group(
                ctx,
                &[
                    u.as_entire_binding(),
                    rays.binding(),
                    self.tris.binding(),
                    hits.binding(),
                    counters.binding(),
                    order.binding(),
                    pairs.binding(),
                    offsets.unwrap_or(&dummy).binding(),
                    lanes.unwrap_or(&dummy).binding(),
                ],
            )
        };
        let check_bg = bind(&params);
        let checks = match offsets {
            Some(_) => pairs.len().max(n_nodes + 1),
            None => pairs.len(),
        };
        let mut enc = encoder(ctx, "crsh brute check pairs");
        {
            let mut pass = ctx.compute_pass(&mut enc, "crsh brute check pairs");
            k.kernel
                .dispatch(ctx, &mut pass, "check_pairs", &check_bg, checks as u32)?;
        }
        submit(ctx, "crsh brute check pairs", enc)?;
        let flags = counters.to_vec(ctx)?;
        if let (true, Some(o)) = (flags[4] & 4 != 0, offsets) {
            // The host check names the first violation.
            let host = o.to_vec(ctx)?;
            crsh_core::check_leaf_offsets(&host, n_nodes, order.len())?;
            return Err(CoreError::InvalidInput(
                "hierarchy leaf offsets are not 0, non-decreasing, ..., the ray count".into(),
            ));
        }
        if flags[4] & 2 != 0 {
            return Err(CoreError::InvalidInput(format!(
                "a candidate pair is out of range ({n_nodes} nodes, {} triangles)",
                self.n_tris
            )));
        }
        if flags[4] & 8 != 0 {
            return Err(CoreError::InvalidInput(
                "a candidate has a lane mask other than all rays on a hierarchy node of more \
                 than 32 rays"
                    .into(),
            ));
        }
        if flags[4] & 1 != 0 {
            return Ok(None);
        }
        // Windows of SPAN pairs per node, until no node has pairs beyond the last window.
        let mut bg = check_bg;
        let mut start = 0u32;
        let c = loop {
            let mut enc = encoder(ctx, "crsh brute candidates");
            {
                let mut pass = ctx.compute_pass(&mut enc, "crsh brute candidates");
                k.kernel
                    .dispatch(ctx, &mut pass, "candidates", &bg, leaves as u32)?;
            }
            submit(ctx, "crsh brute candidates", enc)?;
            let c = counters.to_vec(ctx)?;
            if c[6] == 0 || start >= params.n_pairs {
                break c;
            }
            ctx.queue()
                .write_buffer(counters.buffer(), 6 * 4, bytemuck::bytes_of(&0u32));
            start += SPAN;
            bg = bind(&Params { start, ..params });
        };
        check_invalid(c[5])?;
        Ok(Some((
            u64::from(c[0]) | (u64::from(c[1]) << 32),
            u64::from(c[2]) | (u64::from(c[3]) << 32),
        )))
    }
}

/// The error for a kernel's invalid-ray report (`0xffffffff - index` of the first, or 0).
pub(crate) fn check_invalid(report: u32) -> Result<()> {
    if report == 0 {
        return Ok(());
    }
    Err(CoreError::InvalidInput(format!(
        "ray {} is not valid (NaN or infinite origin or direction, zero direction, or NaN \
         interval)",
        u32::MAX - report
    )))
}

impl Intersector<Wgpu> for BruteForce {
    fn name(&self) -> &str {
        "brute"
    }

    fn intersect(
        &self,
        backend: &Wgpu,
        rays: &GpuBuffer<Ray>,
        query: Query<'_, Wgpu>,
        mode: HitMode,
        hits: &mut GpuBuffer<Hit>,
        stats: &mut Stats,
    ) -> Result<()> {
        if mode.is_edge_width() {
            return Err(mode.unsupported("brute (wgpu)"));
        }
        crsh_core::ray::check_hits_per_ray("rays", rays.len(), hits.len())?;
        let any_hit = mode == HitMode::Any;
        let tests = match query {
            Query::Scene => {
                if rays.is_empty() {
                    return Ok(());
                }
                self.scene_query(rays, any_hit, hits)?
            }
            Query::Candidates { hierarchy, batch } => {
                if let Some(l) = &batch.lanes {
                    if l.len() != batch.pairs.len() {
                        return Err(CoreError::InvalidInput(format!(
                            "{} lane masks for {} candidate pairs",
                            l.len(),
                            batch.pairs.len()
                        )));
                    }
                }
                if batch.pairs.is_empty() || rays.is_empty() {
                    return Ok(());
                }
                let Some(level0) = hierarchy.levels.first() else {
                    return Err(CoreError::InvalidInput("hierarchy has no levels".into()));
                };
                let offsets = hierarchy.leaf_offsets.as_ref();
                if hierarchy.subdivision == 0 && offsets.is_none() {
                    return Err(CoreError::InvalidInput("hierarchy subdivision is 0".into()));
                }
                if let Some(o) = offsets {
                    if o.len() != level0.len() + 1 {
                        return Err(CoreError::InvalidInput(format!(
                            "hierarchy leaf offsets have {} entries for {} lowest nodes \
                             (expected {})",
                            o.len(),
                            level0.len(),
                            level0.len() + 1
                        )));
                    }
                }
                if hierarchy.order.len() != rays.len() {
                    return Err(CoreError::InvalidInput(format!(
                        "hierarchy order has {} entries for {} rays",
                        hierarchy.order.len(),
                        rays.len()
                    )));
                }
                let run = |pairs: &GpuBuffer<Candidate>, lanes: Option<&GpuBuffer<u32>>| {
                    self.candidate_query(
                        rays,
                        &hierarchy.order,
                        level0.len(),
                        hierarchy.subdivision,
                        offsets,
                        pairs,
                        lanes,
                        any_hit,
                        hits,
                    )
                };
                let (tests, found) = match run(&batch.pairs, batch.lanes.as_ref())? {
                    Some(r) => r,
                    None => {
                        // Unsorted or repeated pairs: sort and merge on the host, as the CPU
                        // twin does (a repeat is for the union of its lane masks), then run
                        // again.
                        let ctx = backend.context();
                        let pairs = batch.pairs.to_vec(ctx)?;
                        let (pairs, lanes) = match &batch.lanes {
                            Some(l) => {
                                let (pairs, masks) = sort_with_lanes(&pairs, &l.to_vec(ctx)?);
                                let masks =
                                    GpuBuffer::from_slice(ctx, "crsh sorted lanes", &masks)?;
                                (pairs, Some(masks))
                            }
                            None => (sort_pairs(&pairs), None),
                        };
                        let sorted = GpuBuffer::from_slice(ctx, "crsh sorted pairs", &pairs)?;
                        run(&sorted, lanes.as_ref())?.ok_or_else(|| {
                            CoreError::Backend("sorted pairs reported unsorted".into())
                        })?
                    }
                };
                let first = rays.to_vec_range(backend.context(), 0..1)?;
                let kind = RayKind::from_u32(first[0].kind).ok_or_else(|| {
                    CoreError::InvalidInput(format!("ray 0 has an unknown kind {}", first[0].kind))
                })?;
                stats.add_level(kind, 0, tests, found);
                tests
            }
        };
        stats.add_ray_triangle(tests);
        Ok(())
    }
}
