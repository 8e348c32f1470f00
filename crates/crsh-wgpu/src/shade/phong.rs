//! `phong` on the wgpu backend: direct light with shadows (seed 000 eq. 3.19) and resolution of
//! reflection / refraction hits into the next path vertices (eq. 3.17-3.18).
//!
//! The twin is [`crsh_cpu::shade::phong::Phong`] (same parameters `ambient`, `background`, same
//! conventions: a light behind the geometric normal's plane lights nothing, no highlight when
//! `fd = 0`, emission unweighted, the material's local weight and the record's throughput).
//! `kernels/surface.wgsl` is the twin of [`crsh_cpu::surface::surface_from_hit`].
//!
//! **Deterministic accumulation.** A pixel may receive several records in one call (the
//! reflection and refraction vertices of a bounce). The CPU adds them to the pixel in record
//! order; floating-point addition does not commute, and WGSL has no float atomics, so the
//! device does the same in rounds: each record not yet added elects itself for its pixel with
//! an integer `atomicMin` of its index, and the winners add their contribution. A pixel thus
//! sums its records in record order, as many rounds as the most records any pixel has (read
//! back once), and the image does not depend on scheduling. The per-record contributions
//! agree with the CPU's up to WGSL's rounding of `sqrt`, division and `pow`.
//!
//! Records and rays are bound whole: batches above one storage binding (13 M surface records on
//! a device with 1 GiB bindings, 1.6 M on lavapipe's 128 MiB) fail with
//! [`crate::GpuError::TooLarge`].

use std::sync::Arc;

use bytemuck::{Pod, Zeroable};
use crsh_core::{CoreError, Hit, Ray, Registry, Result, Shader, StageSpec, Stats, Surface};

use crate::adapter::GpuContext;
use crate::backend::{GpuBuffer, Wgpu};
use crate::error::GpuResult;
use crate::kernel::{encoder, submit, uniform, Kernel, Slot};
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
}

struct PhongKernels {
    kernel: Kernel,
}

impl PhongKernels {
    fn new(ctx: &GpuContext) -> GpuResult<PhongKernels> {
        let source = compose(&[GLAM_WGSL, SURFACE_WGSL, SHADER]);
        let mut slots = vec![Slot::Uniform];
        slots.extend([Slot::Read; 5]);
        slots.extend([Slot::ReadWrite; 5]);
        slots.extend([Slot::Read; 3]);
        slots.push(Slot::ReadWrite);
        slots.extend([Slot::Read; 2]);
        Ok(PhongKernels {
            kernel: Kernel::new(
                ctx,
                "crsh phong",
                &source,
                &[
                    "visibility",
                    "contribution",
                    "reset_heads",
                    "elect",
                    "apply",
                    "resolve",
                ],
                &slots,
            )?,
        })
    }
}

/// The GPU Phong shader (variant `phong`).
pub struct Phong {
    scene: Arc<GpuScene>,
    ambient: f32,
    background: f32,
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
        Ok(Phong {
            scene: Arc::clone(scene),
            ambient: spec.f64("ambient")? as f32,
            background: spec.f64("background")? as f32,
        })
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
        }
    }

    /// Binds the 17 slots: `bufs` are the per-call buffers in slot order 1-10 and 14-16.
    #[allow(clippy::too_many_arguments)]
    fn bind(
        &self,
        k: &Kernel,
        params: &Params,
        surfaces: &GpuBuffer<Surface>,
        shadow: (&GpuBuffer<Ray>, &GpuBuffer<Hit>),
        work: (&GpuBuffer<u32>, &GpuBuffer<[f32; 4]>, &GpuBuffer<u32>),
        image: &GpuBuffer<[f32; 4]>,
        report: &GpuBuffer<u32>,
        resolve: (&GpuBuffer<Surface>, &GpuBuffer<Ray>, &GpuBuffer<Hit>),
    ) -> wgpu::BindGroup {
        let ctx = self.scene.ctx();
        let u = uniform(ctx, "crsh phong params", params);
        k.bind_group(
            ctx,
            &[
                u.as_entire_binding(),
                surfaces.binding(),
                shadow.0.binding(),
                shadow.1.binding(),
                self.scene.materials.binding(),
                self.scene.lights.binding(),
                work.0.binding(),
                work.1.binding(),
                work.2.binding(),
                image.binding(),
                report.binding(),
                self.scene.triangles.binding(),
                self.scene.normals.binding(),
                self.scene.info.binding(),
                resolve.0.binding(),
                resolve.1.binding(),
                resolve.2.binding(),
            ],
        )
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
        image: &mut GpuBuffer<[f32; 4]>,
        _stats: &mut Stats,
    ) -> Result<()> {
        if shadow_rays.len() != shadow_hits.len() {
            return Err(CoreError::InvalidInput(format!(
                "{} shadow rays but {} hits",
                shadow_rays.len(),
                shadow_hits.len()
            )));
        }
        let n = surfaces.len();
        if n == 0 {
            return Ok(());
        }
        let ctx = backend.context();
        for (what, bytes) in [
            ("surface records", surfaces.byte_len()),
            ("shadow rays", shadow_rays.byte_len()),
            ("image", image.byte_len()),
        ] {
            ctx.check_storage_binding(what, bytes)?;
        }
        let nl = self.scene.scene.lights.len();
        let k = ctx.kernel(PhongKernels::new)?;
        let visible = GpuBuffer::<u32>::zeroed(ctx, "crsh phong visibility", n * nl)?;
        let contrib = GpuBuffer::<[f32; 4]>::zeroed(ctx, "crsh phong contributions", n)?;
        let per_pixel = GpuBuffer::<u32>::zeroed(ctx, "crsh phong per pixel", image.len())?;
        let report = GpuBuffer::<u32>::zeroed(ctx, "crsh phong report", 4)?;
        let no_surfaces = GpuBuffer::<Surface>::zeroed(ctx, "crsh phong unused", 0)?;
        let no_rays = GpuBuffer::<Ray>::zeroed(ctx, "crsh phong unused", 0)?;
        let no_hits = GpuBuffer::<Hit>::zeroed(ctx, "crsh phong unused", 0)?;
        let params = Params {
            n_pixels: image.len() as u32,
            n_shadow: shadow_rays.len() as u32,
            ..self.params(n)
        };
        let bg = self.bind(
            &k.kernel,
            &params,
            surfaces,
            (shadow_rays, shadow_hits),
            (&visible, &contrib, &per_pixel),
            image,
            &report,
            (&no_surfaces, &no_rays, &no_hits),
        );
        let mut enc = encoder(ctx, "crsh phong");
        {
            let mut pass = ctx.compute_pass(&mut enc, "crsh phong contributions");
            k.kernel
                .dispatch(ctx, &mut pass, "visibility", &bg, shadow_rays.len() as u32)?;
            k.kernel
                .dispatch(ctx, &mut pass, "contribution", &bg, n as u32)?;
        }
        submit(ctx, "crsh phong contributions", enc)?;
        let r = report.to_vec(ctx)?;
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
        let rounds = r[1];
        let mut enc = encoder(ctx, "crsh phong accumulate");
        {
            let mut pass = ctx.compute_pass(&mut enc, "crsh phong accumulate");
            k.kernel
                .dispatch(ctx, &mut pass, "reset_heads", &bg, image.len() as u32)?;
            for _ in 0..rounds {
                k.kernel.dispatch(ctx, &mut pass, "elect", &bg, n as u32)?;
                k.kernel.dispatch(ctx, &mut pass, "apply", &bg, n as u32)?;
            }
        }
        submit(ctx, "crsh phong accumulate", enc)?;
        Ok(())
    }

    fn resolve(
        &self,
        backend: &Wgpu,
        rays: &GpuBuffer<Ray>,
        hits: &GpuBuffer<Hit>,
        _stats: &mut Stats,
    ) -> Result<GpuBuffer<Surface>> {
        if rays.len() != hits.len() {
            return Err(CoreError::InvalidInput(format!(
                "{} rays but {} hits",
                rays.len(),
                hits.len()
            )));
        }
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
        let u32s = GpuBuffer::<u32>::zeroed(ctx, "crsh phong unused", 0)?;
        let vec4s = GpuBuffer::<[f32; 4]>::zeroed(ctx, "crsh phong unused", 0)?;
        let no_surfaces = GpuBuffer::<Surface>::zeroed(ctx, "crsh phong unused", 0)?;
        let no_rays = GpuBuffer::<Ray>::zeroed(ctx, "crsh phong unused", 0)?;
        let no_hits = GpuBuffer::<Hit>::zeroed(ctx, "crsh phong unused", 0)?;
        let bg = self.bind(
            &k.kernel,
            &self.params(n),
            &no_surfaces,
            (&no_rays, &no_hits),
            (
                &u32s,
                &vec4s,
                &GpuBuffer::<u32>::zeroed(ctx, "crsh phong unused", 0)?,
            ),
            &GpuBuffer::<[f32; 4]>::zeroed(ctx, "crsh phong unused", 0)?,
            &report,
            (&out, rays, hits),
        );
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
