//! `crsh stress`: the stability suite (issue 5). Every procedural case of
//! `crsh_scene::stress::cases` runs under every pipeline × `intersect.test` × `raygen.offset`
//! (`crsh_cpu::stress`), and the command prints a Markdown table (false misses, false hits,
//! wrong nearest hits, self-intersections and escapes, each as a count and a rate, plus time)
//! and a summary of which method fails where, with the tests (bounding + ray-triangle) per traced
//! ray of each row, so an acceleration structure's cost on a case shows (seed 002's teapot in a
//! stadium: `--cases stadium --pipelines grid,bvh,crsh`); `--out DIR` also writes `stress.csv`,
//! `stress.md` and `stress.json`.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::PathBuf;

use clap::Args;
use crsh_cpu::stress::{
    intersect_tests, offset_policies, run_suite, variants, StressOutcome, StressRow, Variant,
};
use crsh_scene::stress::StressCase;
use serde::Serialize;

use crate::args::MAX_THREADS;
use crate::error::{CliError, CliResult};
use crate::render::{configure_threads, stage_error};
use crsh::Registries;

/// Arguments of `crsh stress`.
#[derive(Debug, Args)]
pub struct StressArgs {
    /// Pipelines (presets) to run.
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "brute,bvh,crsh,rah",
        value_name = "PIPELINE"
    )]
    pub pipelines: Vec<String>,

    /// `intersect.test` choices to run (default: every choice the catalogue offers).
    #[arg(long, value_delimiter = ',', value_name = "TEST")]
    pub tests: Option<Vec<String>>,

    /// `raygen.offset` choices to run on the frame cases (default: every choice offered).
    #[arg(long, value_delimiter = ',', value_name = "OFFSET")]
    pub offsets: Option<Vec<String>>,

    /// Only the cases whose name contains this text (e.g. `closed/`, `acne`).
    #[arg(long, value_name = "SUBSTRING")]
    pub cases: Option<String>,

    /// Also write stress.csv, stress.md and stress.json into this directory (created if
    /// missing).
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,

    /// Size of the worker pool (default: rayon's); the counts do not depend on it.
    #[arg(long, value_parser = clap::value_parser!(u64).range(1..=MAX_THREADS as u64))]
    pub threads: Option<u64>,
}

/// A choice list: the flag's values checked against the catalogue's choices, or all of them.
fn pick(
    flag: &str,
    key: &str,
    given: &Option<Vec<String>>,
    offered: Vec<String>,
) -> CliResult<Vec<String>> {
    let Some(given) = given else {
        return Ok(offered);
    };
    if offered.is_empty() {
        return Err(CliError::usage(format!(
            "{flag}: this build has no `{key}` parameter (see `crsh pipelines`)"
        )));
    }
    for g in given {
        if !offered.contains(g) {
            return Err(CliError::usage(format!(
                "{flag}: unknown {key} `{g}` (choices: {})",
                offered.join(", ")
            )));
        }
    }
    Ok(given.clone())
}

/// Runs the command.
pub fn run(args: &StressArgs, registries: &Registries) -> CliResult<()> {
    let registry = &registries.cpu;
    for p in &args.pipelines {
        if registry.preset(p).is_none() {
            return Err(CliError::usage(format!(
                "--pipelines: unknown pipeline `{p}` (presets: {})",
                registry
                    .presets()
                    .iter()
                    .map(|p| p.name.as_str())
                    .collect::<Vec<_>>()
                    .join(", ")
            )));
        }
    }
    let tests = pick(
        "--tests",
        "intersect.test",
        &args.tests,
        intersect_tests(registry),
    )?;
    let offsets = pick(
        "--offsets",
        "raygen.offset",
        &args.offsets,
        offset_policies(registry),
    )?;
    let mut cases = crsh_scene::stress::cases();
    if let Some(filter) = &args.cases {
        cases.retain(|c| c.name.contains(filter.as_str()));
        if cases.is_empty() {
            let names: Vec<String> = crsh_scene::stress::cases()
                .into_iter()
                .map(|c| c.name)
                .collect();
            return Err(CliError::usage(format!(
                "--cases {filter}: no case matches (cases: {})",
                names.join(", ")
            )));
        }
    }
    if let Some(dir) = &args.out {
        if dir.exists() && !dir.is_dir() {
            return Err(CliError::usage(format!(
                "--out {}: not a directory",
                dir.display()
            )));
        }
    }
    let threads = configure_threads(args.threads)?;
    let vs = variants(&args.pipelines, &tests, &offsets);
    let rows = run_suite(registry, &cases, &vs, &mut |i, n, name| {
        if std::io::IsTerminal::is_terminal(&std::io::stderr()) {
            eprint!("\r[{}/{n}] {name:<40}", i + 1);
        }
    })
    .map_err(|e| stage_error(e, "stress"))?;
    if std::io::IsTerminal::is_terminal(&std::io::stderr()) {
        eprint!("\r{:60}\r", "");
    }
    let md = markdown(&cases, &rows, threads);
    crate::output::print_stdout(&md)?;
    if let Some(dir) = &args.out {
        std::fs::create_dir_all(dir)
            .map_err(|e| CliError::runtime(format!("--out {}: {e}", dir.display())))?;
        let write = |name: &str, text: String| crate::output::write_text(&dir.join(name), &text);
        write("stress.md", md.clone())?;
        write("stress.csv", csv(&cases, &rows))?;
        let json = serde_json::to_string_pretty(&JsonReport {
            threads,
            cases: cases
                .iter()
                .map(|c| JsonCase {
                    name: &c.name,
                    family: c.family,
                    about: &c.about,
                })
                .collect(),
            rows: &rows,
            summary: summary(&rows)
                .into_iter()
                .map(|(v, o)| JsonSummary {
                    variant: v,
                    totals: o,
                })
                .collect(),
        })
        .map_err(|e| CliError::runtime(format!("stress.json: {e}")))?;
        write("stress.json", json)?;
        println!("wrote {}", dir.join("stress.{csv,md,json}").display());
    }
    let panics = rows.iter().filter(|r| r.outcome.panicked).count();
    if panics > 0 {
        return Err(CliError::runtime(format!(
            "{panics} rows panicked (status column): a stage has a bug"
        )));
    }
    Ok(())
}

#[derive(Serialize)]
struct JsonCase<'a> {
    name: &'a str,
    family: &'a str,
    about: &'a str,
}

#[derive(Serialize)]
struct JsonSummary {
    variant: Variant,
    totals: StressOutcome,
}

#[derive(Serialize)]
struct JsonReport<'a> {
    threads: usize,
    cases: Vec<JsonCase<'a>>,
    rows: &'a [StressRow],
    summary: Vec<JsonSummary>,
}

fn shown(v: &Option<String>) -> &str {
    v.as_deref().unwrap_or("default")
}

/// The offset column: `-` for ray probes (no ray generator involved).
fn offset_cell(r: &StressRow, frame: bool) -> String {
    if frame {
        shown(&r.variant.offset).to_string()
    } else {
        "-".into()
    }
}

fn status(o: &StressOutcome) -> String {
    match (&o.error, o.panicked) {
        (_, true) => format!("PANIC: {}", o.error.as_deref().unwrap_or("")),
        (Some(e), false) if e.chars().count() > 120 => {
            format!("error: {}…", e.chars().take(120).collect::<String>())
        }
        (Some(e), false) => format!("error: {e}"),
        (None, false) if o.failures() == 0 => "ok".into(),
        (None, false) => "wrong".into(),
    }
}

fn pct(o: &StressOutcome, count: u64) -> String {
    format!("{:.4}%", 100.0 * o.rate(count))
}

/// Totals per pipeline × test × offset; ray probes are counted under offset `None` (they run
/// once, whatever the offset), so every row is counted once.
fn summary(rows: &[StressRow]) -> BTreeMap<Variant, StressOutcome> {
    let mut out: BTreeMap<Variant, StressOutcome> = BTreeMap::new();
    for r in rows {
        out.entry(r.variant.clone())
            .or_default()
            .accumulate(&r.outcome);
    }
    out
}

fn md_escape(s: &str) -> String {
    s.replace('|', "\\|").replace('\n', " ")
}

fn markdown(cases: &[StressCase], rows: &[StressRow], threads: usize) -> String {
    let frame = |name: &str| cases.iter().any(|c| c.name == name && c.probe.is_frame());
    let mut s = String::new();
    let _ =
        writeln!(
        s,
        "# crsh stress\n\n{} cases × {} configurations = {} rows, CPU backend, {threads} threads. \
         Rates are per traced ray; `escapes` are misses of rays that had to hit (closed meshes, \
         shared edges and vertices), `false miss` the other misses of rays the truth says hit; \
         offset `-`: explicit rays, no ray generator involved; tests/ray: bounding (BVH nodes, \
         hierarchy nodes, grid cells) plus ray-triangle tests per traced ray; time: tracing only.\n",
        cases.len(),
        rows.iter().map(|r| &r.variant).collect::<std::collections::BTreeSet<_>>().len(),
        rows.len()
    );
    s.push_str(
        "| case | pipeline | test | offset | rays | tests/ray | false miss | rate | false hit | rate | wrong nearest | rate | self-int. | rate | escapes | rate | ms | status |\n\
         |---|---|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|\n",
    );
    for r in rows {
        let o = &r.outcome;
        let _ = writeln!(
            s,
            "| {} | {} | {} | {} | {} | {:.1} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {:.2} | {} |",
            r.case,
            r.variant.pipeline,
            shown(&r.variant.test),
            offset_cell(r, frame(&r.case)),
            o.rays,
            o.tests_per_ray(),
            o.false_misses,
            pct(o, o.false_misses),
            o.false_hits,
            pct(o, o.false_hits),
            o.wrong_nearest,
            pct(o, o.wrong_nearest),
            o.self_intersections,
            pct(o, o.self_intersections),
            o.escapes,
            pct(o, o.escapes),
            o.time_ms,
            md_escape(&status(o)),
        );
    }
    s.push_str(
        "\n## Summary per pipeline × test × offset\n\n\
         | pipeline | test | offset | rows | rays | tests/ray | false miss | false hit | wrong nearest | self-int. | escapes | errors | panics | ms |\n\
         |---|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n",
    );
    for (v, o) in summary(rows) {
        let mine: Vec<&StressRow> = rows.iter().filter(|r| r.variant == v).collect();
        let of = |_: &Variant| mine.iter().copied();
        let _ = writeln!(
            s,
            "| {} | {} | {} | {} | {} | {:.1} | {} | {} | {} | {} | {} | {} | {} | {:.1} |",
            v.pipeline,
            shown(&v.test),
            if v.offset.is_none() && of(&v).all(|r| !frame(&r.case)) {
                "-".to_string()
            } else {
                shown(&v.offset).to_string()
            },
            of(&v).count(),
            o.rays,
            o.tests_per_ray(),
            o.false_misses,
            o.false_hits,
            o.wrong_nearest,
            o.self_intersections,
            o.escapes,
            of(&v).filter(|r| r.outcome.error.is_some()).count(),
            of(&v).filter(|r| r.outcome.panicked).count(),
            o.time_ms,
        );
    }
    s.push_str("\n## Where each test and offset fails\n\n");
    // Per (test, offset): the failing cases in suite order, each with its pipelines.
    let mut wrong: BTreeMap<(String, String), Vec<CasePipelines>> = BTreeMap::new();
    for r in rows
        .iter()
        .filter(|r| r.outcome.failures() > 0 || r.outcome.panicked)
    {
        let key = (
            shown(&r.variant.test).to_string(),
            offset_cell(r, frame(&r.case)),
        );
        let list = wrong.entry(key).or_default();
        match list.iter_mut().find(|(c, _)| *c == r.case) {
            Some((_, pipelines)) if !pipelines.contains(&r.variant.pipeline) => {
                pipelines.push(r.variant.pipeline.clone())
            }
            Some(_) => {}
            None => list.push((r.case.clone(), vec![r.variant.pipeline.clone()])),
        }
    }
    if wrong.is_empty() {
        s.push_str("No wrong answers anywhere.\n");
    }
    for ((test, offset), list) in wrong {
        let items: Vec<String> = list
            .into_iter()
            .map(|(case, p)| format!("{case} ({})", p.join(", ")))
            .collect();
        let _ = writeln!(
            s,
            "- test `{test}`, offset `{offset}`: {}",
            items.join("; ")
        );
    }
    s
}

/// A case name and the pipelines that got it wrong.
type CasePipelines = (String, Vec<String>);

fn csv_field(s: &str) -> String {
    if s.contains([',', '"', '\n']) {
        format!("\"{}\"", s.replace('"', "\"\"").replace('\n', " "))
    } else {
        s.to_string()
    }
}

fn csv(cases: &[StressCase], rows: &[StressRow]) -> String {
    let frame = |name: &str| cases.iter().any(|c| c.name == name && c.probe.is_frame());
    let mut s = String::from(
        "case,family,pipeline,test,offset,rays,bounds_tests,triangle_tests,tests_per_ray,false_misses,false_miss_rate,false_hits,false_hit_rate,\
         wrong_nearest,wrong_nearest_rate,self_intersections,self_intersection_rate,escapes,escape_rate,\
         time_ms,panicked,error\n",
    );
    for r in rows {
        let o = &r.outcome;
        let _ = writeln!(
            s,
            "{},{},{},{},{},{},{},{},{:.4},{},{:e},{},{:e},{},{:e},{},{:e},{},{:e},{:.4},{},{}",
            csv_field(&r.case),
            r.family,
            r.variant.pipeline,
            shown(&r.variant.test),
            offset_cell(r, frame(&r.case)),
            o.rays,
            o.bounds_tests,
            o.triangle_tests,
            o.tests_per_ray(),
            o.false_misses,
            o.rate(o.false_misses),
            o.false_hits,
            o.rate(o.false_hits),
            o.wrong_nearest,
            o.rate(o.wrong_nearest),
            o.self_intersections,
            o.rate(o.self_intersections),
            o.escapes,
            o.rate(o.escapes),
            o.time_ms,
            o.panicked,
            csv_field(o.error.as_deref().unwrap_or("")),
        );
    }
    s
}
