//! `diffuse` on the wgpu backend: the diffuse path tracer's shader (raygen `diffuse`, seed 001
//! §4), the twin of [`crsh_cpu::shade::diffuse::DiffuseShader`].
//!
//! It is the wgpu [`Phong`] shader with the Lambertian model ([`Model::Lambert`]): at a hit,
//! `emission × throughput + Σ visible lights albedo / π · clamp(l · n, 0, 1) · colour ·
//! intensity · attenuation × throughput`, no specular, no ambient, every material opaque; a
//! background record adds `background × throughput`. Contributions are added to the image in
//! record order ([`crate::kernels::accumulate`]). Its resolution keeps each diffuse ray's
//! sample index ([`Ray::light`]) in the next vertex ([`Surface::sample`]), so the next bounce
//! draws the random numbers of the same path.

use std::sync::Arc;

use crsh_core::{
    CoreError, Hit, HitMode, ParamValue, Ray, Registry, Result, Shader, StageSpec, Stats, Surface,
};

use crate::backend::{GpuBuffer, Wgpu};
use crate::scene::GpuScene;
use crate::shade::phong::{Model, Phong};

/// The GPU diffuse path tracer's shader (variant `diffuse`).
pub struct DiffuseShader {
    inner: Phong,
}

/// Registers the wgpu `diffuse` under its CPU twin's catalogue entry (same name, parameters,
/// defaults and documentation).
pub fn register(registry: &mut Registry<Wgpu>) -> Result<()> {
    registry.add_shader(crsh_cpu::shade::diffuse::info(), |ctx, spec| {
        Ok(Box::new(DiffuseShader::new(ctx.scene, spec)?))
    })?;
    Ok(())
}

impl DiffuseShader {
    /// The shader for `scene` with a resolved `spec` (`background`), validated by the CPU
    /// twin's constructor.
    pub fn new(scene: &Arc<GpuScene>, spec: &StageSpec) -> Result<DiffuseShader> {
        crsh_cpu::shade::diffuse::DiffuseShader::new(&scene.scene, spec)?;
        let mut phong_spec = StageSpec::new("phong");
        phong_spec.params = spec.params.clone();
        phong_spec
            .params
            .insert("ambient".into(), ParamValue::Float(0.0));
        Ok(DiffuseShader {
            inner: Phong::new(scene, &phong_spec)?.with_model(Model::Lambert),
        })
    }
}

impl Shader<Wgpu> for DiffuseShader {
    fn name(&self) -> &str {
        "diffuse"
    }

    fn shade_direct(
        &self,
        backend: &Wgpu,
        surfaces: &GpuBuffer<Surface>,
        shadow_rays: &GpuBuffer<Ray>,
        shadow_hits: &GpuBuffer<Hit>,
        mode: HitMode,
        image: &mut GpuBuffer<[f32; 4]>,
        _stats: &mut Stats,
    ) -> Result<()> {
        if mode != HitMode::Any {
            return Err(CoreError::Unsupported {
                stage: "shade",
                variant: "diffuse (wgpu)".into(),
                what: format!(
                    "visibility rays traced with {} queries (only any-hit: soft shadows are \
                     CPU-only)",
                    mode.name()
                ),
            });
        }
        self.inner
            .shade(backend, surfaces, shadow_rays, shadow_hits, image)
    }

    fn resolve(
        &self,
        backend: &Wgpu,
        rays: &GpuBuffer<Ray>,
        hits: &GpuBuffer<Hit>,
        _stats: &mut Stats,
    ) -> Result<GpuBuffer<Surface>> {
        self.inner.next_surfaces(backend, rays, hits)
    }
}
