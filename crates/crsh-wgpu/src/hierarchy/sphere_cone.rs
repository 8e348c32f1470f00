//! `sphere_cone` on the wgpu backend: the bottom-up sphere-cone hierarchy (seed 000 §3.2.7,
//! eq. 3.8-3.15), built level by level, one invocation per node.
//!
//! The twin is [`crsh_cpu::hierarchy::sphere_cone::SphereConeBuilder`] (same parameters
//! `subdivision`, `depth`, `origins`, `leaf_cone` and `leaf_sphere`, same level sizes, the same
//! constructions): leaf cones by the incremental eq. 3.8-3.11 in angle form (the CPU sums and
//! halves the same angles on `(cos, sin)` pairs: the same cone up to rounding), or with
//! `leaf_cone = extremes` from the same two heuristic axes and the same rule for wide nodes
//! (decided in `f32` here, so a node whose candidate axes nearly tie may keep another one than
//! the CPU: either gives a correct cone of nearly the same width), leaf spheres as the exact
//! minimal ball of the origins (Welzl's algorithm, here in its nested non-recursive form; rays from one point get radius
//! 0) or, with `leaf_sphere = box`, centred on the origins' bounding box (the same `f32`
//! centre as the CPU's), upper levels folding the tight cone and sphere unions, then every stored bound
//! re-measured against the stored axis and centre, and `reach` per node (the farthest point a
//! ray of the node reaches, infinite for unbounded rays).
//!
//! What differs: the CPU constructs in `f64`, the device in `f32` (WGSL has no portable `f64`;
//! angles come from the accurate `atan2` / `sin` / `cos` of `kernels/trig.wgsl`, since WGSL's
//! own need not be accurate), so the margins that make every ray certainly inside its node
//! are a little wider: half-angles grow by 2e-6 relative + 1e-6 rad (CPU: 1e-6 + 1e-6), radii
//! by 2e-6 relative + 1e-6 × the coordinates' magnitude (CPU: 1e-6 relative). Nodes therefore agree with the CPU's within those margins plus rounding, and the
//! tests check both that and containment of every ray in f64.

use std::sync::Arc;

use bytemuck::{Pod, Zeroable};
use crsh_core::{
    HierarchyBuilder, Ray, RayHierarchy, Registry, Result, SphereCone, StageSpec, Stats,
};
use crsh_cpu::hierarchy::sphere_cone::{level_sizes, LeafCone, LeafSphere};

use crate::adapter::GpuContext;
use crate::backend::{GpuBuffer, Wgpu};
use crate::error::GpuResult;
use crate::kernel::{encoder, submit, uniform, Kernel, Slot};
use crate::scene::GpuScene;

const SHADER: &str = include_str!("sphere_cone.wgsl");

#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct Params {
    nodes: u32,
    sub: u32,
    below: u32,
    /// 1: bound the segment starts (`origins = start`).
    starts: u32,
    /// 1: lowest cones by `leaf_cone = extremes`.
    leaf_cone: u32,
    /// 1: lowest sphere centres by `leaf_sphere = box`.
    leaf_sphere: u32,
    pad: [u32; 2],
}

struct SphereConeKernels {
    kernel: Kernel,
}

impl SphereConeKernels {
    fn new(ctx: &GpuContext) -> GpuResult<SphereConeKernels> {
        let mut slots = vec![Slot::Uniform];
        slots.extend([Slot::Read; 4]);
        slots.extend([Slot::ReadWrite; 2]);
        Ok(SphereConeKernels {
            kernel: Kernel::new(
                ctx,
                "crsh sphere-cone",
                &crate::kernels::compose(&[
                    crate::kernels::REACH_WGSL,
                    SHADER,
                    crate::kernels::TRIG_WGSL,
                ]),
                &["leaves", "inner"],
                &slots,
            )?,
        })
    }
}

/// The GPU sphere-cone hierarchy builder.
pub struct SphereConeBuilder {
    scene: Arc<GpuScene>,
    subdivision: u32,
    depth: u32,
    starts: bool,
    leaf_cone: LeafCone,
    leaf_sphere: LeafSphere,
}

/// Registers the wgpu `sphere_cone` under its CPU twin's catalogue entry (same name, parameters,
/// defaults and documentation).
pub fn register(registry: &mut Registry<Wgpu>) -> Result<()> {
    registry.add_hierarchy(crsh_cpu::hierarchy::sphere_cone::info(), |ctx, spec| {
        Ok(Box::new(SphereConeBuilder::new(ctx.scene, spec)?))
    })?;
    Ok(())
}

impl SphereConeBuilder {
    /// The builder configured by a resolved `spec` (`subdivision`, `depth`, `origins`),
    /// checked by the CPU twin's constructor.
    pub fn new(scene: &Arc<GpuScene>, spec: &StageSpec) -> Result<SphereConeBuilder> {
        let cpu = crsh_cpu::hierarchy::sphere_cone::SphereConeBuilder::new(&scene.scene, spec)?;
        Ok(SphereConeBuilder {
            scene: Arc::clone(scene),
            subdivision: cpu.subdivision(),
            depth: cpu.depth(),
            starts: cpu.bounds_starts(),
            leaf_cone: cpu.leaf_cone(),
            leaf_sphere: cpu.leaf_sphere(),
        })
    }
}

impl HierarchyBuilder<Wgpu> for SphereConeBuilder {
    fn name(&self) -> &str {
        "sphere_cone"
    }

    fn build(
        &self,
        backend: &Wgpu,
        rays: &GpuBuffer<Ray>,
        order: GpuBuffer<u32>,
        _stats: &mut Stats,
    ) -> Result<RayHierarchy<Wgpu>> {
        let ctx = backend.context();
        let n = rays.len();
        super::check_order_len("sphere_cone", order.len(), n)?;
        let sizes = level_sizes(n, self.subdivision, self.depth);
        let mut levels: Vec<GpuBuffer<SphereCone>> = Vec::with_capacity(sizes.len());
        let mut reach: Vec<GpuBuffer<f32>> = Vec::with_capacity(sizes.len());
        if n == 0 {
            return Ok(RayHierarchy {
                leaf_offsets: None,
                order,
                levels,
                subdivision: self.subdivision,
                reach,
            });
        }
        ctx.check_storage_binding("hierarchy rays", rays.byte_len())?;
        let k = ctx.kernel(SphereConeKernels::new)?;
        let mut enc = encoder(ctx, "crsh sphere-cone");
        let mut below = n;
        for (li, &size) in sizes.iter().enumerate() {
            let nodes = GpuBuffer::<SphereCone>::zeroed(ctx, "crsh hierarchy level", size)?;
            let level_reach = GpuBuffer::<f32>::zeroed(ctx, "crsh hierarchy reach", size)?;
            let params = Params {
                nodes: size as u32,
                sub: self.subdivision,
                below: below as u32,
                starts: u32::from(self.starts),
                leaf_cone: u32::from(self.leaf_cone == LeafCone::Extremes),
                leaf_sphere: u32::from(self.leaf_sphere == LeafSphere::BoxCentre),
                pad: [0; 2],
            };
            let u = uniform(ctx, "crsh sphere-cone params", &params);
            let (children, child_reach) = if li == 0 {
                (&nodes, &level_reach)
            } else {
                (&levels[li - 1], &reach[li - 1])
            };
            // Level 0 reads no children: bind placeholders that are not the outputs.
            let none_nodes;
            let none_reach;
            let (children, child_reach) = if li == 0 {
                none_nodes = GpuBuffer::<SphereCone>::zeroed(ctx, "crsh unused", 0)?;
                none_reach = GpuBuffer::<f32>::zeroed(ctx, "crsh unused", 0)?;
                let _ = (children, child_reach);
                (&none_nodes, &none_reach)
            } else {
                (children, child_reach)
            };
            let bg = k.kernel.bind_group(
                ctx,
                &[
                    u.as_entire_binding(),
                    rays.binding(),
                    order.binding(),
                    children.binding(),
                    child_reach.binding(),
                    nodes.binding(),
                    level_reach.binding(),
                ],
            );
            {
                let mut pass = ctx.compute_pass(&mut enc, "crsh sphere-cone level");
                let entry = if li == 0 { "leaves" } else { "inner" };
                k.kernel.dispatch(ctx, &mut pass, entry, &bg, size as u32)?;
            }
            levels.push(nodes);
            reach.push(level_reach);
            below = size;
        }
        submit(ctx, "crsh sphere-cone", enc)?;
        let _ = &self.scene;
        Ok(RayHierarchy {
            leaf_offsets: None,
            order,
            levels,
            subdivision: self.subdivision,
            reach,
        })
    }
}
