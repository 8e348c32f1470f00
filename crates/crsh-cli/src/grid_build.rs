//! `crsh grid-build`: seed 002's table 1 (§5.1, "time in milliseconds to rebuild the entire
//! grid structure") on this machine. For each triangle count, the random soup of
//! [`crsh_scene::random`] is built once, then its uniform grid (eq. 1 at the default density,
//! the five passes of §3.1) is rebuilt in a 1-thread rayon pool (serial) and in a pool of
//! `--threads` workers (parallel), median of `--repeats` timed runs after `--warmup` ones
//! ([`crsh_cpu::grid_timing::measure`]). It prints the table next to the paper's CPU and GPU
//! rows, then the per-pass split; `--json FILE` also writes every figure.

use std::fmt::Write as _;
use std::path::PathBuf;

use clap::Args;
use crsh_cpu::grid_timing::{measure, paper_ms, BuildMeasurement, PAPER_TRIANGLES};
use crsh_cpu::intersect::grid::DEFAULT_DENSITY;
use crsh_scene::Scene;
use serde::Serialize;

use crate::args::MAX_THREADS;
use crate::error::{CliError, CliResult};
use crate::output;

/// Largest `--sizes` entry: four times the paper's largest scene (the pairs, sort buffers and
/// the scene itself stay around 1 GiB).
pub const MAX_GRID_TRIANGLES: usize = 2_000_000;

/// Largest `--repeats` and `--warmup`.
pub const MAX_GRID_REPEATS: u64 = 100;

/// Arguments of `crsh grid-build`.
#[derive(Debug, Args)]
pub struct GridBuildArgs {
    /// Triangle counts (seed 002 table 1's by default), each in 1..=2000000.
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "5000,10000,50000,100000,200000,300000,400000,500000",
        value_name = "N"
    )]
    pub sizes: Vec<usize>,

    /// Timed rebuilds per size and pool (the median is printed).
    #[arg(long, default_value_t = 5,
          value_parser = clap::value_parser!(u64).range(1..=MAX_GRID_REPEATS))]
    pub repeats: u64,

    /// Untimed rebuilds before the timed ones, per size and pool.
    #[arg(long, default_value_t = 1,
          value_parser = clap::value_parser!(u64).range(0..=MAX_GRID_REPEATS))]
    pub warmup: u64,

    /// Worker threads of the parallel column (default: one per core).
    #[arg(long, value_parser = clap::value_parser!(u64).range(1..=MAX_THREADS as u64))]
    pub threads: Option<u64>,

    /// Seed of the random soups (the same seed and size give the same scene everywhere).
    #[arg(long, default_value_t = crsh_scene::random::DEFAULT_SEED)]
    pub seed: u64,

    /// Also write every figure (medians per pass, grid sizes, the paper's rows) as JSON.
    #[arg(long, value_name = "FILE")]
    pub json: Option<PathBuf>,
}

/// One size of the table.
#[derive(Debug, Serialize)]
struct Row {
    triangles: usize,
    cells: usize,
    dims: [u32; 3],
    pairs: usize,
    serial: BuildMeasurement,
    parallel: BuildMeasurement,
    /// The wgpu rebuild's median, once the GPU twin exists ([`wgpu_rebuild_ms`]).
    wgpu_ms: Option<f64>,
    paper_cpu_ms: Option<f64>,
    paper_gpu_ms: Option<f64>,
}

#[derive(Debug, Serialize)]
struct Report<'a> {
    source: &'static str,
    seed: u64,
    density: f64,
    repeats: u64,
    warmup: u64,
    cores: usize,
    rows: &'a [Row],
}

/// The wgpu column: the median time (ms) to rebuild the grid of `soup` at density `k` on the
/// wgpu backend (the five passes of `crsh_wgpu::intersect::grid`, the scene already on the
/// device, timed to the end of the device work), or `None` on a machine without an adapter.
fn wgpu_rebuild_ms(soup: &Scene, k: f64, warmup: u64, repeats: u64) -> CliResult<Option<f64>> {
    use crsh_core::Backend as _;
    let Ok(device) = crsh_wgpu::Wgpu::new() else {
        return Ok(None);
    };
    let gpu = crsh_wgpu::GpuScene::new(&device, &std::sync::Arc::new(soup.clone()))
        .map_err(|e| CliError::runtime(format!("uploading the triangles: {e}")))?;
    let mut times = Vec::new();
    for i in 0..warmup + repeats {
        let t0 = std::time::Instant::now();
        crsh_wgpu::intersect::grid::UniformGrid::build(&gpu, k)
            .and_then(|_| device.sync())
            .map_err(|e| CliError::runtime(format!("grid rebuild on wgpu: {e}")))?;
        if i >= warmup {
            times.push(t0.elapsed().as_secs_f64() * 1e3);
        }
    }
    times.sort_by(f64::total_cmp);
    Ok(times.get(times.len() / 2).copied())
}

fn check(args: &GridBuildArgs) -> CliResult<()> {
    if args.sizes.is_empty() {
        return Err(CliError::usage("--sizes: give at least one triangle count"));
    }
    for &n in &args.sizes {
        if n == 0 || n > MAX_GRID_TRIANGLES {
            return Err(CliError::usage(format!(
                "--sizes: {n} triangles is outside 1..={MAX_GRID_TRIANGLES}"
            )));
        }
    }
    if let Some(path) = &args.json {
        output::check_json_path(path, "--json")?;
    }
    Ok(())
}

/// Runs the command.
pub fn run(args: &GridBuildArgs) -> CliResult<()> {
    check(args)?;
    let k = DEFAULT_DENSITY;
    let parallel_threads = args.threads.unwrap_or(0) as usize;
    let tty = std::io::IsTerminal::is_terminal(&std::io::stderr());
    let mut rows = Vec::with_capacity(args.sizes.len());
    for (i, &n) in args.sizes.iter().enumerate() {
        if tty {
            eprint!("\r[{}/{}] {n} triangles{:20}", i + 1, args.sizes.len(), "");
        }
        let soup = crsh_scene::random::triangle_soup(n, args.seed)
            .map_err(|e| CliError::runtime(format!("random soup of {n} triangles: {e}")))?;
        let timed = |threads: usize| {
            measure(
                &soup,
                k,
                threads,
                args.warmup as usize,
                args.repeats as usize,
            )
            .map_err(|e| CliError::runtime(format!("grid of {n} triangles: {e}")))
        };
        let serial = timed(1)?;
        let parallel = timed(parallel_threads)?;
        let wgpu_ms = wgpu_rebuild_ms(&soup, k, args.warmup, args.repeats)?;
        let paper = paper_ms(n);
        rows.push(Row {
            triangles: n,
            cells: serial.cells,
            dims: serial.dims,
            pairs: serial.pairs,
            serial,
            parallel,
            wgpu_ms,
            paper_cpu_ms: paper.map(|p| p.0),
            paper_gpu_ms: paper.map(|p| p.1),
        });
    }
    if tty {
        eprint!("\r{:60}\r", "");
    }
    output::print_stdout(&table(args, &rows))?;
    if let Some(path) = &args.json {
        let report = Report {
            source: "seed 002 (Ivson, Duarte, Celes 2009) §5.1, table 1",
            seed: args.seed,
            density: k,
            repeats: args.repeats,
            warmup: args.warmup,
            cores: std::thread::available_parallelism().map_or(1, |n| n.get()),
            rows: &rows,
        };
        let json = serde_json::to_string_pretty(&report)
            .map_err(|e| CliError::runtime(format!("--json: {e}")))?;
        output::write_text(path, &(json + "\n"))?;
        output::print_stdout(&format!("wrote {}\n", path.display()))?;
    }
    Ok(())
}

fn opt_ms(v: Option<f64>) -> String {
    v.map_or_else(|| "-".to_string(), |v| format!("{v:.1}"))
}

/// The printed report: the table-1 comparison, then the per-pass split.
fn table(args: &GridBuildArgs, rows: &[Row]) -> String {
    let mut s = String::new();
    let parallel = rows.first().map_or(0, |r| r.parallel.threads);
    let _ = writeln!(
        s,
        "# Grid rebuild time (seed 002 §5.1, table 1)\n\n\
         Random triangles in [-50, 50]³, enclosing-sphere radius uniform in [0.2, 1.0], seed \
         {}; resolution by eq. 1 at density {DEFAULT_DENSITY}. Whole rebuild (binning set, eq. 1 \
         and the five passes), median of {} runs after {} warm-up, ms. Serial: a 1-thread \
         rayon pool; parallel: {parallel} threads ({} cores available). The paper's rows: a \
         2008 Intel Core 2 (CPU) and a GeForce 8800 Ultra (GPU).\n",
        args.seed,
        args.repeats,
        args.warmup,
        std::thread::available_parallelism().map_or(1, |n| n.get()),
    );
    let wgpu = rows.iter().any(|r| r.wgpu_ms.is_some());
    s.push_str("| #tri | cells | pairs | ours serial ms | ours parallel ms |");
    if wgpu {
        s.push_str(" ours wgpu ms |");
    }
    s.push_str(" paper CPU (Core 2) ms | paper GPU (8800 Ultra) ms |\n|---:|---:|---:|---:|---:|");
    if wgpu {
        s.push_str("---:|");
    }
    s.push_str("---:|---:|\n");
    for r in rows {
        let _ = write!(
            s,
            "| {} | {} | {} | {:.1} | {:.1} |",
            r.triangles, r.cells, r.pairs, r.serial.median_total_ms, r.parallel.median_total_ms
        );
        if wgpu {
            let _ = write!(s, " {} |", opt_ms(r.wgpu_ms));
        }
        let _ = writeln!(
            s,
            " {} | {} |",
            opt_ms(r.paper_cpu_ms),
            opt_ms(r.paper_gpu_ms)
        );
    }
    if rows.iter().any(|r| paper_ms(r.triangles).is_none()) {
        let _ = writeln!(
            s,
            "\n`-`: the paper has no such size (its sizes: {}).",
            PAPER_TRIANGLES.map(|n| n.to_string()).join(", ")
        );
    }
    s.push_str(
        "\n## Per pass (median ms)\n\n\
         setup: binning set and eq. 1; count: triangle boxes and cells per triangle (§3.2.1); \
         scan (§3.2.2); write pairs (§3.2.3); sort: radix sort by cell (§3.2.4); ranges: \
         per-cell start and count (§3.2.5).\n\n\
         | #tri | threads | setup | count | scan | write pairs | sort | ranges | total |\n\
         |---:|---:|---:|---:|---:|---:|---:|---:|---:|\n",
    );
    for r in rows {
        for m in [&r.serial, &r.parallel] {
            let _ = write!(s, "| {} | {} |", r.triangles, m.threads);
            for v in m.median.values() {
                let _ = write!(s, " {v:.2} |");
            }
            let _ = writeln!(s, " {:.2} |", m.median_total_ms);
        }
    }
    s
}
