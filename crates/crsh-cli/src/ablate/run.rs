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
use std::time::Duration;

use crsh::report::{compare_images, mrays_per_s};
use crsh::{Registries, Renderer};
use crsh_core::metrics::to_rgba8;
use crsh_core::{FrameOptions, KindStats, Stats};
use crsh_scene::Scene;
use crsh_wgpu::Wgpu;
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};

use super::plan::{Cell, Plan};
use super::results::{CellAccuracy, CellRays, CellResult, CellTests, Measures, TimeSummary};

/// A loaded scene (or why it did not load).
type LoadedScene = Result<Arc<Scene>, String>;

/// The reference images of the current scene, by reference configuration and size.
type ReferenceImages = HashMap<String, Result<Arc<Vec<u8>>, String>>;

/// What the cells of one scene share: the scene, its renderers (the wgpu one uploads the scene
/// once) and the reference images.
struct SceneState<'r> {
    spec: String,
    scene: LoadedScene,
    cpu: Option<Renderer<'r>>,
    gpu: Option<Result<Renderer<'r>, String>>,
    ref_images: ReferenceImages,
}

/// Runs `cells` (the plan's, or one shard's) in order with `registries`. `on_done` receives
/// each result as it completes (for the per-cell summary line); `quiet` hides the progress bar.
pub fn run_cells(
    plan: &Plan,
    cells: &[&Cell],
    registries: &Registries,
    quiet: bool,
    on_done: &mut dyn FnMut(&CellResult, &ProgressBar),
) -> Vec<CellResult> {
    let bar = progress_bar(cells.len() as u64, quiet);
    let threads = plan.threads.unwrap_or_else(rayon::current_num_threads);
    // The wgpu device of the run: opened by the first wgpu cell (or why it could not be).
    let mut device: Option<Result<Wgpu, String>> = None;
    let mut state: Option<SceneState<'_>> = None;
    let mut out = Vec::with_capacity(cells.len());
    for cell in cells {
        bar.set_message(format!("{} | {}", cell.scene_spec, cell.label()));
        // One scene at a time: the previous one (and its reference images) is freed here.
        if state.as_ref().is_none_or(|s| s.spec != cell.scene_spec) {
            drop(state.take()); // before the next scene loads: one scene in memory at a time
            state = Some(SceneState {
                spec: cell.scene_spec.clone(),
                scene: load_scene(cell),
                cpu: None,
                gpu: None,
                ref_images: HashMap::new(),
            });
        }
        let st = state.as_mut().expect("scene state set above");
        let mut run = || run_cell(plan, cell, registries, st, &mut device, threads);
        let result = match plan.threads {
            Some(n) => crsh_cpu::with_threads(n, run)
                .unwrap_or_else(|e| failed(cell, &st.scene, threads, plan, e.to_string())),
            None => run(),
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

fn run_cell<'r>(
    plan: &Plan,
    cell: &Cell,
    registries: &'r Registries,
    st: &mut SceneState<'r>,
    device: &mut Option<Result<Wgpu, String>>,
    threads: usize,
) -> CellResult {
    let scene = match &st.scene {
        Ok(s) => Arc::clone(s),
        Err(reason) => return failed(cell, &st.scene, threads, plan, reason.clone()),
    };
    if let Some(reason) = &cell.unsupported {
        return failed(cell, &st.scene, threads, plan, reason.clone());
    }
    let measured = catch_unwind(AssertUnwindSafe(|| {
        let renderer: &Renderer<'r> = match cell.backend.as_str() {
            "wgpu" => {
                let gpu = st.gpu.get_or_insert_with(|| {
                    let device = device
                        .get_or_insert_with(|| {
                            Wgpu::new()
                                .map_err(|e| format!("backend wgpu: cannot open a device: {e}"))
                        })
                        .clone()?;
                    Renderer::on_wgpu(registries, Arc::clone(&scene), &device)
                        .map_err(|e| format!("uploading the scene to the device: {e}"))
                });
                gpu.as_ref().map_err(|e| e.clone())?
            }
            _ => st
                .cpu
                .get_or_insert_with(|| Renderer::new(registries, Arc::clone(&scene))),
        };
        measure(plan, cell, renderer, &mut st.ref_images)
    }));
    match measured {
        Ok(Ok(m)) => CellResult {
            status: "ok".to_string(),
            measures: Some(m),
            ..failed(cell, &st.scene, threads, plan, String::new())
        },
        Ok(Err(reason)) => failed(cell, &st.scene, threads, plan, reason),
        Err(p) => failed(
            cell,
            &st.scene,
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

/// Runs a cell's frames with `renderer`: builds the stages, renders the warm-up and the timed
/// repeats, then the accuracy frame with the reference intersector (its image compared with
/// the CPU reference pipeline's, rendered once per configuration and size).
fn measure(
    plan: &Plan,
    cell: &Cell,
    renderer: &Renderer<'_>,
    ref_images: &mut ReferenceImages,
) -> Result<Measures, String> {
    let scene = renderer.scene();
    let frame_size = renderer
        .frame_size(cell.width, Some(height_of(cell, scene)))
        .map_err(|e| e.to_string())?;
    let built = renderer
        .build(&cell.config, frame_size)
        .map_err(|e| format!("building pipeline: {e}"))?;
    let build_stages_ms = built.build_ms();
    let opts = FrameOptions::default().with_max_depth(cell.depth);
    let frame = |reference: Option<&crsh_core::StageSpec>| {
        built
            .render(&opts, reference, &mut |_| {})
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
            let checked = frame(Some(&ref_cfg.intersect))?;
            let rgba = to_rgba8(&checked.image);
            let key = serde_json::json!([
                cell.scene_spec,
                frame_size.width,
                frame_size.height,
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
                    renderer
                        .reference_image(ref_cfg, frame_size, &opts, &mut |_| {})
                        .map(Arc::new)
                        .map_err(|e| format!("reference render failed: {e}"))
                })
                .clone()?;
            let counts = checked.stats.accuracy.clone().unwrap_or_default();
            let a = compare_images(&ref_cfg.intersect.kind, &counts, &rgba, &ref_rgba, 0.0);
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
