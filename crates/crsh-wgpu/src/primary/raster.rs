//! `raster` on the wgpu backend: the G-buffer by a real render pass (seed 000 §3.1).
//!
//! A render pass draws every triangle (one draw, three vertices per triangle read from the
//! scene's triangle buffer in the vertex shader, degenerate ones collapsed to a point) with
//! the scene camera, reverse-Z depth (`near / view depth`, `Greater` test, so among equal
//! depths the first drawn, i.e. the lower triangle id, stays) and writes the triangle id into
//! an `R32Uint` target: a visibility buffer (Burns & Hunt 2013). A compute pass then resolves
//! each pixel exactly as the CPU rasterizer ([`crsh_cpu::primary::raster::Raster`]) does: the
//! pixel-centre camera ray ([`crsh_scene::Camera::direction`]) is intersected with the plane of
//! the visible triangle by the Möller-Trumbore solve on the CPU's prepared triangles, and
//! `surface_from_hit` builds the record (`kernels/surface.wgsl`). Where both backends see the
//! same triangle their records agree to the rounding of WGSL's `sqrt` and division.
//!
//! Coverage is the hardware's (Vulkan: pixel centres, top-left rule, 8 sub-pixel bits as the
//! CPU rasterizer), with vertices projected in f32 (the CPU projects in f64), so the two differ
//! only for pixel centres within rounding of an edge or at equal depths. Geometry nearer than
//! `near` = 1e-6 of the scene's bounding-box diagonal is clipped, as on the CPU. Image sides
//! above the adapter's `max_texture_dimension_2d` are a [`crate::GpuError::TooLarge`]; the
//! records are written in chunks of one storage binding.

use std::sync::Arc;

use bytemuck::{Pod, Zeroable};
use crsh_core::{CoreError, PrimaryVisibility, Registry, Result, StageSpec, Stats, Surface};
use crsh_cpu::triangle::{PreparedTriangle, TriangleSet};

use crate::adapter::GpuContext;
use crate::backend::{create_raw_buffer, GpuBuffer, Wgpu};
use crate::error::{GpuError, GpuResult};
use crate::kernel::{chunks, encoder, submit, uniform, Kernel, Slot};
use crate::scene::GpuScene;

const DRAW: &str = include_str!("raster_draw.wgsl");
const RESOLVE: &str = include_str!("raster_resolve.wgsl");

/// Near plane distance as a fraction of the scene's bounding-box diagonal (as the CPU's).
const NEAR_FRACTION: f32 = 1e-6;

#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct DrawCamera {
    eye: [f32; 3],
    near: f32,
    right: [f32; 3],
    sx: f32,
    up: [f32; 3],
    sy: f32,
    forward: [f32; 3],
    pad: f32,
}

#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct ResolveParams {
    width: u32,
    height: u32,
    row_stride: u32,
    first: u32,
    count: u32,
    n_tris: u32,
    tan_half: f32,
    aspect: f32,
    right: [f32; 3],
    a: f32,
    up: [f32; 3],
    b: f32,
    forward: [f32; 3],
    c: f32,
    eye: [f32; 3],
    d: f32,
}

/// The render pipeline and the resolve kernel (one per device).
struct RasterKernels {
    layout: wgpu::BindGroupLayout,
    pipeline: wgpu::RenderPipeline,
    resolve: Kernel,
}

impl RasterKernels {
    fn new(ctx: &GpuContext) -> GpuResult<RasterKernels> {
        let device = ctx.device();
        let (layout, pipeline) = ctx.capture("crsh raster pipeline", || {
            let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
                label: Some("crsh raster draw"),
                source: wgpu::ShaderSource::Wgsl(
                    format!("{}\n{DRAW}", crate::kernel::COMMON_WGSL).into(),
                ),
            });
            let storage = |binding| wgpu::BindGroupLayoutEntry {
                binding,
                visibility: wgpu::ShaderStages::VERTEX,
                ty: wgpu::BindingType::Buffer {
                    ty: wgpu::BufferBindingType::Storage { read_only: true },
                    has_dynamic_offset: false,
                    min_binding_size: None,
                },
                count: None,
            };
            let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                label: Some("crsh raster draw"),
                entries: &[
                    wgpu::BindGroupLayoutEntry {
                        binding: 0,
                        visibility: wgpu::ShaderStages::VERTEX,
                        ty: wgpu::BindingType::Buffer {
                            ty: wgpu::BufferBindingType::Uniform,
                            has_dynamic_offset: false,
                            min_binding_size: None,
                        },
                        count: None,
                    },
                    storage(1),
                    storage(2),
                ],
            });
            let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
                label: Some("crsh raster draw"),
                bind_group_layouts: &[Some(&layout)],
                immediate_size: 0,
            });
            let pipeline = device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
                label: Some("crsh raster draw"),
                layout: Some(&pipeline_layout),
                vertex: wgpu::VertexState {
                    module: &module,
                    entry_point: Some("vs"),
                    compilation_options: Default::default(),
                    buffers: &[],
                },
                primitive: wgpu::PrimitiveState {
                    topology: wgpu::PrimitiveTopology::TriangleList,
                    cull_mode: None,
                    ..Default::default()
                },
                depth_stencil: Some(wgpu::DepthStencilState {
                    format: wgpu::TextureFormat::Depth32Float,
                    depth_write_enabled: Some(true),
                    depth_compare: Some(wgpu::CompareFunction::Greater),
                    stencil: Default::default(),
                    bias: Default::default(),
                }),
                multisample: Default::default(),
                fragment: Some(wgpu::FragmentState {
                    module: &module,
                    entry_point: Some("fs"),
                    compilation_options: Default::default(),
                    targets: &[Some(wgpu::ColorTargetState {
                        format: wgpu::TextureFormat::R32Uint,
                        blend: None,
                        write_mask: wgpu::ColorWrites::ALL,
                    })],
                }),
                multiview_mask: None,
                cache: None,
            });
            (layout, pipeline)
        })?;
        let resolve_src = crate::kernels::compose(&[
            crate::intersect::MT_WGSL,
            crate::kernels::GLAM_WGSL,
            crate::kernels::SURFACE_WGSL,
            RESOLVE,
        ]);
        let mut slots = vec![Slot::Uniform];
        slots.extend([Slot::Read; 5]);
        slots.extend([Slot::ReadWrite; 2]);
        Ok(RasterKernels {
            layout,
            pipeline,
            resolve: Kernel::new(
                ctx,
                "crsh raster resolve",
                &resolve_src,
                &["resolve"],
                &slots,
            )?,
        })
    }
}

/// The GPU rasterizer (variant `raster`, no parameters).
pub struct Raster {
    scene: Arc<GpuScene>,
    prepared: GpuBuffer<PreparedTriangle>,
}

/// Registers the wgpu `raster` under its CPU twin's catalogue entry (same name, parameters,
/// defaults and documentation).
pub fn register(registry: &mut Registry<Wgpu>) -> Result<()> {
    registry.add_primary(crsh_cpu::primary::raster::info(), |ctx, spec| {
        Ok(Box::new(Raster::new(ctx.scene, spec)?))
    })?;
    Ok(())
}

impl Raster {
    /// Prepares `scene`'s triangles for the resolve (on the host, by the CPU's code).
    pub fn new(scene: &Arc<GpuScene>, spec: &StageSpec) -> Result<Raster> {
        let _ = spec;
        let set: TriangleSet = TriangleSet::new(&scene.scene);
        Ok(Raster {
            scene: Arc::clone(scene),
            prepared: GpuBuffer::from_slice(scene.ctx(), "crsh raster triangles", set.triangles())?,
        })
    }
}

impl PrimaryVisibility<Wgpu> for Raster {
    fn name(&self) -> &str {
        "raster"
    }

    fn gbuffer(
        &self,
        backend: &Wgpu,
        width: u32,
        height: u32,
        _stats: &mut Stats,
    ) -> Result<GpuBuffer<Surface>> {
        let scene = &self.scene.scene;
        if width == 0
            || height == 0
            || width > crsh_core::pipeline::MAX_IMAGE_SIDE
            || height > crsh_core::pipeline::MAX_IMAGE_SIDE
        {
            return Err(CoreError::InvalidInput(format!(
                "image size {width}x{height} is outside 1..={} per side",
                crsh_core::pipeline::MAX_IMAGE_SIDE
            )));
        }
        scene
            .camera
            .validate()
            .map_err(|e| CoreError::InvalidInput(format!("camera: {e}")))?;
        let ctx = backend.context();
        let max_side = ctx.limits().max_texture_dimension_2d;
        if width > max_side || height > max_side {
            return Err(GpuError::TooLarge {
                what: format!("{width}x{height} render target"),
                bytes: u64::from(width) * u64::from(height) * 4,
                limit_name: "max_texture_dimension_2d (pixels per side)",
                limit: u64::from(max_side),
            }
            .into());
        }
        let k = ctx.kernel(RasterKernels::new)?;
        let (r, u, f) = scene.camera.basis();
        let tan_half = (scene.camera.vfov_deg.to_radians() * 0.5).tan();
        let aspect = width as f32 / height as f32;
        let near = NEAR_FRACTION * scene.bounds.diagonal();
        let cam = DrawCamera {
            eye: scene.camera.eye.to_array(),
            near,
            right: r.to_array(),
            sx: 1.0 / (tan_half * aspect),
            up: u.to_array(),
            sy: 1.0 / tan_half,
            forward: f.to_array(),
            pad: 0.0,
        };
        let size = wgpu::Extent3d {
            width,
            height,
            depth_or_array_layers: 1,
        };
        let target = |label, format, usage| {
            ctx.device().create_texture(&wgpu::TextureDescriptor {
                label: Some(label),
                size,
                mip_level_count: 1,
                sample_count: 1,
                dimension: wgpu::TextureDimension::D2,
                format,
                usage,
                view_formats: &[],
            })
        };
        let (ids, depth) = ctx.capture("crsh raster targets", || {
            (
                target(
                    "crsh visibility",
                    wgpu::TextureFormat::R32Uint,
                    wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::COPY_SRC,
                ),
                target(
                    "crsh depth",
                    wgpu::TextureFormat::Depth32Float,
                    wgpu::TextureUsages::RENDER_ATTACHMENT,
                ),
            )
        })?;
        let row_bytes = (u64::from(width) * 4).next_multiple_of(256);
        let id_buffer = create_raw_buffer(
            ctx,
            "crsh visibility ids",
            row_bytes * u64::from(height),
            crate::backend::STAGE_BUFFER_USAGE,
            false,
        )?;
        ctx.check_storage_binding("visibility ids", row_bytes * u64::from(height))?;
        let cam_buf = uniform(ctx, "crsh raster camera", &cam);
        let bind = ctx.device().create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("crsh raster draw"),
            layout: &k.layout,
            entries: &[
                wgpu::BindGroupEntry {
                    binding: 0,
                    resource: cam_buf.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 1,
                    resource: self.scene.triangles.binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 2,
                    resource: self.scene.info.binding(),
                },
            ],
        });
        let n_tris = self.scene.triangle_count() as u32;
        let mut enc = encoder(ctx, "crsh raster");
        {
            let id_view = ids.create_view(&Default::default());
            let depth_view = depth.create_view(&Default::default());
            let mut pass = enc.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("crsh raster"),
                color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                    view: &id_view,
                    depth_slice: None,
                    resolve_target: None,
                    ops: wgpu::Operations {
                        load: wgpu::LoadOp::Clear(wgpu::Color {
                            r: f64::from(crsh_core::NO_HIT),
                            g: 0.0,
                            b: 0.0,
                            a: 0.0,
                        }),
                        store: wgpu::StoreOp::Store,
                    },
                })],
                depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                    view: &depth_view,
                    depth_ops: Some(wgpu::Operations {
                        load: wgpu::LoadOp::Clear(0.0),
                        store: wgpu::StoreOp::Discard,
                    }),
                    stencil_ops: None,
                }),
                timestamp_writes: ctx.render_timestamps(),
                occlusion_query_set: None,
                multiview_mask: None,
            });
            if n_tris > 0 {
                pass.set_pipeline(&k.pipeline);
                pass.set_bind_group(0, &bind, &[]);
                pass.draw(0..n_tris * 3, 0..1);
            }
        }
        enc.copy_texture_to_buffer(
            wgpu::TexelCopyTextureInfo {
                texture: &ids,
                mip_level: 0,
                origin: wgpu::Origin3d::ZERO,
                aspect: wgpu::TextureAspect::All,
            },
            wgpu::TexelCopyBufferInfo {
                buffer: &id_buffer,
                layout: wgpu::TexelCopyBufferLayout {
                    offset: 0,
                    bytes_per_row: Some(row_bytes as u32),
                    rows_per_image: Some(height),
                },
            },
            size,
        );
        let pixels = width as usize * height as usize;
        let out = GpuBuffer::<Surface>::zeroed(ctx, "crsh g-buffer", pixels)?;
        let unused = GpuBuffer::<u32>::zeroed(ctx, "crsh raster unused", 4)?;
        let mut groups = Vec::new();
        for range in chunks::<Surface>(ctx, pixels) {
            let params = ResolveParams {
                width,
                height,
                row_stride: (row_bytes / 4) as u32,
                first: range.start as u32,
                count: range.len() as u32,
                n_tris,
                tan_half,
                aspect,
                right: r.to_array(),
                a: 0.0,
                up: u.to_array(),
                b: 0.0,
                forward: f.to_array(),
                c: 0.0,
                eye: scene.camera.eye.to_array(),
                d: 0.0,
            };
            let pu = uniform(ctx, "crsh raster resolve params", &params);
            let bg = k.resolve.bind_group(
                ctx,
                &[
                    pu.as_entire_binding(),
                    id_buffer.as_entire_binding(),
                    self.prepared.binding(),
                    self.scene.triangles.binding(),
                    self.scene.normals.binding(),
                    self.scene.info.binding(),
                    out.slice_binding(range.clone()),
                    unused.binding(),
                ],
            );
            groups.push((bg, range.len() as u32));
        }
        {
            let mut pass = ctx.compute_pass(&mut enc, "crsh raster resolve");
            for (bg, n) in &groups {
                k.resolve.dispatch(ctx, &mut pass, "resolve", bg, *n)?;
            }
        }
        submit(ctx, "crsh raster", enc)?;
        Ok(out)
    }
}
