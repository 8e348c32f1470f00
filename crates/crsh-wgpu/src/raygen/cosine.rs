//! The kernel behind the wgpu `ao` and `diffuse` generators (`cosine.wgsl`): cosine-weighted
//! rays leaving surfaces, keyed by (pixel, sample, bounce, seed) through `rng.wgsl`.
//!
//! Ray `k` of surface `i` occupies slot `i · per_surface + k` (surface-major, as the CPU twins
//! lay them out) and the passes are [`super::slots`]'s. The per-ray decisions and arithmetic
//! are [`crsh_cpu::raygen::ao::Ao::ray`]'s and [`crsh_cpu::raygen::diffuse::Diffuse::ray`]'s
//! in the same order: throughput (divided by the rays or paths per surface), the threshold,
//! the key's uniforms, [`crsh_core::rng::front_cosine_direction`], then
//! [`crsh_cpu::raygen::whitted::offset_segment`] along the direction; an AO ray ends at
//! `max(length, t_min)`; then the origin offsets ([`super::offsets`],
//! [`crsh_cpu::raygen::offsets::Offsets::apply`]) raise `t_min`, and the rays they empty are
//! counted into [`Stats::add_offset_ended`].

use std::sync::Arc;

use bytemuck::{Pod, Zeroable};
use crsh_core::{Ray, RayKind, Result, StageSpec, Stats, Surface};
use crsh_cpu::raygen::ao::MAX_SAMPLES;
use crsh_cpu::raygen::whitted::policy_from_spec;

use crate::adapter::GpuContext;
use crate::backend::{GpuBuffer, Wgpu};
use crate::error::GpuResult;
use crate::kernel::Kernel;
use crate::kernels::{compose, origin_offset_wgsl, GLAM_WGSL, RNG_WGSL, SEGMENT_WGSL, TRIG_WGSL};
use crate::raygen::offsets::GpuOffsets;
use crate::raygen::slots::{self, Chunk, SlotPasses};
use crate::scene::GpuScene;

const SHADER: &str = include_str!("cosine.wgsl");

/// Uniform block of `cosine.wgsl`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct Params {
    n: u32,
    first: u32,
    count: u32,
    per_surface: u32,
    kind: u32,
    n_materials: u32,
    samples: u32,
    seed: u32,
    policy: u32,
    offset: f32,
    min_throughput: f32,
    length: f32,
    out_first: u32,
    out_count: u32,
    pad: [u32; 2],
}

struct CosineKernels {
    kernel: Kernel,
}

impl CosineKernels {
    fn new(ctx: &GpuContext) -> GpuResult<CosineKernels> {
        Ok(CosineKernels {
            kernel: Kernel::new(
                ctx,
                "crsh cosine rays",
                &compose(&[
                    GLAM_WGSL,
                    TRIG_WGSL,
                    RNG_WGSL,
                    SEGMENT_WGSL,
                    &origin_offset_wgsl(),
                    SHADER,
                    slots::SLOTS_WGSL,
                ]),
                &["count", "emit", "probe"],
                &slots::BINDINGS,
            )?,
        })
    }
}

/// The settings of one cosine-weighted generator, taken from its CPU twin.
pub(crate) struct CosineRays {
    pub scene: Arc<GpuScene>,
    /// [`RayKind::Ao`] or [`RayKind::Diffuse`].
    pub kind: RayKind,
    /// AO rays per surface, or paths per pixel.
    pub samples: u32,
    pub seed: u32,
    pub min_throughput: f32,
    /// The policy code and distance ([`slots::policy_code`]).
    pub policy: (u32, f32),
    /// AO rays' length (unused for diffuse rays).
    pub length: f32,
    /// The origin offsets.
    pub offsets: Arc<GpuOffsets>,
}

impl CosineRays {
    /// The settings a resolved `spec` of the `ao` or `diffuse` generator gives (`samples`,
    /// `seed`, `min_throughput`, the offset policy; already validated by the CPU twin), for
    /// rays of `kind` and AO `length`, with the origin offsets `offsets`.
    pub fn from_spec(
        scene: &Arc<GpuScene>,
        spec: &StageSpec,
        kind: RayKind,
        length: f32,
        offsets: Arc<GpuOffsets>,
    ) -> Result<CosineRays> {
        let (_, policy) = policy_from_spec(&scene.scene, spec)?;
        Ok(CosineRays {
            scene: Arc::clone(scene),
            kind,
            samples: spec.u32_in("samples", 1..=MAX_SAMPLES)?,
            seed: spec.u32_in("seed", 0..=u32::MAX)?,
            min_throughput: spec.f64("min_throughput")? as f32,
            policy: slots::policy_code(policy),
            length,
            offsets,
        })
    }

    fn params(&self, n: usize, per_surface: usize, c: Chunk) -> Params {
        Params {
            n: n as u32,
            first: c.first,
            count: c.count,
            per_surface: per_surface as u32,
            kind: self.kind as u32,
            n_materials: self.scene.scene.materials.len() as u32,
            samples: self.samples,
            seed: self.seed,
            policy: self.policy.0,
            offset: self.policy.1,
            min_throughput: self.min_throughput,
            length: self.length,
            out_first: c.out_first,
            out_count: c.out_count,
            pad: [0; 2],
        }
    }

    fn passes<'a>(&'a self, kernel: &'a Kernel, per_surface: usize) -> SlotPasses<'a> {
        SlotPasses {
            scene: &self.scene,
            kernel,
            label: "crsh cosine rays params",
            per_surface,
            offsets: &self.offsets,
        }
    }

    /// Whether `surfaces` holds a primary vertex (depth 0), read back from the device.
    pub fn any_primary(&self, backend: &Wgpu, surfaces: &GpuBuffer<Surface>) -> Result<bool> {
        let ctx = backend.context();
        if surfaces.is_empty() {
            return Ok(false);
        }
        let k = ctx.kernel(CosineKernels::new)?;
        let report = GpuBuffer::<u32>::zeroed(ctx, "crsh cosine rays report", 4)?;
        let no_slots = GpuBuffer::<u32>::zeroed(ctx, "crsh cosine rays no slots", 0)?;
        let n = surfaces.len();
        self.passes(&k.kernel, 1).pass(
            "probe",
            &|c| self.params(n, 1, c),
            surfaces,
            &no_slots,
            None,
            &report,
        )?;
        Ok(report.to_vec(ctx)?[1] != 0)
    }

    /// The rays of `surfaces` with `per_surface` slots each, compacted in slot order.
    pub fn generate(
        &self,
        backend: &Wgpu,
        surfaces: &GpuBuffer<Surface>,
        per_surface: usize,
        stats: &mut Stats,
    ) -> Result<GpuBuffer<Ray>> {
        let k = backend.context().kernel(CosineKernels::new)?;
        let n = surfaces.len();
        let materials = self.scene.scene.materials.len();
        self.passes(&k.kernel, per_surface).rays(
            backend,
            surfaces,
            self.kind,
            &|c| self.params(n, per_surface, c),
            &|report| slots::check_materials(report, materials),
            stats,
        )
    }
}
