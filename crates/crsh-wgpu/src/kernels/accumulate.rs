//! Ordered accumulation of per-record contributions into an HDR image, and its CPU twin.
//!
//! A shader computes one [`Contribution`] per record in parallel; the CPU shaders then add
//! them to their pixels sequentially in record order. Floating-point addition does not
//! commute and WGSL has no float atomics, so the device reproduces that order: the records
//! fall into *runs*, maximal sequences of consecutive records of one pixel; in each round,
//! every run not yet applied elects itself for its pixel with an integer `atomicMin` of its
//! first index, and each winner adds its whole run to the pixel record by record. A pixel
//! thus receives its records in record order, in as many rounds as it has runs (counted
//! first and read back by the caller together with its own report), and the image does not
//! depend on scheduling: it is [`accumulate_cpu`] bit for bit.
//!
//! The runs keep the rounds few where records of a pixel are adjacent: the surface-major
//! rays of an AO batch are one run per surface whatever the number of samples.
//!
//! Use: [`accumulate_in_order`], around the passes of the caller's kernel that write the
//! contributions; or, by hand, record [`AccumulateKernel::count_heads`] after those passes
//! (it writes the number of rounds into the caller's report), read the report back, and
//! record [`AccumulateKernel::apply`].

use bytemuck::{Pod, Zeroable};

use crate::adapter::GpuContext;
use crate::backend::GpuBuffer;
use crate::error::GpuResult;
use crate::kernel::{encoder, submit, uniform, Kernel, Slot};

const SHADER: &str = include_str!("accumulate.wgsl");

/// [`Contribution::flags`]: add the colour.
pub const ADD: u32 = 1;
/// [`Contribution::flags`]: set the pixel's alpha to 1.
pub const ALPHA: u32 = 2;

/// What one record adds to its pixel (32 bytes, `Contribution` in `common.wgsl`).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct Contribution {
    /// Linear RGB added when `flags` has [`ADD`].
    pub rgb: [f32; 3],
    /// The pixel; a record whose pixel is not in the image does nothing.
    pub pixel: u32,
    /// [`ADD`], [`ALPHA`].
    pub flags: u32,
    /// Padding (the device marks applied runs in `flags`' top bit).
    pub pad: [u32; 3],
}

/// Adds `contributions` to `image` in record order: the CPU twin of the device's ordered
/// accumulation.
pub fn accumulate_cpu(contributions: &[Contribution], image: &mut [[f32; 4]]) {
    for c in contributions {
        let Some(px) = image.get_mut(c.pixel as usize) else {
            continue;
        };
        if c.flags & ADD != 0 {
            px[0] += c.rgb[0];
            px[1] += c.rgb[1];
            px[2] += c.rgb[2];
        }
        if c.flags & ALPHA != 0 {
            px[3] = 1.0;
        }
    }
}

#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct Params {
    n: u32,
    n_pixels: u32,
    report_slot: u32,
    pad: u32,
}

/// The compiled accumulation passes (get it with `ctx.kernel(AccumulateKernel::new)`).
pub struct AccumulateKernel {
    kernel: Kernel,
}

/// The buffers of one accumulation, bound ([`AccumulateKernel::bind`]).
pub struct Accumulation {
    bind_group: crate::kernel::KernelBindings,
    n: u32,
    n_pixels: u32,
}

impl AccumulateKernel {
    /// Compiles the passes for `ctx`'s device.
    pub fn new(ctx: &GpuContext) -> GpuResult<AccumulateKernel> {
        Ok(AccumulateKernel {
            kernel: Kernel::new(
                ctx,
                "crsh accumulate",
                SHADER,
                &["count_heads", "reset_heads", "elect", "apply"],
                &[
                    Slot::Uniform,
                    Slot::ReadWrite,
                    Slot::ReadWrite,
                    Slot::ReadWrite,
                    Slot::ReadWrite,
                ],
            )?,
        })
    }

    /// Binds the contributions, a zeroed per-pixel scratch buffer `heads` (one `u32` per
    /// pixel), the image, and the caller's `report`, whose entry `report_slot` receives the
    /// number of rounds (it must start at 0).
    pub fn bind(
        &self,
        ctx: &GpuContext,
        contributions: &GpuBuffer<Contribution>,
        heads: &GpuBuffer<u32>,
        image: &GpuBuffer<[f32; 4]>,
        report: &GpuBuffer<u32>,
        report_slot: u32,
    ) -> Accumulation {
        let params = Params {
            n: contributions.len() as u32,
            n_pixels: image.len().min(heads.len()) as u32,
            report_slot,
            pad: 0,
        };
        let u = uniform(ctx, "crsh accumulate params", &params);
        let bind_group = self.kernel.bind_group(
            ctx,
            &[
                u.as_entire_binding(),
                contributions.binding(),
                heads.binding(),
                image.binding(),
                report.binding(),
            ],
        );
        Accumulation {
            bind_group,
            n: params.n,
            n_pixels: params.n_pixels,
        }
    }

    /// Records the pass that counts each pixel's runs into the report (after the
    /// contributions are written, before [`AccumulateKernel::apply`]).
    pub fn count_heads(
        &self,
        ctx: &GpuContext,
        pass: &mut wgpu::ComputePass<'_>,
        acc: &Accumulation,
    ) -> GpuResult<()> {
        self.kernel
            .dispatch(ctx, pass, "count_heads", &acc.bind_group, acc.n)
    }

    /// Records `rounds` rounds (the count read back from the report) that add every run to
    /// the image in record order.
    pub fn apply(
        &self,
        ctx: &GpuContext,
        pass: &mut wgpu::ComputePass<'_>,
        acc: &Accumulation,
        rounds: u32,
    ) -> GpuResult<()> {
        if rounds == 0 {
            return Ok(());
        }
        self.kernel
            .dispatch(ctx, pass, "reset_heads", &acc.bind_group, acc.n_pixels)?;
        for _ in 0..rounds {
            self.kernel
                .dispatch(ctx, pass, "elect", &acc.bind_group, acc.n)?;
            self.kernel
                .dispatch(ctx, pass, "apply", &acc.bind_group, acc.n)?;
        }
        Ok(())
    }
}

/// The entry of a shader's report that [`accumulate_in_order`] writes the rounds to.
pub const ROUNDS_SLOT: usize = 1;

/// A shader's contributions and their ordered accumulation into `image`, in two
/// submissions: `contribute` records the passes that write `contributions` (and the
/// bad-input entries of `report`, a zeroed buffer of at least two entries, of which
/// [`ROUNDS_SLOT`] is this function's); the runs are counted in the same pass; the report is
/// read back once and handed to `check`, which turns bad-input entries into the error to
/// return; then the rounds run.
pub fn accumulate_in_order(
    ctx: &GpuContext,
    label: &str,
    contributions: &GpuBuffer<Contribution>,
    image: &GpuBuffer<[f32; 4]>,
    report: &GpuBuffer<u32>,
    contribute: &dyn Fn(&mut wgpu::ComputePass<'_>) -> GpuResult<()>,
    check: &dyn Fn(&[u32]) -> crsh_core::Result<()>,
) -> crsh_core::Result<()> {
    let k = ctx.kernel(AccumulateKernel::new)?;
    let heads = GpuBuffer::<u32>::zeroed(ctx, "crsh accumulate heads", image.len())?;
    let acc = k.bind(
        ctx,
        contributions,
        &heads,
        image,
        report,
        ROUNDS_SLOT as u32,
    );
    let first = format!("{label} contributions");
    let mut enc = encoder(ctx, &first);
    {
        let mut pass = ctx.compute_pass(&mut enc, &first);
        contribute(&mut pass)?;
        k.count_heads(ctx, &mut pass, &acc)?;
    }
    submit(ctx, &first, enc)?;
    let r = report.to_vec(ctx)?;
    check(&r)?;
    let second = format!("{label} accumulate");
    let mut enc = encoder(ctx, &second);
    {
        let mut pass = ctx.compute_pass(&mut enc, &second);
        k.apply(ctx, &mut pass, &acc, r[ROUNDS_SLOT])?;
    }
    submit(ctx, &second, enc)?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn contribution_is_32_bytes_and_the_twin_adds_in_order() {
        assert_eq!(std::mem::size_of::<Contribution>(), 32);
        let c = |rgb: f32, pixel, flags| Contribution {
            rgb: [rgb; 3],
            pixel,
            flags,
            pad: [0; 3],
        };
        let mut image = vec![[0.0f32; 4]; 2];
        accumulate_cpu(
            &[
                c(1.0, 0, ADD),
                c(2.0, 1, ALPHA),
                c(0.5, 0, ADD | ALPHA),
                c(9.0, 7, ADD),
            ],
            &mut image,
        );
        assert_eq!(image, [[1.5, 1.5, 1.5, 1.0], [0.0, 0.0, 0.0, 1.0]]);
    }
}
