//! `bvh` on the wgpu backend: the object-BVH baseline users would run instead of a ray-space
//! hierarchy, on the same adapter.
//!
//! The tree is the CPU twin's ([`crsh_cpu::intersect::bvh::CwBvh`]): obvhs's compressed wide
//! BVH8 (CWBVH, Ylitie, Karras and Laine 2017) built on the host with the same preset
//! (`build_quality`), its `Pod` nodes uploaded as they are, with the leaf triangles prepared for
//! Möller-Trumbore in primitive-slot order and each slot's scene triangle id. `bvh.wgsl`
//! traverses it one ray per invocation with obvhs's `traverse!` loop (node groups and
//! primitive groups as bit masks, children ordered by the ray's octant, a 64-entry stack) and
//! the CPU twin's node test (`child_hits`: the ray's own interval, zero direction components
//! clamped to ±1e-25, slabs widened by the rounding bound of the quantized-plane arithmetic,
//! the culling distance `min(t_max, best t)` widened by 1e-5 relative), so it returns the
//! brute-force hits, ties included, up to the rounding of WGSL's division. Counts as the CPU
//! (its module doc, "Counting"): a bounds test per non-empty child of each visited node, a
//! ray-triangle test per leaf primitive tested, an inner-node visit per node visited and a
//! leaf visit per primitive cluster when its first primitive is tested (`Stats::add_visits`);
//! any-hit rays stop at their first hit. Whole-scene queries only.
//! Only `test = "mt"` has a WGSL twin.

use std::sync::Arc;

use bytemuck::{Pod, Zeroable};
use crsh_core::{
    CoreError, Hit, HitMode, Intersector, Query, Ray, Registry, Result, StageContext, StageSpec,
    Stats,
};
use crsh_cpu::intersect::bvh::CwBvh as CpuBvh;
use crsh_cpu::triangle::PreparedTriangle;

use crate::adapter::GpuContext;
use crate::backend::{GpuBuffer, Wgpu};
use crate::error::GpuResult;
use crate::kernel::{dispatch_chunks, uniform, Kernel, Slot};
use crate::scene::GpuScene;

const SHADER: &str = include_str!("bvh.wgsl");

#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct Params {
    n: u32,
    n_nodes: u32,
    any_hit: u32,
    first: u32,
}

/// A CWBVH node as 20 words (obvhs's `CwBvhNode`, 80 bytes).
type NodeWords = [u32; 20];

struct BvhKernels {
    kernel: Kernel,
}

impl BvhKernels {
    fn new(ctx: &GpuContext) -> GpuResult<BvhKernels> {
        let source = format!("{}\n{SHADER}", super::MT_WGSL);
        let mut slots = vec![Slot::Uniform];
        slots.extend([Slot::Read; 4]);
        slots.extend([Slot::ReadWrite; 2]);
        Ok(BvhKernels {
            kernel: Kernel::new(ctx, "crsh bvh", &source, &["traverse"], &slots)?,
        })
    }
}

/// The GPU CWBVH intersector (variant `bvh`, parameters `build_quality`, `test` = `mt`).
pub struct CwBvh {
    scene: Arc<GpuScene>,
    nodes: GpuBuffer<NodeWords>,
    leaf_tris: GpuBuffer<PreparedTriangle>,
    leaf_ids: GpuBuffer<u32>,
    /// The host tree, kept for the next frame's refit (`update = "refit"`).
    host: Option<CpuBvh>,
}

/// Registers the wgpu `bvh` under its CPU twin's catalogue entry (same name, parameters,
/// defaults and documentation) (`test` offers `mt` only: the other tests have no WGSL twin).
pub fn register(registry: &mut Registry<Wgpu>) -> Result<()> {
    registry.add_intersector(
        crate::registry::mt_only(crsh_cpu::intersect::bvh::info()),
        |ctx, spec| Ok(Box::new(CwBvh::new(ctx.scene, spec)?)),
    )?;
    Ok(())
}

impl CwBvh {
    /// Builds the tree on the host (the CPU twin's build) and uploads it.
    pub fn new(scene: &Arc<GpuScene>, spec: &StageSpec) -> Result<CwBvh> {
        super::require_mt(spec, "bvh")?;
        if !spec.bool("exact")? {
            return Err(CoreError::InvalidParam {
                key: "bvh.exact".into(),
                reason: "`false` (obvhs's own traversal) runs on the CPU backend only; the \
                         wgpu `bvh` is the exact traversal"
                    .into(),
            });
        }
        let cpu = CpuBvh::new(&scene.scene, spec)?;
        let refit = spec.str("update")? == "refit";
        CwBvh::upload(scene, cpu, refit)
    }

    /// Uploads the host tree `cpu`, keeping it when it will be refitted.
    fn upload(scene: &Arc<GpuScene>, cpu: CpuBvh, keep: bool) -> Result<CwBvh> {
        let ctx = scene.ctx();
        let words: Vec<NodeWords> = cpu
            .nodes()
            .iter()
            .map(|n| bytemuck::cast::<_, NodeWords>(*n))
            .collect();
        let leaf = cpu
            .leaf_triangles_mt()
            .ok_or_else(|| CoreError::Backend("bvh leaves not prepared for mt".into()))?;
        Ok(CwBvh {
            scene: Arc::clone(scene),
            nodes: GpuBuffer::from_slice(ctx, "crsh bvh nodes", &words)?,
            leaf_tris: GpuBuffer::from_slice(ctx, "crsh bvh leaf triangles", leaf)?,
            leaf_ids: GpuBuffer::from_slice(ctx, "crsh bvh leaf ids", cpu.leaf_ids())?,
            host: keep.then_some(cpu),
        })
    }
}

impl Intersector<Wgpu> for CwBvh {
    fn name(&self) -> &str {
        "bvh"
    }

    /// The CPU twin's refit ([`CpuBvh::refitted`]) of the kept host tree, uploaded.
    fn refit(&self, ctx: &StageContext<'_, Wgpu>) -> Option<Result<Box<dyn Intersector<Wgpu>>>> {
        let cpu = self.host.as_ref()?.refitted(&ctx.scene.scene)?;
        Some(CwBvh::upload(ctx.scene, cpu, true).map(|b| Box::new(b) as Box<dyn Intersector<Wgpu>>))
    }

    fn supports_candidates(&self) -> bool {
        false
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
            return Err(mode.unsupported("bvh (wgpu)"));
        }
        query.whole_scene_only("bvh")?;
        crsh_core::ray::check_hits_per_ray("rays", rays.len(), hits.len())?;
        if rays.is_empty() {
            return Ok(());
        }
        let ctx = backend.context();
        let k = ctx.kernel(BvhKernels::new)?;
        let counters = GpuBuffer::<u32>::zeroed(ctx, "crsh bvh counters", 10)?;
        dispatch_chunks::<Ray>(
            ctx,
            &k.kernel,
            "crsh bvh",
            "traverse",
            rays.len(),
            |range| {
                let params = Params {
                    n: range.len() as u32,
                    n_nodes: self.nodes.len() as u32,
                    any_hit: u32::from(mode == HitMode::Any),
                    first: range.start as u32,
                };
                let u = uniform(ctx, "crsh bvh params", &params);
                k.kernel.bind_group(
                    ctx,
                    &[
                        u.as_entire_binding(),
                        rays.slice_binding(range.clone()),
                        self.nodes.binding(),
                        self.leaf_tris.binding(),
                        self.leaf_ids.binding(),
                        hits.slice_binding(range.clone()),
                        counters.binding(),
                    ],
                )
            },
        )?;
        let c = counters.to_vec(ctx)?;
        super::brute::check_invalid(c[4])?;
        if c[5] != 0 {
            return Err(CoreError::Backend(
                "bvh traversal stack (64 entries) overflowed".into(),
            ));
        }
        let wide = |at: usize| u64::from(c[at]) | (u64::from(c[at + 1]) << 32);
        stats.add_bounds(wide(0));
        stats.add_ray_triangle(wide(2));
        stats.add_visits(wide(6), wide(8));
        let _ = &self.scene;
        Ok(())
    }
}
