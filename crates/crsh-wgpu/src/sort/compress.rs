//! `compress` on the wgpu backend: the thesis's compression-sorting-decompression (seed 000
//! §3.2.4-3.2.6, figs 3.12-3.15, after Garanzha & Loop 2010), the twin of
//! [`crsh_cpu::sort::compress::CompressSorter`]:
//!
//! 1. **Compression** (`compression`): head flags where a run of equal keys starts, their
//!    exclusive scan numbering the chunks, and each head writing its chunk's first ray and key;
//!    the chunk sizes follow from consecutive bases.
//! 2. **Sorting**: the chunk keys by the GPU radix sort ([`super::radix::stable_radix_order`],
//!    stable).
//! 3. **Decompression** (`decompression`): the skeleton (sorted chunks' sizes), its exclusive
//!    scan into output positions, and one invocation per output position finding its chunk by
//!    binary search.
//!
//! The result is the stable order of the rays by key: the CPU twin's (and the `radix`
//! variant's) permutation, bit for bit. `compression` and `decompression` are timed as
//! sub-stages, as on the CPU.

use std::sync::Arc;

use bytemuck::{Pod, Zeroable};
use crsh_core::{CoreError, Registry, Result, Sorter, StageSpec, Stats};

use crate::adapter::GpuContext;
use crate::backend::{GpuBuffer, Wgpu};
use crate::error::GpuResult;
use crate::kernel::{encoder, submit, uniform, Kernel, Slot};
use crate::kernels::scan::ScanKernel;
use crate::scene::GpuScene;

const SHADER: &str = include_str!("compress.wgsl");

#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct Params {
    n: u32,
    chunks: u32,
    pad: [u32; 2],
}

struct CompressKernels {
    kernel: Kernel,
}

impl CompressKernels {
    fn new(ctx: &GpuContext) -> GpuResult<CompressKernels> {
        let mut slots = vec![Slot::Uniform, Slot::Read];
        slots.extend([Slot::ReadWrite; 4]);
        slots.push(Slot::Read);
        slots.extend([Slot::ReadWrite; 2]);
        Ok(CompressKernels {
            kernel: Kernel::new(
                ctx,
                "crsh compress sort",
                SHADER,
                &[
                    "flag_heads",
                    "write_chunks",
                    "chunk_sizes",
                    "skeleton_sizes",
                    "expand",
                ],
                &slots,
            )?,
        })
    }
}

/// The chunks of a compressed key array (§3.2.4), on the device.
pub struct Chunks {
    /// Key of each chunk.
    pub keys: GpuBuffer<u64>,
    /// Index of each chunk's first ray.
    pub base: GpuBuffer<u32>,
    /// Rays in each chunk.
    pub size: GpuBuffer<u32>,
}

struct Buffers<'a> {
    keys: &'a GpuBuffer<u64>,
    heads: &'a GpuBuffer<u32>,
    base: &'a GpuBuffer<u32>,
    chunk_keys: &'a GpuBuffer<u64>,
    size: &'a GpuBuffer<u32>,
    sorted: &'a GpuBuffer<u32>,
    skeleton: &'a GpuBuffer<u32>,
    order: &'a GpuBuffer<u32>,
}

fn bind(
    ctx: &GpuContext,
    k: &Kernel,
    params: &Params,
    b: &Buffers<'_>,
) -> crate::kernel::KernelBindings {
    let u = uniform(ctx, "crsh compress params", params);
    k.bind_group(
        ctx,
        &[
            u.as_entire_binding(),
            b.keys.binding(),
            b.heads.binding(),
            b.base.binding(),
            b.chunk_keys.binding(),
            b.size.binding(),
            b.sorted.binding(),
            b.skeleton.binding(),
            b.order.binding(),
        ],
    )
}

/// Compression (§3.2.4) of `keys` on the device; the twin of
/// [`crsh_cpu::sort::compress::compress`].
pub fn compress(ctx: &GpuContext, keys: &GpuBuffer<u64>) -> Result<Chunks> {
    let n = keys.len();
    ctx.check_storage_binding("sort keys", keys.byte_len())?;
    let k = ctx.kernel(CompressKernels::new)?;
    let heads = GpuBuffer::<u32>::zeroed(ctx, "crsh compress heads", n)?;
    let total = GpuBuffer::<u32>::zeroed(ctx, "crsh compress total", 4)?;
    let none32 = GpuBuffer::<u32>::zeroed(ctx, "crsh unused", 0)?;
    let none32b = GpuBuffer::<u32>::zeroed(ctx, "crsh unused", 0)?;
    let none32c = GpuBuffer::<u32>::zeroed(ctx, "crsh unused", 0)?;
    let none32d = GpuBuffer::<u32>::zeroed(ctx, "crsh unused", 0)?;
    let none32e = GpuBuffer::<u32>::zeroed(ctx, "crsh unused", 0)?;
    let none64 = GpuBuffer::<u64>::zeroed(ctx, "crsh unused", 0)?;
    if n == 0 {
        return Ok(Chunks {
            keys: none64,
            base: none32,
            size: none32b,
        });
    }
    let params = Params {
        n: n as u32,
        chunks: 0,
        pad: [0; 2],
    };
    let flag_bg = bind(
        ctx,
        &k.kernel,
        &params,
        &Buffers {
            keys,
            heads: &heads,
            base: &none32,
            chunk_keys: &none64,
            size: &none32b,
            sorted: &none32c,
            skeleton: &none32d,
            order: &none32e,
        },
    );
    let mut enc = encoder(ctx, "crsh compress heads");
    {
        let mut pass = ctx.compute_pass(&mut enc, "crsh compress heads");
        k.kernel
            .dispatch(ctx, &mut pass, "flag_heads", &flag_bg, n as u32)?;
    }
    ctx.kernel(ScanKernel::new)?.encode_in_place(
        ctx,
        &mut enc,
        &heads,
        Some((total.buffer(), 0)),
    )?;
    submit(ctx, "crsh compress heads", enc)?;
    let count = total.to_vec(ctx)?[0] as usize;
    let chunk_keys = GpuBuffer::<u64>::zeroed(ctx, "crsh chunk keys", count)?;
    let base = GpuBuffer::<u32>::zeroed(ctx, "crsh chunk bases", count)?;
    let size = GpuBuffer::<u32>::zeroed(ctx, "crsh chunk sizes", count)?;
    let params = Params {
        chunks: count as u32,
        ..params
    };
    let bg = bind(
        ctx,
        &k.kernel,
        &params,
        &Buffers {
            keys,
            heads: &heads,
            base: &base,
            chunk_keys: &chunk_keys,
            size: &size,
            sorted: &none32c,
            skeleton: &none32d,
            order: &none32e,
        },
    );
    let mut enc = encoder(ctx, "crsh compress chunks");
    {
        let mut pass = ctx.compute_pass(&mut enc, "crsh compress chunks");
        k.kernel
            .dispatch(ctx, &mut pass, "write_chunks", &bg, n as u32)?;
        k.kernel
            .dispatch(ctx, &mut pass, "chunk_sizes", &bg, count as u32)?;
    }
    submit(ctx, "crsh compress chunks", enc)?;
    Ok(Chunks {
        keys: chunk_keys,
        base,
        size,
    })
}

/// Decompression (§3.2.6): the ray order from the chunks listed in sorted order; the twin of
/// [`crsh_cpu::sort::compress::decompress`] (for a valid `sorted`, a permutation of the
/// chunks, as the radix sort gives).
pub fn decompress(
    ctx: &GpuContext,
    chunks: &Chunks,
    sorted: &GpuBuffer<u32>,
    n: usize,
) -> Result<GpuBuffer<u32>> {
    let count = chunks.base.len();
    if sorted.len() != count {
        return Err(CoreError::InvalidInput(format!(
            "{} sorted chunks for {count} chunks",
            sorted.len()
        )));
    }
    let order = GpuBuffer::<u32>::zeroed(ctx, "crsh ray order", n)?;
    if n == 0 {
        return Ok(order);
    }
    let k = ctx.kernel(CompressKernels::new)?;
    let skeleton = GpuBuffer::<u32>::zeroed(ctx, "crsh skeleton", count)?;
    let none = GpuBuffer::<u32>::zeroed(ctx, "crsh unused", 0)?;
    let params = Params {
        n: n as u32,
        chunks: count as u32,
        pad: [0; 2],
    };
    let bg = bind(
        ctx,
        &k.kernel,
        &params,
        &Buffers {
            keys: &chunks.keys,
            heads: &none,
            base: &chunks.base,
            chunk_keys: &GpuBuffer::<u64>::zeroed(ctx, "crsh unused", 0)?,
            size: &chunks.size,
            sorted,
            skeleton: &skeleton,
            order: &order,
        },
    );
    let mut enc = encoder(ctx, "crsh decompress");
    {
        let mut pass = ctx.compute_pass(&mut enc, "crsh skeleton");
        k.kernel
            .dispatch(ctx, &mut pass, "skeleton_sizes", &bg, count as u32)?;
    }
    ctx.kernel(ScanKernel::new)?
        .encode_in_place(ctx, &mut enc, &skeleton, None)?;
    {
        let mut pass = ctx.compute_pass(&mut enc, "crsh decompress");
        k.kernel.dispatch(ctx, &mut pass, "expand", &bg, n as u32)?;
    }
    submit(ctx, "crsh decompress", enc)?;
    Ok(order)
}

/// The GPU compress sorter (variant `compress`, no parameters).
pub struct CompressSorter {
    scene: Arc<GpuScene>,
}

/// Registers the wgpu `compress` under its CPU twin's catalogue entry (same name, parameters,
/// defaults and documentation).
pub fn register(registry: &mut Registry<Wgpu>) -> Result<()> {
    registry.add_sorter(crsh_cpu::sort::compress::info(), |ctx, spec| {
        Ok(Box::new(CompressSorter::new(ctx.scene, spec)?))
    })?;
    Ok(())
}

impl CompressSorter {
    /// The sorter (no parameters to read).
    pub fn new(scene: &Arc<GpuScene>, spec: &StageSpec) -> Result<CompressSorter> {
        let _ = spec;
        Ok(CompressSorter {
            scene: Arc::clone(scene),
        })
    }
}

impl Sorter<Wgpu> for CompressSorter {
    fn name(&self) -> &str {
        "compress"
    }

    fn sort(
        &self,
        backend: &Wgpu,
        keys: &GpuBuffer<u64>,
        key_bits: u32,
        stats: &mut Stats,
    ) -> Result<GpuBuffer<u32>> {
        let _ = &self.scene;
        let ctx = backend.context();
        if key_bits > 64 {
            return Err(CoreError::InvalidInput(format!(
                "key_bits {key_bits} is more than 64"
            )));
        }
        let chunks = crsh_core::timed(backend, stats, "compression", |_| compress(ctx, keys))?;
        // The chunk keys are every key value, so the radix sort's check covers every key.
        let sorted = super::radix::stable_radix_order(ctx, &chunks.keys, key_bits)?;
        crsh_core::timed(backend, stats, "decompression", |_| {
            decompress(ctx, &chunks, &sorted, keys.len())
        })
    }
}
