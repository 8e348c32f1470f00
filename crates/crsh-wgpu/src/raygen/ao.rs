//! `ao` on the wgpu backend: ambient-occlusion rays (seed 001 §4), the twin of
//! [`crsh_cpu::raygen::ao::Ao`].
//!
//! The same parameters and validation (the CPU constructor runs on the same spec), the same
//! slots (`samples` per surface, surface-major), the same rays: throughput = the surface's /
//! `samples`, the `min_throughput` threshold, the direction
//! [`crsh_core::rng::front_cosine_direction`] for the key (pixel, sample, bounce = the
//! surface's depth, `seed`) computed by `rng.wgsl` (the same random words bit for bit), the
//! Whitted offset policy along it, and `t_max = max(ao_length × diagonal, t_min)`. Directions
//! and origins agree with the CPU's up to the rounding of `sqrt`, division and the sine /
//! cosine polynomials; everything else is equal. Trimming is the scan-based compaction of
//! [`super::whitted`] (`cosine.wgsl`, shared with [`super::diffuse`]).
//!
//! With `offsets` other than `none`, each ray's `t_min` is raised past the hemispheres of the
//! triangle it leaves, as the CPU twin does ([`super::offsets`]); the rays this empties are
//! counted into [`Stats::add_offset_ended`].

use std::sync::Arc;

use crsh_core::{CoreError, Ray, RayGen, RayKind, Registry, Result, StageSpec, Stats, Surface};

use crate::backend::{GpuBuffer, Wgpu};
use crate::raygen::cosine::CosineRays;
use crate::raygen::offsets::{without_offsets, GpuOffsets};
use crate::scene::GpuScene;

/// The GPU ambient-occlusion ray generator (variant `ao`).
pub struct Ao {
    rays: CosineRays,
}

/// Registers the wgpu `ao` under its CPU twin's catalogue entry (same name, parameters,
/// defaults and documentation).
pub fn register(registry: &mut Registry<Wgpu>) -> Result<()> {
    registry.add_raygen(crsh_cpu::raygen::ao::info(), |ctx, spec| {
        Ok(Box::new(Ao::new(ctx.scene, spec)?))
    })?;
    Ok(())
}

impl Ao {
    /// The generator for `scene` with a resolved `spec` (parameters as the CPU variant's; the
    /// hemisphere set of `offsets` is built and uploaded here).
    pub fn new(scene: &Arc<GpuScene>, spec: &StageSpec) -> Result<Ao> {
        // The CPU constructor validates every other parameter and computes the length.
        let cpu = crsh_cpu::raygen::ao::Ao::new(&scene.scene, &without_offsets(spec))?;
        let offsets = GpuOffsets::from_spec(scene, spec)?;
        Ok(Ao {
            rays: CosineRays::from_spec(scene, spec, RayKind::Ao, cpu.length(), offsets)?,
        })
    }
}

impl RayGen<Wgpu> for Ao {
    fn name(&self) -> &str {
        "ao"
    }

    fn table_bytes(&self) -> u64 {
        self.rays.offsets.table_bytes()
    }

    fn visibility_kind(&self) -> RayKind {
        RayKind::Ao
    }

    fn bounce_kinds(&self) -> &[RayKind] {
        &[]
    }

    fn generate(
        &self,
        backend: &Wgpu,
        surfaces: &GpuBuffer<Surface>,
        kind: RayKind,
        stats: &mut Stats,
    ) -> Result<GpuBuffer<Ray>> {
        if kind != RayKind::Ao {
            return Err(CoreError::Unsupported {
                stage: "raygen",
                variant: "ao".into(),
                what: format!(
                    "{} rays (it makes ambient-occlusion rays only)",
                    kind.name()
                ),
            });
        }
        let per_surface = self.rays.samples as usize;
        self.rays.generate(backend, surfaces, per_surface, stats)
    }
}
