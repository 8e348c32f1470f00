//! `morton` on the wgpu backend: the 5-D Morton key of the quantized origin and the
//! octahedral direction, one invocation per ray. The twin is
//! [`crsh_cpu::hash::morton_octa::MortonOcta`] (same parameters and field widths, the same
//! interleaving) and, like the thesis hash on the device ([`super::thesis`]), the same keys bit
//! for bit: origin cells by [`crsh_core::quantize::UniformCells`], direction cells by
//! [`crsh_core::quantize::octahedral_cells`] (sums of absolute components and products that
//! only feed comparisons, no division). Direction fields wider than
//! [`super::thesis::MAX_FIELD_BITS`] are refused.

use std::sync::Arc;

use bytemuck::{Pod, Zeroable};
use crsh_core::quantize::UniformCells;
use crsh_core::{Hasher, Ray, RayKind, Registry, Result, StageSpec, Stats};
use crsh_cpu::hash::morton_octa::MortonOcta as CpuMorton;

use crate::adapter::GpuContext;
use crate::backend::{GpuBuffer, Wgpu};
use crate::error::GpuResult;
use crate::kernel::{Kernel, Slot};
use crate::scene::GpuScene;

const SHADER: &str = include_str!("morton_octa.wgsl");

#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct Params {
    n: u32,
    origin_bits: u32,
    u_bits: u32,
    v_bits: u32,
    lo: [f32; 3],
    a: f32,
    hi: [f32; 3],
    b: f32,
    scale: [f32; 3],
    c: f32,
}

struct MortonKernels {
    kernel: Kernel,
}

impl MortonKernels {
    fn new(ctx: &GpuContext) -> GpuResult<MortonKernels> {
        Ok(MortonKernels {
            kernel: Kernel::new(
                ctx,
                "crsh morton hash",
                &format!("{}\n{SHADER}", super::thesis::QUANTIZE_WGSL),
                &["hash"],
                &[Slot::Uniform, Slot::Read, Slot::ReadWrite],
            )?,
        })
    }
}

/// The GPU Morton-octahedral hasher.
pub struct MortonOcta {
    scene: Arc<GpuScene>,
    params: Params,
    key_bits: u32,
}

/// Registers the wgpu `morton` under its CPU twin's catalogue entry (same name, parameters,
/// defaults and documentation).
pub fn register(registry: &mut Registry<Wgpu>) -> Result<()> {
    registry.add_hasher(crsh_cpu::hash::morton_octa::info(), |ctx, spec| {
        Ok(Box::new(MortonOcta::new(ctx.scene, spec)?))
    })?;
    Ok(())
}

impl MortonOcta {
    /// The hasher for `scene` with a resolved `spec` (validated and sized by the CPU twin).
    pub fn new(scene: &Arc<GpuScene>, spec: &StageSpec) -> Result<MortonOcta> {
        let cpu = CpuMorton::new(&scene.scene, spec)?;
        let [o, _, _, u, v] = cpu.widths();
        super::thesis::check_field_width("morton", &[u, v])?;
        let b = scene.scene.bounds;
        let cells = [0, 1, 2].map(|i| UniformCells::new(b.min[i], b.max[i], o));
        Ok(MortonOcta {
            scene: Arc::clone(scene),
            params: Params {
                n: 0,
                origin_bits: o,
                u_bits: u,
                v_bits: v,
                lo: cells.map(|c| c.lo),
                a: 0.0,
                hi: cells.map(|c| c.hi),
                b: 0.0,
                scale: cells.map(|c| c.scale),
                c: 0.0,
            },
            key_bits: crsh_core::Hasher::<crsh_cpu::Cpu>::key_bits(&cpu),
        })
    }
}

impl Hasher<Wgpu> for MortonOcta {
    fn name(&self) -> &str {
        "morton"
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
        if rays.is_empty() {
            return Ok(GpuBuffer::zeroed(ctx, "crsh ray keys", 0)?);
        }
        let k = ctx.kernel(MortonKernels::new)?;
        let _ = &self.scene;
        super::per_ray_keys(ctx, &k.kernel, "crsh morton hash", rays, |range| Params {
            n: range.len() as u32,
            ..self.params
        })
    }
}
