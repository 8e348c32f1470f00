//! Frames of an animated scene: what a frame costs when the geometry moves.
//!
//! [`render_frames`] renders frames `0..n` of a [`crsh_scene::AnimatedScene`] with one pipeline.
//! Every frame it
//!
//! 1. brings the scene to the frame in place ([`crsh_scene::AnimatedScene::update`]): the
//!    moving instances' vertices and normals (`scene_ms`) and, for pipelines with a ray-space
//!    hierarchy (the only stages that read them), their triangles' and meshes' bounding spheres
//!    (`spheres_ms`), seed 000's whole per-frame price for moving geometry (§3.2.2, §3.3);
//! 2. on wgpu, uploads the scene (`upload_ms`, seed 002 table 6's "upload");
//! 3. rebuilds the pipeline for it ([`crsh_core::Registry::rebuild`]): every stage is built
//!    again for the moved scene, and an intersector whose structure can be refitted (`bvh`
//!    with `update = "refit"`) refits it; each stage's time is in `stages`, the acceleration
//!    structures' (the traverser's and the intersector's build or refit, plus the spheres) in
//!    `structure_ms`;
//! 4. renders it, with the reference on the frames `reference_every` samples.
//!
//! The frame time the comparison is about is `frame_ms = update.total_ms + render_ms`: update
//! and rebuild, then trace and shade.
//!
//! Two scene buffers alternate, so the scene of the frame being built is never the one the
//! previous frame's pipeline still holds, and nothing is copied per frame.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::sync::Arc;
use std::time::Instant;

use crsh_core::{FrameOptions, PipelineConfig, Progress, StageBuild, StageKind};
use crsh_scene::{AnimatedScene, Scene};
use crsh_wgpu::Wgpu;
use serde::{Deserialize, Serialize};

use crate::error::Result;
use crate::registries::{BackendKind, Registries};
use crate::renderer::{Render, RenderRequest, Renderer};
use crate::report::{
    group, AdapterReport, RunInfo, SceneInfo, SetupTimes, StatsReport, TestsReport,
};

/// What one frame spent before tracing: the scene update and the pipeline rebuild.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct UpdateReport {
    /// Moving the instances' vertices and normals, their boxes and the scene bounds, ms.
    pub scene_ms: f64,
    /// Their triangle and mesh bounding spheres, ms (pipelines with a ray-space hierarchy
    /// only; 0 for the others, which never read them).
    pub spheres_ms: f64,
    /// Uploading the scene to the device, ms (wgpu only).
    pub upload_ms: f64,
    /// Each stage's build or refit, in construction order.
    pub stages: Vec<StageBuild>,
    /// What the acceleration structures' update was: the spheres when they were updated, the
    /// traverser's build or refit (a `dual` traverser's object hierarchy) and the
    /// intersector's: `bvh rebuild`, `bvh refit`, `grid rebuild`,
    /// `spheres + crsh rebuild + brute rebuild`, `spheres + dual refit + brute rebuild` ...
    pub structure: String,
    /// Its time: the traverser's and the intersector's build or refit, plus the spheres when
    /// they were updated, ms.
    pub structure_ms: f64,
    /// Everything before tracing: scene, spheres, upload and every stage, ms.
    pub total_ms: f64,
    /// Triangles moved this frame.
    pub moved_triangles: u64,
}

/// One rendered frame.
#[derive(Clone, Debug)]
pub struct FrameRender {
    /// Frame number.
    pub frame: u32,
    /// Scene time, seconds.
    pub time_s: f32,
    /// The scene at this frame.
    pub scene: Arc<Scene>,
    /// The render (image, stats, accuracy on sampled frames).
    pub render: Render,
    /// The update and rebuild before it.
    pub update: UpdateReport,
}

impl FrameRender {
    /// Trace time: the tracing stages of every ray kind (hash to final tests), ms.
    pub fn trace_ms(&self) -> f64 {
        self.render
            .stats
            .per_kind
            .values()
            .map(|k| k.trace_ms)
            .sum()
    }

    /// The frame's render time (primary visibility to shading), ms.
    pub fn render_ms(&self) -> f64 {
        self.render.stats.time_ms("total")
    }

    /// Update, rebuild and render, ms.
    pub fn frame_ms(&self) -> f64 {
        self.update.total_ms + self.render_ms()
    }
}

/// What [`render_frames`] renders.
#[derive(Clone, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub struct FramesRequest {
    /// Each frame's request (size, bounces, reference).
    pub render: RenderRequest,
    /// Frames `0..frames`.
    pub frames: u32,
    /// With a reference, check every `reference_every`-th frame (frame 0 included; 1: all).
    pub reference_every: u32,
}

/// Most frames of one request.
pub const MAX_FRAMES: u32 = 100_000;

impl FramesRequest {
    /// Frames `0..frames` as `render` says, every one checked against its reference.
    pub fn new(render: RenderRequest, frames: u32) -> FramesRequest {
        FramesRequest {
            render,
            frames,
            reference_every: 1,
        }
    }

    /// The same request checking every `every`-th frame against the reference.
    pub fn with_reference_every(self, every: u32) -> FramesRequest {
        FramesRequest {
            reference_every: every,
            ..self
        }
    }
}

/// Renders frames `0..request.frames` of `anim` with `cfg` on the CPU (`device: None`) or on
/// `device`, handing each to `on_frame` as it is done (see the module documentation).
///
/// # Errors
/// What resolving, building or rendering returns; [`crsh_core::CoreError::InvalidInput`] for
/// 0 frames or more than [`MAX_FRAMES`], or `reference_every` 0; the first error of
/// `on_frame`.
pub fn render_frames(
    registries: &Registries,
    anim: &AnimatedScene,
    device: Option<&Wgpu>,
    cfg: &PipelineConfig,
    request: &FramesRequest,
    progress: &mut dyn FnMut(u32, Progress),
    on_frame: &mut dyn FnMut(FrameRender) -> Result<()>,
) -> Result<()> {
    let invalid = |m: String| crate::Error::from(crsh_core::CoreError::InvalidInput(m));
    if request.frames == 0 || request.frames > MAX_FRAMES {
        return Err(invalid(format!(
            "{} frames: ask for 1..={MAX_FRAMES}",
            request.frames
        )));
    }
    if request.reference_every == 0 {
        return Err(invalid("reference_every must be at least 1".into()));
    }
    let backend = match device {
        None => BackendKind::Cpu,
        Some(_) => BackendKind::Wgpu,
    };
    let resolved = registries.resolve(cfg, backend)?;
    let spheres = resolved.traverse.is_some();
    let mut scenes = [
        Arc::new(anim.scene().clone()),
        Arc::new(anim.scene().clone()),
    ];
    let mut previous = None;
    let opts = FrameOptions::default().with_max_depth(request.render.max_depth);
    for f in 0..request.frames {
        let slot = &mut scenes[(f % 2) as usize];
        let scene = match Arc::get_mut(slot) {
            Some(s) => s,
            // Someone (an `on_frame` keeping `FrameRender::scene`) holds it: copy.
            None => Arc::make_mut(slot),
        };
        let times = anim.update(scene, f, spheres)?;
        let scene = Arc::clone(slot);
        let t_upload = Instant::now();
        let renderer = match device {
            None => Renderer::new(registries, Arc::clone(&scene)),
            Some(d) => Renderer::on_wgpu(registries, Arc::clone(&scene), d)?,
        };
        let upload_ms = match device {
            None => 0.0,
            Some(_) => t_upload.elapsed().as_secs_f64() * 1e3,
        };
        let frame = renderer.frame_size(request.render.width, request.render.height)?;
        let built = match previous.take() {
            None => renderer.build(&resolved, frame)?,
            Some(p) => renderer.rebuild(p)?,
        };
        let checked = request.render.reference.is_some() && f % request.reference_every == 0;
        let reference = match &request.render.reference {
            Some(r) if checked => Some(renderer.reference_config(&resolved, r)?),
            _ => None,
        };
        let mut frame_progress = |p: Progress| progress(f, p);
        let host = built.render(
            &opts.clone().with_primary_triangles(reference.is_some()),
            reference.as_ref().map(|r| &r.intersect),
            &mut frame_progress,
        )?;
        let accuracy = match &reference {
            None => None,
            Some(ref_cfg) => {
                let t0 = Instant::now();
                let want = renderer.reference_frame(ref_cfg, frame, &opts, &mut frame_progress)?;
                Some(want.compare(
                    &ref_cfg.intersect.kind,
                    &host,
                    t0.elapsed().as_secs_f64() * 1e3,
                ))
            }
        };
        let update = update_report(times, spheres, upload_ms, built.builds());
        let render = Render {
            config: built.config().clone(),
            backend,
            adapter: renderer.adapter(),
            frame,
            max_depth: request.render.max_depth,
            image: host.image,
            stats: host.stats,
            build_stages_ms: built.build_ms(),
            stage_table_bytes: built.builds().iter().map(|b| b.bytes).sum(),
            accuracy,
            threads: rayon::current_num_threads(),
        };
        previous = Some(built);
        drop(renderer);
        on_frame(FrameRender {
            frame: f,
            time_s: anim.time_of(f),
            scene,
            render,
            update,
        })?;
    }
    Ok(())
}

fn update_report(
    times: crsh_scene::UpdateTimes,
    spheres: bool,
    upload_ms: f64,
    builds: &[StageBuild],
) -> UpdateReport {
    // The acceleration structures: a traverser's (an object hierarchy) and the intersector's.
    let structures: Vec<&StageBuild> = [StageKind::Traverse, StageKind::Intersect]
        .iter()
        .filter_map(|k| builds.iter().find(|b| b.slot == k.key()))
        .collect();
    let mut names: Vec<String> = structures
        .iter()
        .map(|b| {
            format!(
                "{} {}",
                b.variant,
                if b.refit { "refit" } else { "rebuild" }
            )
        })
        .collect();
    if names.is_empty() {
        names.push("none".to_string());
    }
    if spheres {
        names.insert(0, "spheres".to_string());
    }
    let structure = names.join(" + ");
    let ms: f64 = structures.iter().map(|b| b.ms).sum();
    let stages_ms: f64 = builds.iter().map(|b| b.ms).sum();
    UpdateReport {
        scene_ms: times.geometry_ms,
        spheres_ms: times.spheres_ms,
        upload_ms,
        stages: builds.to_vec(),
        structure,
        structure_ms: ms + times.spheres_ms,
        total_ms: times.geometry_ms + times.spheres_ms + upload_ms + stages_ms,
        moved_triangles: times.triangles,
    }
}

/// One frame's row of a [`FramesReport`].
#[derive(Clone, Debug, Serialize)]
pub struct FrameRow {
    /// Frame number.
    pub frame: u32,
    /// Scene time, seconds.
    pub time_s: f32,
    /// The update and rebuild.
    pub update: UpdateReport,
    /// Tracing (hash to final tests, every kind), ms.
    pub trace_ms: f64,
    /// Shading, ms.
    pub shade_ms: f64,
    /// The whole render (primary to shading), ms.
    pub render_ms: f64,
    /// `update.total_ms + render_ms`.
    pub frame_ms: f64,
    /// Rays traced.
    pub traced_rays: u64,
    /// Bounds and ray-triangle tests per traced ray (`None` when not counted).
    pub tests_per_ray: Option<f64>,
    /// The frame's full report (its `output` is the frame's PNG).
    pub report: StatsReport,
}

/// Sums over the frames of a [`FramesReport`].
#[derive(Clone, Debug, Default, Serialize)]
pub struct FrameTotals {
    /// Frames rendered.
    pub frames: u32,
    /// Σ update (scene, spheres, upload, stage builds), ms.
    pub update_ms: f64,
    /// Σ acceleration-structure update (intersector build or refit, spheres), ms.
    pub structure_ms: f64,
    /// Σ trace, ms.
    pub trace_ms: f64,
    /// Σ shade, ms.
    pub shade_ms: f64,
    /// Σ render, ms.
    pub render_ms: f64,
    /// Σ frame (update + render), ms.
    pub frame_ms: f64,
    /// Mean frame time, ms.
    pub mean_frame_ms: f64,
    /// Σ rays traced.
    pub traced_rays: u64,
    /// Σ tests.
    pub tests: TestsReport,
    /// Frames checked against the reference.
    pub frames_checked: u32,
    /// Lowest hit agreement over the checked frames.
    pub min_hit_agreement: Option<f64>,
}

/// The stats JSON of `crsh render --frames N`: the run, one row per frame, the totals.
#[derive(Clone, Debug, Serialize)]
pub struct FramesReport {
    /// crsh version.
    pub version: &'static str,
    /// The scene (at frame 0).
    pub scene: SceneInfo,
    /// Frames per second of scene time.
    pub fps: f32,
    /// Triangles that move.
    pub moving_triangles: u64,
    /// Pipeline name.
    pub pipeline: String,
    /// The resolved pipeline.
    pub config: PipelineConfig,
    /// The stage variants that ran.
    pub stages: BTreeMap<String, String>,
    /// Backend.
    pub backend: String,
    /// The wgpu adapter.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub adapter: Option<AdapterReport>,
    /// Worker threads.
    pub threads: usize,
    /// Image size and bounces.
    pub width: u32,
    /// Image height.
    pub height: u32,
    /// Bounce limit.
    pub max_depth: u32,
    /// Per-frame rows.
    pub frames: Vec<FrameRow>,
    /// Sums.
    pub totals: FrameTotals,
    /// How the program set up its memory allocator (as [`crate::report::StatsReport`]'s).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub allocator: Option<String>,
}

impl FramesReport {
    /// An empty report of `config` rendering `anim` loaded from `source`.
    pub fn new(anim: &AnimatedScene, source: &str, config: &PipelineConfig) -> FramesReport {
        FramesReport {
            version: env!("CARGO_PKG_VERSION"),
            scene: SceneInfo::of(anim.scene(), source),
            fps: anim.fps(),
            moving_triangles: anim.moving_triangles() as u64,
            pipeline: config.name.clone(),
            config: config.clone(),
            stages: BTreeMap::new(),
            backend: String::new(),
            adapter: None,
            threads: 0,
            width: 0,
            height: 0,
            max_depth: 0,
            frames: Vec::new(),
            totals: FrameTotals::default(),
            allocator: None,
        }
    }

    /// Adds frame `f`, written to `output` (empty: none), with `setup` times.
    pub fn push(&mut self, f: &FrameRender, output: &str, setup: SetupTimes) {
        let r = &f.render;
        let report = StatsReport::new(
            RunInfo {
                scene: SceneInfo::of(&f.scene, &self.scene.source),
                config: &r.config,
                backend: r.backend.name(),
                adapter: r.adapter.clone(),
                threads: r.threads,
                width: r.frame.width,
                height: r.frame.height,
                max_depth: r.max_depth,
                output: output.to_string(),
                setup,
            },
            &r.stats,
            r.accuracy.clone(),
        );
        if self.frames.is_empty() {
            self.pipeline = r.config.name.clone();
            self.config = r.config.clone();
            self.stages = r.stats.stages.clone();
            self.backend = r.backend.name().to_string();
            self.adapter = r.adapter.clone();
            self.threads = r.threads;
            self.width = r.frame.width;
            self.height = r.frame.height;
            self.max_depth = r.max_depth;
        }
        let row = FrameRow {
            frame: f.frame,
            time_s: f.time_s,
            update: f.update.clone(),
            trace_ms: f.trace_ms(),
            shade_ms: r.stats.time_ms("shading"),
            render_ms: f.render_ms(),
            frame_ms: f.frame_ms(),
            traced_rays: r.stats.traced_rays,
            tests_per_ray: report.tests.per_traced_ray,
            report,
        };
        let t = &mut self.totals;
        t.frames += 1;
        t.update_ms += row.update.total_ms;
        t.structure_ms += row.update.structure_ms;
        t.trace_ms += row.trace_ms;
        t.shade_ms += row.shade_ms;
        t.render_ms += row.render_ms;
        t.frame_ms += row.frame_ms;
        t.mean_frame_ms = t.frame_ms / t.frames as f64;
        t.traced_rays += row.traced_rays;
        let mut sum = t.tests.counts();
        sum.add(&r.stats.tests);
        t.tests = TestsReport::new(&sum, t.traced_rays);
        if let Some(a) = &r.accuracy {
            t.frames_checked += 1;
            t.min_hit_agreement = Some(
                t.min_hit_agreement
                    .map_or(a.hit_agreement, |m| m.min(a.hit_agreement)),
            );
        }
        self.frames.push(row);
    }

    /// The JSON text (pretty-printed).
    pub fn to_json(&self) -> String {
        serde_json::to_string_pretty(self).unwrap_or_else(|e| format!("{{\"error\": \"{e}\"}}"))
    }

    /// The summary printed by `crsh render --frames`: one line per frame and the totals.
    pub fn summary(&self) -> String {
        let mut s = String::new();
        let sc = &self.scene;
        let _ = writeln!(
            s,
            "scene     {} ({}): {} triangles, {} moving, {} fps",
            sc.name,
            sc.source,
            group(sc.triangles),
            group(self.moving_triangles),
            self.fps
        );
        let _ = writeln!(
            s,
            "pipeline  {} on {} ({} threads), {}x{}, depth {}: {}",
            self.pipeline,
            self.backend,
            self.threads,
            self.width,
            self.height,
            self.max_depth,
            crate::report::names_line(&self.stages)
        );
        let _ = writeln!(
            s,
            "frame  scene ms  spheres ms  structure                 struct ms  update ms  trace ms  render ms  frame ms  tests/ray  agreement"
        );
        for r in &self.frames {
            let agreement = r
                .report
                .accuracy
                .as_ref()
                .map(|a| format!("{:.6}", a.hit_agreement))
                .unwrap_or_else(|| "-".into());
            let _ = writeln!(
                s,
                "{:>5}  {:>8.2}  {:>10.2}  {:<24}  {:>9.2}  {:>9.2}  {:>8.2}  {:>9.2}  {:>8.2}  {:>9}  {}",
                r.frame,
                r.update.scene_ms,
                r.update.spheres_ms,
                r.update.structure,
                r.update.structure_ms,
                r.update.total_ms,
                r.trace_ms,
                r.render_ms,
                r.frame_ms,
                tests_cell(r.tests_per_ray),
                agreement
            );
        }
        let t = &self.totals;
        let _ = writeln!(
            s,
            "total  {} frames: update {:.1} ms (structure {:.1}) | trace {:.1} | render {:.1} | frame {:.1} ms, mean {:.2} ms/frame | {} tests per traced ray{}",
            t.frames,
            t.update_ms,
            t.structure_ms,
            t.trace_ms,
            t.render_ms,
            t.frame_ms,
            t.mean_frame_ms,
            tests_cell(t.tests.per_traced_ray),
            match t.min_hit_agreement {
                Some(a) => format!(
                    " | hit agreement ≥ {a:.6} on {} checked frames",
                    t.frames_checked
                ),
                None => String::new(),
            }
        );
        s
    }
}

/// Tests per ray with one decimal, or "—" when they were not counted.
fn tests_cell(v: Option<f64>) -> String {
    v.map_or_else(|| "—".to_string(), |v| format!("{v:.1}"))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frames(preset: &str, sets: &[&str], n: u32) -> Vec<FrameRender> {
        let registries = Registries::builtin();
        let (anim, _) = crsh_scene::load_animated("cornell-mirrors-animated").unwrap();
        let mut cfg = registries.preset(preset).unwrap();
        for s in sets {
            cfg.set(s).unwrap();
        }
        let request = FramesRequest::new(
            RenderRequest::new()
                .with_width(24)
                .with_height(24)
                .with_max_depth(1)
                .with_reference("brute"),
            n,
        );
        let mut out = Vec::new();
        render_frames(
            &registries,
            &anim,
            None,
            &cfg,
            &request,
            &mut |_, _| {},
            &mut |f| {
                out.push(f);
                Ok(())
            },
        )
        .unwrap();
        out
    }

    #[test]
    fn every_pipeline_agrees_with_brute_force_on_every_frame() {
        for (preset, sets) in [
            ("bvh", &[][..]),
            ("bvh", &["intersect.update=refit"][..]),
            ("bvh", &["intersect.kind=grid"][..]),
            ("crsh", &[][..]),
            ("rah", &[][..]),
            ("dual_inline", &["traverse.update=refit"][..]),
            ("dual_screen_bvh", &["traverse.update=refit"][..]),
        ] {
            let fs = frames(preset, sets, 4);
            assert_eq!(fs.len(), 4);
            for f in &fs {
                let a = f.render.accuracy.as_ref().unwrap();
                assert_eq!(a.hit_agreement, 1.0, "{preset} {sets:?} frame {}", f.frame);
                assert!(a.rays_compared > 0);
                assert!(f.update.moved_triangles > 0);
                assert!(f.frame_ms() >= f.update.total_ms);
                let intersect = f
                    .update
                    .stages
                    .iter()
                    .find(|b| b.slot == "intersect")
                    .unwrap();
                let refit = sets.contains(&"intersect.update=refit") && f.frame > 0;
                assert_eq!(
                    intersect.refit, refit,
                    "{preset} {sets:?} frame {}",
                    f.frame
                );
                let traverse = f.update.stages.iter().find(|b| b.slot == "traverse");
                let refit = sets.contains(&"traverse.update=refit") && f.frame > 0;
                assert_eq!(
                    traverse.map(|b| b.refit),
                    traverse.map(|_| refit),
                    "{preset} {sets:?} frame {}",
                    f.frame
                );
                if refit {
                    assert!(
                        f.update.structure.contains("dual refit"),
                        "{}",
                        f.update.structure
                    );
                }
                // Only the ray-space hierarchies pay for the spheres.
                let hierarchy = f.render.stats.stages.contains_key("traverse");
                assert_eq!(f.update.structure.starts_with("spheres"), hierarchy);
                assert_eq!(f.update.spheres_ms > 0.0, hierarchy, "{preset}");
            }
            assert_ne!(
                fs[0].render.image, fs[3].render.image,
                "{preset}: nothing moved"
            );
        }
    }

    #[test]
    fn the_report_has_a_row_per_frame_and_their_totals() {
        let fs = frames("crsh", &[], 3);
        let (anim, _) = crsh_scene::load_animated("cornell-mirrors-animated").unwrap();
        let mut report = FramesReport::new(&anim, "cornell-mirrors-animated", &fs[0].render.config);
        for f in &fs {
            report.push(f, "", SetupTimes::default());
        }
        let t = &report.totals;
        assert_eq!((t.frames, t.frames_checked), (3, 3));
        assert_eq!(t.min_hit_agreement, Some(1.0));
        let sum: u64 = fs.iter().map(|f| f.render.stats.traced_rays).sum();
        assert_eq!(t.traced_rays, sum);
        assert!((t.frame_ms - fs.iter().map(FrameRender::frame_ms).sum::<f64>()).abs() < 1e-9);
        let json: serde_json::Value = serde_json::from_str(&report.to_json()).unwrap();
        assert_eq!(json["frames"].as_array().unwrap().len(), 3);
        assert!(
            json["frames"][1]["update"]["structure_ms"]
                .as_f64()
                .unwrap()
                > 0.0
        );
        assert_eq!(json["frames"][2]["report"]["stages"]["traverse"], "crsh");
        let summary = report.summary();
        assert!(
            summary.contains("spheres + crsh rebuild + brute rebuild"),
            "{summary}"
        );
        assert_eq!(summary.lines().count(), 3 + 3 + 1);
    }

    #[test]
    fn bad_requests_are_errors() {
        let registries = Registries::builtin();
        let (anim, _) = crsh_scene::load_animated("cornell-mirrors-animated").unwrap();
        let cfg = registries.preset("bvh").unwrap();
        for req in [
            FramesRequest::new(RenderRequest::new(), 0),
            FramesRequest::new(RenderRequest::new(), 2).with_reference_every(0),
        ] {
            let e = render_frames(
                &registries,
                &anim,
                None,
                &cfg,
                &req,
                &mut |_, _| {},
                &mut |_| Ok(()),
            );
            assert!(e.is_err());
        }
    }
}
