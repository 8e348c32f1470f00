//! `diffuse`: the shader of the diffuse path tracer (raygen `diffuse`, seed 001 §4).
//!
//! Direct light ([`Shader::shade_direct`]) is the Phong shader's with the Lambertian model
//! ([`Model::Lambert`]): at a hit, `emission × throughput + Σ visible lights albedo / π ·
//! clamp(l · n, 0, 1) · colour · intensity · attenuation × throughput` (a light behind the
//! geometric normal lights nothing; visibility from the shadow rays); a background record (a
//! path that left the scene) adds `background × throughput`, the environment's light.
//!
//! [`Shader::resolve`] turns diffuse rays and their nearest hits into the next path vertices
//! like the Phong shader, and stores each ray's sample index ([`Ray::light`]) in the vertex
//! ([`Surface::sample`]), so the next bounce draws the random numbers of the same path.

use std::sync::Arc;

use crsh_core::{
    Hit, HitMode, ParamInfo, Ray, RayKind, Registry, Result, Shader, StageKind, StageSpec,
    StageVariantInfo, Stats, Surface,
};
use crsh_scene::Scene;

use crate::backend::Cpu;
use crate::shade::phong::{Model, Phong};

/// The diffuse path tracer's shader (variant `diffuse`).
#[derive(Clone, Debug)]
pub struct DiffuseShader {
    inner: Phong,
}

/// The catalogue entry of the `diffuse` shader.
pub fn info() -> StageVariantInfo {
    StageVariantInfo::new(
        StageKind::Shade,
        "diffuse",
        "Lambertian direct light at every path vertex and emission, for raygen `diffuse`",
    )
    .param(
        ParamInfo::float(
            "background",
            0.0,
            "grey radiance of the environment that paths leaving the scene see",
        )
        .range(0.0, f64::INFINITY),
    )
}

/// Registers `diffuse` ([`info`], [`DiffuseShader::new`]).
pub fn register(registry: &mut Registry<Cpu>) -> Result<()> {
    registry.add_shader(info(), |ctx, spec| {
        Ok(Box::new(DiffuseShader::new(ctx.scene, spec)?))
    })?;
    Ok(())
}

impl DiffuseShader {
    /// The shader for `scene` with a resolved `spec` (`background` ≥ 0).
    pub fn new(scene: &Arc<Scene>, spec: &StageSpec) -> Result<DiffuseShader> {
        let mut phong_spec = StageSpec::new("phong");
        phong_spec.params = spec.params.clone();
        phong_spec
            .params
            .insert("ambient".into(), crsh_core::ParamValue::Float(0.0));
        Ok(DiffuseShader {
            inner: Phong::new(scene, &phong_spec)?.with_model(Model::Lambert),
        })
    }

    /// The next path vertices of diffuse `rays` and their nearest `hits`, each carrying its
    /// ray's sample index.
    pub fn next_surfaces(&self, rays: &[Ray], hits: &[Hit]) -> Result<Vec<Surface>> {
        let mut next = self.inner.next_surfaces(rays, hits)?;
        for (s, r) in next.iter_mut().zip(rays) {
            if r.kind == RayKind::Diffuse as u32 {
                s.flags |= r.light << Surface::SAMPLE_SHIFT;
            }
        }
        Ok(next)
    }
}

impl Shader<Cpu> for DiffuseShader {
    fn name(&self) -> &str {
        "diffuse"
    }

    fn shade_direct(
        &self,
        _backend: &Cpu,
        surfaces: &Vec<Surface>,
        shadow_rays: &Vec<Ray>,
        shadow_hits: &Vec<Hit>,
        mode: HitMode,
        image: &mut Vec<[f32; 4]>,
        _stats: &mut Stats,
    ) -> Result<()> {
        self.inner
            .shade_mode(surfaces, shadow_rays, shadow_hits, mode, image)
    }

    fn resolve(
        &self,
        _backend: &Cpu,
        rays: &Vec<Ray>,
        hits: &Vec<Hit>,
        _stats: &mut Stats,
    ) -> Result<Vec<Surface>> {
        self.next_surfaces(rays, hits)
    }
}
