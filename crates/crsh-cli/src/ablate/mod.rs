//! `crsh ablate`: runs a matrix of scenes × pipelines × parameters × backends, measures each
//! cell (warm-up, timed repeats, counters, accuracy against a reference), and writes
//! `results.csv`, `results.json`, charts (PNG and SVG) and `report.html` into a directory.
//! `--shard K/N` runs one share of the cells (for N processes on any scheduler), `--merge`
//! joins the shards' directories, `--redraw` rebuilds charts and report from a `results.json`,
//! and `--compare OLD.json NEW.json` prints per-cell ratios of two runs.
//!
//! With `frames = N` in the plan (or `--frames N`) every cell renders frames `0..N` of its
//! scene loaded as an animated scene, timing each frame's update and structure rebuild or
//! refit with its render: `results.json` carries the per-frame rows and their totals,
//! `results.csv` the mean frame, update, structure and render times, `frames.csv` one line
//! per cell and frame, and each scene gets a `SCENE-frames` chart (mean frame time split into
//! update and rebuild, then render, per pipeline cell).
//!
//! With `baseline = { KEY = VALUE }` in the plan every cell is also set against the cell
//! identical but for `KEY = VALUE` ([`baseline`]): `baseline.csv`, `baseline.md` (seed 001
//! tables 2-4's layout) and a table in the report. `--dry-run` expands and checks a plan and
//! prints its cells without running them.
//!
//! - [`plan`] — the plan (TOML or the command line's quick form) and its expansion into cells;
//! - [`run`] — running the cells;
//! - [`results`] — what was measured, `results.json` and `results.csv`, shards;
//! - [`merge`] — `--merge`;
//! - [`charts`] — the charts per scene;
//! - [`html`] — `report.html`;
//! - [`headline`] — the per-scene headline numbers printed at the end;
//! - [`compare`] — `--compare`;
//! - [`baseline`] — the cells against their baseline cells.
//! - [`anchors`] — every cell against the fastest Embree cell on the same rays.

pub mod anchors;
pub mod baseline;
pub mod charts;
pub mod compare;
pub mod headline;
pub mod html;
pub mod merge;
pub mod plan;
pub mod results;
pub mod run;

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::time::Instant;

use clap::Args;
use crsh::Registries;

use crate::error::{CliError, CliResult};
use crate::output::{canonical, RunFiles};
use plan::{split_list, Cell, Plan, QuickPlan};
use results::{CellResult, Expansion, Machine, Results, ShardInfo};

/// `crsh ablate`.
#[derive(Debug, Args)]
#[command(
    after_help = "Examples:\n  crsh ablate --plan plans/quick.toml --out ablate-quick\n  crsh ablate --scenes cornell-mirrors,office-boxes --pipelines crsh,rah,bvh \\\n      --set hierarchy.subdivision=8,16 --set hierarchy.depth=2,3 --width 128 --out ablate-cli\n  crsh ablate --compare before/results.json after/results.json"
)]
pub struct AblateArgs {
    /// The plan file (TOML; see README, "crsh ablate"). Without it, the quick form below
    /// describes the plan.
    #[arg(long, value_name = "PLAN.toml", conflicts_with_all = ["scenes", "pipelines", "set", "backends", "width", "height", "depth"])]
    pub plan: Option<PathBuf>,

    /// Output directory (created if missing): results.csv, results.json, charts/, report.html.
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,

    /// Quick form: scenes, comma-separated (built-in names, manifests, OBJ files)
    /// [default: cornell-mirrors].
    #[arg(long, value_name = "A,B,...")]
    pub scenes: Option<String>,

    /// Quick form: pipelines, comma-separated presets or pipeline files [default: crsh,rah,bvh].
    #[arg(long, value_name = "A,B,...")]
    pub pipelines: Option<String>,

    /// Quick form: a swept setting, `KEY=V1,V2,...` (repeatable); every combination is a cell.
    /// Keys of a stage slot a pipeline leaves empty do not apply to it (a key that applies to
    /// no pipeline is an error).
    #[arg(long = "set", value_name = "KEY=V1,V2")]
    pub set: Vec<String>,

    /// Quick form: backends, comma-separated (`cpu`, `wgpu`) [default: cpu].
    #[arg(long, value_name = "A,B")]
    pub backends: Option<String>,

    /// Quick form: image widths, comma-separated [default: 256].
    #[arg(long, value_name = "W,...")]
    pub width: Option<String>,

    /// Quick form: image height [default: width / the camera's aspect, else square].
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..=crsh_core::pipeline::MAX_IMAGE_SIDE as i64))]
    pub height: Option<u32>,

    /// Quick form: bounce depths, comma-separated [default: 3].
    #[arg(long, value_name = "D,...")]
    pub depth: Option<String>,

    /// Frames of an animated scene per cell, 1..=100000 (overrides the plan's `frames`): each
    /// cell times sequences of frames, every frame's update and rebuild with its render
    /// [default: one static frame].
    #[arg(long, value_name = "N")]
    pub frames: Option<u32>,

    /// Timed runs per cell (overrides the plan's `repeat`) [default: 5].
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..=plan::MAX_REPEAT as i64))]
    pub repeat: Option<u32>,

    /// Reference intersector for accuracy, or `none` (overrides the plan's) [default: bvh].
    #[arg(long, value_name = "INTERSECTOR|none")]
    pub reference: Option<String>,

    /// Worker threads (overrides the plan's) [default: rayon's choice].
    #[arg(long, value_parser = clap::value_parser!(u64).range(1..=crate::args::MAX_THREADS as u64))]
    pub threads: Option<u64>,

    /// No progress bar and no per-cell lines (the closing summary is still printed).
    #[arg(long, short)]
    pub quiet: bool,

    /// Compare two results.json files: per-cell ratios new/old of time, tests and hit agreement.
    #[arg(long, num_args = 2, value_names = ["OLD.json", "NEW.json"], conflicts_with_all = ["plan", "out", "scenes", "pipelines", "set", "shard", "merge", "redraw", "frames"])]
    pub compare: Option<Vec<PathBuf>>,

    /// Run only shard K of N: the cells whose index i (in the plan's expansion) has
    /// i mod N = K-1. Start N processes with K = 1..N (Slurm array jobs, Kubernetes indexed
    /// Jobs, GNU parallel, ...), each with its own --out, then --merge their directories.
    #[arg(long, value_name = "K/N")]
    pub shard: Option<String>,

    /// Merge the directories of the shards of one run (`--shard K/N`) into --out: one
    /// results.csv / results.json, charts and report. Shards of different plans, expansions,
    /// revisions or versions, and missing or repeated shards, are refused.
    #[arg(long, num_args = 1.., value_name = "DIR", conflicts_with_all = ["plan", "scenes", "pipelines", "set", "backends", "width", "height", "depth", "repeat", "reference", "threads", "shard", "redraw", "frames"])]
    pub merge: Option<Vec<PathBuf>>,

    /// Expand and check the plan (pipelines, grids, depths, baseline) and print its cells per
    /// scene and pipeline, without running or writing anything (no --out needed).
    #[arg(long, conflicts_with_all = ["compare", "merge", "redraw", "shard"])]
    pub dry_run: bool,

    /// Rebuild the charts, results.csv and report.html from DIR/results.json (into --out, by
    /// default DIR itself), without running anything.
    #[arg(long, value_name = "DIR", conflicts_with_all = ["plan", "scenes", "pipelines", "set", "backends", "width", "height", "depth", "repeat", "reference", "threads", "shard", "frames"])]
    pub redraw: Option<PathBuf>,
}

fn parse_u32_list(s: &str, what: &str) -> CliResult<Vec<u32>> {
    split_list(s)
        .iter()
        .map(|v| {
            v.parse::<u32>()
                .map_err(|_| CliError::usage(format!("--{what} {s}: `{v}` is not a whole number")))
        })
        .collect()
}

/// The plan, its text (as shown in the report) and where it came from.
fn plan_of(args: &AblateArgs) -> CliResult<(Plan, String, String, Option<PathBuf>)> {
    let (mut plan, text, source, dir) = match &args.plan {
        Some(path) => {
            let plan = plan::read_plan(path)?;
            let text = std::fs::read_to_string(path).unwrap_or_default();
            let dir = path
                .parent()
                .map(|p| {
                    if p.as_os_str().is_empty() {
                        PathBuf::from(".")
                    } else {
                        p.to_path_buf()
                    }
                })
                .unwrap_or_else(|| PathBuf::from("."));
            (plan, text, path.display().to_string(), Some(dir))
        }
        None => {
            let quick = QuickPlan {
                scenes: args.scenes.as_deref().map(split_list).unwrap_or_default(),
                pipelines: args
                    .pipelines
                    .as_deref()
                    .map(split_list)
                    .unwrap_or_default(),
                sets: args.set.clone(),
                backends: args.backends.as_deref().map(split_list).unwrap_or_default(),
                width: args
                    .width
                    .as_deref()
                    .map(|w| parse_u32_list(w, "width"))
                    .transpose()?
                    .unwrap_or_default(),
                height: args.height,
                depth: args
                    .depth
                    .as_deref()
                    .map(|d| parse_u32_list(d, "depth"))
                    .transpose()?
                    .unwrap_or_default(),
                repeat: None,
                reference: None,
                threads: None,
                frames: None,
            };
            let plan = quick.into_plan()?;
            (plan, String::new(), "the command line".to_string(), None)
        }
    };
    if let Some(r) = args.repeat {
        plan.repeat = r;
    }
    if let Some(r) = &args.reference {
        plan.reference = r.clone();
    }
    if let Some(t) = args.threads {
        plan.threads = Some(t as usize);
    }
    if let Some(f) = args.frames {
        plan.frames = Some(f);
    }
    let text = if text.is_empty() {
        toml::to_string(&plan).unwrap_or_default()
    } else {
        text
    };
    Ok((plan, text, source, dir))
}

/// Prepares `DIR` and `DIR/charts`; an existing file in the way is a usage error.
fn prepare_out(out: &Path) -> CliResult<PathBuf> {
    if out.exists() && !out.is_dir() {
        return Err(CliError::usage(format!(
            "--out {}: exists and is not a directory",
            out.display()
        )));
    }
    let charts = out.join("charts");
    std::fs::create_dir_all(&charts)
        .map_err(|e| CliError::runtime(format!("creating {}: {e}", charts.display())))?;
    Ok(charts)
}

/// One line per finished cell.
fn cell_line(c: &CellResult, n: usize) -> String {
    let head = format!(
        "[{}/{n}] {} | {} | {}",
        c.index + 1,
        c.scene,
        c.label,
        c.backend
    );
    match &c.measures {
        Some(m) if c.ok() && m.frames.is_some() => {
            let t = &m.frames.as_ref().expect("checked").totals;
            let acc = t
                .min_hit_agreement
                .map(|a| format!(", agreement ≥ {a:.6} on {} frames", t.frames_checked))
                .unwrap_or_default();
            format!(
                "{head}: {} frames, {:.2} ms/frame (update {:.2}, structure {:.2}, render {:.2}), {} tests/ray{acc}{}",
                t.frames,
                t.mean_frame_ms,
                t.mean_update_ms,
                t.mean_structure_ms,
                t.mean_render_ms,
                m.tests.per_ray_text(),
                if m.counters_equal_across_repeats {
                    ""
                } else {
                    " (counters differ between repeats!)"
                }
            )
        }
        Some(m) if c.ok() => {
            let t = m.timings_ms.get("total").copied().unwrap_or_default();
            let acc = m
                .accuracy
                .as_ref()
                .map(|a| format!(", agreement {:.6}", a.hit_agreement))
                .unwrap_or_default();
            format!(
                "{head}: {:.1} ms (min {:.1}, max {:.1}), {} tests/ray, {:.3} Mrays/s{acc}{}",
                t.median,
                t.min,
                t.max,
                m.tests.per_ray_text(),
                m.mrays_per_s.get("overall").copied().unwrap_or(0.0),
                if m.counters_equal_across_repeats {
                    ""
                } else {
                    " (counters differ between repeats!)"
                }
            )
        }
        _ => format!("{head}: FAILED: {}", c.reason),
    }
}

/// FNV-1a, 64 bits: a digest that is the same on every machine and build.
fn fnv1a(bytes: impl IntoIterator<Item = u8>, mut h: u64) -> u64 {
    for b in bytes {
        h ^= b as u64;
        h = h.wrapping_mul(0x0000_0100_0000_01b3);
    }
    h
}

/// What `cells` (a whole expansion) are, for checking that shards belong together.
fn expansion_of(cells: &[Cell]) -> Expansion {
    let mut h = 0xcbf2_9ce4_8422_2325u64;
    for c in cells {
        let line = serde_json::json!([
            c.index,
            c.scene_spec,
            c.label(),
            c.backend,
            c.width,
            c.height,
            c.depth,
            c.config,
            c.reference,
            c.unsupported,
        ])
        .to_string();
        h = fnv1a(line.bytes().chain([b'\n']), h);
    }
    Expansion {
        cells: cells.len(),
        digest: format!("{h:016x}"),
    }
}

/// The files [`write_outputs`] writes (or removes, when stale) in the output directory,
/// besides `charts/`.
const OUT_FILES: [&str; 6] = [
    "results.json",
    "results.csv",
    "frames.csv",
    "baseline.csv",
    "baseline.md",
    "report.html",
];

/// Refuses an output directory `out` where writing the results (with `results.json` when
/// `write_json`) would write over an input in `files`.
fn check_outputs(mut files: RunFiles, out: &Path, write_json: bool) -> CliResult<()> {
    for name in OUT_FILES {
        if write_json || name != "results.json" {
            files.output(&out.join(name), "--out");
        }
    }
    files.output_dir(&out.join("charts"), "--out");
    files.check()
}

/// Writes `results.json`, `results.csv`, the charts and `report.html` of `results` into
/// `out` (created if missing), removing chart files of an earlier run that this one does not
/// draw. Returns the number of chart files.
fn write_outputs(results: &Results, out: &Path, write_json: bool) -> CliResult<usize> {
    let charts_dir = prepare_out(out)?;
    let charts = charts::write_all(results, &charts_dir)
        .map_err(|e| CliError::runtime(format!("drawing charts: {e}")))?;
    let drawn: BTreeSet<String> = charts
        .iter()
        .flat_map(|(_, files)| files.iter())
        .flat_map(|f| [format!("{}.png", f.stem), format!("{}.svg", f.stem)])
        .collect();
    remove_stale_charts(&charts_dir, &drawn)?;
    let w = |name: &str, text: &str| crate::output::write_text(&out.join(name), text);
    if write_json {
        w("results.json", &(results.to_json() + "\n"))?;
    }
    w("results.csv", &results.to_csv())?;
    // Files only some plans have: an earlier run's into the same directory would not match
    // this one, so where this run has none they go.
    let pairing = baseline::pair(results);
    for (name, text) in [
        ("frames.csv", results.frames_csv()),
        (
            "baseline.csv",
            pairing.as_ref().map(|p| baseline::to_csv(p, results)),
        ),
        (
            "baseline.md",
            pairing.as_ref().map(|p| baseline::to_markdown(p, results)),
        ),
    ] {
        let path = out.join(name);
        match text {
            Some(text) => w(name, &text)?,
            None if path.is_file() => std::fs::remove_file(&path).map_err(|e| {
                CliError::runtime(format!("removing stale {}: {e}", path.display()))
            })?,
            None => {}
        }
    }
    w("report.html", &html::report(results, &charts))?;
    Ok(drawn.len())
}

/// Removes the `.png` and `.svg` files in `dir` that are not in `keep` (charts of scenes or
/// axes an earlier run into the same directory drew and this one does not).
fn remove_stale_charts(dir: &Path, keep: &BTreeSet<String>) -> CliResult<()> {
    let entries = std::fs::read_dir(dir)
        .map_err(|e| CliError::runtime(format!("listing {}: {e}", dir.display())))?;
    for entry in entries.flatten() {
        let path = entry.path();
        let name = entry.file_name().to_string_lossy().to_string();
        let chart = path.extension().is_some_and(|e| e == "png" || e == "svg");
        if chart && path.is_file() && !keep.contains(&name) {
            std::fs::remove_file(&path).map_err(|e| {
                CliError::runtime(format!("removing stale {}: {e}", path.display()))
            })?;
        }
    }
    Ok(())
}

/// The closing summary: headline, cell counts, what was written.
fn summary(results: &Results, out: &Path, charts: usize) -> String {
    let ok = results.cells.iter().filter(|c| c.ok()).count();
    let scope = match (&results.shard, results.merged_from.len()) {
        (Some(s), _) => format!(" (shard {s} of {} cells)", results.expansion.cells),
        (None, n) if n > 0 => format!(" (merged from {n} shards)"),
        _ => String::new(),
    };
    format!(
        "{}{} cells{scope}: {ok} ran, {} failed, in {:.1} s\nwrote     {}/results.csv, results.json, {}{}report.html and {charts} charts in charts/\n",
        headline::headline(results),
        results.cells.len(),
        results.cells.len() - ok,
        results.wall_s,
        out.display(),
        if results.has_frames() {
            "frames.csv, "
        } else {
            ""
        },
        if results.plan.baseline.is_empty() {
            ""
        } else {
            "baseline.csv, baseline.md, "
        },
    )
}

/// What `--dry-run` prints: the cells per scene (and why a scene's cells would fail) and per
/// pipeline (with their depths), and the baseline's pairing.
fn dry_run_text(plan: &Plan, source: &str, cells: &[Cell]) -> String {
    use std::fmt::Write as _;
    let mut out = format!(
        "plan {source}: {} cells, {} timed runs each (nothing run)\n",
        cells.len(),
        plan.repeat
    );
    if let Some(r) = plan.light_radius {
        let _ = writeln!(out, "light radius {r} (every light of every scene)");
    }
    let mut scenes: Vec<&str> = Vec::new();
    let mut labels: Vec<&str> = Vec::new();
    for c in cells {
        if !scenes.contains(&c.scene_spec.as_str()) {
            scenes.push(&c.scene_spec);
        }
        if !labels.contains(&c.pipeline.as_str()) {
            labels.push(&c.pipeline);
        }
    }
    for s in scenes {
        let of: Vec<&Cell> = cells.iter().filter(|c| c.scene_spec == s).collect();
        let unsupported = of.iter().filter(|c| c.unsupported.is_some()).count();
        let _ = write!(out, "scene {s}: {} cells", of.len());
        if let Some(Err(why)) = of.first().map(|c| &c.scene) {
            let _ = write!(out, " (would fail: {why})");
        }
        if unsupported > 0 {
            let _ = write!(out, " ({unsupported} a backend cannot run)");
        }
        out.push('\n');
    }
    for l in labels {
        let of: Vec<&Cell> = cells.iter().filter(|c| c.pipeline == l).collect();
        let mut depths: Vec<u32> = of.iter().map(|c| c.depth).collect();
        depths.sort_unstable();
        depths.dedup();
        let depths: Vec<String> = depths.iter().map(u32::to_string).collect();
        let _ = writeln!(
            out,
            "pipeline {l}: {} cells, depth {}",
            of.len(),
            depths.join(", ")
        );
    }
    if let Some((key, value)) = plan.baseline.iter().next() {
        let value = value.to_string();
        let sweeping = cells.iter().filter(|c| c.params.contains_key(key)).count();
        let base = cells
            .iter()
            .filter(|c| c.params.get(key) == Some(&value))
            .count();
        let _ = writeln!(
            out,
            "baseline {key} = {value}: {sweeping} cells set against {base} baseline cells"
        );
    }
    out
}

/// Runs `crsh ablate` with `registries` (plans resolve their pipelines and variants there).
pub fn run(args: &AblateArgs, registries: &Registries) -> CliResult<()> {
    if let Some(files) = &args.compare {
        return match files.as_slice() {
            [old, new] => compare::run(old, new),
            _ => Err(CliError::usage(
                "--compare takes two files: OLD.json NEW.json",
            )),
        };
    }
    if let Some(dirs) = &args.merge {
        let out = args
            .out
            .as_ref()
            .ok_or_else(|| CliError::usage("--merge needs --out DIR for the merged results"))?;
        let mut files = RunFiles::new();
        for d in dirs {
            files.input(&d.join("results.json"), "a shard's results.json");
        }
        check_outputs(files, out, true)?;
        let results = merge::merge(dirs)?;
        let charts = write_outputs(&results, out, true)?;
        return crate::output::print_stdout(&summary(&results, out, charts));
    }
    if let Some(dir) = &args.redraw {
        let results = merge::read_results(dir)?;
        let out = args.out.as_deref().unwrap_or(dir);
        let write_json = canonical(out) != canonical(dir);
        let mut files = RunFiles::new();
        files.input(&dir.join("results.json"), "the results.json redrawn");
        check_outputs(files, out, write_json)?;
        let charts = write_outputs(&results, out, write_json)?;
        return crate::output::print_stdout(&summary(&results, out, charts));
    }
    if args.dry_run {
        let (plan, _, source, dir) = plan_of(args)?;
        let cells = plan::expand(&plan, dir.as_deref(), registries)?;
        return crate::output::print_stdout(&dry_run_text(&plan, &source, &cells));
    }
    let out = args.out.as_ref().ok_or_else(|| {
        CliError::usage(
            "--out DIR is required (or --compare OLD.json NEW.json, --merge DIR..., --redraw DIR, --dry-run)",
        )
    })?;
    let shard = args
        .shard
        .as_deref()
        .map(ShardInfo::parse)
        .transpose()
        .map_err(CliError::usage)?;
    let (plan, plan_text, plan_source, plan_dir) = plan_of(args)?;
    let all_cells = plan::expand(&plan, plan_dir.as_deref(), registries)?;
    let expansion = expansion_of(&all_cells);
    let cells: Vec<&Cell> = all_cells
        .iter()
        .filter(|c| shard.is_none_or(|s| s.holds(c.index)))
        .collect();
    let mut files = RunFiles::new();
    if let Some(p) = &args.plan {
        files.input(p, "the plan");
    }
    for p in &plan.pipelines {
        if registries.preset(&p.pipeline).is_none() {
            files.input(Path::new(&p.pipeline), "a pipeline file of the plan");
            if let Some(d) = &plan_dir {
                files.input(&d.join(&p.pipeline), "a pipeline file of the plan");
            }
        }
    }
    let scenes: BTreeSet<&str> = all_cells
        .iter()
        .filter_map(|c| c.scene.as_deref().ok())
        .collect();
    for s in scenes {
        files.scene(s);
    }
    check_outputs(files, out, true)?;
    prepare_out(out)?;

    let started = Instant::now();
    let threads = plan.threads.unwrap_or_else(rayon::current_num_threads);
    let machine = Machine::gather(threads, cells.iter().any(|c| c.backend == "wgpu"));
    let n = all_cells.len();
    let quiet = args.quiet;
    let results_cells = run::run_cells(&plan, &cells, registries, quiet, &mut |c, bar| {
        if quiet {
            return;
        }
        let line = cell_line(c, n);
        if bar.is_hidden() {
            let _ = crate::output::print_stdout(&(line + "\n"));
        } else {
            bar.println(line);
        }
    });
    let title = plan.title.clone().unwrap_or_else(|| match &args.plan {
        Some(p) => format!(
            "crsh ablation: {}",
            p.file_stem().map_or("plan".into(), |s| s.to_string_lossy())
        ),
        None => "crsh ablation".to_string(),
    });
    let mut results = Results {
        version: env!("CARGO_PKG_VERSION").to_string(),
        title,
        plan_source,
        plan,
        plan_text,
        machine,
        wall_s: 0.0,
        expansion,
        shard,
        merged_from: Vec::new(),
        cells: results_cells,
    };
    results.wall_s = started.elapsed().as_secs_f64();
    let charts = write_outputs(&results, out, true)?;
    crate::output::print_stdout(&summary(&results, out, charts))?;
    let ok = results.cells.iter().filter(|c| c.ok()).count();
    if ok == 0 && !results.cells.is_empty() {
        return Err(CliError::runtime(format!(
            "every cell failed (first reason: {})",
            results.cells.first().map_or("", |c| c.reason.as_str())
        )));
    }
    Ok(())
}
