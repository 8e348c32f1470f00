//! Ray hashing on the device.

pub mod morton_octa;
pub mod thesis;
pub mod tile;

use std::ops::Range;

use bytemuck::Pod;
use crsh_core::{Ray, Result};

use crate::adapter::GpuContext;
use crate::backend::GpuBuffer;
use crate::kernel::{dispatch_chunks, uniform, Kernel};

/// One key per ray of `rays` by `kernel`'s `hash` entry, whose bindings are a uniform, the
/// rays and the keys (`morton`, `tile`): the batch in binding-sized chunks, each chunk's
/// uniform made by `params` from its range, every chunk dispatched in one pass.
pub(crate) fn per_ray_keys<P: Pod>(
    ctx: &GpuContext,
    kernel: &Kernel,
    label: &str,
    rays: &GpuBuffer<Ray>,
    params: impl Fn(Range<usize>) -> P,
) -> Result<GpuBuffer<u64>> {
    let n = rays.len();
    let keys = GpuBuffer::<u64>::zeroed(ctx, "crsh ray keys", n)?;
    if n == 0 {
        return Ok(keys);
    }
    dispatch_chunks::<Ray>(ctx, kernel, label, "hash", n, |range| {
        let u = uniform(ctx, label, &params(range.clone()));
        kernel.bind_group(
            ctx,
            &[
                u.as_entire_binding(),
                rays.slice_binding(range.clone()),
                keys.slice_binding(range.clone()),
            ],
        )
    })?;
    Ok(keys)
}
