//! `crsh tables`: seed 000's evaluation tables (chapter 4) for any scenes and configurations.
//!
//! For every scene, every ray-space-hierarchy pipeline runs once per (subdivision, depth)
//! configuration, and every pipeline without a hierarchy (`bvh`, `brute`) once per scene, on
//! the very same rays (generation does not depend on the intersector, and every pipeline is
//! exact). The Markdown report holds, in the thesis's order:
//!
//! 1. per scene and configuration, the per-level counters of tables 4.1-4.3 (and 4.5-4.23):
//!    `# SH INTERSECTIONS / MISSES / HITS` per level (and `RE` for reflection, `RF` for
//!    refraction rays), with our extra columns for the mesh-culling tests above the top level
//!    and the final ray-triangle tests below level 1;
//! 2. per configuration, the totals of table 4.4 (4.8, ...): total tests, percentage of brute
//!    force and tests per traced ray per scene, with the brute-force row and the
//!    hierarchy-less pipelines as baselines;
//! 3. the configuration comparison of figs 4.7-4.23: total tests per configuration relative to
//!    the first one;
//! 4. throughput on the same rays: traced rays, tracing time and Mrays/s per pipeline (and
//!    hit agreement with `--reference`);
//! 5. the rendering-time tables 4.25-4.27 for the first configuration: wall time per stage
//!    (median of `--repeat` runs) and its share of the frame.
//!
//! `--csv DIR` writes the same data as `levels.csv`, `totals.csv` and `times.csv`.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::sync::Arc;
use std::time::Instant;

use crsh::report::{group, mrays_per_s};
use crsh::{BackendKind, Built, Registries, Renderer};
use crsh_core::{FrameOptions, LevelStats, PipelineConfig, RayKind, Stats, STAGE_TIMINGS};
use crsh_scene::Scene;

use crate::args::TablesArgs;
use crate::error::{CliError, CliResult};
use crate::output;
use crate::render::{configure_threads, library_error, pipeline_config, reference_config};

/// One hierarchy configuration.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Config {
    subdivision: u32,
    depth: u32,
}

impl Config {
    fn label(self) -> String {
        format!("subdivision {} depth {}", self.subdivision, self.depth)
    }
}

/// One pipeline's frame on one scene (and configuration, for hierarchy pipelines).
struct Run {
    pipeline: String,
    /// `None` for pipelines without a ray-space hierarchy.
    config: Option<Config>,
    /// Counters of the first run, timings the per-stage median over the repeats.
    stats: Stats,
}

/// Everything measured on one scene.
struct SceneRuns {
    name: String,
    triangles: u64,
    width: u32,
    height: u32,
    runs: Vec<Run>,
}

impl SceneRuns {
    fn find(&self, pipeline: &str, config: Config) -> Option<&Run> {
        self.runs
            .iter()
            .find(|r| r.pipeline == pipeline && r.config.is_none_or(|c| c == config))
    }
}

/// The files `--csv DIR` writes.
const CSV_FILES: [&str; 3] = ["levels.csv", "totals.csv", "times.csv"];

/// Runs `crsh tables`.
pub fn run(args: &TablesArgs, registries: &Registries) -> CliResult<()> {
    if let Some(path) = &args.out {
        output::check_md_path(path, "--out")?;
    }
    if let Some(dir) = &args.csv {
        if !dir.is_dir() {
            return Err(CliError::usage(format!(
                "--csv {}: not an existing directory",
                dir.display()
            )));
        }
    }
    let mut files = output::RunFiles::new();
    for scene in &args.scenes {
        files.scene(scene);
    }
    for pipeline in &args.pipelines {
        files.pipeline(registries, pipeline);
    }
    if let Some(path) = &args.out {
        files.output(path, "--out");
    }
    if let Some(dir) = &args.csv {
        for name in CSV_FILES {
            files.output(&dir.join(name), format!("--csv {}'s", dir.display()));
        }
    }
    files.check()?;
    let configs: Vec<Config> = args
        .subdivision
        .iter()
        .flat_map(|&subdivision| {
            args.depth
                .iter()
                .map(move |&depth| Config { subdivision, depth })
        })
        .collect();
    // Resolve every pipeline × configuration before any work, so a typo fails at once.
    let cpu = BackendKind::Cpu;
    let mut plan: Vec<(String, Option<Config>, PipelineConfig)> = Vec::new();
    for name in &args.pipelines {
        let base = pipeline_config(registries, name, &args.set, cpu)?;
        if base.hierarchy.is_none() {
            plan.push((name.clone(), None, base));
            continue;
        }
        for &c in &configs {
            let mut sets = args.set.clone();
            sets.push(format!("hierarchy.subdivision={}", c.subdivision));
            sets.push(format!("hierarchy.depth={}", c.depth));
            plan.push((
                name.clone(),
                Some(c),
                pipeline_config(registries, name, &sets, cpu)?,
            ));
        }
    }
    let threads = configure_threads(args.threads)?;
    // Load every scene, then build every pipeline once on the first (stage parameters are
    // range-checked there), before the long part starts.
    let loaded = args
        .scenes
        .iter()
        .map(|source| {
            crsh_scene::load(source)
                .map(Arc::new)
                .map_err(|e| CliError::runtime(format!("cannot load scene `{source}`: {e}")))
        })
        .collect::<CliResult<Vec<Arc<Scene>>>>()?;
    let first = loaded
        .first()
        .ok_or_else(|| CliError::usage("--scene: name at least one scene"))?;
    // The reference intersector (the same for every pipeline: only its spec is used).
    let reference = match (&args.reference, plan.first()) {
        (Some(name), Some((_, _, cfg))) => Some(reference_config(registries, cfg, name)?.intersect),
        _ => None,
    };
    // Stage parameters a scene can refuse (e.g. too few hash bits for its lights) fail here,
    // on the first scene, before the long part starts.
    let probe = Renderer::new(registries, Arc::clone(first));
    let probe_frame = probe
        .frame_size(args.width, args.height)
        .map_err(|e| CliError::usage(format!("--width {}: {e}", args.width)))?;
    for (name, config, cfg) in &plan {
        let what = config.map_or(format!("pipeline `{name}`"), |c| {
            format!("pipeline `{name}`, {}", c.label())
        });
        probe
            .build(cfg, probe_frame)
            .map_err(|e| library_error(e, &what))?;
    }

    let mut scenes = Vec::new();
    for scene in &loaded {
        let renderer = Renderer::new(registries, Arc::clone(scene));
        let frame = renderer.frame_size(args.width, args.height).map_err(|e| {
            CliError::usage(format!("--width {} on {}: {e}", args.width, scene.name))
        })?;
        let opts = FrameOptions::default().with_max_depth(args.bounces);
        let mut runs = Vec::new();
        for (name, config, cfg) in &plan {
            let what = match config {
                Some(c) => format!("{} {name} {}", scene.name, c.label()),
                None => format!("{} {name}", scene.name),
            };
            let t0 = Instant::now();
            let stats = renderer
                .build(cfg, frame)
                .and_then(|built| measure(&built, &opts, reference.as_ref(), args.repeat))
                .map_err(|e| library_error(e, &what))?;
            if !args.quiet {
                eprintln!(
                    "tables: {what}: {} tests, {:.0} ms",
                    group(stats.tests.total),
                    t0.elapsed().as_secs_f64() * 1e3
                );
            }
            runs.push(Run {
                pipeline: name.clone(),
                config: *config,
                stats,
            });
        }
        scenes.push(SceneRuns {
            name: scene.name.clone(),
            triangles: scene.triangle_count() as u64,
            width: frame.width,
            height: frame.height,
            runs,
        });
    }

    let md = markdown(&scenes, &configs, &args.pipelines, args, threads);
    if let Some(path) = &args.out {
        output::write_text(path, &md)?;
    }
    if let Some(dir) = &args.csv {
        let [levels, totals, times] = CSV_FILES;
        output::write_text(&dir.join(levels), &levels_csv(&scenes))?;
        output::write_text(&dir.join(totals), &totals_csv(&scenes))?;
        output::write_text(&dir.join(times), &times_csv(&scenes))?;
    }
    output::print_stdout(&md)
}

/// Renders `repeat` frames: counters (and accuracy) from the first, each stage's time the
/// median over all of them.
fn measure(
    built: &Built<'_>,
    opts: &FrameOptions,
    reference: Option<&crsh_core::StageSpec>,
    repeat: u32,
) -> crsh::Result<Stats> {
    let mut first: Option<Stats> = None;
    let mut times: BTreeMap<String, Vec<f64>> = BTreeMap::new();
    let mut trace: BTreeMap<String, Vec<f64>> = BTreeMap::new();
    for i in 0..repeat.max(1) {
        let frame = built.render(opts, reference.filter(|_| i == 0), &mut |_| {})?;
        for (k, v) in &frame.stats.timings_ms {
            times.entry(k.clone()).or_default().push(*v);
        }
        for (k, v) in &frame.stats.per_kind {
            trace.entry(k.clone()).or_default().push(v.trace_ms);
        }
        if first.is_none() {
            first = Some(frame.stats);
        }
    }
    let mut stats = first.unwrap_or_default();
    for (k, v) in times {
        stats.timings_ms.insert(k, median(v));
    }
    for (k, v) in trace {
        if let Some(ks) = stats.per_kind.get_mut(&k) {
            ks.trace_ms = median(v);
        }
    }
    Ok(stats)
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    match v.len() {
        0 => 0.0,
        n if n % 2 == 1 => v[n / 2],
        n => 0.5 * (v[n / 2 - 1] + v[n / 2]),
    }
}

/// The thesis's two-letter ray kind labels.
fn kind_label(kind: &str) -> &'static str {
    match kind {
        "shadow" => "SH",
        "reflection" => "RE",
        "refraction" => "RF",
        _ => "PR",
    }
}

const KINDS: [RayKind; 3] = [RayKind::Shadow, RayKind::Reflection, RayKind::Refraction];

/// The pseudo-level of the mesh-culling tests, above every node level.
const MESHES: u32 = u32::MAX;

/// Column name of a level: [`MESHES`] the mesh-culling tests, 0 the final ray-triangle tests.
fn level_name(level: u32) -> String {
    match level {
        0 => "final".into(),
        MESHES => "meshes".into(),
        l => format!("level {l}"),
    }
}

/// The counters of `kind` at `level` ([`MESHES`]: the mesh-culling tests).
fn level_of(s: &Stats, kind: &str, level: u32) -> Option<LevelStats> {
    if level == MESHES {
        return s.mesh_culling.get(kind).map(|c| LevelStats {
            ray_kind: kind.to_string(),
            level,
            tests: c.tests,
            hits: c.hits,
            misses: c.misses,
        });
    }
    s.levels
        .iter()
        .find(|l| l.ray_kind == kind && l.level == level)
        .cloned()
}

fn pct(part: f64, whole: f64) -> String {
    if whole > 0.0 {
        format!("{:.2}%", 100.0 * part / whole)
    } else {
        "–".into()
    }
}

fn per_ray(s: &Stats) -> f64 {
    if s.traced_rays == 0 {
        0.0
    } else {
        s.tests.total as f64 / s.traced_rays as f64
    }
}

/// Tracing time of every traced kind (rasterized primaries trace nothing and report 0).
fn trace_ms(s: &Stats) -> f64 {
    s.per_kind.values().map(|v| v.trace_ms).sum()
}

/// Traced rays over their tracing time, as `crsh render` reports it.
fn mrays(s: &Stats) -> f64 {
    mrays_per_s(s).get("overall").copied().unwrap_or(0.0)
}

/// `x` with three significant digits (Mrays/s spans 0.001 to 100 between methods).
fn sig3(x: f64) -> String {
    if x == 0.0 || !x.is_finite() {
        return format!("{x}");
    }
    let decimals = (2 - x.abs().log10().floor() as i32).max(0) as usize;
    format!("{x:.decimals$}")
}

fn rays_caption(s: &Stats) -> String {
    let parts: Vec<String> = KINDS
        .iter()
        .filter(|&&k| s.rays.get(k) > 0)
        .map(|&k| format!("{} {}", group(s.rays.get(k)), k.name()))
        .collect();
    if parts.is_empty() {
        "no secondary rays".into()
    } else {
        parts.join(" & ")
    }
}

fn markdown(
    scenes: &[SceneRuns],
    configs: &[Config],
    pipelines: &[String],
    args: &TablesArgs,
    threads: usize,
) -> String {
    let mut md = String::new();
    let _ = writeln!(md, "# CRSH evaluation tables (seed 000, chapter 4)\n");
    let _ = writeln!(
        md,
        "Scenes: {}. Pipelines: {}. Configurations: {}. Bounces: {}. CPU backend, {threads} \
         threads; times are the median of {} run(s). Test counts include misses and hits \
         (bounding-sphere tests and ray-triangle tests); \"final\" is the exact ray-triangle \
         tests on the survivors, \"meshes\" the top level against the per-mesh bounding spheres.\n",
        scenes
            .iter()
            .map(|s| format!(
                "{} ({} triangles, {}×{})",
                s.name,
                group(s.triangles),
                s.width,
                s.height
            ))
            .collect::<Vec<_>>()
            .join(", "),
        pipelines.join(", "),
        configs
            .iter()
            .map(|c| format!("{}×{}", c.subdivision, c.depth))
            .collect::<Vec<_>>()
            .join(", "),
        args.bounces,
        args.repeat.max(1),
    );

    // 1. Per-level tables (4.1-4.3, ...).
    let _ = writeln!(
        md,
        "## Hierarchy traversal results (tables 4.1-4.3 and 4.5-4.23)\n"
    );
    for c in configs {
        for scene in scenes {
            let runs: Vec<&Run> = scene.runs.iter().filter(|r| r.config == Some(*c)).collect();
            if runs.is_empty() {
                continue;
            }
            let top = runs
                .iter()
                .flat_map(|r| r.stats.levels.iter().map(|l| l.level))
                .max()
                .unwrap_or(0);
            let mut levels: Vec<u32> = (0..=top).rev().collect();
            if runs.iter().any(|r| !r.stats.mesh_culling.is_empty()) {
                levels.insert(0, MESHES);
            }
            let _ = writeln!(md, "### {} — {}\n", scene.name.to_uppercase(), c.label());
            let _ = write!(md, "| {} |", scene.name.to_uppercase());
            for &l in &levels {
                let _ = write!(md, " {} |", level_name(l).to_uppercase());
            }
            let _ = writeln!(md);
            let _ = writeln!(md, "|---|{}", "---:|".repeat(levels.len()));
            for r in &runs {
                let _ = writeln!(md, "| **{}** |{}", r.pipeline, " |".repeat(levels.len()));
                for kind in KINDS {
                    let name = kind.name();
                    if !r.stats.levels.iter().any(|l| l.ray_kind == name) {
                        continue;
                    }
                    let lab = kind_label(name);
                    for (what, get) in [
                        (
                            "INTERSECTIONS",
                            (|l: &LevelStats| l.tests) as fn(&LevelStats) -> u64,
                        ),
                        ("MISSES", |l| l.misses),
                        ("HITS", |l| l.hits),
                    ] {
                        let _ = write!(md, "| # {lab} {what} |");
                        for &l in &levels {
                            match level_of(&r.stats, name, l) {
                                Some(ls) => {
                                    let _ = write!(md, " {} |", group(get(&ls)));
                                }
                                None => md.push_str(" – |"),
                            }
                        }
                        let _ = writeln!(md);
                    }
                }
            }
            let _ = writeln!(
                md,
                "\n{} rays.\n",
                runs.first()
                    .map_or_else(String::new, |r| rays_caption(&r.stats))
            );
        }
    }

    // 2. Totals (table 4.4, ...).
    let _ = writeln!(
        md,
        "## Total intersection tests (tables 4.4, 4.8, ..., 4.24)\n"
    );
    for c in configs {
        let _ = writeln!(md, "### {}\n", c.label());
        let _ = write!(md, "| algorithm |");
        for s in scenes {
            let _ = write!(
                md,
                " {0} total tests | {0} relative | {0} tests / ray |",
                s.name.to_uppercase()
            );
        }
        let _ = writeln!(md);
        let _ = writeln!(md, "|---|{}", "---:|---:|---:|".repeat(scenes.len()));
        let _ = write!(md, "| brute force |");
        for s in scenes {
            let bf = s.runs.first().map_or(0, |r| r.stats.tests.brute_force);
            let _ = write!(md, " {} | 100% | {} |", group(bf), group(s.triangles));
        }
        let _ = writeln!(md);
        for p in pipelines {
            let _ = write!(md, "| {p} |");
            for s in scenes {
                match s.find(p, *c) {
                    Some(r) => {
                        let t = &r.stats.tests;
                        let _ = write!(
                            md,
                            " {} | {} | {:.1} |",
                            group(t.total),
                            pct(t.total as f64, t.brute_force as f64),
                            per_ray(&r.stats)
                        );
                    }
                    None => md.push_str(" – | – | – |"),
                }
            }
            let _ = writeln!(md);
        }
        let _ = writeln!(md);
        let captions: Vec<String> = scenes
            .iter()
            .map(|s| {
                let r = s.runs.first().map(|r| rays_caption(&r.stats));
                format!("{} ({})", s.name.to_uppercase(), r.unwrap_or_default())
            })
            .collect();
        let _ = writeln!(md, "Rays: {}.\n", captions.join(", "));
        // Ratios between the hierarchy pipelines, as the thesis's text quotes them.
        let hier: Vec<&String> = pipelines
            .iter()
            .filter(|p| {
                scenes
                    .iter()
                    .any(|s| s.find(p, *c).is_some_and(|r| r.config.is_some()))
            })
            .collect();
        for w in hier.windows(2) {
            let (a, b) = (w[0], w[1]);
            let ratios: Vec<String> = scenes
                .iter()
                .filter_map(|s| {
                    let (ra, rb) = (s.find(a, *c)?, s.find(b, *c)?);
                    Some(format!(
                        "{} {:.3}×",
                        s.name,
                        ra.stats.tests.total as f64 / rb.stats.tests.total.max(1) as f64
                    ))
                })
                .collect();
            let _ = writeln!(md, "Total tests {a} / {b}: {}.\n", ratios.join(", "));
        }
    }

    // 3. Configuration comparison.
    if configs.len() > 1 {
        let base = configs[0];
        let _ = writeln!(
            md,
            "## Configuration comparison (figs 4.7-4.23): total tests relative to {}\n",
            base.label()
        );
        let _ = write!(md, "| scene | algorithm |");
        for c in configs {
            let _ = write!(md, " {}×{} |", c.subdivision, c.depth);
        }
        let _ = writeln!(md);
        let _ = writeln!(md, "|---|---|{}", "---:|".repeat(configs.len()));
        for s in scenes {
            for p in pipelines {
                let Some(b) = s.find(p, base).filter(|r| r.config.is_some()) else {
                    continue;
                };
                let _ = write!(md, "| {} | {p} |", s.name);
                for c in configs {
                    match s.find(p, *c) {
                        Some(r) => {
                            let _ = write!(
                                md,
                                " {} ({:.2}×) |",
                                group(r.stats.tests.total),
                                r.stats.tests.total as f64 / b.stats.tests.total.max(1) as f64
                            );
                        }
                        None => md.push_str(" – |"),
                    }
                }
                let _ = writeln!(md);
            }
        }
        let _ = writeln!(md);
    }

    // 4. Throughput on the same rays.
    let _ = writeln!(md, "## Throughput on the same rays\n");
    let with_acc = args.reference.is_some();
    let _ = writeln!(
        md,
        "| scene | algorithm | configuration | traced rays | trace ms | Mrays/s | frame ms |{}",
        if with_acc { " hit agreement |" } else { "" }
    );
    let _ = writeln!(
        md,
        "|---|---|---|---:|---:|---:|---:|{}",
        if with_acc { "---:|" } else { "" }
    );
    for s in scenes {
        for r in &s.runs {
            let _ = write!(
                md,
                "| {} | {} | {} | {} | {:.1} | {} | {:.1} |",
                s.name,
                r.pipeline,
                r.config
                    .map_or("–".into(), |c| format!("{}×{}", c.subdivision, c.depth)),
                group(r.stats.traced_rays),
                trace_ms(&r.stats),
                sig3(mrays(&r.stats)),
                r.stats.time_ms("total"),
            );
            if with_acc {
                let a = r.stats.accuracy.as_ref().map_or(1.0, |a| a.hit_agreement());
                let _ = write!(md, " {a:.6} |");
            }
            let _ = writeln!(md);
        }
    }
    let _ = writeln!(md);

    // 5. Rendering time (tables 4.25-4.27) for the first configuration.
    if let Some(&c) = configs.first() {
        let _ = writeln!(md, "## Rendering time (tables 4.25-4.27), {}\n", c.label());
        for s in scenes {
            let runs: Vec<&Run> = pipelines.iter().filter_map(|p| s.find(p, c)).collect();
            if runs.is_empty() {
                continue;
            }
            let _ = write!(md, "| {} |", s.name.to_uppercase());
            for r in &runs {
                let _ = write!(
                    md,
                    " {} ({:.0} ms per frame) | relative |",
                    r.pipeline,
                    r.stats.time_ms("total")
                );
            }
            let _ = writeln!(md);
            let _ = writeln!(md, "|---|{}", "---:|---:|".repeat(runs.len()));
            for key in STAGE_TIMINGS {
                if !runs.iter().any(|r| r.stats.timings_ms.contains_key(key)) {
                    continue;
                }
                let _ = write!(md, "| {} |", key.replace('_', " ").to_uppercase());
                for r in &runs {
                    match r.stats.timings_ms.get(key) {
                        Some(&ms) => {
                            let _ =
                                write!(md, " {ms:.2} | {} |", pct(ms, r.stats.time_ms("total")));
                        }
                        None => md.push_str(" – | – |"),
                    }
                }
                let _ = writeln!(md);
            }
            let _ = writeln!(md);
        }
    }
    md
}

fn config_cols(r: &Run) -> String {
    match r.config {
        Some(c) => format!("{},{}", c.subdivision, c.depth),
        None => ",".into(),
    }
}

fn levels_csv(scenes: &[SceneRuns]) -> String {
    let mut out = String::from(
        "scene,pipeline,subdivision,depth,ray_kind,level,level_name,tests,hits,misses\n",
    );
    for s in scenes {
        for r in &s.runs {
            let mut levels = r.stats.levels.clone();
            levels.extend(
                r.stats
                    .mesh_culling
                    .keys()
                    .filter_map(|k| level_of(&r.stats, k, MESHES)),
            );
            levels.sort_by(|a, b| a.ray_kind.cmp(&b.ray_kind).then(b.level.cmp(&a.level)));
            for l in levels {
                let _ = writeln!(
                    out,
                    "{},{},{},{},{},{},{},{},{}",
                    s.name,
                    r.pipeline,
                    config_cols(r),
                    l.ray_kind,
                    if l.level == MESHES {
                        String::new()
                    } else {
                        l.level.to_string()
                    },
                    level_name(l.level),
                    l.tests,
                    l.hits,
                    l.misses
                );
            }
        }
    }
    out
}

fn totals_csv(scenes: &[SceneRuns]) -> String {
    let mut out = String::from(
        "scene,pipeline,subdivision,depth,triangles,width,height,rays_shadow,rays_reflection,\
         rays_refraction,traced_rays,bounds_tests,ray_triangle_tests,total_tests,brute_force_tests,\
         fraction_of_brute_force,tests_per_ray,trace_ms,mrays_per_s,frame_ms,\
         peak_candidate_bytes,hit_agreement\n",
    );
    for s in scenes {
        for r in &s.runs {
            let st = &r.stats;
            let t = &st.tests;
            let _ = writeln!(
                out,
                "{},{},{},{},{},{},{},{},{},{},{},{},{},{},{:.9},{:.3},{:.3},{:.4},{:.3},{},{}",
                s.name,
                r.pipeline,
                config_cols(r),
                s.triangles,
                s.width,
                s.height,
                st.rays.shadow,
                st.rays.reflection,
                st.rays.refraction,
                st.traced_rays,
                t.bounds,
                t.ray_triangle,
                t.total,
                t.brute_force,
                if t.brute_force > 0 {
                    t.total as f64 / t.brute_force as f64
                } else {
                    0.0
                },
                per_ray(st),
                trace_ms(st),
                mrays(st),
                st.time_ms("total"),
                st.peak_candidate_bytes,
                st.accuracy
                    .as_ref()
                    .map_or(String::new(), |a| format!("{:.9}", a.hit_agreement())),
            );
        }
    }
    out
}

fn times_csv(scenes: &[SceneRuns]) -> String {
    let mut out = String::from("scene,pipeline,subdivision,depth,stage,ms,fraction_of_total\n");
    for s in scenes {
        for r in &s.runs {
            let total = r.stats.time_ms("total");
            for key in STAGE_TIMINGS.iter().copied().chain(["total"]) {
                if let Some(&ms) = r.stats.timings_ms.get(key) {
                    let _ = writeln!(
                        out,
                        "{},{},{},{key},{ms:.4},{:.6}",
                        s.name,
                        r.pipeline,
                        config_cols(r),
                        if total > 0.0 { ms / total } else { 0.0 }
                    );
                }
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn level_names_and_median() {
        assert_eq!(level_name(0), "final");
        assert_eq!(level_name(1), "level 1");
        assert_eq!(level_name(MESHES), "meshes");
        assert_eq!(median(vec![3.0, 1.0, 2.0]), 2.0);
        assert_eq!(median(vec![4.0, 1.0, 2.0, 3.0]), 2.5);
        assert_eq!(median(vec![]), 0.0);
        assert_eq!(sig3(0.004217), "0.00422");
        assert_eq!(sig3(7.153), "7.15");
        assert_eq!(sig3(123.4), "123");
    }
}
