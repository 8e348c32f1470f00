//! `thesis` on the wgpu backend: the per-kind ray hashes of seed 000 §3.2.3 (figs 3.8-3.9),
//! one invocation per ray.
//!
//! The twin is [`crsh_cpu::hash::thesis::ThesisHasher`], whose constructor sizes the fields
//! (same parameters, same layouts: shadow keys = light index, then θ and φ of the direction from
//! the light; reflection / refraction keys = origin cells in the scene bounds, then θ and φ;
//! fields interleaved or concatenated, the same 64-bit key layout).
//!
//! **Not bit-identical.** The CPU quantizes in `f64` with correctly rounded `acos` and `atan2`;
//! WGSL has no portable `f64`, and its `acos`, `atan2` and division need not be correctly
//! rounded, so the device quantizes in `f32`: a ray whose angle or coordinate lies within
//! rounding (about 1e-6 of the field's range) of a cell boundary can land in the neighbouring
//! cell. The tests measure it: on the built-in scenes nearly every key is identical and every
//! differing key differs in one field by one cell. Such a ray is still traced exactly (the
//! hierarchy bounds whatever rays it is given); only its place in the sort order, hence the
//! hierarchy's tightness, can change, so counts can differ slightly from the CPU's while the
//! hits do not. Layouts with a field wider than [`MAX_FIELD_BITS`] (f32's significand) are
//! refused. A bit-identical hash needs integer quantization on both sides (threshold tables
//! for θ and φ, exact rational floors for the origin), which is the planned next step.

use std::sync::Arc;

use bytemuck::{Pod, Zeroable};
use crsh_core::quantize::FieldOrder;
use crsh_core::{CoreError, Hasher, Ray, RayKind, Registry, Result, StageSpec, Stats};
use crsh_cpu::hash::thesis::ThesisHasher as CpuThesis;

use crate::adapter::GpuContext;
use crate::backend::{GpuBuffer, Wgpu};
use crate::error::GpuResult;
use crate::kernel::{chunks, encoder, submit, uniform, Kernel, Slot};
use crate::scene::GpuScene;

const SHADER: &str = include_str!("thesis.wgsl");

/// The quantization helpers shared by the hashes (`quantize.wgsl`).
pub(crate) const QUANTIZE_WGSL: &str = concat!(
    include_str!("quantize.wgsl"),
    "\n",
    include_str!("../kernels/trig.wgsl")
);

#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct Params {
    n: u32,
    n_lights: u32,
    interleave: u32,
    light_bits: u32,
    shadow_theta_bits: u32,
    shadow_phi_bits: u32,
    origin_bits: u32,
    bounce_theta_bits: u32,
    bounce_phi_bits: u32,
    first: u32,
    pad: [u32; 2],
    lo: [f32; 3],
    c: f32,
    hi: [f32; 3],
    d: f32,
}

struct ThesisKernels {
    kernel: Kernel,
}

impl ThesisKernels {
    fn new(ctx: &GpuContext) -> GpuResult<ThesisKernels> {
        Ok(ThesisKernels {
            kernel: Kernel::new(
                ctx,
                "crsh thesis hash",
                &format!("{QUANTIZE_WGSL}\n{SHADER}"),
                &["hash"],
                &[
                    Slot::Uniform,
                    Slot::Read,
                    Slot::Read,
                    Slot::ReadWrite,
                    Slot::ReadWrite,
                ],
            )?,
        })
    }
}

/// The widest field the device quantizes (f32 has a 24-bit significand: wider cells would be
/// decided by rounding, not by the ray; 20 bits keep that error below a tenth of a cell).
pub const MAX_FIELD_BITS: u32 = 20;

/// Refuses a layout with a field wider than [`MAX_FIELD_BITS`].
pub(crate) fn check_field_width(variant: &str, widths: &[u32]) -> Result<()> {
    match widths.iter().find(|&&w| w > MAX_FIELD_BITS) {
        Some(w) => Err(CoreError::Unsupported {
            stage: "hash",
            variant: variant.into(),
            what: format!(
                "a {w}-bit field on the wgpu backend (it quantizes in f32: at most \
                 {MAX_FIELD_BITS} bits per field; use fewer bits or --backend cpu)"
            ),
        }),
        None => Ok(()),
    }
}

/// The GPU thesis hasher.
pub struct ThesisHasher {
    scene: Arc<GpuScene>,
    params: Params,
    key_bits: u32,
}

/// Registers the wgpu `thesis` under its CPU twin's catalogue entry (same name, parameters,
/// defaults and documentation).
pub fn register(registry: &mut Registry<Wgpu>) -> Result<()> {
    registry.add_hasher(crsh_cpu::hash::thesis::info(), |ctx, spec| {
        Ok(Box::new(ThesisHasher::new(ctx.scene, spec)?))
    })?;
    Ok(())
}

impl ThesisHasher {
    /// The hasher for `scene` with a resolved `spec` (the CPU twin's parameters, validated and
    /// laid out by its constructor).
    pub fn new(scene: &Arc<GpuScene>, spec: &StageSpec) -> Result<ThesisHasher> {
        let cpu = CpuThesis::new(&scene.scene, spec)?;
        let s = cpu.shadow_layout();
        let b = cpu.bounce_layout();
        check_field_width(
            "thesis",
            &[
                s.theta_bits,
                s.phi_bits,
                b.origin_bits,
                b.theta_bits,
                b.phi_bits,
            ],
        )?;
        let interleave = u32::from(s.order == FieldOrder::Interleaved);
        Ok(ThesisHasher {
            scene: Arc::clone(scene),
            params: Params {
                n: 0,
                n_lights: scene.scene.lights.len() as u32,
                interleave,
                light_bits: s.light_bits,
                shadow_theta_bits: s.theta_bits,
                shadow_phi_bits: s.phi_bits,
                origin_bits: b.origin_bits,
                bounce_theta_bits: b.theta_bits,
                bounce_phi_bits: b.phi_bits,
                first: 0,
                pad: [0; 2],
                lo: b.bounds.min.to_array(),
                c: 0.0,
                hi: b.bounds.max.to_array(),
                d: 0.0,
            },
            key_bits: crsh_core::Hasher::<crsh_cpu::Cpu>::key_bits(&cpu),
        })
    }
}

impl Hasher<Wgpu> for ThesisHasher {
    fn name(&self) -> &str {
        "thesis"
    }

    fn key_bits(&self) -> u32 {
        self.key_bits
    }

    fn hash(
        &self,
        backend: &Wgpu,
        rays: &GpuBuffer<Ray>,
        _kind: RayKind,
        _stats: &mut Stats,
    ) -> Result<GpuBuffer<u64>> {
        let ctx = backend.context();
        let n = rays.len();
        let keys = GpuBuffer::<u64>::zeroed(ctx, "crsh ray keys", n)?;
        if n == 0 {
            return Ok(keys);
        }
        let k = ctx.kernel(ThesisKernels::new)?;
        let report = GpuBuffer::<u32>::zeroed(ctx, "crsh hash report", 4)?;
        let mut groups = Vec::new();
        for range in chunks::<Ray>(ctx, n) {
            let params = Params {
                n: range.len() as u32,
                first: range.start as u32,
                ..self.params
            };
            let u = uniform(ctx, "crsh thesis params", &params);
            let bg = k.kernel.bind_group(
                ctx,
                &[
                    u.as_entire_binding(),
                    rays.slice_binding(range.clone()),
                    self.scene.lights.binding(),
                    keys.slice_binding(range.clone()),
                    report.binding(),
                ],
            );
            groups.push((bg, range.len() as u32));
        }
        let mut enc = encoder(ctx, "crsh thesis hash");
        {
            let mut pass = ctx.compute_pass(&mut enc, "crsh thesis hash");
            for (bg, n) in &groups {
                k.kernel.dispatch(ctx, &mut pass, "hash", bg, *n)?;
            }
        }
        submit(ctx, "crsh thesis hash", enc)?;
        let bad = report.to_vec(ctx)?[0];
        if bad != 0 {
            let i = (u32::MAX - bad) as usize;
            let r = rays.to_vec_range(ctx, i..i + 1)?[0];
            return Err(CoreError::InvalidInput(format!(
                "ray {i} cannot be hashed: kind {}, light {} of {} lights, segment end {}",
                r.kind,
                r.light,
                self.scene.scene.lights.len(),
                r.origin + r.dir * r.t_max
            )));
        }
        Ok(keys)
    }
}
