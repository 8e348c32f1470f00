//! `ao` on the wgpu backend: the ambient-occlusion shader (seed 001 §4), the twin of
//! [`crsh_cpu::shade::ao::AoShader`].
//!
//! A pixel's value is the unoccluded fraction of its AO rays: every record of the batch, the
//! surfaces and then the rays, contributes to its pixel (`ao.wgsl`): a surface
//! `background × throughput` where it is a miss (and alpha 1 whatever it is), a ray its
//! throughput where its any-hit query found nothing. The contributions are added in that
//! order, the CPU's, by [`crate::kernels::accumulate`]: a surface is one run and the
//! surface-major rays of a surface another, so a G-buffer batch takes two rounds whatever the
//! number of samples, and the image equals the CPU's bit for bit on the same rays and hits.
//!
//! [`Shader::resolve`] builds path vertices as the Phong shader does (the `ao` generator makes
//! no bounce rays, so the frame driver never calls it for an AO pipeline).

use std::sync::Arc;

use bytemuck::{Pod, Zeroable};
use crsh_core::{
    CoreError, Hit, HitMode, Ray, RayKind, Registry, Result, Shader, StageSpec, Stats, Surface,
};

use crate::adapter::GpuContext;
use crate::backend::{GpuBuffer, Wgpu};
use crate::error::GpuResult;
use crate::kernel::{uniform, Kernel, Slot};
use crate::kernels::accumulate::{accumulate_in_order, Contribution};
use crate::scene::GpuScene;
use crate::shade::phong::Phong;

const SHADER: &str = include_str!("ao.wgsl");

#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct Params {
    n_surfaces: u32,
    n_rays: u32,
    n_pixels: u32,
    background: f32,
}

struct AoKernels {
    kernel: Kernel,
}

impl AoKernels {
    fn new(ctx: &GpuContext) -> GpuResult<AoKernels> {
        Ok(AoKernels {
            kernel: Kernel::new(
                ctx,
                "crsh ao shade",
                SHADER,
                &["contribution"],
                &[
                    Slot::Uniform,
                    Slot::Read,
                    Slot::Read,
                    Slot::Read,
                    Slot::ReadWrite,
                    Slot::ReadWrite,
                ],
            )?,
        })
    }
}

/// The GPU ambient-occlusion shader (variant `ao`).
pub struct AoShader {
    background: f32,
    resolver: Phong,
}

/// Registers the wgpu `ao` under its CPU twin's catalogue entry (same name, parameters,
/// defaults and documentation).
pub fn register(registry: &mut Registry<Wgpu>) -> Result<()> {
    registry.add_shader(crsh_cpu::shade::ao::info(), |ctx, spec| {
        Ok(Box::new(AoShader::new(ctx.scene, spec)?))
    })?;
    Ok(())
}

impl AoShader {
    /// The shader for `scene` with a resolved `spec` (`background`), validated by the CPU
    /// twin's constructor.
    pub fn new(scene: &Arc<GpuScene>, spec: &StageSpec) -> Result<AoShader> {
        crsh_cpu::shade::ao::AoShader::new(&scene.scene, spec)?;
        let background = spec.f64("background")? as f32;
        Ok(AoShader {
            background,
            resolver: Phong::from_parts(scene, 0.0, background),
        })
    }

    /// Adds the unoccluded fraction of every surface's AO rays to `image` (module docs).
    pub fn shade(
        &self,
        backend: &Wgpu,
        surfaces: &GpuBuffer<Surface>,
        rays: &GpuBuffer<Ray>,
        hits: &GpuBuffer<Hit>,
        image: &mut GpuBuffer<[f32; 4]>,
    ) -> Result<()> {
        crsh_core::ray::check_hits_per_ray("AO rays", rays.len(), hits.len())?;
        let records = surfaces.len() + rays.len();
        if records == 0 {
            return Ok(());
        }
        if records >= u32::MAX as usize {
            return Err(CoreError::InvalidInput(format!(
                "{} surfaces and {} AO rays do not fit 32-bit record indices",
                surfaces.len(),
                rays.len()
            )));
        }
        let ctx = backend.context();
        for (what, bytes) in [
            ("surface records", surfaces.byte_len()),
            ("AO rays", rays.byte_len()),
            (
                "contributions",
                (records * std::mem::size_of::<Contribution>()) as u64,
            ),
            ("image", image.byte_len()),
        ] {
            ctx.check_storage_binding(what, bytes)?;
        }
        let k = ctx.kernel(AoKernels::new)?;
        let contrib = GpuBuffer::<Contribution>::zeroed(ctx, "crsh ao contributions", records)?;
        let report = GpuBuffer::<u32>::zeroed(ctx, "crsh ao report", 4)?;
        let params = Params {
            n_surfaces: surfaces.len() as u32,
            n_rays: rays.len() as u32,
            n_pixels: image.len() as u32,
            background: self.background,
        };
        let u = uniform(ctx, "crsh ao params", &params);
        let bg = k.kernel.bind_group(
            ctx,
            &[
                u.as_entire_binding(),
                surfaces.binding(),
                rays.binding(),
                hits.binding(),
                contrib.binding(),
                report.binding(),
            ],
        );
        let contribute = |pass: &mut wgpu::ComputePass<'_>| {
            k.kernel
                .dispatch(ctx, pass, "contribution", &bg, records as u32)
        };
        let check = |r: &[u32]| {
            if r[0] != 0 {
                return Err(CoreError::InvalidInput(format!(
                    "surface record {} does not fit an image of {} pixels",
                    u32::MAX - r[0],
                    image.len()
                )));
            }
            if r[2] != 0 {
                return Err(CoreError::InvalidInput(format!(
                    "ray {} is not an AO ray of these {} surfaces and {} pixels",
                    u32::MAX - r[2],
                    surfaces.len(),
                    image.len()
                )));
            }
            Ok(())
        };
        accumulate_in_order(
            ctx,
            "crsh ao",
            &contrib,
            image,
            &report,
            &contribute,
            &check,
        )
    }
}

impl Shader<Wgpu> for AoShader {
    fn name(&self) -> &str {
        "ao"
    }

    fn shades(&self, kind: RayKind) -> bool {
        kind == RayKind::Ao
    }

    fn shade_direct(
        &self,
        backend: &Wgpu,
        surfaces: &GpuBuffer<Surface>,
        rays: &GpuBuffer<Ray>,
        hits: &GpuBuffer<Hit>,
        mode: HitMode,
        image: &mut GpuBuffer<[f32; 4]>,
        _stats: &mut Stats,
    ) -> Result<()> {
        if mode != HitMode::Any {
            return Err(CoreError::Unsupported {
                stage: "shade",
                variant: "ao (wgpu)".into(),
                what: format!(
                    "visibility rays traced with {} queries (only any-hit: soft shadows are \
                     CPU-only)",
                    mode.name()
                ),
            });
        }
        self.shade(backend, surfaces, rays, hits, image)
    }

    fn resolve(
        &self,
        backend: &Wgpu,
        rays: &GpuBuffer<Ray>,
        hits: &GpuBuffer<Hit>,
        _stats: &mut Stats,
    ) -> Result<GpuBuffer<Surface>> {
        self.resolver.next_surfaces(backend, rays, hits)
    }
}
