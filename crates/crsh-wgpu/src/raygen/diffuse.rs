//! `diffuse` on the wgpu backend: diffuse paths with next-event shadow rays (seed 001 §4), the
//! twin of [`crsh_cpu::raygen::diffuse::Diffuse`].
//!
//! - **Shadow rays** are the wgpu [`Whitted`] generator's with every material opaque and
//!   diffuse ([`Whitted::lambertian`]), as the CPU twin makes them with its Whitted generator.
//! - **Diffuse rays** come from `cosine.wgsl` (shared with [`super::ao`]): a primary vertex
//!   (depth 0) starts `samples` paths, ray `k` with throughput `throughput × albedo /
//!   samples`; a deeper vertex continues its own path (the sample index in
//!   [`Surface::sample`]) with one ray of throughput `throughput × albedo`; albedo = the
//!   material's diffuse colour, clamped at 0. The slots are the CPU's: `samples` per surface
//!   when the batch holds a primary vertex, else 1 (the device is asked which, one read-back,
//!   only when `samples > 1`). Directions come from `rng.wgsl` for the key (pixel, sample,
//!   bounce = depth, `seed`): the CPU's random words bit for bit.
//!
//! `offsets` other than `none` is refused ([`CoreError::Unsupported`]) until seed 001's
//! hemisphere sets exist on the device; so no ray's interval is ever emptied by an offset and
//! [`Stats::add_offset_ended`] has nothing to count.

use std::sync::Arc;

use crsh_core::{CoreError, Ray, RayGen, RayKind, Registry, Result, StageSpec, Stats, Surface};

use crate::backend::{GpuBuffer, Wgpu};
use crate::raygen::cosine::CosineRays;
use crate::raygen::slots;
use crate::raygen::whitted::Whitted;
use crate::scene::GpuScene;

/// The GPU diffuse path-tracing generator (variant `diffuse`).
pub struct Diffuse {
    shadows: Whitted,
    rays: CosineRays,
}

/// Registers the wgpu `diffuse` under its CPU twin's catalogue entry (same name, parameters,
/// defaults and documentation).
pub fn register(registry: &mut Registry<Wgpu>) -> Result<()> {
    registry.add_raygen(crsh_cpu::raygen::diffuse::info(), |ctx, spec| {
        Ok(Box::new(Diffuse::new(ctx.scene, spec)?))
    })?;
    Ok(())
}

impl Diffuse {
    /// The generator for `scene` with a resolved `spec` (parameters as the CPU variant's;
    /// `offsets` other than `none` is refused).
    pub fn new(scene: &Arc<GpuScene>, spec: &StageSpec) -> Result<Diffuse> {
        slots::refuse_offsets(spec, "diffuse")?;
        // The CPU constructor validates every parameter and the materials' colours.
        crsh_cpu::raygen::diffuse::Diffuse::new(&scene.scene, spec)?;
        Ok(Diffuse {
            shadows: Whitted::new(scene, spec)?.lambertian(),
            rays: CosineRays::from_spec(scene, spec, RayKind::Diffuse, 0.0)?,
        })
    }

    /// Paths started per pixel.
    pub fn samples(&self) -> u32 {
        self.rays.samples
    }
}

impl RayGen<Wgpu> for Diffuse {
    fn name(&self) -> &str {
        "diffuse"
    }

    fn bounce_kinds(&self) -> &[RayKind] {
        &[RayKind::Diffuse]
    }

    fn generate(
        &self,
        backend: &Wgpu,
        surfaces: &GpuBuffer<Surface>,
        kind: RayKind,
        stats: &mut Stats,
    ) -> Result<GpuBuffer<Ray>> {
        match kind {
            RayKind::Shadow => self.shadows.generate(backend, surfaces, kind, stats),
            RayKind::Diffuse => {
                let per_surface =
                    if self.rays.samples > 1 && self.rays.any_primary(backend, surfaces)? {
                        self.rays.samples as usize
                    } else {
                        1
                    };
                self.rays.generate(backend, surfaces, per_surface, stats)
            }
            other => Err(CoreError::Unsupported {
                stage: "raygen",
                variant: "diffuse".into(),
                what: format!("{} rays (it makes shadow and diffuse rays)", other.name()),
            }),
        }
    }
}
