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
//! With the plan's `frames`, each scene loads once as an animated scene and a cell runs
//! sequences of frames ([`crsh::render_frames`], on the CPU or on the run's wgpu device):
//! `warmup` untimed sequences, `repeat` timed ones (each frame's times the median over them,
//! its counters equal in every one), then one more with the reference checking every
//! `reference_every`-th frame.
//!
//! A cell that fails (scene missing, stage construction or render error, no wgpu adapter, a
//! panic) is recorded with its reason and the run goes on.

use std::collections::{BTreeMap, HashMap};
use std::io::IsTerminal;
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::sync::Arc;
use std::time::Duration;

use crsh::report::mrays_per_s;
use crsh::{AccuracyReport, FramesRequest, Registries, RenderRequest, Renderer, UpdateReport};
use crsh_core::{AccuracyCounts, FrameOptions, KindStats, RayKind, Stats};
use crsh_scene::{AnimatedScene, Scene};
use crsh_wgpu::Wgpu;
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};

use super::plan::{Cell, Plan};
use super::results::{
    CellAccuracy, CellFrames, CellRays, CellResult, CellTests, FrameMeasure, FramesTotals,
    KindPerRay, Measures, TimeSummary,
};

/// A loaded scene (or why it did not load).
type LoadedScene = Result<Arc<Scene>, String>;

/// The reference images of the current scene, by reference configuration and size.
type ReferenceImages = HashMap<String, Result<Arc<crsh::ReferenceFrame>, String>>;

/// What the cells of one scene share: the scene, its renderers (the wgpu one uploads the scene
/// once) and the reference images.
struct SceneState<'r> {
    spec: String,
    scene: LoadedScene,
    /// The scene as an animated scene (plans with `frames`; `scene` is its frame 0).
    anim: Option<Arc<AnimatedScene>>,
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
            let (scene, anim) = if plan.frames.is_some() {
                load_animated(cell, plan.light_radius)
            } else {
                (load_scene(cell, plan.light_radius), None)
            };
            state = Some(SceneState {
                spec: cell.scene_spec.clone(),
                scene,
                anim,
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

/// Loads the cell's scene, with every light's radius set to `light_radius` when the plan
/// gives one.
fn load_scene(cell: &Cell, light_radius: Option<f32>) -> LoadedScene {
    let path = cell.scene.clone()?;
    match catch_unwind(|| {
        let mut s = crsh_scene::load(&path)?;
        if let Some(r) = light_radius {
            s.set_light_radius(r)?;
        }
        Ok::<_, crsh_scene::SceneError>(s)
    }) {
        Ok(Ok(s)) => Ok(Arc::new(s)),
        Ok(Err(e)) => Err(format!("cannot load scene {}: {e}", cell.scene_spec)),
        Err(p) => Err(format!(
            "loading scene {} panicked: {}",
            cell.scene_spec,
            crsh_core::panic_message(p.as_ref())
        )),
    }
}

/// Loads the cell's scene as an animated scene: its frame 0 as the scene, and the animation
/// (lights of radius `light_radius` when the plan gives one).
fn load_animated(
    cell: &Cell,
    light_radius: Option<f32>,
) -> (LoadedScene, Option<Arc<AnimatedScene>>) {
    let path = match &cell.scene {
        Ok(p) => p.clone(),
        Err(e) => return (Err(e.clone()), None),
    };
    match catch_unwind(|| {
        let (mut anim, report) = crsh_scene::load_animated(&path)?;
        if let Some(r) = light_radius {
            anim.set_light_radius(r)?;
        }
        Ok::<_, crsh_scene::SceneError>((anim, report))
    }) {
        Ok(Ok((anim, _))) => (Ok(Arc::new(anim.scene().clone())), Some(Arc::new(anim))),
        Ok(Err(e)) => (
            Err(format!("cannot load scene {}: {e}", cell.scene_spec)),
            None,
        ),
        Err(p) => (
            Err(format!(
                "loading scene {} panicked: {}",
                cell.scene_spec,
                crsh_core::panic_message(p.as_ref())
            )),
            None,
        ),
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
    let open_device = |device: &mut Option<Result<Wgpu, String>>| {
        device
            .get_or_insert_with(|| {
                Wgpu::new().map_err(|e| format!("backend wgpu: cannot open a device: {e}"))
            })
            .clone()
    };
    if let Some(frames) = plan.frames {
        let measured = catch_unwind(AssertUnwindSafe(|| {
            let anim = st
                .anim
                .as_ref()
                .ok_or("the scene did not load as an animated scene")?;
            let gpu = match cell.backend.as_str() {
                "wgpu" => Some(open_device(device)?),
                _ => None,
            };
            measure_frames(plan, cell, registries, anim, gpu.as_ref(), frames)
        }));
        return outcome(plan, cell, &st.scene, threads, measured);
    }
    let measured = catch_unwind(AssertUnwindSafe(|| {
        let renderer: &Renderer<'r> = match cell.backend.as_str() {
            "wgpu" => {
                let gpu = st.gpu.get_or_insert_with(|| {
                    let device = open_device(device)?;
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
    outcome(plan, cell, &st.scene, threads, measured)
}

/// The cell's result from what measuring it returned (or its panic).
fn outcome(
    plan: &Plan,
    cell: &Cell,
    scene: &LoadedScene,
    threads: usize,
    measured: std::thread::Result<Result<Measures, String>>,
) -> CellResult {
    match measured {
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
    for g in &mut c.generations {
        g.trace_ms = 0.0;
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
            .render(
                &opts.clone().with_primary_triangles(reference.is_some()),
                reference,
                &mut |_| {},
            )
            .map_err(|e| format!("render failed: {e}"))
    };
    for _ in 0..plan.warmup {
        frame(None)?;
    }
    let mut runs: Vec<Stats> = Vec::with_capacity(plan.repeat as usize);
    for _ in 0..plan.repeat {
        runs.push(frame(None)?.stats);
    }
    let accuracy = match &cell.reference {
        None => None,
        Some(ref_cfg) => {
            let checked = frame(Some(&ref_cfg.intersect))?;
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
            let want = ref_images
                .entry(key)
                .or_insert_with(|| {
                    renderer
                        .reference_frame(ref_cfg, frame_size, &opts, &mut |_| {})
                        .map(Arc::new)
                        .map_err(|e| format!("reference render failed: {e}"))
                })
                .clone()?;
            let counts = checked.stats.accuracy.clone().unwrap_or_default();
            let a = want.compare(&ref_cfg.intersect.kind, &checked, 0.0);
            Some(CellAccuracy {
                reference: a.reference,
                primary_agreement: a.primary_agreement,
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

    Ok(measures_of(
        &runs,
        scene.triangle_count() as u64,
        build_stages_ms,
        accuracy,
    ))
}

/// The measures of a cell's timed `runs` (at least one): counters from the first (and whether
/// every run gave the same), every time key's median, min and max, Mrays/s from the medians.
fn measures_of(
    runs: &[Stats],
    triangles: u64,
    build_stages_ms: f64,
    accuracy: Option<CellAccuracy>,
) -> Measures {
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

    let t = &first.tests;
    let traced = first.traced_rays;
    let ratio = |a: f64, b: f64| if b > 0.0 { a / b } else { 0.0 };
    Measures {
        triangles,
        rays: CellRays {
            primary: first.rays.primary,
            shadow: first.rays.shadow,
            reflection: first.rays.reflection,
            refraction: first.rays.refraction,
            ao: first.rays.ao,
            diffuse: first.rays.diffuse,
            traced,
        },
        tests: CellTests {
            bounds: t.bounds,
            ray_triangle: t.ray_triangle,
            total: t.total,
            brute_force: t.brute_force,
            per_ray: ratio(t.total as f64, traced as f64),
            fraction: ratio(t.total as f64, t.brute_force as f64),
            inner_nodes: t.inner_nodes,
            leaves: t.leaves,
            inner_nodes_per_ray: ratio(t.inner_nodes as f64, traced as f64),
            leaves_per_ray: ratio(t.leaves as f64, traced as f64),
            uncounted: t.uncounted,
        },
        per_kind_per_ray: median
            .per_kind
            .iter()
            .map(|(k, s)| (k.clone(), KindPerRay::of(s)))
            .collect(),
        per_kind: median.per_kind.clone(),
        levels: first.levels.clone(),
        mesh_culling: first.mesh_culling.clone(),
        packets: first.packets.clone(),
        peak_candidate_bytes: first.peak_candidate_bytes,
        counters_equal_across_repeats: counters_equal,
        timings_ms,
        device_timings_ms,
        mrays_per_s: mrays_per_s(&median),
        build_stages_ms,
        accuracy,
        frames: None,
    }
}

/// What a sequence keeps of one frame (not its image or scene, so that nothing holds the
/// scene buffers `render_frames` alternates).
struct FrameRun {
    frame: u32,
    time_s: f32,
    update: UpdateReport,
    stats: Stats,
    trace_ms: f64,
    render_ms: f64,
    frame_ms: f64,
    accuracy: Option<AccuracyReport>,
}

/// The counters of a frame of a sequence, without its times: equal across sequences.
fn frame_counters(f: &FrameRun) -> (Stats, String, u64) {
    (
        counters(&f.stats),
        f.update.structure.clone(),
        f.update.moved_triangles,
    )
}

/// Adds the counters and times of `s` to `sum` (a sequence's frames as one run: counters and
/// times summed, the peak candidate bytes the largest).
fn add_stats(sum: &mut Stats, s: &Stats) {
    sum.stages.clone_from(&s.stages);
    for kind in RayKind::ALL {
        sum.rays.add(kind, s.rays.get(kind));
    }
    sum.tests.add(&s.tests);
    sum.traced_rays += s.traced_rays;
    for (kind, k) in &s.per_kind {
        let e = sum.per_kind.entry(kind.clone()).or_default();
        e.rays += k.rays;
        e.bounds += k.bounds;
        e.ray_triangle += k.ray_triangle;
        e.trace_ms += k.trace_ms;
        e.inner_nodes += k.inner_nodes;
        e.leaves += k.leaves;
        e.offset_ended += k.offset_ended;
    }
    add_level_rows(&mut sum.levels, &s.levels);
    add_level_rows(&mut sum.object_levels, &s.object_levels);
    for (kind, c) in &s.mesh_culling {
        let e = sum.mesh_culling.entry(kind.clone()).or_default();
        e.tests += c.tests;
        e.hits += c.hits;
        e.misses += c.misses;
    }
    for (kind, p) in &s.packets {
        sum.packets.entry(kind.clone()).or_default().add(p);
    }
    for (key, choice) in &s.choices {
        sum.choices.insert(key.clone(), choice.clone());
    }
    for (k, v) in &s.timings_ms {
        *sum.timings_ms.entry(k.clone()).or_default() += v;
    }
    for (k, v) in &s.device_timings_ms {
        *sum.device_timings_ms.entry(k.clone()).or_default() += v;
    }
    sum.peak_candidate_bytes = sum.peak_candidate_bytes.max(s.peak_candidate_bytes);
}

/// A sequence of frames as one run: [`add_stats`] over its frames, each frame's update under
/// `update`, and `total` every frame's update and render.
fn sequence_stats(seq: &[FrameRun]) -> Stats {
    let mut sum = Stats::default();
    for f in seq {
        add_stats(&mut sum, &f.stats);
    }
    let update: f64 = seq.iter().map(|f| f.update.total_ms).sum();
    sum.timings_ms.insert("update".into(), update);
    sum.timings_ms
        .insert("total".into(), seq.iter().map(|f| f.frame_ms).sum());
    sum
}

/// Runs a frames cell: `warmup` untimed sequences of `frames` frames, `repeat` timed ones,
/// then one with the reference on every `reference_every`-th frame (see the module
/// documentation). The measures are over the whole sequence ([`sequence_stats`]), with one
/// [`FrameMeasure`] per frame.
fn measure_frames(
    plan: &Plan,
    cell: &Cell,
    registries: &Registries,
    anim: &AnimatedScene,
    device: Option<&Wgpu>,
    frames: u32,
) -> Result<Measures, String> {
    let scene = anim.scene();
    let base = RenderRequest::new()
        .with_width(cell.width)
        .with_height(height_of(cell, scene))
        .with_max_depth(cell.depth);
    let sequence = |request: &FramesRequest| -> Result<Vec<FrameRun>, String> {
        let mut out = Vec::with_capacity(frames as usize);
        crsh::render_frames(
            registries,
            anim,
            device,
            &cell.config,
            request,
            &mut |_, _| {},
            &mut |f| {
                out.push(FrameRun {
                    frame: f.frame,
                    time_s: f.time_s,
                    trace_ms: f.trace_ms(),
                    render_ms: f.render_ms(),
                    frame_ms: f.frame_ms(),
                    update: f.update,
                    stats: f.render.stats,
                    accuracy: f.render.accuracy,
                });
                Ok(())
            },
        )
        .map_err(|e| format!("rendering frames: {e}"))?;
        Ok(out)
    };
    let plain = FramesRequest::new(base.clone(), frames);
    for _ in 0..plan.warmup {
        sequence(&plain)?;
    }
    let mut runs: Vec<Vec<FrameRun>> = Vec::with_capacity(plan.repeat as usize);
    for _ in 0..plan.repeat {
        runs.push(sequence(&plain)?);
    }
    let first = &runs[0];
    let counters_equal = runs.iter().all(|seq| {
        seq.len() == first.len()
            && seq
                .iter()
                .zip(first)
                .all(|(a, b)| frame_counters(a) == frame_counters(b))
    });

    // The accuracy sequence: untimed, the reference on the sampled frames.
    let checked: Vec<FrameRun> = match &cell.reference {
        None => Vec::new(),
        Some(r) => {
            let request = FramesRequest::new(base.with_reference(&r.intersect.kind), frames)
                .with_reference_every(plan.reference_every);
            sequence(&request)?
        }
    };
    let agreement = |frame: u32| {
        checked
            .iter()
            .find(|f| f.frame == frame)
            .and_then(|f| f.accuracy.as_ref())
            .map(|a| a.hit_agreement)
    };

    let median = |pick: &dyn Fn(&FrameRun) -> f64, i: usize| {
        TimeSummary::of(&runs.iter().map(|seq| pick(&seq[i])).collect::<Vec<_>>()).median
    };
    let rows: Vec<FrameMeasure> = first
        .iter()
        .enumerate()
        .map(|(i, f)| {
            let tests = f.stats.tests.total;
            let traced = f.stats.traced_rays;
            FrameMeasure {
                frame: f.frame,
                time_s: f.time_s,
                structure: f.update.structure.clone(),
                moved_triangles: f.update.moved_triangles,
                scene_ms: median(&|f: &FrameRun| f.update.scene_ms, i),
                spheres_ms: median(&|f: &FrameRun| f.update.spheres_ms, i),
                upload_ms: median(&|f: &FrameRun| f.update.upload_ms, i),
                structure_ms: median(&|f: &FrameRun| f.update.structure_ms, i),
                update_ms: median(&|f: &FrameRun| f.update.total_ms, i),
                trace_ms: median(&|f: &FrameRun| f.trace_ms, i),
                render_ms: median(&|f: &FrameRun| f.render_ms, i),
                frame_ms: median(&|f: &FrameRun| f.frame_ms, i),
                traced_rays: traced,
                tests,
                tests_per_ray: if traced > 0 {
                    tests as f64 / traced as f64
                } else {
                    0.0
                },
                hit_agreement: agreement(f.frame),
            }
        })
        .collect();
    let build_stages_ms = TimeSummary::of(
        &runs
            .iter()
            .map(|seq| {
                seq.iter()
                    .flat_map(|f| f.update.stages.iter())
                    .map(|b| b.ms)
                    .sum::<f64>()
            })
            .collect::<Vec<_>>(),
    )
    .median;
    let sequences: Vec<Stats> = runs.iter().map(|seq| sequence_stats(seq)).collect();
    let mut m = measures_of(
        &sequences,
        scene.triangle_count() as u64,
        build_stages_ms,
        frames_accuracy(&checked),
    );
    m.counters_equal_across_repeats = counters_equal && m.counters_equal_across_repeats;
    m.frames = Some(CellFrames {
        totals: FramesTotals::of(&rows),
        rows,
    });
    Ok(m)
}

/// The accuracy of the checked frames of a sequence (`None` when none was checked): the
/// lowest hit agreement and PSNR, the counts summed, the mean |t| error over every agreeing
/// hit.
fn frames_accuracy(seq: &[FrameRun]) -> Option<CellAccuracy> {
    let checked: Vec<(&AccuracyReport, AccuracyCounts)> = seq
        .iter()
        .filter_map(|f| {
            let a = f.accuracy.as_ref()?;
            Some((a, f.stats.accuracy.clone().unwrap_or_default()))
        })
        .collect();
    let (first, _) = checked.first()?;
    let mut counts = AccuracyCounts::default();
    for (_, c) in &checked {
        counts.rays += c.rays;
        counts.agreeing += c.agreeing;
        counts.hit_miss_mismatches += c.hit_miss_mismatches;
        counts.nearest_mismatches += c.nearest_mismatches;
        counts.t_compared += c.t_compared;
        counts.t_abs_error_sum += c.t_abs_error_sum;
        counts.self_hits += c.self_hits;
    }
    Some(CellAccuracy {
        reference: first.reference.clone(),
        primary_agreement: checked
            .iter()
            .filter_map(|(a, _)| a.primary_agreement)
            .reduce(f64::min),
        hit_agreement: checked
            .iter()
            .map(|(a, _)| a.hit_agreement)
            .fold(f64::INFINITY, f64::min),
        psnr_db: checked
            .iter()
            .filter_map(|(a, _)| a.psnr_db)
            .reduce(f64::min),
        images_identical: checked.iter().all(|(a, _)| a.images_identical),
        pixels_differing: checked.iter().map(|(a, _)| a.pixels_differing).sum(),
        rays_compared: counts.rays,
        hit_miss_mismatches: counts.hit_miss_mismatches,
        nearest_mismatches: counts.nearest_mismatches,
        mean_abs_t_error: counts.mean_abs_t_error(),
        self_hits: counts.self_hits,
        self_hit_rate: counts.self_hit_rate(),
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

/// Adds `rows` to `sum`, row by row matched on (ray kind, level).
fn add_level_rows(sum: &mut Vec<crsh_core::LevelStats>, rows: &[crsh_core::LevelStats]) {
    for l in rows {
        match sum
            .iter_mut()
            .find(|x| x.ray_kind == l.ray_kind && x.level == l.level)
        {
            Some(x) => {
                x.tests += l.tests;
                x.hits += l.hits;
                x.misses += l.misses;
            }
            None => sum.push(l.clone()),
        }
    }
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
        a.generation_mut(1, crsh_core::RayKind::Shadow).trace_ms = 1.0;
        b.generation_mut(1, crsh_core::RayKind::Shadow).trace_ms = 2.0;
        assert_eq!(counters(&a), counters(&b));
        b.add_bounds(1);
        assert_ne!(counters(&a), counters(&b));
    }
}
