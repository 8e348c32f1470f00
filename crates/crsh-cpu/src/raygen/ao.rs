//! `ao`: ambient-occlusion rays (seed 001 §4: "AO rays are rendered using several radii set to
//! a fixed percentage of the scene size. Each primary ray that finds an intersection is used
//! to generate exactly one AO ray").
//!
//! Every surface record of the first pass that holds a hit spawns `samples` rays (one, the
//! paper's setting, by default), surface-major (the rays of surface 0, then surface 1, ...),
//! compacted. Ray `j` of a surface takes the cosine-weighted direction
//! [`crsh_core::rng::front_cosine_direction`] about the surface's shading normal (kept in
//! front of its geometric normal) for the uniforms of the key (pixel, `j`, bounce = the
//! surface's depth, `seed`) ([`crsh_core::rng`]), so the rays are the same whatever the thread
//! count and on both backends. Its length is `ao_length × |scene bounding-box diagonal|`
//! (the paper's 1 %, 5 %, 10 %, 25 %: `0.01` .. `0.25`), measured from the surface point; it
//! is an any-hit ray ([`RayKind::Ao`]). The self-intersection policy is the Whitted
//! generator's ([`super::whitted::offset_segment`], param `offset`). Its throughput is the
//! surface's divided by `samples`, so the `ao` shader's sum over unoccluded rays is the
//! unoccluded fraction. [`Ray::light`] holds the sample index.
//!
//! Paths end at the first vertex ([`RayGen::bounce_kinds`] is empty): the frame's bounce
//! depth does not matter.
//!
//! With `offsets` other than `none`, each ray's `t_min` is raised past the empty hemispheres
//! of the triangle it leaves ([`super::offsets`], seed 001 §3). A ray whose offset passes its
//! length keeps its slot with the empty interval `t_min = t_max`: it stays in the batch (the
//! shader counts it unoccluded, per-ray averages keep their denominator) and intersectors end
//! it without traversal ([`Stats::add_offset_ended`] counts them).

use std::sync::Arc;
use std::time::Instant;

use crsh_core::{
    CoreError, ParamInfo, Ray, RayGen, RayKind, Registry, Result, StageKind, StageSpec,
    StageVariantInfo, Stats, Surface,
};
use crsh_scene::Scene;

use crate::backend::Cpu;
use crate::raygen::cosine::{fill_runs, fill_slots, CosineRays};
use crate::raygen::offsets::{self, Offsets};
use crate::raygen::whitted::{min_throughput_param, offset_params, policy_from_spec};
use crate::trim::concat_in_order;

/// The most rays per surface `samples` allows.
pub const MAX_SAMPLES: u32 = 4096;

/// The ambient-occlusion ray generator (variant `ao`). See the module docs.
#[derive(Clone, Debug)]
pub struct Ao {
    samples: u32,
    length: f32,
    rays: CosineRays,
    offsets: Offsets,
}

/// The catalogue entry of the `ao` ray generator.
pub fn info() -> StageVariantInfo {
    let info = StageVariantInfo::new(
        StageKind::Raygen,
        "ao",
        "ambient-occlusion rays: cosine-weighted, a fraction of the scene diagonal long, any \
         hit, counter-based random numbers (seed 001 §4)",
    )
    .param(ParamInfo::int(
        "samples",
        1,
        1,
        MAX_SAMPLES as i64,
        "AO rays per primary hit (the paper: 1)",
    ))
    .param(
        ParamInfo::float(
            "ao_length",
            0.1,
            "ray length as a fraction of the scene's bounding-box diagonal (the paper: 0.01, \
             0.05, 0.10, 0.25)",
        )
        .range(0.0, f64::INFINITY),
    )
    .param(ParamInfo::int(
        "seed",
        0,
        0,
        u32::MAX as i64,
        "seed of the counter-based random numbers",
    ))
    .param(
        ParamInfo::float(
            "min_throughput",
            1e-3,
            "rays whose largest throughput component is below this are not spawned",
        )
        .range(0.0, f64::INFINITY),
    );
    offsets::offsets_param(offset_params(info))
}

/// Registers `ao` ([`info`], [`Ao::new`]).
pub fn register(registry: &mut Registry<Cpu>) -> Result<()> {
    registry.add_raygen(info(), |ctx, spec| Ok(Box::new(Ao::new(ctx.scene, spec)?)))?;
    Ok(())
}

impl Ao {
    /// A generator for `scene` with the parameters of a resolved `spec` (see [`info`]).
    pub fn new(scene: &Arc<Scene>, spec: &StageSpec) -> Result<Ao> {
        let samples = spec.u32_in("samples", 1..=MAX_SAMPLES)?;
        let seed = spec.u32_in("seed", 0..=u32::MAX)?;
        let ao_length = spec.f64("ao_length")?;
        if !ao_length.is_finite() || ao_length <= 0.0 {
            return Err(CoreError::InvalidParam {
                key: "raygen.ao_length".into(),
                reason: format!("{ao_length} must be a finite fraction of the diagonal > 0"),
            });
        }
        let (_, policy) = policy_from_spec(scene, spec)?;
        let length = (ao_length * scene.bounds.diagonal() as f64) as f32;
        if !(length.is_finite() && length > 0.0) {
            return Err(CoreError::InvalidInput(format!(
                "scene `{}`: an AO length of {ao_length} × its diagonal is {length}",
                scene.name
            )));
        }
        Ok(Ao {
            samples,
            length,
            rays: CosineRays {
                seed,
                min_throughput: min_throughput_param(spec)?,
                policy,
            },
            offsets: Offsets::from_spec(scene, spec)?,
        })
    }

    /// The rays' length in scene units (`ao_length × diagonal`).
    pub fn length(&self) -> f32 {
        self.length
    }

    /// The origin offsets in use.
    pub fn offsets(&self) -> &Offsets {
        &self.offsets
    }

    /// AO ray `sample` of surface `s` (index `source`), before the origin offset.
    pub fn ray(&self, source: u32, s: &Surface, sample: u32) -> Option<Ray> {
        let throughput = s.throughput / self.samples as f32;
        self.rays
            .ray(RayKind::Ao, source, s, sample, throughput, self.length)
    }

    /// Ray creation before trimming: `samples` slots per surface (surface-major) and their
    /// head flags (1 where a ray was made), with the origin offsets applied. Returns the slots,
    /// the flags and the number of rays the offsets ended (interval emptied).
    pub fn slots(&self, surfaces: &[Surface]) -> Result<(Vec<Ray>, Vec<u32>, u64)> {
        fill_slots(
            surfaces,
            self.samples as usize,
            "AO rays",
            &self.offsets,
            |source, sample, s| self.ray(source, s, sample),
        )
    }

    /// [`Ao::slots`]' rays compacted per run as they are made ([`fill_runs`]), and the count
    /// the offsets ended: what [`RayGen::generate`] concatenates.
    pub fn runs(&self, surfaces: &[Surface]) -> Result<(Vec<Vec<Ray>>, u64)> {
        fill_runs(
            surfaces,
            self.samples as usize,
            "AO rays",
            &self.offsets,
            |source, sample, s| self.ray(source, s, sample),
        )
    }
}

impl RayGen<Cpu> for Ao {
    fn name(&self) -> &str {
        "ao"
    }

    fn table_bytes(&self) -> u64 {
        self.offsets.table_bytes()
    }

    fn visibility_kind(&self) -> RayKind {
        RayKind::Ao
    }

    fn bounce_kinds(&self) -> &[RayKind] {
        &[]
    }

    fn generate(
        &self,
        _backend: &Cpu,
        surfaces: &Vec<Surface>,
        kind: RayKind,
        stats: &mut Stats,
    ) -> Result<Vec<Ray>> {
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
        let (runs, ended) = self.runs(surfaces)?;
        stats.add_offset_ended(kind, ended);
        let t = Instant::now();
        let rays = concat_in_order(runs);
        stats.add_time("trimming", t.elapsed());
        Ok(rays)
    }
}
