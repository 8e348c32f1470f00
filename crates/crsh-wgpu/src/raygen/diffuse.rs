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
//! With `offsets` other than `none`, one hemisphere set is built and shared by both kinds:
//! diffuse rays and surface-origin shadow rays get `t_min` raised, light-origin shadow rays
//! `t_max` cut, as the CPU twin does ([`super::offsets`]); the rays this empties are counted
//! into [`Stats::add_offset_ended`].

use std::sync::Arc;

use crsh_core::{CoreError, Ray, RayGen, RayKind, Registry, Result, StageSpec, Stats, Surface};

use crate::backend::{GpuBuffer, Wgpu};
use crate::raygen::cosine::CosineRays;
use crate::raygen::offsets::{without_offsets, GpuOffsets};
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
    /// The generator for `scene` with a resolved `spec` (parameters as the CPU variant's; the
    /// hemisphere set of `offsets` is built and uploaded once, for both ray kinds).
    pub fn new(scene: &Arc<GpuScene>, spec: &StageSpec) -> Result<Diffuse> {
        // The CPU constructor validates every other parameter and the materials' colours.
        crsh_cpu::raygen::diffuse::Diffuse::new(&scene.scene, &without_offsets(spec))?;
        let offsets = GpuOffsets::from_spec(scene, spec)?;
        Ok(Diffuse {
            shadows: Whitted::with_offsets(scene, spec, Arc::clone(&offsets))?.lambertian(),
            rays: CosineRays::from_spec(scene, spec, RayKind::Diffuse, 0.0, offsets)?,
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

    fn table_bytes(&self) -> u64 {
        RayGen::<Wgpu>::table_bytes(&self.shadows)
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
