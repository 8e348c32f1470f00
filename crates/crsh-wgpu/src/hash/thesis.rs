//! `thesis` on the wgpu backend: the per-kind ray hashes of seed 000 §3.2.3 (figs 3.8-3.9),
//! one invocation per ray.
//!
//! The twin is [`crsh_cpu::hash::thesis::ThesisHasher`], whose constructor sizes the fields
//! (same parameters, same layouts: shadow keys = light index, then θ and φ of the direction from
//! the light; reflection / refraction keys = origin cells in the scene bounds, then θ and φ;
//! fields interleaved or concatenated, the same 64-bit key layout).
//!
//! **Bit-identical.** Both sides quantize with [`crsh_core::quantize`]'s exact scheme: origin
//! cells as `floor((x − lo) · scale)` with the host's `f32` scale (a subtraction and a product,
//! correctly rounded in WGSL, nothing an FMA can fuse), and `θ`, `φ` cells by comparisons of the
//! scaled direction against boundary tables the host computes once
//! ([`crsh_core::quantize::theta_table`], [`crsh_core::quantize::phi_table`], uploaded with the
//! hasher); every product that feeds a sum is a sum of exact partial products
//! ([`crsh_core::quantize::product`]), so contraction cannot change a bit, and NaN, infinities
//! and subnormals are screened by their bits. No division, `sqrt`, `acos` or `atan2` runs on the
//! device (WGSL does not round them correctly). The shadow rays' light→point convention is
//! decided with the same products. The tests compare every key with the CPU's. Direction fields
//! wider than [`MAX_FIELD_BITS`] (the tables' limit) are refused.

use std::sync::{Arc, OnceLock};

use bytemuck::{Pod, Zeroable};
use crsh_core::quantize::{phi_table, theta_table, FieldOrder, UniformCells};
use crsh_core::{CoreError, Hasher, Ray, RayKind, Registry, Result, StageSpec, Stats};
use crsh_cpu::hash::thesis::ThesisHasher as CpuThesis;

use crate::adapter::GpuContext;
use crate::backend::{GpuBuffer, Wgpu};
use crate::error::GpuResult;
use crate::kernel::{dispatch_chunks, uniform, Kernel, Slot};
use crate::scene::GpuScene;

const SHADER: &str = include_str!("thesis.wgsl");

/// The quantization helpers shared by the hashes (`quantize.wgsl`).
pub(crate) const QUANTIZE_WGSL: &str = include_str!("quantize.wgsl");

/// The spherical direction cells (`spherical.wgsl`), over the boundary tables.
const SPHERICAL_WGSL: &str = include_str!("spherical.wgsl");

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
    shadow_theta_base: u32,
    shadow_phi_base: u32,
    bounce_theta_base: u32,
    bounce_phi_base: u32,
    pad: [u32; 2],
    lo: [f32; 3],
    c: f32,
    hi: [f32; 3],
    d: f32,
    scale: [f32; 3],
    e: f32,
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
                &format!("{QUANTIZE_WGSL}\n{SPHERICAL_WGSL}\n{SHADER}"),
                &["hash"],
                &[
                    Slot::Uniform,
                    Slot::Read,
                    Slot::Read,
                    Slot::ReadWrite,
                    Slot::ReadWrite,
                    Slot::Read,
                ],
            )?,
        })
    }
}

/// The widest direction field the device quantizes: the boundary tables travel to the device
/// ([`crsh_core::quantize::MAX_TABLE_BITS`], `2^20` entries).
pub const MAX_FIELD_BITS: u32 = crsh_core::quantize::MAX_TABLE_BITS;

/// Refuses a layout with a direction field wider than [`MAX_FIELD_BITS`].
pub(crate) fn check_field_width(variant: &str, widths: &[u32]) -> Result<()> {
    match widths.iter().find(|&&w| w > MAX_FIELD_BITS) {
        Some(w) => Err(CoreError::Unsupported {
            stage: "hash",
            variant: variant.into(),
            what: format!(
                "a {w}-bit direction field on the wgpu backend (its boundary tables hold at \
                 most {MAX_FIELD_BITS} bits per field; use fewer bits or --backend cpu)"
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
    /// The four boundary tables, concatenated (offsets in `params`).
    tables: Vec<f32>,
    /// `tables` on the device, uploaded on first use.
    tables_on_device: OnceLock<GpuBuffer<f32>>,
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
            &[s.theta_bits, s.phi_bits, b.theta_bits, b.phi_bits],
        )?;
        let interleave = u32::from(s.order == FieldOrder::Interleaved);
        let mut tables = Vec::new();
        let mut base = |t: &[f32]| {
            let at = tables.len() as u32;
            tables.extend_from_slice(t);
            at
        };
        let shadow_theta_base = base(theta_table(s.theta_bits));
        let shadow_phi_base = base(phi_table(s.phi_bits));
        let bounce_theta_base = base(theta_table(b.theta_bits));
        let bounce_phi_base = base(phi_table(b.phi_bits));
        let cells =
            [0, 1, 2].map(|i| UniformCells::new(b.bounds.min[i], b.bounds.max[i], b.origin_bits));
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
                shadow_theta_base,
                shadow_phi_base,
                bounce_theta_base,
                bounce_phi_base,
                pad: [0; 2],
                lo: cells.map(|c| c.lo),
                c: 0.0,
                hi: cells.map(|c| c.hi),
                d: 0.0,
                scale: cells.map(|c| c.scale),
                e: 0.0,
            },
            key_bits: crsh_core::Hasher::<crsh_cpu::Cpu>::key_bits(&cpu),
            tables,
            tables_on_device: OnceLock::new(),
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
        if self.tables_on_device.get().is_none() {
            let t = GpuBuffer::from_slice(ctx, "crsh thesis boundary tables", &self.tables)?;
            let _ = self.tables_on_device.set(t);
        }
        let tables = self.tables_on_device.get().expect("uploaded above");
        dispatch_chunks::<Ray>(ctx, &k.kernel, "crsh thesis hash", "hash", n, |range| {
            let params = Params {
                n: range.len() as u32,
                first: range.start as u32,
                ..self.params
            };
            let u = uniform(ctx, "crsh thesis params", &params);
            k.kernel.bind_group(
                ctx,
                &[
                    u.as_entire_binding(),
                    rays.slice_binding(range.clone()),
                    self.scene.lights.binding(),
                    keys.slice_binding(range.clone()),
                    report.binding(),
                    tables.binding(),
                ],
            )
        })?;
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
