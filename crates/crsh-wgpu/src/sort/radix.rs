//! `radix` on the wgpu backend: the stable permutation that orders the rays by their keys'
//! low `key_bits` bits (seed 000 §3.2.5 sorts with a radix sort), the twin of
//! [`crsh_cpu::sort::radix::RadixSorter`].
//!
//! An LSD radix sort of (key, index) pairs with 4-bit digits, `⌈key_bits / 4⌉` passes, each:
//! 1. `histogram`: per block of 1024 keys, the count of each digit, stored digit-major;
//! 2. the exclusive scan of those counts ([`crate::kernels::scan`]): for each (digit, block)
//!    the position of its first key;
//! 3. `scatter`: each of a block's 128 invocations owns 8 consecutive keys; an exclusive scan
//!    over the invocations per digit (in workgroup memory) gives each key its rank among the
//!    block's keys of the same digit before it, so equal digits keep their order.
//!
//! Every pass is stable, so the result is the one order by key, then by original index: the
//! CPU twin's, bit for bit (a stable sort is unique). Keys are `u64` on the host and
//! `vec2<u32>` in WGSL. A key with bits above `key_bits` is an error, as on the CPU.

use std::sync::Arc;

use bytemuck::{Pod, Zeroable};
use crsh_core::{CoreError, Registry, Result, Sorter, StageSpec, Stats};

use crate::adapter::GpuContext;
use crate::backend::{GpuBuffer, Wgpu};
use crate::error::GpuResult;
use crate::kernel::{encoder, grid, submit, uniform, Kernel, Slot};
use crate::kernels::scan::ScanKernel;
use crate::scene::GpuScene;

const SHADER: &str = include_str!("radix.wgsl");

/// Keys per block of the histogram and scatter passes (must match `radix.wgsl`).
pub const RADIX_BLOCK: usize = 1024;
/// Bits per pass.
const DIGIT_BITS: u32 = 4;

#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct Params {
    n: u32,
    blocks: u32,
    shift: u32,
    mask_lo: u32,
    mask_hi: u32,
    groups_x: u32,
    pad: [u32; 2],
}

struct RadixKernels {
    kernel: Kernel,
}

impl RadixKernels {
    fn new(ctx: &GpuContext) -> GpuResult<RadixKernels> {
        let mut slots = vec![Slot::Uniform, Slot::Read, Slot::Read];
        slots.extend([Slot::ReadWrite; 4]);
        Ok(RadixKernels {
            kernel: Kernel::new(
                ctx,
                "crsh radix sort",
                SHADER,
                &["init", "histogram", "scatter"],
                &slots,
            )?,
        })
    }
}

/// The stable order of `keys` by their low `key_bits` bits on the device: `order[i]` is the
/// index of the key that goes to position `i`. The twin of
/// [`crsh_cpu::sort::radix::stable_radix_order`].
pub fn stable_radix_order(
    ctx: &GpuContext,
    keys: &GpuBuffer<u64>,
    key_bits: u32,
) -> Result<GpuBuffer<u32>> {
    if key_bits > 64 {
        return Err(CoreError::InvalidInput(format!(
            "key_bits {key_bits} is more than 64"
        )));
    }
    let n = keys.len();
    if n >= u32::MAX as usize - RADIX_BLOCK {
        return Err(CoreError::InvalidInput(format!(
            "{n} keys do not fit 32-bit indices"
        )));
    }
    let blocks = n.div_ceil(RADIX_BLOCK);
    for (what, bytes) in [
        ("sort keys", keys.byte_len()),
        ("sort histogram", (blocks * 16 * 4) as u64),
    ] {
        ctx.check_storage_binding(what, bytes)?;
    }
    let vals_a = GpuBuffer::<u32>::zeroed(ctx, "crsh sort values", n)?;
    if n == 0 {
        return Ok(vals_a);
    }
    let k = ctx.kernel(RadixKernels::new)?;
    let scan = ctx.kernel(ScanKernel::new)?;
    let keys_a = GpuBuffer::<u64>::zeroed(ctx, "crsh sort keys", n)?;
    let keys_b = GpuBuffer::<u64>::zeroed(ctx, "crsh sort keys", n)?;
    let vals_b = GpuBuffer::<u32>::zeroed(ctx, "crsh sort values", n)?;
    let hist = GpuBuffer::<u32>::zeroed(ctx, "crsh sort histogram", blocks * 16)?;
    let report = GpuBuffer::<u32>::zeroed(ctx, "crsh sort report", 4)?;
    let mask = if key_bits >= 64 {
        0
    } else {
        !((1u64 << key_bits) - 1)
    };
    let (gx, gy) = grid(ctx, blocks as u32)?;
    let base = Params {
        n: n as u32,
        blocks: blocks as u32,
        shift: 0,
        mask_lo: mask as u32,
        mask_hi: (mask >> 32) as u32,
        groups_x: gx,
        pad: [0; 2],
    };
    let bind = |params: &Params,
                keys_in: &GpuBuffer<u64>,
                vals_in: &GpuBuffer<u32>,
                keys_out: &GpuBuffer<u64>,
                vals_out: &GpuBuffer<u32>| {
        let u = uniform(ctx, "crsh radix params", params);
        k.kernel.bind_group(
            ctx,
            &[
                u.as_entire_binding(),
                keys_in.binding(),
                vals_in.binding(),
                keys_out.binding(),
                vals_out.binding(),
                hist.binding(),
                report.binding(),
            ],
        )
    };
    let mut enc = encoder(ctx, "crsh radix sort");
    {
        // Identity values into vals_a (keys_out / vals_in unused here).
        let bg = bind(&base, keys, &vals_b, &keys_a, &vals_a);
        let mut pass = ctx.compute_pass(&mut enc, "crsh radix init");
        k.kernel.dispatch(ctx, &mut pass, "init", &bg, n as u32)?;
    }
    let passes = key_bits.div_ceil(DIGIT_BITS);
    // Ping-pong: pass 0 reads the input keys; values start in vals_a.
    let mut flip = false;
    for pass_i in 0..passes {
        let params = Params {
            shift: pass_i * DIGIT_BITS,
            ..base
        };
        let keys_in = if pass_i == 0 {
            keys
        } else if flip {
            &keys_b
        } else {
            &keys_a
        };
        let (vals_in, keys_out, vals_out) = if flip {
            (&vals_b, &keys_a, &vals_a)
        } else {
            (&vals_a, &keys_b, &vals_b)
        };
        let bg = bind(&params, keys_in, vals_in, keys_out, vals_out);
        {
            let mut pass = ctx.compute_pass(&mut enc, "crsh radix histogram");
            k.kernel.set(&mut pass, "histogram", &bg)?;
            pass.dispatch_workgroups(gx, gy, 1);
        }
        scan.encode_in_place(ctx, &mut enc, &hist, None)?;
        {
            let mut pass = ctx.compute_pass(&mut enc, "crsh radix scatter");
            k.kernel.set(&mut pass, "scatter", &bg)?;
            pass.dispatch_workgroups(gx, gy, 1);
        }
        flip = !flip;
    }
    submit(ctx, "crsh radix sort", enc)?;
    let r = report.to_vec(ctx)?[0];
    if r != 0 {
        let i = (u32::MAX - r) as usize;
        let key = keys.to_vec_range(ctx, i..i + 1)?[0];
        return Err(CoreError::InvalidInput(format!(
            "key {key:#x} has bits set above key_bits = {key_bits}"
        )));
    }
    Ok(if flip { vals_b } else { vals_a })
}

/// The GPU radix sorter (variant `radix`, no parameters).
pub struct RadixSorter {
    scene: Arc<GpuScene>,
}

/// Registers the wgpu `radix` under its CPU twin's catalogue entry (same name, parameters,
/// defaults and documentation).
pub fn register(registry: &mut Registry<Wgpu>) -> Result<()> {
    registry.add_sorter(crsh_cpu::sort::radix::info(), |ctx, spec| {
        Ok(Box::new(RadixSorter::new(ctx.scene, spec)?))
    })?;
    Ok(())
}

impl RadixSorter {
    /// The sorter (no parameters to read).
    pub fn new(scene: &Arc<GpuScene>, spec: &StageSpec) -> Result<RadixSorter> {
        let _ = spec;
        Ok(RadixSorter {
            scene: Arc::clone(scene),
        })
    }
}

impl Sorter<Wgpu> for RadixSorter {
    fn name(&self) -> &str {
        "radix"
    }

    fn sort(
        &self,
        backend: &Wgpu,
        keys: &GpuBuffer<u64>,
        key_bits: u32,
        _stats: &mut Stats,
    ) -> Result<GpuBuffer<u32>> {
        let _ = &self.scene;
        stable_radix_order(backend.context(), keys, key_bits)
    }
}
