//! `whitted` on the wgpu backend: shadow, reflection and refraction rays (seed 000 §3.2.3,
//! eq. 3.1-3.7) with trimming by scan-based compaction (§3.2.4, fig. 3.10).
//!
//! The twin is [`crsh_cpu::raygen::whitted::Whitted`]: the same parameters, the same slots
//! (one per surface, or per light and surface, light-major, for shadow rays), the same
//! decisions (background, back-facing light culling, throughput threshold, total internal
//! reflection) and the same offset policies, [`crsh_cpu::raygen::whitted::offset_segment`]
//! and Wächter & Binder's `offset_ray` included (`kernels/segment.wgsl`, bit manipulation
//! with `bitcast`), with the same operations in the same order; rays agree with the CPU's up
//! to the rounding of `sqrt` and division, which WGSL does not require to be correctly
//! rounded. The passes (count, scan, emit) are those of `raygen/slots.rs`.
//!
//! The `offsets` parameter (seed 001's hemisphere sets, [`super::offsets`]) is applied where
//! the CPU twin applies it, by `kernels/origin_offset.wgsl`: shadow rays from the light get
//! `t_max` cut ([`crsh_cpu::raygen::offsets::Offsets::cut_end`]), every other ray `t_min`
//! raised ([`crsh_cpu::raygen::offsets::Offsets::apply`]); emptied rays are counted into
//! [`Stats::add_offset_ended`].

use std::sync::Arc;

use bytemuck::{Pod, Zeroable};
use crsh_core::{CoreError, Ray, RayGen, RayKind, Registry, Result, StageSpec, Stats, Surface};

use crate::adapter::GpuContext;
use crate::backend::{GpuBuffer, Wgpu};
use crate::error::GpuResult;
use crate::kernel::Kernel;
use crate::kernels::{compose, origin_offset_wgsl, GLAM_WGSL, SEGMENT_WGSL};
use crate::raygen::offsets::{without_offsets, GpuOffsets};
use crate::raygen::slots::{self, Chunk, SlotPasses};
use crate::scene::GpuScene;

const SHADER: &str = include_str!("whitted.wgsl");

/// Uniform block of `whitted.wgsl`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct Params {
    n: u32,
    first: u32,
    count: u32,
    per_surface: u32,
    kind: u32,
    n_materials: u32,
    shadow_from_light: u32,
    cull_backfacing: u32,
    policy: u32,
    offset: f32,
    min_throughput: f32,
    out_first: u32,
    out_count: u32,
    lambertian: u32,
    pad: [u32; 2],
}

struct WhittedKernels {
    kernel: Kernel,
}

impl WhittedKernels {
    fn new(ctx: &GpuContext) -> GpuResult<WhittedKernels> {
        Ok(WhittedKernels {
            kernel: Kernel::new(
                ctx,
                "crsh whitted",
                &compose(&[
                    GLAM_WGSL,
                    SEGMENT_WGSL,
                    &origin_offset_wgsl(),
                    SHADER,
                    slots::SLOTS_WGSL,
                ]),
                &["count", "emit"],
                &slots::BINDINGS,
            )?,
        })
    }
}

/// The GPU Whitted ray generator; its settings are those of the CPU twin built from the same
/// spec (which validates them).
pub struct Whitted {
    scene: Arc<GpuScene>,
    shadow_from_light: bool,
    cull_backfacing: bool,
    min_throughput: f32,
    policy: u32,
    offset: f32,
    lambertian: bool,
    offsets: Arc<GpuOffsets>,
}

/// Registers the wgpu `whitted` under its CPU twin's catalogue entry (same name, parameters,
/// defaults and documentation).
pub fn register(registry: &mut Registry<Wgpu>) -> Result<()> {
    registry.add_raygen(crsh_cpu::raygen::whitted::info(), |ctx, spec| {
        Ok(Box::new(Whitted::new(ctx.scene, spec)?))
    })?;
    Ok(())
}

impl Whitted {
    /// The generator for `scene` with a resolved `spec` (parameters as the CPU variant's; the
    /// hemisphere set of `offsets` is built and uploaded here).
    pub fn new(scene: &Arc<GpuScene>, spec: &StageSpec) -> Result<Whitted> {
        let offsets = GpuOffsets::from_spec(scene, spec)?;
        Whitted::with_offsets(scene, spec, offsets)
    }

    /// The generator for `scene` with a resolved `spec` and the origin offsets `offsets`
    /// already uploaded (in place of `spec`'s).
    pub fn with_offsets(
        scene: &Arc<GpuScene>,
        spec: &StageSpec,
        offsets: Arc<GpuOffsets>,
    ) -> Result<Whitted> {
        // The CPU constructor validates every other parameter and the scene's materials and
        // lights (without building a second hemisphere set).
        let cpu = crsh_cpu::raygen::whitted::Whitted::new(&scene.scene, &without_offsets(spec))?;
        if cpu.shadow() != crsh_cpu::raygen::whitted::ShadowMode::Hard {
            return Err(CoreError::Unsupported {
                stage: "raygen",
                variant: "whitted (wgpu)".into(),
                what: format!(
                    "shadow = {} (soft shadows are CPU-only; use shadow = hard)",
                    cpu.shadow().name()
                ),
            });
        }
        let (policy, offset) = slots::policy_code(cpu.policy());
        Ok(Whitted {
            scene: Arc::clone(scene),
            shadow_from_light: spec.str("shadow_origin")? == "light",
            cull_backfacing: spec.bool("cull_backfacing")?,
            min_throughput: spec.f64("min_throughput")? as f32,
            policy,
            offset,
            lambertian: false,
            offsets,
        })
    }

    /// The same generator with every material treated as opaque and purely diffuse, as
    /// [`crsh_cpu::raygen::whitted::Whitted::lambertian`]: shadow rays carry the surface's
    /// whole throughput and no reflection or refraction ray is made (the `diffuse`
    /// generator's shadow rays).
    pub fn lambertian(mut self) -> Self {
        self.lambertian = true;
        self
    }

    /// The uniform block of one dispatch.
    fn params(&self, n: usize, per_surface: usize, kind: RayKind, c: Chunk) -> Params {
        Params {
            n: n as u32,
            first: c.first,
            count: c.count,
            per_surface: per_surface as u32,
            kind: kind as u32,
            n_materials: self.scene.scene.materials.len() as u32,
            shadow_from_light: u32::from(self.shadow_from_light),
            cull_backfacing: u32::from(self.cull_backfacing),
            policy: self.policy,
            offset: self.offset,
            min_throughput: self.min_throughput,
            out_first: c.out_first,
            out_count: c.out_count,
            lambertian: u32::from(self.lambertian),
            pad: [0; 2],
        }
    }
}

impl RayGen<Wgpu> for Whitted {
    fn name(&self) -> &str {
        "whitted"
    }

    fn table_bytes(&self) -> u64 {
        self.offsets.table_bytes()
    }

    fn generate(
        &self,
        backend: &Wgpu,
        surfaces: &GpuBuffer<Surface>,
        kind: RayKind,
        stats: &mut Stats,
    ) -> Result<GpuBuffer<Ray>> {
        if matches!(kind, RayKind::Primary | RayKind::Ao | RayKind::Diffuse) {
            return Err(CoreError::Unsupported {
                stage: "raygen",
                variant: "whitted".into(),
                what: format!(
                    "{} rays (primary visibility makes camera rays; raygen `ao` and `diffuse` the others)",
                    kind.name()
                ),
            });
        }
        let ctx = backend.context();
        let n = surfaces.len();
        let per_surface = if kind == RayKind::Shadow {
            self.scene.scene.lights.len()
        } else {
            1
        };
        let k = ctx.kernel(WhittedKernels::new)?;
        let passes = SlotPasses {
            scene: &self.scene,
            kernel: &k.kernel,
            label: "crsh whitted params",
            per_surface,
            offsets: &self.offsets,
        };
        let materials = self.scene.scene.materials.len();
        passes.rays(
            backend,
            surfaces,
            kind,
            &|c| self.params(n, per_surface, kind, c),
            &|report| slots::check_materials(report, materials),
            stats,
        )
    }
}
