//! Running the cells: each scene loads once; each cell builds its stages, runs the warm-up and
//! the timed repeats, checks its counters are equal across repeats, then runs once more with
//! the reference intersector and compares its image with the reference pipeline's image
//! (rendered once per scene, size, depth and primary / raygen / shade configuration).
//!
//! `wgpu` cells run the same pipeline configuration on the wgpu backend (one device per run,
//! the scene uploaded once per scene); their reference intersector runs on the host, so
//! agreement is measured against the CPU's answer, and their image is compared with the CPU
//! reference pipeline's image.
//!
//! A cell that fails (scene missing, stage construction or render error, no wgpu adapter, a
//! panic) is recorded with its reason and the run goes on.

use std::collections::{BTreeMap, HashMap};
use std::io::IsTerminal;
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::sync::Arc;
use std::time::{Duration, Instant};

use crsh_core::metrics::to_rgba8;
use crsh_core::{render_frame, Backend, FrameOptions, Intersector, KindStats, Stages, Stats};
use crsh_cpu::Cpu;
use crsh_scene::Scene;
use crsh_wgpu::{GpuScene, HostIntersector, Wgpu};
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};

use super::plan::{Cell, Plan};
use super::results::{CellAccuracy, CellRays, CellResult, CellTests, Measures, TimeSummary};
use crate::report::mrays_per_s;

/// A loaded scene (or why it did not load).
type LoadedScene = Result<Arc<Scene>, String>;

/// The wgpu device of a run (opened by the first wgpu cell, or why it could not be) and the
/// current scene on it.
#[derive(Default)]
struct GpuState {
    device: Option<Result<Wgpu, String>>,
    scene: Option<(String, Arc<GpuScene>)>,
}

impl GpuState {
    /// The scene `spec` on the device, uploading it on first use.
    fn scene(&mut self, spec: &str, scene: &Arc<Scene>) -> Result<Arc<GpuScene>, String> {
        let device = self
            .device
            .get_or_insert_with(|| {
                Wgpu::new().map_err(|e| format!("backend wgpu: cannot open a device: {e}"))
            })
            .clone()?;
        match &self.scene {
            Some((s, g)) if s == spec => Ok(Arc::clone(g)),
            _ => {
                self.scene = None;
                let g = GpuScene::new(&device, scene)
                    .map_err(|e| format!("uploading the scene to the device: {e}"))?;
                self.scene = Some((spec.to_string(), Arc::clone(&g)));
                Ok(g)
            }
        }
    }
}

/// Runs every cell in order. `on_done` receives each result as it completes (for the
/// per-cell summary line); `quiet` hides the progress bar.
pub fn run_cells(
    plan: &Plan,
    cells: &[Cell],
    quiet: bool,
    on_done: &mut dyn FnMut(&CellResult, &ProgressBar),
) -> Vec<CellResult> {
    let bar = progress_bar(cells.len() as u64, quiet);
    let threads = plan.threads.unwrap_or_else(rayon::current_num_threads);
    let mut scenes: HashMap<String, LoadedScene> = HashMap::new();
    let mut ref_images: HashMap<String, Result<Arc<Vec<u8>>, String>> = HashMap::new();
    let mut gpu = GpuState::default();
    let mut out = Vec::with_capacity(cells.len());
    for (i, cell) in cells.iter().enumerate() {
        bar.set_message(format!("{} | {}", cell.scene_spec, cell.label()));
        // Free the previous scene (and its reference images) once its cells are done.
        if i > 0 && cells[i - 1].scene_spec != cell.scene_spec {
            scenes.clear();
            ref_images.clear();
            gpu.scene = None;
        }
        let scene = scenes
            .entry(cell.scene_spec.clone())
            .or_insert_with(|| load_scene(cell))
            .clone();
        let result = match plan.threads {
            Some(n) => crsh_cpu::with_threads(n, || {
                run_cell(plan, cell, &scene, threads, &mut ref_images, &mut gpu)
            })
            .unwrap_or_else(|e| failed(cell, &scene, threads, plan, e.to_string())),
            None => run_cell(plan, cell, &scene, threads, &mut ref_images, &mut gpu),
        };
        on_done(&result, &bar);
        out.push(result);
        bar.inc(1);
    }
    bar.finish_and_clear();
    out
}

fn load_scene(cell: &Cell) -> LoadedScene {
    let path = cell.scene.clone()?;
    match catch_unwind(|| crsh_scene::load(&path)) {
        Ok(Ok(s)) => Ok(Arc::new(s)),
        Ok(Err(e)) => Err(format!("cannot load scene {}: {e}", cell.scene_spec)),
        Err(p) => Err(format!(
            "loading scene {} panicked: {}",
            cell.scene_spec,
            crsh_core::panic_message(p.as_ref())
        )),
    }
}

fn failed(
    cell: &Cell,
    scene: &LoadedScene,
    threads: usize,
    plan: &Plan,
    reason: String,
) -> CellResult {
    let (name, height) = match scene {
        Ok(s) => (s.name.clone(), height_of(cell, s)),
        Err(_) => (cell.scene_spec.clone(), cell.height.unwrap_or(0)),
    };
    CellResult {
        index: cell.index,
        label: cell.label(),
        scene: name,
        scene_source: cell.scene_spec.clone(),
        pipeline: cell.pipeline.clone(),
        backend: cell.backend.clone(),
        params: cell.params.clone(),
        width: cell.width,
        height,
        depth: cell.depth,
        status: "failed".to_string(),
        reason,
        repeat: plan.repeat,
        threads,
        config: cell.config.clone(),
        measures: None,
    }
}

fn height_of(cell: &Cell, scene: &Scene) -> u32 {
    cell.height
        .or_else(|| scene.camera.height_for(cell.width))
        .unwrap_or(cell.width)
        .clamp(1, crsh_core::pipeline::MAX_IMAGE_SIDE)
}

fn run_cell(
    plan: &Plan,
    cell: &Cell,
    scene: &LoadedScene,
    threads: usize,
    ref_images: &mut HashMap<String, Result<Arc<Vec<u8>>, String>>,
    gpu: &mut GpuState,
) -> CellResult {
    let s = match scene {
        Ok(s) => s,
        Err(reason) => return failed(cell, scene, threads, plan, reason.clone()),
    };
    match catch_unwind(AssertUnwindSafe(|| measure(plan, cell, s, ref_images, gpu))) {
        Ok(Ok(m)) => CellResult {
            status: "ok".to_string(),
            measures: Some(m),
            ..failed(cell, scene, threads, plan, String::new())
        },
        Ok(Err(reason)) => failed(cell, scene, threads, plan, reason),
        Err(p) => failed(
            cell,
            scene,
            threads,
            plan,
            format!("panicked: {}", crsh_core::panic_message(p.as_ref())),
        ),
    }
}

/// The counters of a frame, without its times: equal across repeats of a deterministic cell.
fn counters(s: &Stats) -> Stats {
    let mut c = s.clone();
    c.timings_ms.clear();
    c.device_timings_ms.clear();
    c.accuracy = None;
    for k in c.per_kind.values_mut() {
        k.trace_ms = 0.0;
    }
    c
}

fn measure(
    plan: &Plan,
    cell: &Cell,
    scene: &Arc<Scene>,
    ref_images: &mut HashMap<String, Result<Arc<Vec<u8>>, String>>,
    gpu: &mut GpuState,
) -> Result<Measures, String> {
    match cell.backend.as_str() {
        "wgpu" => {
            // A stage the GPU lacks is this cell's reason, adapter or not.
            crsh_wgpu::check_supported(&cell.config)
                .map_err(|e| format!("building pipeline: {e}"))?;
            let gscene = gpu.scene(&cell.scene_spec, scene)?;
            let t_build = Instant::now();
            let stages = crsh_wgpu::build_stages(&cell.config, &gscene)
                .map_err(|e| format!("building pipeline: {e}"))?;
            let build_ms = t_build.elapsed().as_secs_f64() * 1e3;
            let reference = |spec: &crsh_core::StageSpec| {
                HostIntersector::build(spec, &gscene)
                    .map(|r| Box::new(r) as Box<dyn Intersector<Wgpu>>)
            };
            measure_on(
                &gscene.backend,
                &stages,
                build_ms,
                &reference,
                plan,
                cell,
                scene,
                ref_images,
            )
        }
        _ => {
            let t_build = Instant::now();
            let stages = crsh_cpu::build_stages(&cell.config, scene)
                .map_err(|e| format!("building pipeline: {e}"))?;
            let build_ms = t_build.elapsed().as_secs_f64() * 1e3;
            let reference = |spec: &crsh_core::StageSpec| crsh_cpu::build_intersector(spec, scene);
            measure_on(
                &Cpu, &stages, build_ms, &reference, plan, cell, scene, ref_images,
            )
        }
    }
}

/// Builds a cell's reference intersector on backend `B`.
type ReferenceBuilder<'a, B> =
    dyn Fn(&crsh_core::StageSpec) -> crsh_core::Result<Box<dyn Intersector<B>>> + 'a;

/// Runs a cell's frames on `backend`: warm-up, timed repeats, and the accuracy frame with the
/// reference intersector (its image compared with the CPU reference pipeline's).
#[allow(clippy::too_many_arguments)]
fn measure_on<B: Backend>(
    backend: &B,
    stages: &Stages<B>,
    build_stages_ms: f64,
    build_reference: &ReferenceBuilder<'_, B>,
    plan: &Plan,
    cell: &Cell,
    scene: &Arc<Scene>,
    ref_images: &mut HashMap<String, Result<Arc<Vec<u8>>, String>>,
) -> Result<Measures, String> {
    let opts = FrameOptions {
        width: cell.width,
        height: height_of(cell, scene),
        max_depth: cell.depth,
        triangles: scene.triangle_count() as u64,
    };
    let frame = |reference: Option<&dyn Intersector<B>>| {
        render_frame(backend, stages, &opts, reference, &mut |_| {})
            .map_err(|e| format!("render failed: {e}"))
    };
    for _ in 0..plan.warmup {
        frame(None)?;
    }
    let mut runs: Vec<Stats> = Vec::with_capacity(plan.repeat as usize);
    for _ in 0..plan.repeat {
        runs.push(frame(None)?.stats);
    }
    let first = &runs[0];
    let counters_equal = runs.iter().all(|r| counters(r) == counters(first));

    let summarise = |times: &dyn Fn(&Stats) -> &BTreeMap<String, f64>| {
        let mut keys: Vec<&String> = runs.iter().flat_map(|r| times(r).keys()).collect();
        keys.sort();
        keys.dedup();
        keys.into_iter()
            .map(|k| {
                let v: Vec<f64> = runs
                    .iter()
                    .map(|r| times(r).get(k).copied().unwrap_or(0.0))
                    .collect();
                (k.clone(), TimeSummary::of(&v))
            })
            .collect::<BTreeMap<String, TimeSummary>>()
    };
    let timings_ms = summarise(&|r: &Stats| &r.timings_ms);
    let device_timings_ms = summarise(&|r: &Stats| &r.device_timings_ms);
    // The median run's view: counters from the first run (equal in all), per-kind trace times
    // and the frame total as medians, from which Mrays/s follow.
    let mut median = first.clone();
    median.timings_ms = timings_ms
        .iter()
        .map(|(k, t)| (k.clone(), t.median))
        .collect();
    for (kind, ks) in median.per_kind.iter_mut() {
        let v: Vec<f64> = runs
            .iter()
            .map(|r| r.per_kind.get(kind).map_or(0.0, |k: &KindStats| k.trace_ms))
            .collect();
        ks.trace_ms = TimeSummary::of(&v).median;
    }

    let accuracy = match &cell.reference {
        None => None,
        Some(ref_cfg) => {
            let reference = build_reference(&ref_cfg.intersect)
                .map_err(|e| format!("building the reference intersector: {e}"))?;
            let checked = frame(Some(reference.as_ref()))?;
            let image = backend
                .download(&checked.image)
                .map_err(|e| format!("reading the image back: {e}"))?;
            let rgba = to_rgba8(&image);
            let key = serde_json::json!([
                cell.scene_spec,
                opts.width,
                opts.height,
                opts.max_depth,
                ref_cfg.primary,
                ref_cfg.raygen,
                ref_cfg.shade,
                ref_cfg.intersect,
            ])
            .to_string();
            let ref_rgba = ref_images
                .entry(key)
                .or_insert_with(|| {
                    crsh_cpu::render(scene, ref_cfg, &opts, None, &mut |_| {})
                        .map(|f| Arc::new(to_rgba8(&f.image)))
                        .map_err(|e| format!("reference render failed: {e}"))
                })
                .clone()?;
            let counts = checked.stats.accuracy.clone().unwrap_or_default();
            let a = crate::render::accuracy_report(
                &ref_cfg.intersect.kind,
                &counts,
                &rgba,
                &ref_rgba,
                0.0,
            );
            Some(CellAccuracy {
                reference: a.reference,
                hit_agreement: a.hit_agreement,
                psnr_db: a.psnr_db,
                images_identical: a.images_identical,
                pixels_differing: a.pixels_differing,
                rays_compared: a.rays_compared,
                hit_miss_mismatches: a.hit_miss_mismatches,
                nearest_mismatches: a.nearest_mismatches,
                mean_abs_t_error: a.mean_abs_t_error,
                self_hits: counts.self_hits,
                self_hit_rate: counts.self_hit_rate(),
            })
        }
    };

    let t = &first.tests;
    let traced = first.traced_rays;
    let ratio = |a: f64, b: f64| if b > 0.0 { a / b } else { 0.0 };
    Ok(Measures {
        triangles: scene.triangle_count() as u64,
        rays: CellRays {
            primary: first.rays.primary,
            shadow: first.rays.shadow,
            reflection: first.rays.reflection,
            refraction: first.rays.refraction,
            traced,
        },
        tests: CellTests {
            bounds: t.bounds,
            ray_triangle: t.ray_triangle,
            total: t.total,
            brute_force: t.brute_force,
            per_ray: ratio(t.total as f64, traced as f64),
            fraction: ratio(t.total as f64, t.brute_force as f64),
        },
        per_kind: median.per_kind.clone(),
        levels: first.levels.clone(),
        mesh_culling: first.mesh_culling.clone(),
        peak_candidate_bytes: first.peak_candidate_bytes,
        counters_equal_across_repeats: counters_equal,
        timings_ms,
        device_timings_ms,
        mrays_per_s: mrays_per_s(&median),
        build_stages_ms,
        accuracy,
    })
}

/// The bar over cells, on stderr; hidden when stderr is not a terminal or with `--quiet`.
fn progress_bar(len: u64, quiet: bool) -> ProgressBar {
    let bar = ProgressBar::with_draw_target(Some(len), ProgressDrawTarget::hidden());
    if !quiet && std::io::stderr().is_terminal() {
        bar.set_draw_target(ProgressDrawTarget::stderr());
        if let Ok(style) = ProgressStyle::with_template(
            "ablate [{bar:30}] {pos}/{len} cells, {elapsed} elapsed, ETA {eta} | {wide_msg}",
        ) {
            bar.set_style(style.progress_chars("=> "));
        }
        bar.enable_steady_tick(Duration::from_millis(500));
    }
    bar
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn counters_ignore_times() {
        let mut a = Stats::default();
        a.add_bounds(5);
        a.per_kind.insert(
            "shadow".into(),
            KindStats {
                rays: 3,
                trace_ms: 1.0,
                ..Default::default()
            },
        );
        a.timings_ms.insert("total".into(), 2.0);
        let mut b = a.clone();
        b.timings_ms.insert("total".into(), 3.0);
        b.per_kind.get_mut("shadow").unwrap().trace_ms = 9.0;
        assert_eq!(counters(&a), counters(&b));
        b.add_bounds(1);
        assert_ne!(counters(&a), counters(&b));
    }
}
