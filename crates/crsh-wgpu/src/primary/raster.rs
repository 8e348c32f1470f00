//! `raster` on the wgpu backend: the G-buffer by a real render pass (Reis 2015 §3.1).
//!
//! A render pass draws every triangle (one draw, three vertices per triangle read from the
//! scene's triangle buffer in the vertex shader, degenerate ones collapsed to a point) with
//! the scene camera and writes the triangle id into an `R32Uint` target: a visibility buffer
//! (Burns & Hunt 2013). A compute pass then resolves each pixel exactly as the CPU rasterizer
//! ([`crsh_cpu::primary::raster::Raster`]) does: the pixel-centre camera ray
//! ([`crsh_scene::Camera::direction`]) is intersected with the plane of the visible triangle by
//! the Möller-Trumbore solve on the CPU's prepared triangles, and `surface_from_hit` builds the
//! record (`kernels/surface.wgsl`). Where both backends see the same triangle their records
//! agree to the rounding of WGSL's `sqrt` and division.
//!
//! **Depth is the CPU's, not the hardware's.** The fragment shader solves the same plane hit
//! for its pixel centre and writes `t · 2^-k` as the fragment depth (a power of two with every
//! visible `t · 2^-k < 1/2`, so the scaling is exact), discarding the fragment where the CPU
//! would (no finite plane hit with `t > 0`). The `Less` test then keeps the nearer triangle
//! and, among equal depths, the first drawn, i.e. the lower id: [`crsh_core::Hit::closer_than`],
//! the CPU rasterizer's rule. An interpolated hardware depth would depend on the backend: on
//! OpenGL without clip control, wgpu maps clip z from `[0, 1]` to `[-1, 1]` (`z' = 2z − w`), so
//! a reverse-Z depth near 0 lands near −1, where an `f32` resolves only about 6e-8, and a
//! poster 2 cm in front of a wall 5 m away (a relative depth gap of 4e-3 on a reverse-Z value
//! of about 1e-7) came out behind it. Writing the depth costs the early depth test, a small
//! price next to the traced bounces.
//!
//! Coverage is the hardware's (pixel centres, top-left rule, 8 sub-pixel bits as the CPU
//! rasterizer), with vertices projected in f32 (the CPU projects in f64), so the two differ
//! only for pixel centres within rounding of an edge or at depths equal within rounding.
//! Geometry nearer than `near` = 1e-6 of the scene's bounding-box diagonal is clipped, as on
//! the CPU (clip z = `near`, clip w = the view depth). Image sides above the adapter's
//! `max_texture_dimension_2d` are a [`crate::GpuError::TooLarge`]; the records are written in
//! chunks of one storage binding.

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
const CAMERA_RAY: &str = include_str!("camera_ray.wgsl");

/// Near plane distance as a fraction of the scene's bounding-box diagonal (as the CPU's).
const NEAR_FRACTION: f32 = 1e-6;

/// `View` in `camera_ray.wgsl`: what the pixel-centre camera ray needs.
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct View {
    right: [f32; 3],
    tan_half: f32,
    up: [f32; 3],
    aspect: f32,
    forward: [f32; 3],
    width: u32,
    eye: [f32; 3],
    height: u32,
}

#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct DrawCamera {
    view: View,
    near: f32,
    sx: f32,
    sy: f32,
    depth_scale: f32,
}

#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct ResolveParams {
    view: View,
    row_stride: u32,
    first: u32,
    count: u32,
    n_tris: u32,
}

/// The depth scale of the draw pass: a power of two `2^-k` with `t · 2^-k < 1/2` for every
/// point of `bounds` seen from `eye` (so a fragment's depth `t · 2^-k` is exact, ordered as
/// `t`, and inside the depth range with room for rounding).
fn depth_scale(eye: crsh_core::glam::Vec3, bounds: &crsh_core::Aabb) -> f32 {
    let (lo, hi) = (bounds.min.as_dvec3(), bounds.max.as_dvec3());
    let e = eye.as_dvec3();
    let far = (0..8)
        .map(|i| {
            let c = crsh_core::glam::DVec3::new(
                if i & 1 == 0 { lo.x } else { hi.x },
                if i & 2 == 0 { lo.y } else { hi.y },
                if i & 4 == 0 { lo.z } else { hi.z },
            );
            (c - e).length()
        })
        .filter(|d| d.is_finite())
        .fold(f64::MIN_POSITIVE, f64::max);
    let k = (2.0 * far).log2().ceil().clamp(-120.0, 120.0) as i32;
    2f32.powi(-k)
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
                    format!(
                        "{}\n{}",
                        crate::kernel::COMMON_WGSL,
                        crate::kernels::compose(&[
                            crate::intersect::MT_WGSL,
                            crate::kernels::GLAM_WGSL,
                            CAMERA_RAY,
                            DRAW
                        ])
                    )
                    .into(),
                ),
            });
            let storage = |binding, visibility| wgpu::BindGroupLayoutEntry {
                binding,
                visibility,
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
                        visibility: wgpu::ShaderStages::VERTEX_FRAGMENT,
                        ty: wgpu::BindingType::Buffer {
                            ty: wgpu::BufferBindingType::Uniform,
                            has_dynamic_offset: false,
                            min_binding_size: None,
                        },
                        count: None,
                    },
                    storage(1, wgpu::ShaderStages::VERTEX),
                    storage(2, wgpu::ShaderStages::VERTEX),
                    storage(3, wgpu::ShaderStages::FRAGMENT),
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
                    depth_compare: Some(wgpu::CompareFunction::Less),
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
            CAMERA_RAY,
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
        let view = View {
            right: r.to_array(),
            tan_half,
            up: u.to_array(),
            aspect,
            forward: f.to_array(),
            width,
            eye: scene.camera.eye.to_array(),
            height,
        };
        let cam = DrawCamera {
            view,
            near,
            sx: 1.0 / (tan_half * aspect),
            sy: 1.0 / tan_half,
            depth_scale: depth_scale(scene.camera.eye, &scene.bounds),
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
                wgpu::BindGroupEntry {
                    binding: 3,
                    resource: self.prepared.binding(),
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
                        load: wgpu::LoadOp::Clear(1.0),
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
                view,
                row_stride: (row_bytes / 4) as u32,
                first: range.start as u32,
                count: range.len() as u32,
                n_tris,
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
