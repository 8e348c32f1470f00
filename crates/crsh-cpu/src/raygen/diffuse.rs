//! `diffuse`: diffuse path tracing with next-event estimation on the point lights (seed 001
//! §4: "each path is extended in a random direction until it finds a light, leaves the scene
//! or reaches a maximum recursion depth"; its counts are per ray, not per path).
//!
//! Every material is treated as opaque and Lambertian with albedo = its diffuse colour
//! (reflectivity and transparency are ignored). At every path vertex:
//! - **Shadow rays** to every light, made exactly as the Whitted generator makes them
//!   ([`super::whitted`], params `shadow_origin`, `cull_backfacing`), carrying the vertex's
//!   whole throughput: the `diffuse` shader turns the unoccluded ones into direct light.
//! - **Diffuse rays** ([`RayKind::Diffuse`], nearest hit): at the primary vertex (depth 0)
//!   `samples` paths start, ray `j` with throughput `throughput × albedo / samples`; a deeper
//!   vertex continues its own path with one ray of throughput `throughput × albedo` (cosine
//!   sampling of a Lambertian BRDF: the `cos θ / π` of the pdf cancels the BRDF's `albedo / π`
//!   and the cosine). The direction is [`crsh_core::rng::front_cosine_direction`] about the
//!   shading normal for the key (pixel, sample, bounce = the vertex's depth, `seed`), so paths
//!   are the same whatever the thread count and on both backends. [`Ray::light`] holds the
//!   sample index, which the shader's resolve stores in the next vertex
//!   ([`Surface::sample`]).
//!
//! Paths stop at the frame's bounce depth, on a miss (the background is the environment
//! light), or when the throughput falls below `min_throughput`.
//!
//! With `offsets`, both the diffuse rays and surface-origin shadow rays get their `t_min`
//! raised past the hemispheres of the triangle they leave, and light-origin shadow rays their
//! `t_max` cut ([`super::offsets`]).

use std::sync::Arc;
use std::time::Instant;

use crsh_core::glam::Vec3;
use crsh_core::{
    CoreError, ParamInfo, Ray, RayGen, RayKind, Registry, Result, StageKind, StageSpec,
    StageVariantInfo, Stats, Surface,
};
use crsh_scene::Scene;

use crate::backend::Cpu;
use crate::raygen::ao::MAX_SAMPLES;
use crate::raygen::cosine::{fill_runs, fill_slots, CosineRays};
use crate::raygen::offsets::{self, Offsets};
use crate::raygen::whitted::{min_throughput_param, policy_from_spec, surface_ray_params, Whitted};
use crate::trim::concat_in_order;

/// The diffuse path-tracing generator (variant `diffuse`). See the module docs.
#[derive(Clone, Debug)]
pub struct Diffuse {
    shadows: Whitted,
    albedo: Vec<Vec3>,
    samples: u32,
    rays: CosineRays,
}

/// The catalogue entry of the `diffuse` ray generator.
pub fn info() -> StageVariantInfo {
    let info = StageVariantInfo::new(
        StageKind::Raygen,
        "diffuse",
        "diffuse paths: cosine-weighted Lambertian bounces (nearest hit) with shadow rays to \
         the lights at every vertex, counter-based random numbers (seed 001 §4)",
    )
    .param(ParamInfo::int(
        "samples",
        1,
        1,
        MAX_SAMPLES as i64,
        "paths per pixel",
    ))
    .param(ParamInfo::int(
        "seed",
        0,
        0,
        u32::MAX as i64,
        "seed of the counter-based random numbers",
    ));
    offsets::offsets_param(surface_ray_params(info))
}

/// Registers `diffuse` ([`info`], [`Diffuse::new`]).
pub fn register(registry: &mut Registry<Cpu>) -> Result<()> {
    registry.add_raygen(info(), |ctx, spec| {
        Ok(Box::new(Diffuse::new(ctx.scene, spec)?))
    })?;
    Ok(())
}

impl Diffuse {
    /// A generator for `scene` with the parameters of a resolved `spec` (see [`info`]).
    pub fn new(scene: &Arc<Scene>, spec: &StageSpec) -> Result<Diffuse> {
        let samples = spec.u32_in("samples", 1..=MAX_SAMPLES)?;
        let seed = spec.u32_in("seed", 0..=u32::MAX)?;
        let (_, policy) = policy_from_spec(scene, spec)?;
        let mut albedo = Vec::with_capacity(scene.materials.len());
        for m in &scene.materials {
            if !m.diffuse.is_finite() {
                return Err(CoreError::InvalidInput(format!(
                    "material `{}` has a non-finite diffuse colour",
                    m.name
                )));
            }
            albedo.push(m.diffuse.max(Vec3::ZERO));
        }
        // One hemisphere set for both kinds: the shadow generator is built without offsets and
        // given this one.
        let offsets = Offsets::from_spec(scene, spec)?;
        let mut shadow_spec = spec.clone();
        shadow_spec
            .params
            .insert("offsets".into(), crsh_core::ParamValue::Str("none".into()));
        Ok(Diffuse {
            shadows: Whitted::new(scene, &shadow_spec)?
                .lambertian()
                .with_offsets(offsets),
            albedo,
            samples,
            rays: CosineRays {
                seed,
                min_throughput: min_throughput_param(spec)?,
                policy,
            },
        })
    }

    /// The origin offsets in use.
    pub fn offsets(&self) -> &Offsets {
        self.shadows.offsets()
    }

    /// Paths started per pixel.
    pub fn samples(&self) -> u32 {
        self.samples
    }

    /// The diffuse ray of path `sample` leaving surface `s` (index `source`), before the
    /// origin offset.
    pub fn ray(&self, source: u32, s: &Surface, sample: u32, paths: u32) -> Option<Ray> {
        let albedo = self.albedo.get(s.material as usize).copied()?;
        let throughput = s.throughput * albedo / paths as f32;
        self.rays.ray(
            RayKind::Diffuse,
            source,
            s,
            sample,
            throughput,
            f32::INFINITY,
        )
    }

    /// Diffuse ray creation before trimming: `samples` slots per primary vertex (depth 0),
    /// one per deeper vertex, surface-major, with their head flags and the origin offsets
    /// applied; plus the number of rays the offsets ended. Every surface of one batch has the
    /// same depth in the frame driver; a mixed batch is made with the largest slot count.
    pub fn diffuse_slots(&self, surfaces: &[Surface]) -> Result<(Vec<Ray>, Vec<u32>, u64)> {
        let per = self.diffuse_batch(surfaces)?;
        fill_slots(
            surfaces,
            per,
            "diffuse rays",
            self.shadows.offsets(),
            |source, k, s| self.diffuse_ray(source, k, s),
        )
    }

    /// [`Diffuse::diffuse_slots`]' rays compacted per run as they are made ([`fill_runs`]), and
    /// the count the offsets ended: what [`RayGen::generate`] concatenates.
    pub fn diffuse_runs(&self, surfaces: &[Surface]) -> Result<(Vec<Vec<Ray>>, u64)> {
        let per = self.diffuse_batch(surfaces)?;
        fill_runs(
            surfaces,
            per,
            "diffuse rays",
            self.shadows.offsets(),
            |source, k, s| self.diffuse_ray(source, k, s),
        )
    }

    /// Checks a batch's materials and gives its slots per surface.
    fn diffuse_batch(&self, surfaces: &[Surface]) -> Result<usize> {
        if let Some(s) = crate::position_first(surfaces, |s| {
            s.is_hit() && s.material as usize >= self.albedo.len()
        })
        .map(|i| &surfaces[i])
        {
            return Err(CoreError::InvalidInput(format!(
                "surface of pixel {} has material {} but the scene has {}",
                s.pixel,
                s.material,
                self.albedo.len()
            )));
        }
        Ok(if surfaces.iter().any(|s| s.depth == 0) {
            self.samples as usize
        } else {
            1
        })
    }

    /// Diffuse slot `k` of surface `s` (index `source`): a primary vertex starts `samples`
    /// paths; a deeper one continues its own.
    fn diffuse_ray(&self, source: u32, k: u32, s: &Surface) -> Option<Ray> {
        let (sample, paths) = if s.depth == 0 {
            (k, self.samples)
        } else if k == 0 {
            (s.sample(), 1)
        } else {
            return None;
        };
        self.ray(source, s, sample, paths)
    }
}

impl RayGen<Cpu> for Diffuse {
    fn name(&self) -> &str {
        "diffuse"
    }

    fn table_bytes(&self) -> u64 {
        self.offsets().table_bytes()
    }

    fn bounce_kinds(&self) -> &[RayKind] {
        &[RayKind::Diffuse]
    }

    fn generate(
        &self,
        backend: &Cpu,
        surfaces: &Vec<Surface>,
        kind: RayKind,
        stats: &mut Stats,
    ) -> Result<Vec<Ray>> {
        let runs = match kind {
            RayKind::Shadow => return self.shadows.generate(backend, surfaces, kind, stats),
            RayKind::Diffuse => {
                let (runs, ended) = self.diffuse_runs(surfaces)?;
                stats.add_offset_ended(kind, ended);
                runs
            }
            other => {
                return Err(CoreError::Unsupported {
                    stage: "raygen",
                    variant: "diffuse".into(),
                    what: format!("{} rays (it makes shadow and diffuse rays)", other.name()),
                })
            }
        };
        let t = Instant::now();
        let rays = concat_in_order(runs);
        stats.add_time("trimming", t.elapsed());
        Ok(rays)
    }
}
