//! The plumbing every compute kernel of the backend shares: compiling a WGSL module with the
//! shared records of `kernels/common.wgsl` prepended, one bind group layout per kernel, 1D
//! dispatches folded into a 2D grid when they exceed the adapter's per-dimension limit, uniform
//! parameter blocks, and chunking of buffers larger than one storage binding.
//!
//! A kernel module (say `hash/thesis.rs` with `hash/thesis.wgsl`) declares its bindings as
//! [`Slot`]s, compiles once per device through [`crate::GpuContext::kernel`], and records its
//! dispatches into a pass begun with [`crate::GpuContext::compute_pass`] (which times it for the
//! open stage).

use std::ops::Range;

use wgpu::util::DeviceExt;

use crate::adapter::GpuContext;
use crate::backend::GpuBuffer;
use crate::error::{GpuError, GpuResult};

/// WGSL source shared by every kernel (records and helpers); [`Kernel::new`] prepends it.
pub const COMMON_WGSL: &str = include_str!("kernels/common.wgsl");

/// Invocations per workgroup of 1D kernels (`WG` in `common.wgsl`).
pub const WG: u32 = 256;

/// What one binding of a kernel's group 0 is, in binding order.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Slot {
    /// `var<uniform>`: a parameter block.
    Uniform,
    /// `var<storage, read>`.
    Read,
    /// `var<storage, read_write>`.
    ReadWrite,
}

/// A compiled WGSL module: one compute pipeline per entry point over the bindings
/// `0..slots.len()` of group 0.
///
/// Each entry point gets a bind group layout of only the bindings it statically uses (naga's
/// analysis of the module, the rule by which wgpu derives layouts itself), so that a module
/// whose entry points share many buffers stays within `max_storage_buffers_per_shader_stage`
/// as long as each entry point does: 8 under WebGPU's default limits, 16 on Mesa's OpenGL.
/// Entry points that use the same bindings share one layout.
#[derive(Debug)]
pub struct Kernel {
    label: &'static str,
    /// One layout per distinct set of used bindings, with the bindings it holds.
    layouts: Vec<(Vec<u32>, wgpu::BindGroupLayout)>,
    /// Entry point, pipeline, index into `layouts`.
    pipelines: Vec<(&'static str, wgpu::ComputePipeline, usize)>,
}

/// The bind groups of one set of resources for a [`Kernel`]: one per layout of its entry
/// points ([`Kernel::bind_group`]).
#[derive(Debug)]
pub struct KernelBindings {
    groups: Vec<wgpu::BindGroup>,
}

/// Bindings `0..n_slots` of group 0 that each of `entries` statically uses in `source`
/// (through the functions it calls), in binding order.
pub fn entry_bindings(
    label: &str,
    source: &str,
    entries: &[&str],
    n_slots: usize,
) -> GpuResult<Vec<Vec<u32>>> {
    use wgpu::naga;
    let invalid = |reason: String| GpuError::Device {
        op: format!("kernel `{label}`"),
        reason,
    };
    let module =
        naga::front::wgsl::parse_str(source).map_err(|e| invalid(e.emit_to_string(source)))?;
    let info = naga::valid::Validator::new(
        naga::valid::ValidationFlags::all(),
        naga::valid::Capabilities::all(),
    )
    .validate(&module)
    .map_err(|e| invalid(e.emit_to_string(source)))?;
    entries
        .iter()
        .map(|&entry| {
            let index = module
                .entry_points
                .iter()
                .position(|e| e.name == entry)
                .ok_or_else(|| invalid(format!("no entry point `{entry}` in the module")))?;
            let uses = info.get_entry_point(index);
            let mut used: Vec<u32> = module
                .global_variables
                .iter()
                .filter(|(h, _)| !uses[*h].is_empty())
                .filter_map(|(_, var)| var.binding.as_ref())
                .filter(|b| b.group == 0 && (b.binding as usize) < n_slots)
                .map(|b| b.binding)
                .collect();
            used.sort_unstable();
            used.dedup();
            Ok(used)
        })
        .collect()
}

/// Fails with [`GpuError::Limit`] when the bindings `used` of `slots` need more storage or
/// uniform buffers in one shader stage than `limits` allow.
pub fn check_binding_limits(
    what: &str,
    slots: &[Slot],
    used: &[u32],
    limits: &wgpu::Limits,
) -> GpuResult<()> {
    let count = |f: fn(Slot) -> bool| {
        used.iter()
            .filter(|&&b| slots.get(b as usize).is_some_and(|&s| f(s)))
            .count() as u32
    };
    let storage = count(|s| s != Slot::Uniform);
    let uniform = count(|s| s == Slot::Uniform);
    for (needed, limit, name) in [
        (
            storage,
            limits.max_storage_buffers_per_shader_stage,
            "max_storage_buffers_per_shader_stage",
        ),
        (
            uniform,
            limits.max_uniform_buffers_per_shader_stage,
            "max_uniform_buffers_per_shader_stage",
        ),
    ] {
        if needed > limit {
            return Err(GpuError::Limit {
                what: what.to_string(),
                needed: u64::from(needed),
                limit_name: name,
                limit: u64::from(limit),
            });
        }
    }
    Ok(())
}

impl Kernel {
    /// Compiles `source` (with [`COMMON_WGSL`] prepended) and creates a pipeline for each of
    /// `entries`, each with the layout of the `slots` it uses. Compilation errors come back as
    /// [`GpuError::Device`]; an entry point that needs more buffers than the device allows
    /// as [`GpuError::Limit`].
    pub fn new(
        ctx: &GpuContext,
        label: &'static str,
        source: &str,
        entries: &[&'static str],
        slots: &[Slot],
    ) -> GpuResult<Kernel> {
        let device = ctx.device();
        let full = format!("{COMMON_WGSL}\n{source}");
        let used = entry_bindings(label, &full, entries, slots.len())?;
        let limits = ctx.limits();
        for (entry, used) in entries.iter().zip(&used) {
            check_binding_limits(
                &format!("kernel `{label}` entry `{entry}`"),
                slots,
                used,
                &limits,
            )?;
        }
        let mut sets: Vec<Vec<u32>> = Vec::new();
        let layout_of: Vec<usize> = used
            .iter()
            .map(|u| match sets.iter().position(|s| s == u) {
                Some(i) => i,
                None => {
                    sets.push(u.clone());
                    sets.len() - 1
                }
            })
            .collect();
        ctx.capture(label, || {
            let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
                label: Some(label),
                source: wgpu::ShaderSource::Wgsl(full.into()),
            });
            let layouts: Vec<(Vec<u32>, wgpu::BindGroupLayout, wgpu::PipelineLayout)> = sets
                .into_iter()
                .map(|set| {
                    let layout_entries: Vec<wgpu::BindGroupLayoutEntry> = set
                        .iter()
                        .map(|&b| layout_entry(b, slots[b as usize]))
                        .collect();
                    let layout =
                        device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                            label: Some(label),
                            entries: &layout_entries,
                        });
                    let pipeline_layout =
                        device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
                            label: Some(label),
                            bind_group_layouts: &[Some(&layout)],
                            immediate_size: 0,
                        });
                    (set, layout, pipeline_layout)
                })
                .collect();
            let pipelines = entries
                .iter()
                .zip(&layout_of)
                .map(|(&entry, &l)| {
                    let p = device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                        label: Some(entry),
                        layout: Some(&layouts[l].2),
                        module: &module,
                        entry_point: Some(entry),
                        compilation_options: Default::default(),
                        cache: None,
                    });
                    (entry, p, l)
                })
                .collect();
            Kernel {
                label,
                layouts: layouts.into_iter().map(|(s, l, _)| (s, l)).collect(),
                pipelines,
            }
        })
    }

    fn entry(&self, entry: &str) -> GpuResult<&(&'static str, wgpu::ComputePipeline, usize)> {
        self.pipelines
            .iter()
            .find(|(name, _, _)| *name == entry)
            .ok_or_else(|| GpuError::Device {
                op: format!("kernel `{}`", self.label),
                reason: format!("no entry point `{entry}` was compiled"),
            })
    }

    /// The pipeline of entry point `entry` (one of those given to [`Kernel::new`]).
    pub fn pipeline(&self, entry: &str) -> GpuResult<&wgpu::ComputePipeline> {
        self.entry(entry).map(|(_, p, _)| p)
    }

    /// The bindings entry point `entry` uses, in binding order.
    pub fn bindings_of(&self, entry: &str) -> GpuResult<&[u32]> {
        self.entry(entry)
            .map(|(_, _, l)| self.layouts[*l].0.as_slice())
    }

    /// The bind groups of `resources`, in slot order: each layout's group holds the resources
    /// of the bindings its entry points use.
    pub fn bind_group(
        &self,
        ctx: &GpuContext,
        resources: &[wgpu::BindingResource<'_>],
    ) -> KernelBindings {
        let groups = self
            .layouts
            .iter()
            .map(|(set, layout)| {
                let entries: Vec<wgpu::BindGroupEntry<'_>> = set
                    .iter()
                    .filter_map(|&b| {
                        resources.get(b as usize).map(|r| wgpu::BindGroupEntry {
                            binding: b,
                            resource: r.clone(),
                        })
                    })
                    .collect();
                ctx.device().create_bind_group(&wgpu::BindGroupDescriptor {
                    label: Some(self.label),
                    layout,
                    entries: &entries,
                })
            })
            .collect();
        KernelBindings { groups }
    }

    /// Records a dispatch of `entry` over `invocations` invocations of [`WG`]-wide workgroups
    /// (2D when wider than the adapter allows; the shader uses `linear_id` and must bound-check
    /// against its own element count). Nothing is recorded for 0 invocations.
    pub fn dispatch(
        &self,
        ctx: &GpuContext,
        pass: &mut wgpu::ComputePass<'_>,
        entry: &str,
        bindings: &KernelBindings,
        invocations: u32,
    ) -> GpuResult<()> {
        if invocations == 0 {
            return Ok(());
        }
        let (x, y) = grid(ctx, invocations.div_ceil(WG))?;
        self.set(pass, entry, bindings)?;
        pass.dispatch_workgroups(x, y, 1);
        Ok(())
    }

    /// Sets `entry`'s pipeline and its bind group of `bindings` on `pass` (for dispatches
    /// shaped by the caller, e.g. indirect ones).
    pub fn set(
        &self,
        pass: &mut wgpu::ComputePass<'_>,
        entry: &str,
        bindings: &KernelBindings,
    ) -> GpuResult<()> {
        let (_, pipeline, l) = self.entry(entry)?;
        pass.set_pipeline(pipeline);
        pass.set_bind_group(0, &bindings.groups[*l], &[]);
        Ok(())
    }
}

/// The layout entry of binding `binding`, a `slot`, visible to compute.
fn layout_entry(binding: u32, slot: Slot) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::COMPUTE,
        ty: wgpu::BindingType::Buffer {
            ty: match slot {
                Slot::Uniform => wgpu::BufferBindingType::Uniform,
                Slot::Read => wgpu::BufferBindingType::Storage { read_only: true },
                Slot::ReadWrite => wgpu::BufferBindingType::Storage { read_only: false },
            },
            has_dynamic_offset: false,
            min_binding_size: None,
        },
        count: None,
    }
}

/// `groups` workgroups as an `(x, y)` grid within the adapter's per-dimension limit.
pub fn grid(ctx: &GpuContext, groups: u32) -> GpuResult<(u32, u32)> {
    let max = ctx.max_workgroups_per_dimension().max(1);
    let x = groups.clamp(1, max);
    let y = groups.div_ceil(x);
    if y > max {
        return Err(GpuError::TooLarge {
            what: format!("dispatch of {groups} workgroups"),
            bytes: u64::from(groups),
            limit_name: "max_compute_workgroups_per_dimension squared",
            limit: u64::from(max) * u64::from(max),
        });
    }
    Ok((x, y))
}

/// A uniform buffer holding `value` (a `#[repr(C)]` block padded to 16 bytes by the caller).
pub fn uniform<T: bytemuck::Pod>(ctx: &GpuContext, label: &str, value: &T) -> wgpu::Buffer {
    ctx.device()
        .create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some(label),
            contents: bytemuck::bytes_of(value),
            usage: wgpu::BufferUsages::UNIFORM,
        })
}

/// Submits `encoder` (device errors become [`GpuError::Device`] naming `op`).
pub fn submit(ctx: &GpuContext, op: &str, encoder: wgpu::CommandEncoder) -> GpuResult<()> {
    ctx.capture(op, || {
        ctx.queue().submit([encoder.finish()]);
    })
}

/// A new command encoder labelled `label`.
pub fn encoder(ctx: &GpuContext, label: &str) -> wgpu::CommandEncoder {
    ctx.device()
        .create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some(label) })
}

/// The most elements of `T` one storage binding may hold on this device, rounded down so that
/// consecutive chunks start at offsets aligned to `min_storage_buffer_offset_alignment`.
pub fn chunk_elems<T>(ctx: &GpuContext) -> usize {
    let elem = std::mem::size_of::<T>().max(1) as u64;
    let align = u64::from(ctx.limits().min_storage_buffer_offset_alignment).max(1);
    // Elements per alignment unit: chunks must be a whole number of `lcm(elem, align)` bytes.
    let unit = lcm(elem, align);
    let max = ctx.max_storage_binding_bytes();
    let bytes = (max / unit) * unit;
    (bytes / elem).max(1) as usize
}

fn lcm(a: u64, b: u64) -> u64 {
    fn gcd(a: u64, b: u64) -> u64 {
        if b == 0 {
            a
        } else {
            gcd(b, a % b)
        }
    }
    a / gcd(a, b) * b
}

/// `0..len` cut into consecutive ranges of at most [`chunk_elems::<T>`] elements: the pieces a
/// kernel binds one at a time (with [`GpuBuffer::slice_binding`]) when a buffer is larger than
/// one storage binding. One empty range for `len == 0`.
pub fn chunks<T>(ctx: &GpuContext, len: usize) -> Vec<Range<usize>> {
    let step = chunk_elems::<T>(ctx);
    if len == 0 {
        return std::iter::once(0..0).collect();
    }
    (0..len)
        .step_by(step)
        .map(|start| start..(start + step).min(len))
        .collect()
}

/// Runs `kernel`'s `entry` with one invocation per element of a batch of `len` elements of
/// `T`, cut into [`chunks`] (each chunk's bind group made by `bind` from its range), every
/// chunk dispatched in one compute pass and submitted: the per-ray shape of the hashes and of
/// the whole-scene intersectors. Nothing is recorded for `len == 0`.
pub fn dispatch_chunks<T>(
    ctx: &GpuContext,
    kernel: &Kernel,
    label: &str,
    entry: &str,
    len: usize,
    mut bind: impl FnMut(Range<usize>) -> KernelBindings,
) -> GpuResult<()> {
    let groups: Vec<(KernelBindings, u32)> = chunks::<T>(ctx, len)
        .into_iter()
        .map(|range| {
            let n = range.len() as u32;
            (bind(range), n)
        })
        .collect();
    let mut enc = encoder(ctx, label);
    {
        let mut pass = ctx.compute_pass(&mut enc, label);
        for (bg, n) in &groups {
            kernel.dispatch(ctx, &mut pass, entry, bg, *n)?;
        }
    }
    submit(ctx, label, enc)
}

impl<T: bytemuck::Pod> GpuBuffer<T> {
    /// Elements `range` as a storage binding. `range.start` must be a multiple of
    /// [`chunk_elems::<T>`] (or 0), as the ranges of [`chunks`] are; an empty range binds the
    /// buffer's first 16 bytes (wgpu forbids empty bindings; kernels take counts from their
    /// parameters).
    pub fn slice_binding(&self, range: Range<usize>) -> wgpu::BindingResource<'_> {
        let elem = std::mem::size_of::<T>() as u64;
        let offset = range.start as u64 * elem;
        let size = (range.len() as u64 * elem).max(crate::backend::MIN_BUFFER_BYTES);
        let size = crate::backend::padded_size(size).min(self.buffer().size() - offset);
        wgpu::BindingResource::Buffer(wgpu::BufferBinding {
            buffer: self.buffer(),
            offset,
            size: wgpu::BufferSize::new(size),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn common_wgsl_declares_the_workgroup_size() {
        assert!(COMMON_WGSL.contains(&format!("const WG: u32 = {WG}u;")));
    }

    #[test]
    fn lcm_of_record_sizes_and_alignments() {
        assert_eq!(lcm(64, 256), 256);
        assert_eq!(lcm(80, 256), 1280);
        assert_eq!(lcm(48, 256), 768);
        assert_eq!(lcm(8, 256), 256);
    }
}
