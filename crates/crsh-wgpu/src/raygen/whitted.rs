//! `whitted` on the wgpu backend: shadow, reflection and refraction rays (seed 000 §3.2.3,
//! eq. 3.1-3.7) with trimming by scan-based compaction (§3.2.4, fig. 3.10).
//!
//! The twin is [`crsh_cpu::raygen::whitted::Whitted`]: the same parameters, the same slots
//! (one per surface, or per light and surface, light-major, for shadow rays), the same
//! decisions (background, back-facing light culling, throughput threshold, total internal
//! reflection) and the same offset policies, [`crsh_cpu::raygen::whitted::offset_segment`]
//! and Wächter & Binder's `offset_ray` included (bit manipulation with `bitcast`), with the
//! same operations in the same order; rays agree with the CPU's up to the rounding of `sqrt`
//! and division, which WGSL does not require to be correctly rounded.
//!
//! Three passes, no slot array in memory:
//! 1. `count` (stage `ray_creation`) evaluates every slot and writes its head flag;
//! 2. the flags are scanned in place into output positions ([`crate::kernels::scan`]), the
//!    `trimming` sub-stage, whose total is the number of rays;
//! 3. `emit` (part of `trimming`) evaluates each slot again and writes the ray of every kept
//!    slot at its position, which is the CPU's compacted order.
//!
//! Surfaces are bound one storage binding's worth at a time, and the output in chunks of one
//! binding (the `emit` pass runs once per output chunk), so neither limits the batch size;
//! the flags (4 bytes per slot) must fit one binding.

use std::sync::Arc;

use bytemuck::{Pod, Zeroable};
use crsh_core::{CoreError, Ray, RayGen, RayKind, Registry, Result, StageSpec, Stats, Surface};

use crate::adapter::GpuContext;
use crate::backend::{GpuBuffer, Wgpu};
use crate::error::GpuResult;
use crate::kernel::{chunks, encoder, submit, uniform, Kernel, Slot};
use crate::kernels::scan::ScanKernel;
use crate::scene::GpuScene;

const SHADER: &str = include_str!("whitted.wgsl");

/// Uniform block of `whitted.wgsl`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct Params {
    n: u32,
    first: u32,
    count: u32,
    per_surface: u32,
    kind: u32,
    n_materials: u32,
    shadow_from_light: u32,
    cull_backfacing: u32,
    policy: u32,
    offset: f32,
    min_throughput: f32,
    out_first: u32,
    out_count: u32,
    pad: [u32; 3],
}

struct WhittedKernels {
    kernel: Kernel,
}

impl WhittedKernels {
    fn new(ctx: &GpuContext) -> GpuResult<WhittedKernels> {
        Ok(WhittedKernels {
            kernel: Kernel::new(
                ctx,
                "crsh whitted",
                SHADER,
                &["count", "emit"],
                &[
                    Slot::Uniform,
                    Slot::Read,
                    Slot::Read,
                    Slot::Read,
                    Slot::ReadWrite,
                    Slot::ReadWrite,
                    Slot::ReadWrite,
                ],
            )?,
        })
    }
}

/// The GPU Whitted ray generator; its settings are those of the CPU twin built from the same
/// spec (which validates them).
pub struct Whitted {
    scene: Arc<GpuScene>,
    shadow_from_light: bool,
    cull_backfacing: bool,
    min_throughput: f32,
    policy: u32,
    offset: f32,
}

/// Registers the wgpu `whitted` under its CPU twin's catalogue entry (same name, parameters,
/// defaults and documentation).
pub fn register(registry: &mut Registry<Wgpu>) -> Result<()> {
    registry.add_raygen(crsh_cpu::raygen::whitted::info(), |ctx, spec| {
        Ok(Box::new(Whitted::new(ctx.scene, spec)?))
    })?;
    Ok(())
}

impl Whitted {
    /// The generator for `scene` with a resolved `spec` (parameters as the CPU variant's).
    pub fn new(scene: &Arc<GpuScene>, spec: &StageSpec) -> Result<Whitted> {
        use crsh_cpu::raygen::whitted::{OffsetPolicy, Whitted as CpuWhitted};
        // The CPU constructor validates every parameter and the scene's materials and lights.
        let cpu = CpuWhitted::new(&scene.scene, spec)?;
        let (policy, offset) = match cpu.policy() {
            OffsetPolicy::Normal(d) => (0, d),
            OffsetPolicy::Scaled(d) => (1, d),
            OffsetPolicy::Fixed(d) => (2, d),
            OffsetPolicy::Wachter => (3, 0.0),
        };
        Ok(Whitted {
            scene: Arc::clone(scene),
            shadow_from_light: spec.str("shadow_origin")? == "light",
            cull_backfacing: spec.bool("cull_backfacing")?,
            min_throughput: spec.f64("min_throughput")? as f32,
            policy,
            offset,
        })
    }

    /// Builds `params` for one pass.
    fn params(&self, n: usize, per_surface: usize, kind: RayKind) -> Params {
        Params {
            n: n as u32,
            first: 0,
            count: 0,
            per_surface: per_surface as u32,
            kind: kind as u32,
            n_materials: self.scene.scene.materials.len() as u32,
            shadow_from_light: u32::from(self.shadow_from_light),
            cull_backfacing: u32::from(self.cull_backfacing),
            policy: self.policy,
            offset: self.offset,
            min_throughput: self.min_throughput,
            out_first: 0,
            out_count: 0,
            pad: [0; 3],
        }
    }

    /// Records one pass of `entry` over every surface chunk (and, for `emit`, one output
    /// chunk) into a new encoder and submits it.
    #[allow(clippy::too_many_arguments)]
    fn pass(
        &self,
        k: &Kernel,
        entry: &str,
        base: Params,
        surfaces: &GpuBuffer<Surface>,
        slots: &GpuBuffer<u32>,
        out: Option<(&GpuBuffer<Ray>, std::ops::Range<usize>)>,
        report: &GpuBuffer<u32>,
    ) -> GpuResult<()> {
        let ctx = self.scene.ctx();
        let dummy;
        let (out_buf, out_range) = match out {
            Some((b, r)) => (b, r),
            None => {
                dummy = GpuBuffer::<Ray>::zeroed(ctx, "crsh whitted no output", 0)?;
                (&dummy, 0..0)
            }
        };
        let mut groups = Vec::new();
        for range in chunks::<Surface>(ctx, surfaces.len()) {
            let params = Params {
                first: range.start as u32,
                count: range.len() as u32,
                out_first: out_range.start as u32,
                out_count: out_range.len() as u32,
                ..base
            };
            let u = uniform(ctx, "crsh whitted params", &params);
            let bg = k.bind_group(
                ctx,
                &[
                    u.as_entire_binding(),
                    surfaces.slice_binding(range.clone()),
                    self.scene.lights.binding(),
                    self.scene.materials.binding(),
                    slots.binding(),
                    out_buf.slice_binding(out_range.clone()),
                    report.binding(),
                ],
            );
            groups.push((bg, range.len() as u32 * base.per_surface));
        }
        let mut enc = encoder(ctx, entry);
        {
            let mut pass = ctx.compute_pass(&mut enc, entry);
            for (bg, n) in &groups {
                k.dispatch(ctx, &mut pass, entry, bg, *n)?;
            }
        }
        submit(ctx, entry, enc)
    }
}

impl RayGen<Wgpu> for Whitted {
    fn name(&self) -> &str {
        "whitted"
    }

    fn generate(
        &self,
        backend: &Wgpu,
        surfaces: &GpuBuffer<Surface>,
        kind: RayKind,
        stats: &mut Stats,
    ) -> Result<GpuBuffer<Ray>> {
        if kind == RayKind::Primary {
            return Err(CoreError::Unsupported {
                stage: "raygen",
                variant: "whitted".into(),
                what: "primary rays (primary visibility makes those)".into(),
            });
        }
        let ctx = backend.context();
        let n = surfaces.len();
        let per_surface = if kind == RayKind::Shadow {
            self.scene.scene.lights.len()
        } else {
            1
        };
        let total = n.checked_mul(per_surface);
        if n > u32::MAX as usize || total.is_none_or(|t| t >= u32::MAX as usize) {
            return Err(CoreError::InvalidInput(format!(
                "{n} surfaces × {per_surface} rays do not fit 32-bit ray indices"
            )));
        }
        let total = total.unwrap_or(0);
        if total == 0 {
            return Ok(GpuBuffer::zeroed(ctx, "crsh rays", 0)?);
        }
        ctx.check_storage_binding("ray slot flags", total as u64 * 4)?;
        let k = ctx.kernel(WhittedKernels::new)?;
        let slots = GpuBuffer::<u32>::zeroed(ctx, "crsh whitted slots", total)?;
        let report = GpuBuffer::<u32>::zeroed(ctx, "crsh whitted report", 4)?;
        let base = self.params(n, per_surface, kind);
        self.pass(&k.kernel, "count", base, surfaces, &slots, None, &report)?;
        let bad = report.to_vec(ctx)?[0];
        if bad != 0 {
            return Err(CoreError::InvalidInput(format!(
                "surface of pixel {} has a material the scene does not have ({} materials)",
                u32::MAX - bad,
                self.scene.scene.materials.len()
            )));
        }
        crsh_core::timed(backend, stats, "trimming", |_| {
            let kept = ctx.kernel(ScanKernel::new)?.scan_in_place(ctx, &slots)? as usize;
            let rays = GpuBuffer::<Ray>::zeroed(ctx, "crsh rays", kept)?;
            for out in chunks::<Ray>(ctx, kept) {
                if out.is_empty() {
                    continue;
                }
                self.pass(
                    &k.kernel,
                    "emit",
                    base,
                    surfaces,
                    &slots,
                    Some((&rays, out)),
                    &report,
                )?;
            }
            Ok(rays)
        })
    }
}
