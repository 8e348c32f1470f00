//! What every wgpu ray generator shares: the three passes over its slots (ray creation, then
//! trimming by scan-based compaction, seed 000 §3.2.3-3.2.4, fig. 3.10), the bindings its
//! kernel declares (seed 001's hemisphere table among them, [`super::offsets`]), and the
//! offset-policy codes of `segment.wgsl`.
//!
//! A generator's kernel is its own WGSL (the parameters, `slot_of` and `make`) followed by
//! [`SLOTS_WGSL`], which declares the shared bindings and two entry points over the slots of
//! one surface chunk:
//! 1. `count` evaluates every slot and writes its head flag (1 where a ray is made), and
//!    counts the rays whose interval an origin offset emptied (`report[2]`, read back with
//!    the bad-material report and added to [`Stats::add_offset_ended`]);
//! 2. the flags are scanned in place into output positions ([`crate::kernels::scan`]), the
//!    `trimming` sub-stage, whose total is the number of rays;
//! 3. `emit` (part of `trimming`) evaluates each slot again and writes the ray of every kept
//!    slot at its position, which is the CPU's compacted order.
//!
//! No slot array is kept in memory. Surfaces are bound one storage binding's worth at a time
//! and the output in chunks of one binding (`emit` runs once per output chunk), so neither
//! limits the batch size; the flags (4 bytes per slot) must fit one binding.

use std::ops::Range;

use bytemuck::Pod;
use crsh_core::{CoreError, Ray, RayKind, Result, Stats, Surface};
use crsh_cpu::raygen::whitted::OffsetPolicy;

use crate::backend::{GpuBuffer, Wgpu};
use crate::error::GpuResult;
use crate::kernel::{chunks, encoder, submit, uniform, Kernel, Slot};
use crate::kernels::scan::ScanKernel;
use crate::raygen::offsets::GpuOffsets;
use crate::scene::GpuScene;

/// The passes and bindings every generator's kernel ends with (`slots.wgsl`).
pub(crate) const SLOTS_WGSL: &str = include_str!("slots.wgsl");

/// The bindings of a ray generator's kernel, in order: its parameters, the surface chunk, the
/// scene's lights and materials, the slot flags / positions, the output chunk, a report of
/// `u32` atomics (`[0]`: `0xffffffff − pixel` of a surface with a material the scene does not
/// have; `[2]`: rays an origin offset ended), and the hemisphere set's parameters, table and
/// triangle index ([`GpuOffsets::bindings`]).
pub(crate) const BINDINGS: [Slot; 10] = [
    Slot::Uniform,
    Slot::Read,
    Slot::Read,
    Slot::Read,
    Slot::ReadWrite,
    Slot::ReadWrite,
    Slot::ReadWrite,
    Slot::Uniform,
    Slot::Read,
    Slot::Read,
];

/// Where one dispatch of a pass works: the surfaces bound (`first`, `count` of the batch) and,
/// for `emit`, the output positions bound (`out_first`, `out_count`).
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct Chunk {
    pub first: u32,
    pub count: u32,
    pub out_first: u32,
    pub out_count: u32,
}

/// The code and distance `segment.wgsl`'s `offset_segment` takes for `policy`: 0 normal,
/// 1 scaled, 2 fixed, 3 wachter.
pub(crate) fn policy_code(policy: OffsetPolicy) -> (u32, f32) {
    match policy {
        OffsetPolicy::Normal(d) => (0, d),
        OffsetPolicy::Scaled(d) => (1, d),
        OffsetPolicy::Fixed(d) => (2, d),
        OffsetPolicy::Wachter => (3, 0.0),
    }
}

/// One generator's passes over the slots of a batch: `per_surface` slots per surface, laid out
/// as the kernel's `count` and `emit` expect.
pub(crate) struct SlotPasses<'a> {
    /// The scene (device, lights, materials).
    pub scene: &'a GpuScene,
    /// The generator's kernel ([`BINDINGS`]).
    pub kernel: &'a Kernel,
    /// Buffer label prefix, e.g. `crsh whitted`.
    pub label: &'static str,
    /// Slots per surface.
    pub per_surface: usize,
    /// The origin offsets (none, or a hemisphere set).
    pub offsets: &'a GpuOffsets,
}

impl SlotPasses<'_> {
    /// Records `entry` over every surface chunk (for `emit`, with one output chunk `out`) into
    /// a new encoder and submits it; `params` makes each dispatch's uniform block.
    pub fn pass<P: Pod>(
        &self,
        entry: &str,
        params: &dyn Fn(Chunk) -> P,
        surfaces: &GpuBuffer<Surface>,
        slots: &GpuBuffer<u32>,
        out: Option<(&GpuBuffer<Ray>, Range<usize>)>,
        report: &GpuBuffer<u32>,
    ) -> GpuResult<()> {
        let ctx = self.scene.ctx();
        let dummy;
        let (out_buf, out_range) = match out {
            Some((b, r)) => (b, r),
            None => {
                dummy = GpuBuffer::<Ray>::zeroed(ctx, "crsh raygen no output", 0)?;
                (&dummy, 0..0)
            }
        };
        let mut groups = Vec::new();
        for range in chunks::<Surface>(ctx, surfaces.len()) {
            let chunk = Chunk {
                first: range.start as u32,
                count: range.len() as u32,
                out_first: out_range.start as u32,
                out_count: out_range.len() as u32,
            };
            let u = uniform(ctx, self.label, &params(chunk));
            let [hemi, hemi_table, hemi_index] = self.offsets.bindings();
            let bg = self.kernel.bind_group(
                ctx,
                &[
                    u.as_entire_binding(),
                    surfaces.slice_binding(range.clone()),
                    self.scene.lights.binding(),
                    self.scene.materials.binding(),
                    slots.binding(),
                    out_buf.slice_binding(out_range.clone()),
                    report.binding(),
                    hemi,
                    hemi_table,
                    hemi_index,
                ],
            );
            groups.push((bg, (range.len() * self.per_surface) as u32));
        }
        let mut enc = encoder(ctx, entry);
        {
            let mut pass = ctx.compute_pass(&mut enc, entry);
            for (bg, n) in &groups {
                self.kernel.dispatch(ctx, &mut pass, entry, bg, *n)?;
            }
        }
        submit(ctx, entry, enc)
    }

    /// The rays of `kind` of `surfaces`, compacted in slot order: `count`, then `check` on the
    /// report read back (it turns a bad-input report into the error to return) and the rays
    /// the origin offsets ended added to `stats`, then the scan and `emit` (timed as
    /// `trimming`).
    pub fn rays<P: Pod>(
        &self,
        backend: &Wgpu,
        surfaces: &GpuBuffer<Surface>,
        kind: RayKind,
        params: &dyn Fn(Chunk) -> P,
        check: &dyn Fn(&[u32]) -> Result<()>,
        stats: &mut Stats,
    ) -> Result<GpuBuffer<Ray>> {
        let ctx = backend.context();
        let n = surfaces.len();
        let total = n.checked_mul(self.per_surface);
        if n > u32::MAX as usize || total.is_none_or(|t| t >= u32::MAX as usize) {
            return Err(CoreError::InvalidInput(format!(
                "{n} surfaces × {} rays do not fit 32-bit ray indices",
                self.per_surface
            )));
        }
        let total = total.unwrap_or(0);
        if total == 0 {
            return Ok(GpuBuffer::zeroed(ctx, "crsh rays", 0)?);
        }
        ctx.check_storage_binding("ray slot flags", total as u64 * 4)?;
        let slots = GpuBuffer::<u32>::zeroed(ctx, "crsh raygen slots", total)?;
        let report = GpuBuffer::<u32>::zeroed(ctx, "crsh raygen report", 4)?;
        self.pass("count", params, surfaces, &slots, None, &report)?;
        let reported = report.to_vec(ctx)?;
        check(&reported)?;
        stats.add_offset_ended(kind, u64::from(reported[2]));
        crsh_core::timed(backend, stats, "trimming", |_| {
            let kept = ctx.kernel(ScanKernel::new)?.scan_in_place(ctx, &slots)? as usize;
            let rays = GpuBuffer::<Ray>::zeroed(ctx, "crsh rays", kept)?;
            for out in chunks::<Ray>(ctx, kept) {
                if out.is_empty() {
                    continue;
                }
                self.pass(
                    "emit",
                    params,
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

/// The error for a report whose `[0]` names a surface with a material the scene lacks.
pub(crate) fn check_materials(report: &[u32], materials: usize) -> Result<()> {
    match report.first() {
        Some(&bad) if bad != 0 => Err(CoreError::InvalidInput(format!(
            "surface of pixel {} has a material the scene does not have ({materials} materials)",
            u32::MAX - bad
        ))),
        _ => Ok(()),
    }
}
