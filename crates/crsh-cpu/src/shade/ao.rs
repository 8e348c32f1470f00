//! `ao`: the ambient-occlusion shader (seed 001 §4's AO renders): a pixel's value is the
//! unoccluded fraction of its AO rays.
//!
//! [`Shader::shade_direct`] receives the `ao` generator's rays and their any-hit results: every
//! ray that found no occluder adds its throughput (the surface's divided by the rays per
//! surface) to its pixel, so a primary hit with all `samples` rays free gets its full
//! throughput (white for a camera ray) and a fully occluded one 0. A ray whose origin offset
//! passed its length (seed 001: an empty interval) found nothing and counts as free. A
//! background record adds `background × throughput`. Grey: the three channels are equal.
//! Alpha is 1 wherever a record was shaded. Contributions are added in record order, so the
//! image does not depend on the thread count.
//!
//! [`Shader::resolve`] builds path vertices as the Phong shader does (the `ao` generator makes
//! no bounce rays, so the frame driver never calls it for an AO pipeline).

use std::sync::Arc;

use crsh_core::{
    CoreError, Hit, HitMode, ParamInfo, Ray, RayKind, Registry, Result, Shader, StageKind,
    StageSpec, StageVariantInfo, Stats, Surface,
};
use crsh_scene::Scene;
use rayon::prelude::*;

use crate::backend::Cpu;

/// The ambient-occlusion shader (variant `ao`).
#[derive(Clone, Debug)]
pub struct AoShader {
    scene: Arc<Scene>,
    background: f32,
}

/// The catalogue entry of the `ao` shader.
pub fn info() -> StageVariantInfo {
    StageVariantInfo::new(
        StageKind::Shade,
        "ao",
        "ambient occlusion: the unoccluded fraction of each pixel's AO rays (raygen `ao`)",
    )
    .param(
        ParamInfo::float("background", 0.0, "grey level of pixels that see nothing")
            .range(0.0, f64::INFINITY),
    )
}

/// Registers `ao` ([`info`], [`AoShader::new`]).
pub fn register(registry: &mut Registry<Cpu>) -> Result<()> {
    registry.add_shader(info(), |ctx, spec| {
        Ok(Box::new(AoShader::new(ctx.scene, spec)?))
    })?;
    Ok(())
}

impl AoShader {
    /// The shader for `scene` with a resolved `spec` (`background` ≥ 0).
    pub fn new(scene: &Arc<Scene>, spec: &StageSpec) -> Result<AoShader> {
        let background = spec.f64("background")?;
        if !background.is_finite() || background < 0.0 {
            return Err(CoreError::InvalidParam {
                key: "shade.background".into(),
                reason: format!("{background} must be a finite number ≥ 0"),
            });
        }
        Ok(AoShader {
            scene: scene.clone(),
            background: background as f32,
        })
    }

    /// Adds the unoccluded fraction of every surface's AO rays to `image` (module docs).
    pub fn shade(
        &self,
        surfaces: &[Surface],
        rays: &[Ray],
        hits: &[Hit],
        image: &mut [[f32; 4]],
    ) -> Result<()> {
        crsh_core::ray::check_hits_per_ray("AO rays", rays.len(), hits.len())?;
        if let Some(s) = surfaces.iter().find(|s| s.pixel as usize >= image.len()) {
            return Err(CoreError::InvalidInput(format!(
                "surface record for pixel {} does not fit an image of {} pixels",
                s.pixel,
                image.len()
            )));
        }
        if let Some(r) = rays.iter().find(|r| {
            r.kind != RayKind::Ao as u32
                || r.source as usize >= surfaces.len()
                || r.pixel as usize >= image.len()
        }) {
            return Err(CoreError::InvalidInput(format!(
                "ray of kind {} for surface {} and pixel {} is not an AO ray of these {} \
                 surfaces and {} pixels",
                r.kind,
                r.source,
                r.pixel,
                surfaces.len(),
                image.len()
            )));
        }
        for s in surfaces {
            let px = &mut image[s.pixel as usize];
            if !s.is_hit() {
                let c = s.throughput * self.background;
                px[0] += c.x;
                px[1] += c.y;
                px[2] += c.z;
            }
            px[3] = 1.0;
        }
        let free: Vec<bool> = hits.par_iter().map(|h| !h.is_hit()).collect();
        for (r, free) in rays.iter().zip(free) {
            if free {
                let px = &mut image[r.pixel as usize];
                px[0] += r.throughput.x;
                px[1] += r.throughput.y;
                px[2] += r.throughput.z;
            }
        }
        Ok(())
    }
}

impl Shader<Cpu> for AoShader {
    fn name(&self) -> &str {
        "ao"
    }

    fn shades(&self, kind: RayKind) -> bool {
        kind == RayKind::Ao
    }

    fn shade_direct(
        &self,
        _backend: &Cpu,
        surfaces: &Vec<Surface>,
        rays: &Vec<Ray>,
        hits: &Vec<Hit>,
        mode: HitMode,
        image: &mut Vec<[f32; 4]>,
        _stats: &mut Stats,
    ) -> Result<()> {
        if mode != HitMode::Any {
            return Err(CoreError::Unsupported {
                stage: "shade",
                variant: "ao".into(),
                what: format!(
                    "ambient-occlusion rays traced with {} queries (only any-hit)",
                    mode.name()
                ),
            });
        }
        self.shade(surfaces, rays, hits, image)
    }

    fn resolve(
        &self,
        _backend: &Cpu,
        rays: &Vec<Ray>,
        hits: &Vec<Hit>,
        _stats: &mut Stats,
    ) -> Result<Vec<Surface>> {
        crate::surface::next_surfaces(&self.scene, rays, hits)
    }
}
