//! `phong` on the wgpu backend: direct light with shadows (seed 000 eq. 3.19) and resolution of
//! reflection / refraction hits into the next path vertices (eq. 3.17-3.18).
//!
//! The twin is [`crsh_cpu::shade::phong::Phong`] (same parameters `ambient`, `background`, same
//! conventions: a light behind the geometric normal's plane lights nothing, no highlight when
//! `fd = 0`, emission unweighted, the material's local weight and the record's throughput),
//! including its Lambertian model ([`Model::Lambert`], which the `diffuse` shader uses).
//! `kernels/surface.wgsl` is the twin of [`crsh_cpu::surface::surface_from_hit`].
//!
//! **Deterministic accumulation.** A pixel may receive several records in one call (the
//! reflection and refraction vertices of a bounce). The CPU adds them to the pixel in record
//! order; the device does the same with [`crate::kernels::accumulate`] (runs of records of
//! one pixel elected in rounds by an integer `atomicMin`), so the image does not depend on
//! scheduling. The per-record contributions agree with the CPU's up to WGSL's rounding of
//! `sqrt`, division and `pow`.
//!
//! Records and rays are bound whole: batches above one storage binding (13 M surface records on
//! a device with 1 GiB bindings, 1.6 M on lavapipe's 128 MiB) fail with
//! [`crate::GpuError::TooLarge`].

use std::sync::Arc;

use bytemuck::{Pod, Zeroable};
use crsh_core::{
    CoreError, Hit, HitMode, Ray, Registry, Result, Shader, StageSpec, Stats, Surface,
};
pub use crsh_cpu::shade::phong::Model;

use crate::adapter::GpuContext;
use crate::backend::{GpuBuffer, Wgpu};
use crate::error::GpuResult;
use crate::kernel::{encoder, submit, uniform, Kernel, Slot};
use crate::kernels::accumulate::{accumulate_in_order, Contribution};
use crate::kernels::{compose, GLAM_WGSL, SURFACE_WGSL};
use crate::scene::GpuScene;

const SHADER: &str = include_str!("phong.wgsl");

#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct Params {
    n: u32,
    n_lights: u32,
    n_pixels: u32,
    n_materials: u32,
    n_tris: u32,
    n_shadow: u32,
    ambient: f32,
    background: f32,
    lambert: u32,
    pad: [u32; 3],
}

struct PhongKernels {
    kernel: Kernel,
}

impl PhongKernels {
    fn new(ctx: &GpuContext) -> GpuResult<PhongKernels> {
        let mut slots = vec![Slot::Uniform];
        slots.extend([Slot::Read; 5]);
        slots.extend([Slot::ReadWrite; 3]);
        slots.extend([Slot::Read; 3]);
        slots.push(Slot::ReadWrite);
        slots.extend([Slot::Read; 2]);
        Ok(PhongKernels {
            kernel: Kernel::new(
                ctx,
                "crsh phong",
                &compose(&[GLAM_WGSL, SURFACE_WGSL, SHADER]),
                &["visibility", "contribution", "resolve"],
                &slots,
            )?,
        })
    }
}

/// The per-call buffers of one dispatch of `phong.wgsl`; `None` binds an empty buffer.
#[derive(Default)]
struct Calls<'a> {
    surfaces: Option<&'a GpuBuffer<Surface>>,
    shadow_rays: Option<&'a GpuBuffer<Ray>>,
    shadow_hits: Option<&'a GpuBuffer<Hit>>,
    visible: Option<&'a GpuBuffer<u32>>,
    contrib: Option<&'a GpuBuffer<Contribution>>,
    resolved: Option<&'a GpuBuffer<Surface>>,
    rays: Option<&'a GpuBuffer<Ray>>,
    hits: Option<&'a GpuBuffer<Hit>>,
}

/// The GPU Phong shader (variant `phong`).
pub struct Phong {
    scene: Arc<GpuScene>,
    ambient: f32,
    background: f32,
    model: Model,
}

/// Registers the wgpu `phong` under its CPU twin's catalogue entry (same name, parameters,
/// defaults and documentation).
pub fn register(registry: &mut Registry<Wgpu>) -> Result<()> {
    registry.add_shader(crsh_cpu::shade::phong::info(), |ctx, spec| {
        Ok(Box::new(Phong::new(ctx.scene, spec)?))
    })?;
    Ok(())
}

impl Phong {
    /// The shader for `scene` with a resolved `spec` (`ambient`, `background`), validated by
    /// the CPU twin's constructor (parameters, materials, lights).
    pub fn new(scene: &Arc<GpuScene>, spec: &StageSpec) -> Result<Phong> {
        crsh_cpu::shade::phong::Phong::new(&scene.scene, spec)?;
        Ok(Phong::from_parts(
            scene,
            spec.f64("ambient")? as f32,
            spec.f64("background")? as f32,
        ))
    }

    /// The shader with these settings, unvalidated (for shaders that only resolve hits).
    pub(crate) fn from_parts(scene: &Arc<GpuScene>, ambient: f32, background: f32) -> Phong {
        Phong {
            scene: Arc::clone(scene),
            ambient,
            background,
            model: Model::Phong,
        }
    }

    /// The same shader with the reflection model `model`, as
    /// [`crsh_cpu::shade::phong::Phong::with_model`]. With [`Model::Lambert`], resolution also
    /// keeps each diffuse ray's sample index in its vertex ([`Surface::sample`]), as the
    /// `diffuse` shader needs.
    pub fn with_model(mut self, model: Model) -> Self {
        self.model = model;
        self
    }

    fn params(&self, n: usize) -> Params {
        let s = &self.scene.scene;
        Params {
            n: n as u32,
            n_lights: s.lights.len() as u32,
            n_pixels: 0,
            n_materials: s.materials.len() as u32,
            n_tris: s.triangle_count() as u32,
            n_shadow: 0,
            ambient: self.ambient,
            background: self.background,
            lambert: u32::from(self.model == Model::Lambert),
            pad: [0; 3],
        }
    }

    /// Binds `calls` (empty buffers where `None`) with the scene's buffers and `report`.
    fn bind(
        &self,
        k: &Kernel,
        params: &Params,
        calls: Calls<'_>,
        report: &GpuBuffer<u32>,
    ) -> GpuResult<crate::kernel::KernelBindings> {
        let ctx = self.scene.ctx();
        let u = uniform(ctx, "crsh phong params", params);
        let no_surfaces = GpuBuffer::<Surface>::zeroed(ctx, "crsh phong unused", 0)?;
        let no_rays = GpuBuffer::<Ray>::zeroed(ctx, "crsh phong unused", 0)?;
        let no_hits = GpuBuffer::<Hit>::zeroed(ctx, "crsh phong unused", 0)?;
        let no_u32 = GpuBuffer::<u32>::zeroed(ctx, "crsh phong unused", 0)?;
        let no_contrib = GpuBuffer::<Contribution>::zeroed(ctx, "crsh phong unused", 0)?;
        Ok(k.bind_group(
            ctx,
            &[
                u.as_entire_binding(),
                calls.surfaces.unwrap_or(&no_surfaces).binding(),
                calls.shadow_rays.unwrap_or(&no_rays).binding(),
                calls.shadow_hits.unwrap_or(&no_hits).binding(),
                self.scene.materials.binding(),
                self.scene.lights.binding(),
                calls.visible.unwrap_or(&no_u32).binding(),
                calls.contrib.unwrap_or(&no_contrib).binding(),
                report.binding(),
                self.scene.triangles.binding(),
                self.scene.normals.binding(),
                self.scene.info.binding(),
                calls.resolved.unwrap_or(&no_surfaces).binding(),
                calls.rays.unwrap_or(&no_rays).binding(),
                calls.hits.unwrap_or(&no_hits).binding(),
            ],
        ))
    }

    /// Adds the direct light of `surfaces` to `image` ([`Shader::shade_direct`]).
    pub fn shade(
        &self,
        backend: &Wgpu,
        surfaces: &GpuBuffer<Surface>,
        shadow_rays: &GpuBuffer<Ray>,
        shadow_hits: &GpuBuffer<Hit>,
        image: &mut GpuBuffer<[f32; 4]>,
    ) -> Result<()> {
        crsh_core::ray::check_hits_per_ray("shadow rays", shadow_rays.len(), shadow_hits.len())?;
        let n = surfaces.len();
        if n == 0 {
            return Ok(());
        }
        let ctx = backend.context();
        for (what, bytes) in [
            ("surface records", surfaces.byte_len()),
            ("shadow rays", shadow_rays.byte_len()),
            (
                "contributions",
                (n * std::mem::size_of::<Contribution>()) as u64,
            ),
            ("image", image.byte_len()),
        ] {
            ctx.check_storage_binding(what, bytes)?;
        }
        let nl = self.scene.scene.lights.len();
        let k = ctx.kernel(PhongKernels::new)?;
        let visible = GpuBuffer::<u32>::zeroed(ctx, "crsh phong visibility", n * nl)?;
        let contrib = GpuBuffer::<Contribution>::zeroed(ctx, "crsh phong contributions", n)?;
        let report = GpuBuffer::<u32>::zeroed(ctx, "crsh phong report", 4)?;
        let params = Params {
            n_pixels: image.len() as u32,
            n_shadow: shadow_rays.len() as u32,
            ..self.params(n)
        };
        let calls = Calls {
            surfaces: Some(surfaces),
            shadow_rays: Some(shadow_rays),
            shadow_hits: Some(shadow_hits),
            visible: Some(&visible),
            contrib: Some(&contrib),
            ..Calls::default()
        };
        let bg = self.bind(&k.kernel, &params, calls, &report)?;
        let contribute = |pass: &mut wgpu::ComputePass<'_>| {
            k.kernel
                .dispatch(ctx, pass, "visibility", &bg, shadow_rays.len() as u32)?;
            k.kernel.dispatch(ctx, pass, "contribution", &bg, n as u32)
        };
        let check = |r: &[u32]| {
            if r[2] != 0 {
                return Err(CoreError::InvalidInput(format!(
                    "shadow ray {} does not match {n} surfaces and {nl} lights",
                    u32::MAX - r[2]
                )));
            }
            if r[0] != 0 {
                return Err(CoreError::InvalidInput(format!(
                    "surface record {} does not fit an image of {} pixels and {} materials",
                    u32::MAX - r[0],
                    image.len(),
                    self.scene.scene.materials.len()
                )));
            }
            Ok(())
        };
        accumulate_in_order(
            ctx,
            "crsh phong",
            &contrib,
            image,
            &report,
            &contribute,
            &check,
        )
    }

    /// The next path vertices of `rays` and their nearest `hits` ([`Shader::resolve`]); a hit
    /// on a triangle the scene does not have is an error, as in the CPU twin
    /// ([`crsh_cpu::surface::next_surfaces`], which every CPU shader resolves with).
    pub(crate) fn next_surfaces(
        &self,
        backend: &Wgpu,
        rays: &GpuBuffer<Ray>,
        hits: &GpuBuffer<Hit>,
    ) -> Result<GpuBuffer<Surface>> {
        crsh_core::ray::check_hits_per_ray("rays", rays.len(), hits.len())?;
        let ctx = backend.context();
        let n = rays.len();
        let out = GpuBuffer::<Surface>::zeroed(ctx, "crsh path vertices", n)?;
        if n == 0 {
            return Ok(out);
        }
        for (what, bytes) in [("rays", rays.byte_len()), ("path vertices", out.byte_len())] {
            ctx.check_storage_binding(what, bytes)?;
        }
        let k = ctx.kernel(PhongKernels::new)?;
        let report = GpuBuffer::<u32>::zeroed(ctx, "crsh phong report", 4)?;
        let calls = Calls {
            resolved: Some(&out),
            rays: Some(rays),
            hits: Some(hits),
            ..Calls::default()
        };
        let bg = self.bind(&k.kernel, &self.params(n), calls, &report)?;
        let mut enc = encoder(ctx, "crsh phong resolve");
        {
            let mut pass = ctx.compute_pass(&mut enc, "crsh phong resolve");
            k.kernel
                .dispatch(ctx, &mut pass, "resolve", &bg, n as u32)?;
        }
        submit(ctx, "crsh phong resolve", enc)?;
        let r = report.to_vec(ctx)?;
        if r[0] != 0 {
            return Err(CoreError::InvalidInput(format!(
                "hit of ray {} is on a triangle the scene does not have ({} triangles)",
                u32::MAX - r[0],
                self.scene.triangle_count()
            )));
        }
        Ok(out)
    }
}

impl Shader<Wgpu> for Phong {
    fn name(&self) -> &str {
        "phong"
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
                variant: "phong (wgpu)".into(),
                what: format!(
                    "visibility rays traced with {} queries (only any-hit: soft shadows are \
                     CPU-only)",
                    mode.name()
                ),
            });
        }
        self.shade(backend, surfaces, shadow_rays, shadow_hits, image)
    }

    fn resolve(
        &self,
        backend: &Wgpu,
        rays: &GpuBuffer<Ray>,
        hits: &GpuBuffer<Hit>,
        _stats: &mut Stats,
    ) -> Result<GpuBuffer<Surface>> {
        self.next_surfaces(backend, rays, hits)
    }
}
