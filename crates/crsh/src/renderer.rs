//! The renderer: a scene and a pipeline description in, a frame (image, stats, accuracy) out,
//! on either backend.
//!
//! [`Renderer::render`] does everything a `crsh render` does: resolves the pipeline against the
//! backend's registry, sizes the frame from the scene camera's aspect, builds the stages, renders,
//! and with a reference traces every batch again and compares the image with the reference
//! pipeline's. For repeated frames of one pipeline (benchmarks, ablations) use
//! [`Renderer::build`] once and [`Built::render`] per frame.

use std::sync::Arc;
use std::time::Instant;

use crsh_core::metrics::to_rgba8;
use crsh_core::{
    Backend, CoreError, FrameOptions, FrameSize, Intersector, Pipeline, PipelineConfig, Progress,
    StageBuild, StageContext, StageSpec, Stats,
};
use crsh_cpu::Cpu;
use crsh_scene::Scene;
use crsh_wgpu::{GpuScene, HostIntersector, Wgpu};

use crate::error::Result;
use crate::registries::{BackendKind, Registries};
use crate::report::{
    compare_images, AccuracyReport, AdapterReport, SceneInfo, SetupTimes, StatsReport,
};

/// Renders frames of one scene with pipelines from [`Registries`], on the CPU or on a wgpu
/// device.
pub struct Renderer<'r> {
    registries: &'r Registries,
    scene: Arc<Scene>,
    gpu: Option<Arc<GpuScene>>,
}

/// What to render: the image size, the bounce depth and an optional reference.
///
/// ```
/// let r = crsh::RenderRequest::new().with_width(256).with_reference("brute");
/// assert_eq!((r.width, r.height, r.max_depth), (256, None, 3));
/// ```
#[derive(Clone, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub struct RenderRequest {
    /// Image width in pixels (512 by default).
    pub width: u32,
    /// Image height; `None`: the width divided by the scene camera's framing aspect, or square
    /// when the camera has none.
    pub height: Option<u32>,
    /// Reflection / refraction bounces after the primary hit (3 by default).
    pub max_depth: u32,
    /// An intersector variant of the CPU registry (`brute64`, `brute`, `bvh`, ...) that traces
    /// every batch again, and whose reference pipeline (same primary, ray generation and
    /// shading; every ray against the whole scene) renders the reference image.
    pub reference: Option<String>,
}

impl Default for RenderRequest {
    fn default() -> Self {
        RenderRequest {
            width: 512,
            height: None,
            max_depth: FrameOptions::default().max_depth,
            reference: None,
        }
    }
}

impl RenderRequest {
    /// The defaults: 512 pixels wide, height from the camera, 3 bounces, no reference.
    pub fn new() -> RenderRequest {
        RenderRequest::default()
    }

    /// The same request `width` pixels wide.
    pub fn with_width(self, width: u32) -> RenderRequest {
        RenderRequest { width, ..self }
    }

    /// The same request `height` pixels high.
    pub fn with_height(self, height: u32) -> RenderRequest {
        RenderRequest {
            height: Some(height),
            ..self
        }
    }

    /// The same request with `max_depth` bounces.
    pub fn with_max_depth(self, max_depth: u32) -> RenderRequest {
        RenderRequest { max_depth, ..self }
    }

    /// The same request measured against the reference intersector `name`.
    pub fn with_reference(self, name: &str) -> RenderRequest {
        RenderRequest {
            reference: Some(name.to_string()),
            ..self
        }
    }
}

/// A frame read back to the host.
#[derive(Clone, Debug)]
pub struct HostFrame {
    /// Linear HDR RGBA, row-major, top row first.
    pub image: Vec<[f32; 4]>,
    /// What the frame measured.
    pub stats: Stats,
    /// The triangle each pixel's primary hit is on, when the options asked for it
    /// ([`FrameOptions::primary_triangles`]).
    pub primary_triangles: Option<Vec<u32>>,
}

/// The reference pipeline's frame as accuracy reports compare it ([`Renderer::reference_frame`]).
#[derive(Clone, Debug)]
pub struct ReferenceFrame {
    /// The 8-bit RGBA image.
    pub rgba: Vec<u8>,
    /// The triangle each pixel's primary hit is on ([`crsh_core::NO_HIT`] for the background).
    pub primary_triangles: Vec<u32>,
}

impl ReferenceFrame {
    /// The accuracy report of a frame against this reference: [`compare_images`] on the
    /// images, with the primaries compared when the frame kept them.
    pub fn compare(
        &self,
        reference: &str,
        frame: &HostFrame,
        reference_render_ms: f64,
    ) -> AccuracyReport {
        let counts = frame.stats.accuracy.clone().unwrap_or_default();
        let report = compare_images(
            reference,
            &counts,
            &to_rgba8(&frame.image),
            &self.rgba,
            reference_render_ms,
        );
        match &frame.primary_triangles {
            Some(p) => report.with_primaries(p, &self.primary_triangles),
            None => report,
        }
    }
}

/// What [`Renderer::render`] produced.
#[derive(Clone, Debug)]
pub struct Render {
    /// The pipeline, resolved against the backend's registry.
    pub config: PipelineConfig,
    /// The backend that ran it.
    pub backend: BackendKind,
    /// The wgpu adapter that ran it.
    pub adapter: Option<AdapterReport>,
    /// The image size.
    pub frame: FrameSize,
    /// The bounce depth.
    pub max_depth: u32,
    /// Linear HDR RGBA, row-major, top row first.
    pub image: Vec<[f32; 4]>,
    /// What the frame measured; [`Stats::stages`] names the stages that ran.
    pub stats: Stats,
    /// Wall time of building the stages (e.g. an object BVH), ms.
    pub build_stages_ms: f64,
    /// Bytes of the tables the stages built and report (seed 001's hemisphere sets).
    pub stage_table_bytes: u64,
    /// Agreement with the reference, when one was asked for.
    pub accuracy: Option<AccuracyReport>,
    /// Worker threads of the CPU pool that rendered (and traced the reference).
    pub threads: usize,
}

impl Render {
    /// The image as 8-bit sRGB RGBA.
    pub fn rgba8(&self) -> Vec<u8> {
        to_rgba8(&self.image)
    }

    /// Writes the image to `path` as an 8-bit sRGB PNG.
    pub fn write_png(&self, path: &std::path::Path) -> Result<()> {
        crate::output::write_png(path, self.frame.width, self.frame.height, &self.rgba8())
    }

    /// The stats report (JSON document and summary) of this frame: `scene` loaded from
    /// `source` in `scene_load_ms`, the image written to `output` (empty: none).
    pub fn report(
        &self,
        scene: &Scene,
        source: &str,
        output: &str,
        scene_load_ms: f64,
    ) -> StatsReport {
        StatsReport::new(
            crate::report::RunInfo {
                scene: SceneInfo::of(scene, source),
                config: &self.config,
                backend: self.backend.name(),
                adapter: self.adapter.clone(),
                threads: self.threads,
                width: self.frame.width,
                height: self.frame.height,
                max_depth: self.max_depth,
                output: output.to_string(),
                setup: SetupTimes {
                    build_stages_ms: self.build_stages_ms,
                    stage_table_bytes: self.stage_table_bytes,
                    ..SetupTimes::new(scene_load_ms)
                },
            },
            &self.stats,
            self.accuracy.clone(),
        )
    }
}

/// A pipeline built by a [`Renderer`] for one frame size, ready to render frames. It keeps
/// the scene it was built for (not the renderer), so it may outlive the renderer: the frames
/// of an animation rebuild it for the next frame's scene ([`Renderer::rebuild`]).
pub struct Built<'r> {
    registries: &'r Registries,
    scene: Arc<Scene>,
    gpu: Option<Arc<GpuScene>>,
    inner: BuiltInner,
    build_ms: f64,
}

enum BuiltInner {
    Cpu(Pipeline<Cpu>),
    Wgpu(Pipeline<Wgpu>),
}

impl<'r> Renderer<'r> {
    /// A renderer of `scene` on the CPU.
    pub fn new(registries: &'r Registries, scene: Arc<Scene>) -> Renderer<'r> {
        Renderer {
            registries,
            scene,
            gpu: None,
        }
    }

    /// A renderer of `scene` on the wgpu `device`: the scene is uploaded once, here.
    pub fn on_wgpu(
        registries: &'r Registries,
        scene: Arc<Scene>,
        device: &Wgpu,
    ) -> Result<Renderer<'r>> {
        let gpu = GpuScene::new(device, &scene)?;
        Ok(Renderer {
            registries,
            scene,
            gpu: Some(gpu),
        })
    }

    /// The backend frames run on.
    pub fn backend(&self) -> BackendKind {
        match self.gpu {
            None => BackendKind::Cpu,
            Some(_) => BackendKind::Wgpu,
        }
    }

    /// The scene.
    pub fn scene(&self) -> &Arc<Scene> {
        &self.scene
    }

    /// The registries stages come from.
    pub fn registries(&self) -> &'r Registries {
        self.registries
    }

    /// The adapter of a wgpu renderer.
    pub fn adapter(&self) -> Option<AdapterReport> {
        self.gpu
            .as_ref()
            .map(|g| AdapterReport::of(g.backend.context().info()))
    }

    /// The frame `width` pixels wide, `height` high or else as the scene camera's framing
    /// aspect says (square without one).
    ///
    /// # Errors
    /// [`CoreError::InvalidInput`] when a side is 0 or above
    /// [`crsh_core::MAX_IMAGE_SIDE`], naming the aspect when it made the height too large.
    pub fn frame_size(&self, width: u32, height: Option<u32>) -> Result<FrameSize> {
        let camera = &self.scene.camera;
        let Some(h) = height else {
            let h = camera.height_for_f64(width).unwrap_or(width as f64);
            if !(1.0..=crsh_core::pipeline::MAX_IMAGE_SIDE as f64).contains(&h) {
                return Err(CoreError::InvalidInput(format!(
                    "width {width} with the camera's aspect {} gives a height of {h} pixels, outside 1..={}; give a height",
                    camera.aspect.unwrap_or(1.0),
                    crsh_core::pipeline::MAX_IMAGE_SIDE
                ))
                .into());
            }
            return Ok(FrameSize::new(width, h as u32)?);
        };
        Ok(FrameSize::new(width, h)?)
    }

    fn cpu_context(&self, frame: FrameSize) -> StageContext<'_, Cpu> {
        StageContext::new(&Cpu, &self.scene, frame)
    }

    fn built(&self, inner: BuiltInner, t0: Instant) -> Built<'r> {
        Built {
            registries: self.registries,
            scene: Arc::clone(&self.scene),
            gpu: self.gpu.clone(),
            inner,
            build_ms: t0.elapsed().as_secs_f64() * 1e3,
        }
    }

    /// `previous` (built by a renderer of the same backend for the same triangles, e.g. the
    /// last frame of an animation) rebuilt for this renderer's scene
    /// ([`crsh_core::Registry::rebuild`]: every stage constructed again, except intersectors
    /// that refit; [`Built::builds`] says what each did).
    ///
    /// # Errors
    /// [`CoreError::InvalidInput`] when `previous` ran on the other backend or for another
    /// triangle count; what building a stage returns.
    pub fn rebuild(&self, previous: Built<'_>) -> Result<Built<'r>> {
        if previous.scene.triangle_count() != self.scene.triangle_count() {
            return Err(CoreError::InvalidInput(format!(
                "rebuild: the pipeline was built for {} triangles, the scene has {}",
                previous.scene.triangle_count(),
                self.scene.triangle_count()
            ))
            .into());
        }
        let t0 = Instant::now();
        let inner = match (&previous.inner, &self.gpu) {
            (BuiltInner::Cpu(p), None) => {
                BuiltInner::Cpu(self.registries.cpu.rebuild(&self.cpu_context(p.frame), p)?)
            }
            (BuiltInner::Wgpu(p), Some(g)) => {
                let ctx = StageContext::new(&g.backend, g, p.frame);
                BuiltInner::Wgpu(self.registries.wgpu.rebuild(&ctx, p)?)
            }
            _ => {
                return Err(CoreError::InvalidInput(
                    "rebuild: the pipeline ran on the other backend".into(),
                )
                .into())
            }
        };
        drop(previous);
        Ok(self.built(inner, t0))
    }

    /// Builds `cfg` for `frame` on this renderer's backend: resolved against that backend's
    /// registry ([`Registries::resolve`]: a variant only the other backend has is
    /// [`CoreError::Unsupported`]), then constructed and timed.
    pub fn build(&self, cfg: &PipelineConfig, frame: FrameSize) -> Result<Built<'r>> {
        let cfg = self.registries.resolve(cfg, self.backend())?;
        let t0 = Instant::now();
        let inner = match &self.gpu {
            None => BuiltInner::Cpu(self.registries.cpu.build(&self.cpu_context(frame), &cfg)?),
            Some(g) => {
                let ctx = StageContext::new(&g.backend, g, frame);
                BuiltInner::Wgpu(self.registries.wgpu.build(&ctx, &cfg)?)
            }
        };
        Ok(self.built(inner, t0))
    }

    /// The reference pipeline of `cfg` with the intersector `intersect`
    /// ([`PipelineConfig::reference`]), resolved against the CPU registry: the reference
    /// always runs on the CPU.
    pub fn reference_config(
        &self,
        cfg: &PipelineConfig,
        intersect: &str,
    ) -> Result<PipelineConfig> {
        Ok(self
            .registries
            .resolve(&cfg.reference(intersect), BackendKind::Cpu)?)
    }

    /// The 8-bit image and the primary triangles of the (resolved) reference pipeline
    /// `reference` on the CPU.
    pub fn reference_frame(
        &self,
        reference: &PipelineConfig,
        frame: FrameSize,
        opts: &FrameOptions,
        progress: &mut dyn FnMut(Progress),
    ) -> Result<ReferenceFrame> {
        let f = self.registries.cpu.render(
            &self.cpu_context(frame),
            reference,
            &opts.clone().with_primary_triangles(true),
            None,
            progress,
        )?;
        Ok(ReferenceFrame {
            rgba: to_rgba8(&f.image),
            primary_triangles: f.primary_triangles.unwrap_or_default(),
        })
    }

    /// Renders one frame of `cfg` as `request` says (see the module documentation).
    pub fn render(
        &self,
        cfg: &PipelineConfig,
        request: &RenderRequest,
        progress: &mut dyn FnMut(Progress),
    ) -> Result<Render> {
        let resolved = self.registries.resolve(cfg, self.backend())?;
        let reference = request
            .reference
            .as_deref()
            .map(|r| self.reference_config(&resolved, r))
            .transpose()?;
        let frame = self.frame_size(request.width, request.height)?;
        let opts = FrameOptions::default()
            .with_max_depth(request.max_depth)
            .with_primary_triangles(reference.is_some());
        let built = self.build(&resolved, frame)?;
        let host = built.render(&opts, reference.as_ref().map(|r| &r.intersect), progress)?;
        let accuracy = match &reference {
            None => None,
            Some(ref_cfg) => {
                let t0 = Instant::now();
                let want = self.reference_frame(ref_cfg, frame, &opts, &mut |p| {
                    progress(Progress {
                        message: format!("reference: {}", p.message),
                        ..p
                    })
                })?;
                Some(want.compare(
                    &ref_cfg.intersect.kind,
                    &host,
                    t0.elapsed().as_secs_f64() * 1e3,
                ))
            }
        };
        Ok(Render {
            config: built.config().clone(),
            backend: self.backend(),
            adapter: self.adapter(),
            frame,
            max_depth: request.max_depth,
            image: host.image,
            stats: host.stats,
            build_stages_ms: built.build_ms(),
            stage_table_bytes: built.builds().iter().map(|b| b.bytes).sum(),
            accuracy,
            threads: rayon::current_num_threads(),
        })
    }
}

impl Built<'_> {
    /// The resolved pipeline description the stages were built from.
    pub fn config(&self) -> &PipelineConfig {
        match &self.inner {
            BuiltInner::Cpu(p) => &p.config,
            BuiltInner::Wgpu(p) => &p.config,
        }
    }

    /// The frame size the stages were built for.
    pub fn frame(&self) -> FrameSize {
        match &self.inner {
            BuiltInner::Cpu(p) => p.frame,
            BuiltInner::Wgpu(p) => p.frame,
        }
    }

    /// Wall time of building the stages, ms.
    pub fn build_ms(&self) -> f64 {
        self.build_ms
    }

    /// What building each stage did and took ([`crsh_core::Pipeline::builds`]).
    pub fn builds(&self) -> &[StageBuild] {
        match &self.inner {
            BuiltInner::Cpu(p) => &p.builds,
            BuiltInner::Wgpu(p) => &p.builds,
        }
    }

    /// Renders one frame and reads it back. With `reference` (an intersector spec of the CPU
    /// registry), every batch is traced again by it on the host and
    /// [`Stats::accuracy`] is filled.
    pub fn render(
        &self,
        opts: &FrameOptions,
        reference: Option<&StageSpec>,
        progress: &mut dyn FnMut(Progress),
    ) -> Result<HostFrame> {
        let cpu_reference = |frame: FrameSize| -> Result<Option<Box<dyn Intersector<Cpu>>>> {
            Ok(reference
                .map(|spec| {
                    self.registries
                        .cpu
                        .build_intersector(&StageContext::new(&Cpu, &self.scene, frame), spec)
                })
                .transpose()?)
        };
        match &self.inner {
            BuiltInner::Cpu(p) => {
                let reference = cpu_reference(p.frame)?;
                let f = p.render(&Cpu, opts, reference.as_deref(), progress)?;
                Ok(HostFrame {
                    image: f.image,
                    stats: f.stats,
                    primary_triangles: f.primary_triangles,
                })
            }
            BuiltInner::Wgpu(p) => {
                let g = self
                    .gpu
                    .as_ref()
                    .expect("a wgpu pipeline is built by a wgpu renderer");
                let reference = cpu_reference(p.frame)?.map(HostIntersector::new);
                let f = p.render(
                    &g.backend,
                    opts,
                    reference.as_ref().map(|h| h as &dyn Intersector<Wgpu>),
                    progress,
                )?;
                let image = g.backend.download(&f.image)?;
                Ok(HostFrame {
                    image,
                    stats: f.stats,
                    primary_triangles: f.primary_triangles,
                })
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scene(name: &str) -> Arc<Scene> {
        Arc::new(crsh_scene::builtin::build(name).unwrap())
    }

    #[test]
    fn renders_fill_the_brute_force_figures_and_name_the_stages() {
        let registries = Registries::builtin();
        let s = scene("office-boxes");
        let renderer = Renderer::new(&registries, Arc::clone(&s));
        let cfg = registries.preset("crsh").unwrap();
        let req = RenderRequest::new()
            .with_width(24)
            .with_height(16)
            .with_max_depth(1)
            .with_reference("brute");
        let r = renderer.render(&cfg, &req, &mut |_| {}).unwrap();
        assert_eq!(r.image.len(), 24 * 16);
        assert_eq!(
            r.stats.tests.brute_force,
            r.stats.traced_rays * s.triangle_count() as u64
        );
        assert!(r.stats.tests.brute_force > 0);
        assert_eq!(r.stats.stages["hash"], "thesis");
        assert_eq!(r.stats.stages["traverse"], "crsh");
        let acc = r.accuracy.as_ref().unwrap();
        assert_eq!(acc.hit_agreement, 1.0);
        assert!(acc.images_identical);
        assert_eq!(
            (acc.primary_agreement, acc.primary_pixels),
            (Some(1.0), 24 * 16)
        );
        let report = r.report(&s, "office-boxes", "", 0.0);
        assert_eq!(report.stages, r.stats.stages);
        assert!(report.summary().contains("hash=thesis"));
        assert!(report
            .summary()
            .contains("primary agreement 1.000000 over 384 pixels (0 see another triangle)"));
        // The same build renders again, equal counters; the primary triangles only when
        // asked for, and then the CPU rasterizer's.
        let built = renderer.build(&r.config, r.frame).unwrap();
        let opts = FrameOptions::default().with_max_depth(1);
        let again = built.render(&opts, None, &mut |_| {}).unwrap();
        assert_eq!(again.stats.tests, r.stats.tests);
        assert!(again.primary_triangles.is_none());
        let kept = built
            .render(&opts.with_primary_triangles(true), None, &mut |_| {})
            .unwrap();
        let raster =
            crsh_cpu::primary::raster::Raster::new(&s, &crsh_core::StageSpec::new("raster"))
                .unwrap();
        let want: Vec<u32> = raster
            .visibility(24, 16)
            .unwrap()
            .iter()
            .map(|h| h.tri)
            .collect();
        assert_eq!(kept.primary_triangles, Some(want));
        assert_eq!(kept.stats.tests, r.stats.tests);
    }

    #[test]
    fn the_height_follows_the_camera_and_absurd_sizes_are_errors() {
        let registries = Registries::builtin();
        let mut s = crsh_scene::builtin::build("cornell-mirrors").unwrap();
        s.camera.aspect = Some(2.0);
        let renderer = Renderer::new(&registries, Arc::new(s));
        assert_eq!(
            renderer.frame_size(64, None).unwrap(),
            FrameSize::new(64, 32).unwrap()
        );
        assert_eq!(
            renderer.frame_size(64, Some(5)).unwrap(),
            FrameSize::new(64, 5).unwrap()
        );
        assert!(renderer.frame_size(0, None).is_err());
        assert!(renderer.frame_size(64, Some(100_000)).is_err());
        let mut tall = crsh_scene::builtin::build("cornell-mirrors").unwrap();
        tall.camera.aspect = Some(0.5);
        let tall = Renderer::new(&registries, Arc::new(tall));
        let e = tall.frame_size(16384, None).unwrap_err();
        assert!(e.to_string().contains("aspect"), "{e}");
    }
}
