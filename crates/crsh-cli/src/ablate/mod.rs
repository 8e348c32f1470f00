//! `crsh ablate`: runs a matrix of scenes × pipelines × parameters × backends, measures each
//! cell (warm-up, timed repeats, counters, accuracy against a reference), and writes
//! `results.csv`, `results.json`, charts (PNG and SVG) and `report.html` into a directory.
//! `crsh ablate --compare OLD.json NEW.json` prints per-cell ratios of two runs.
//!
//! - [`plan`] — the plan (TOML or the command line's quick form) and its expansion into cells;
//! - [`run`] — running the cells;
//! - [`results`] — what was measured, `results.json` and `results.csv`;
//! - [`charts`] — the three charts per scene;
//! - [`html`] — `report.html`;
//! - [`headline`] — the per-scene headline numbers printed at the end;
//! - [`compare`] — `--compare`.

pub mod charts;
pub mod compare;
pub mod headline;
pub mod html;
pub mod plan;
pub mod results;
pub mod run;

use std::path::{Path, PathBuf};
use std::time::Instant;

use clap::Args;

use crate::error::{CliError, CliResult};
use plan::{split_list, Plan, QuickPlan};
use results::{CellResult, Machine, Results};

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
    #[arg(long, num_args = 2, value_names = ["OLD.json", "NEW.json"], conflicts_with_all = ["plan", "out", "scenes", "pipelines", "set"])]
    pub compare: Option<Vec<PathBuf>>,
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
        Some(m) if c.ok() => {
            let t = m.timings_ms.get("total").copied().unwrap_or_default();
            let acc = m
                .accuracy
                .as_ref()
                .map(|a| format!(", agreement {:.6}", a.hit_agreement))
                .unwrap_or_default();
            format!(
                "{head}: {:.1} ms (min {:.1}, max {:.1}), {:.1} tests/ray, {:.3} Mrays/s{acc}{}",
                t.median,
                t.min,
                t.max,
                m.tests.per_ray,
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

/// Runs `crsh ablate`.
pub fn run(args: &AblateArgs) -> CliResult<()> {
    if let Some(files) = &args.compare {
        return match files.as_slice() {
            [old, new] => compare::run(old, new),
            _ => Err(CliError::usage(
                "--compare takes two files: OLD.json NEW.json",
            )),
        };
    }
    let out = args
        .out
        .as_ref()
        .ok_or_else(|| CliError::usage("--out DIR is required (or --compare OLD.json NEW.json)"))?;
    let (plan, plan_text, plan_source, plan_dir) = plan_of(args)?;
    let catalogue = crsh_cpu::catalogue();
    let cells = plan::expand(&plan, plan_dir.as_deref(), &catalogue)?;
    let charts_dir = prepare_out(out)?;

    let started = Instant::now();
    let threads = plan.threads.unwrap_or_else(rayon::current_num_threads);
    let machine = Machine::gather(threads, cells.iter().any(|c| c.backend == "wgpu"));
    let n = cells.len();
    let quiet = args.quiet;
    let results_cells = run::run_cells(&plan, &cells, quiet, &mut |c, bar| {
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
        machine,
        wall_s: 0.0,
        cells: results_cells,
    };
    let charts = charts::write_all(&results, &charts_dir)
        .map_err(|e| CliError::runtime(format!("drawing charts: {e}")))?;
    results.wall_s = started.elapsed().as_secs_f64();
    let w = |name: &str, text: &str| crate::output::write_text(&out.join(name), text);
    w("results.json", &(results.to_json() + "\n"))?;
    w("results.csv", &results.to_csv())?;
    w("report.html", &html::report(&results, &charts, &plan_text))?;

    let ok = results.cells.iter().filter(|c| c.ok()).count();
    let summary = format!(
        "{}{} cells: {ok} ran, {} failed, in {:.1} s\nwrote     {}/results.csv, results.json, report.html and {} charts in charts/\n",
        headline::headline(&results),
        results.cells.len(),
        results.cells.len() - ok,
        results.wall_s,
        out.display(),
        charts.iter().map(|(_, f)| f.len()).sum::<usize>(),
    );
    crate::output::print_stdout(&summary)?;
    if ok == 0 {
        return Err(CliError::runtime(format!(
            "every cell failed (first reason: {})",
            results.cells.first().map_or("", |c| c.reason.as_str())
        )));
    }
    Ok(())
}
