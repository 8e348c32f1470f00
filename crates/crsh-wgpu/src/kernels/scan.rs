//! Exclusive prefix sum (scan) of `u32` on the device, and its CPU twin.
//!
//! `out[i] = in[0] + ... + in[i-1]` (so `out[0] = 0`) and `total = in[0] + ... + in[n-1]`,
//! all with wrapping (mod 2^32) addition on both sides. Stream compaction, binning and the
//! hierarchy builders of later stages use it to turn per-item counts into output offsets.
//!
//! The GPU version is the classic three-phase scan (Blelloch 1990; Harris et al., GPU Gems 3
//! ch. 39): every workgroup scans a block of [`SCAN_BLOCK`] elements in workgroup memory with
//! a work-efficient up-sweep / down-sweep and writes the block total; the block totals are
//! scanned recursively the same way until one block remains; then each block's scanned total
//! is added back to its elements. Dispatches wider than the adapter's
//! `max_compute_workgroups_per_dimension` fold into a 2D grid.

use wgpu::util::DeviceExt;

use crate::adapter::GpuContext;
use crate::backend::{create_raw_buffer, map_read_bytes, GpuBuffer};
use crate::error::{GpuError, GpuResult};

/// Elements scanned per workgroup (256 invocations × 8 elements); must match `scan.wgsl`.
///
/// Eight elements per invocation halve the barriers per element compared with four (about
/// 1.5× faster on lavapipe for 2^22 elements) while the block (8 KiB of workgroup memory plus
/// 1 KiB of partial sums) stays within WebGPU's 16 KiB minimum.
pub const SCAN_BLOCK: usize = 2048;

const SHADER: &str = include_str!("scan.wgsl");

/// Exclusive prefix sum with wrapping addition: returns `(prefix, total)`, the CPU twin of
/// [`exclusive_scan`].
pub fn exclusive_scan_cpu(input: &[u32]) -> (Vec<u32>, u32) {
    let mut out = Vec::with_capacity(input.len());
    let mut run = 0u32;
    for &v in input {
        out.push(run);
        run = run.wrapping_add(v);
    }
    (out, run)
}

/// Uniform block of one scan level (mirrors `Params` in `scan.wgsl`).
#[repr(C)]
#[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
struct Params {
    n: u32,
    blocks: u32,
    groups_x: u32,
    _pad: u32,
}

/// The compiled scan pipelines for one device. Get the shared instance with
/// `ctx.kernel(ScanKernel::new)` (what [`exclusive_scan`] does) rather than compiling it
/// per call.
#[derive(Debug)]
pub struct ScanKernel {
    layout: wgpu::BindGroupLayout,
    scan: wgpu::ComputePipeline,
    add: wgpu::ComputePipeline,
    max_groups_x: u32,
}

fn storage_entry(binding: u32) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::COMPUTE,
        ty: wgpu::BindingType::Buffer {
            ty: wgpu::BufferBindingType::Storage { read_only: false },
            has_dynamic_offset: false,
            min_binding_size: None,
        },
        count: None,
    }
}

impl ScanKernel {
    /// Compiles the kernel for `ctx`'s device.
    pub fn new(ctx: &GpuContext) -> GpuResult<Self> {
        let device = ctx.device();
        ctx.capture("compile scan kernel", || {
            let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
                label: Some("crsh scan"),
                source: wgpu::ShaderSource::Wgsl(SHADER.into()),
            });
            let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                label: Some("crsh scan"),
                entries: &[
                    wgpu::BindGroupLayoutEntry {
                        binding: 0,
                        visibility: wgpu::ShaderStages::COMPUTE,
                        ty: wgpu::BindingType::Buffer {
                            ty: wgpu::BufferBindingType::Uniform,
                            has_dynamic_offset: false,
                            min_binding_size: None,
                        },
                        count: None,
                    },
                    storage_entry(1),
                    storage_entry(2),
                ],
            });
            let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
                label: Some("crsh scan"),
                bind_group_layouts: &[Some(&layout)],
                immediate_size: 0,
            });
            let pipeline = |entry: &str| {
                device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                    label: Some(entry),
                    layout: Some(&pipeline_layout),
                    module: &module,
                    entry_point: Some(entry),
                    compilation_options: Default::default(),
                    cache: None,
                })
            };
            ScanKernel {
                scan: pipeline("scan_blocks"),
                add: pipeline("add_offsets"),
                layout,
                max_groups_x: ctx.max_workgroups_per_dimension(),
            }
        })
    }

    /// Caps the workgroups per dispatch row (at most the adapter's limit), so that tests can
    /// exercise the 2D dispatch path with small inputs.
    pub fn with_max_groups_x(mut self, max_groups_x: u32) -> Self {
        self.max_groups_x = max_groups_x.clamp(1, self.max_groups_x);
        self
    }

    /// Records an in-place exclusive scan of `data` into `encoder`; when `total` is given, the
    /// wrapping sum of all elements is copied to that buffer at that byte offset (4-aligned;
    /// the buffer needs `COPY_DST`). Scratch buffers are kept alive by the encoder.
    pub fn encode_in_place(
        &self,
        ctx: &GpuContext,
        encoder: &mut wgpu::CommandEncoder,
        data: &GpuBuffer<u32>,
        total: Option<(&wgpu::Buffer, u64)>,
    ) -> GpuResult<()> {
        let n = data.len();
        ctx.check_storage_binding("scan input", data.byte_len())?;
        if n > (u32::MAX as usize) - SCAN_BLOCK {
            return Err(GpuError::TooLarge {
                what: "scan input (elements are indexed with u32)".into(),
                bytes: data.byte_len(),
                limit_name: "u32 element index",
                limit: ((u32::MAX as usize - SCAN_BLOCK) * 4) as u64,
            });
        }
        if n == 0 {
            if let Some((buf, offset)) = total {
                encoder.clear_buffer(buf, offset, Some(4));
            }
            return Ok(());
        }
        // lens[0] = n, lens[i + 1] = blocks of level i; the last level has one element.
        let mut lens = vec![n];
        loop {
            let blocks = lens[lens.len() - 1].div_ceil(SCAN_BLOCK);
            lens.push(blocks);
            if blocks == 1 {
                break;
            }
        }
        let mut scratch = Vec::with_capacity(lens.len() - 1);
        for &len in &lens[1..] {
            scratch.push(GpuBuffer::<u32>::zeroed(ctx, "crsh scan block sums", len)?);
        }
        let level_buffer = |i: usize| if i == 0 { data } else { &scratch[i - 1] };
        let levels = lens.len() - 1;
        let mut bind_groups = Vec::with_capacity(levels);
        let mut grids = Vec::with_capacity(levels);
        for i in 0..levels {
            let blocks = lens[i + 1] as u32;
            let groups_x = blocks.min(self.max_groups_x);
            let groups_y = blocks.div_ceil(groups_x);
            if groups_y > ctx.max_workgroups_per_dimension() {
                return Err(GpuError::TooLarge {
                    what: format!("scan dispatch of {blocks} workgroups"),
                    bytes: data.byte_len(),
                    limit_name: "max_compute_workgroups_per_dimension squared",
                    limit: u64::from(groups_x) * u64::from(ctx.max_workgroups_per_dimension()),
                });
            }
            let params = Params {
                n: lens[i] as u32,
                blocks,
                groups_x,
                _pad: 0,
            };
            let uniform = ctx
                .device()
                .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                    label: Some("crsh scan params"),
                    contents: bytemuck::bytes_of(&params),
                    usage: wgpu::BufferUsages::UNIFORM,
                });
            bind_groups.push(ctx.device().create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("crsh scan level"),
                layout: &self.layout,
                entries: &[
                    wgpu::BindGroupEntry {
                        binding: 0,
                        resource: uniform.as_entire_binding(),
                    },
                    wgpu::BindGroupEntry {
                        binding: 1,
                        resource: level_buffer(i).binding(),
                    },
                    wgpu::BindGroupEntry {
                        binding: 2,
                        resource: level_buffer(i + 1).binding(),
                    },
                ],
            }));
            grids.push((groups_x, groups_y));
        }
        {
            let mut pass = ctx.compute_pass(encoder, "crsh scan");
            pass.set_pipeline(&self.scan);
            for (bind_group, &(x, y)) in bind_groups.iter().zip(&grids) {
                pass.set_bind_group(0, bind_group, &[]);
                pass.dispatch_workgroups(x, y, 1);
            }
            // The top level is a single block (its offset is 0): add back from the level below.
            pass.set_pipeline(&self.add);
            for i in (0..levels - 1).rev() {
                pass.set_bind_group(0, &bind_groups[i], &[]);
                pass.dispatch_workgroups(grids[i].0, grids[i].1, 1);
            }
        }
        if let Some((buf, offset)) = total {
            encoder.copy_buffer_to_buffer(level_buffer(levels).buffer(), 0, buf, offset, 4);
        }
        Ok(())
    }

    /// Scans `data` in place and returns the total (submits and waits).
    pub fn scan_in_place(&self, ctx: &GpuContext, data: &GpuBuffer<u32>) -> GpuResult<u32> {
        if data.is_empty() {
            return Ok(0);
        }
        let staging = create_raw_buffer(
            ctx,
            "crsh scan total",
            4,
            wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            false,
        )?;
        let mut encoder = ctx
            .device()
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("crsh scan"),
            });
        ctx.capture("encode scan", || {
            self.encode_in_place(ctx, &mut encoder, data, Some((&staging, 0)))
        })??;
        ctx.capture("submit scan", || {
            ctx.queue().submit([encoder.finish()]);
        })?;
        let bytes = map_read_bytes(ctx, &staging, 4)?;
        Ok(u32::from_le_bytes([bytes[0], bytes[1], bytes[2], bytes[3]]))
    }

    /// Scans a copy of `input`: returns `(prefix, total)` and leaves `input` unchanged.
    pub fn scan(
        &self,
        ctx: &GpuContext,
        input: &GpuBuffer<u32>,
    ) -> GpuResult<(GpuBuffer<u32>, u32)> {
        let out = GpuBuffer::<u32>::zeroed(ctx, "crsh scan output", input.len())?;
        if input.is_empty() {
            return Ok((out, 0));
        }
        let mut encoder = ctx
            .device()
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("crsh scan copy"),
            });
        encoder.copy_buffer_to_buffer(input.buffer(), 0, out.buffer(), 0, input.byte_len());
        ctx.capture("submit scan copy", || {
            ctx.queue().submit([encoder.finish()]);
        })?;
        let total = self.scan_in_place(ctx, &out)?;
        Ok((out, total))
    }
}

/// Exclusive prefix sum of `input` on the device with wrapping addition: `(prefix, total)`,
/// identical to [`exclusive_scan_cpu`]. Uses the context's cached [`ScanKernel`].
///
/// Fails with [`GpuError::TooLarge`] when `input` exceeds the storage binding limit.
pub fn exclusive_scan(
    ctx: &GpuContext,
    input: &GpuBuffer<u32>,
) -> GpuResult<(GpuBuffer<u32>, u32)> {
    ctx.kernel(ScanKernel::new)?.scan(ctx, input)
}

/// In-place variant of [`exclusive_scan`]: overwrites `data` with its exclusive prefix sum and
/// returns the total.
pub fn exclusive_scan_in_place(ctx: &GpuContext, data: &GpuBuffer<u32>) -> GpuResult<u32> {
    ctx.kernel(ScanKernel::new)?.scan_in_place(ctx, data)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cpu_scan_is_exclusive_and_wraps() {
        let (out, total) = exclusive_scan_cpu(&[3, u32::MAX, 2, 0]);
        assert_eq!(out, vec![0, 3, 2, 4]);
        assert_eq!(total, 4);
        assert_eq!(exclusive_scan_cpu(&[]), (vec![], 0));
    }

    #[test]
    fn block_size_matches_wgsl() {
        assert!(SHADER.contains(&format!("const BLOCK: u32 = {SCAN_BLOCK}u;")));
        assert!(SHADER.contains(&format!("const ITEMS: u32 = {}u;", SCAN_BLOCK / 256)));
        assert!(SHADER.contains("const WG: u32 = 256u;"));
        assert!(SHADER.contains("@workgroup_size(256)"));
    }

    #[test]
    fn params_match_wgsl_uniform_layout() {
        assert_eq!(std::mem::size_of::<Params>(), 16);
    }
}
