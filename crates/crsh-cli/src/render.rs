//! `crsh render`: resolve the pipeline, load the scene, render, compare with a reference,
//! write the PNG and the stats, print the summary.

use std::io::IsTerminal;
use std::path::Path;
use std::sync::Arc;
use std::time::{Duration, Instant};

use crsh_core::metrics::{psnr_rgba8, to_rgba8};
use crsh_core::pipeline::MAX_IMAGE_SIDE;
use crsh_core::{
    render_frame, Backend, CoreError, FrameOptions, Intersector, PipelineConfig, Progress,
    StageVariantInfo,
};
use crsh_cpu::Cpu;
use crsh_wgpu::{GpuScene, HostIntersector, Wgpu};
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};

use crate::args::{BackendChoice, RenderArgs};
use crate::error::{CliError, CliResult};
use crate::output;
use crate::report::{AccuracyReport, AdapterReport, RunInfo, SceneInfo, SetupTimes, StatsReport};

/// Runs `crsh render`.
pub fn run(args: &RenderArgs) -> CliResult<()> {
    output::check_png_path(&args.out)?;
    if let Some(stats) = &args.stats {
        output::check_writable(stats, "--stats")?;
    }
    let catalogue = crsh_cpu::catalogue();
    let cfg = pipeline_config(&args.pipeline, &args.set, &catalogue)?;
    if args.backend == BackendChoice::Wgpu {
        crsh_wgpu::check_supported(&cfg)
            .map_err(|e| stage_error(e, &format!("pipeline `{}`", cfg.name)))?;
    }
    // The reference always runs on the CPU (on the wgpu backend through the host), so it may
    // name any CPU intersector, brute64 included.
    let reference = args
        .reference
        .as_deref()
        .map(|name| reference_config(&cfg, name, &catalogue))
        .transpose()?;
    // Open the device before loading the scene: without an adapter, fail fast and clearly.
    let gpu = match args.backend {
        BackendChoice::Cpu => None,
        BackendChoice::Wgpu => Some(Wgpu::new().map_err(|e| wgpu_unavailable(&e))?),
    };
    let threads = configure_threads(args.threads)?;

    let t_load = Instant::now();
    let (scene, load_report) = crsh_scene::load_with_report(&args.scene)
        .map_err(|e| CliError::runtime(format!("cannot load scene `{}`: {e}", args.scene)))?;
    let scene_load_ms = ms_since(t_load);
    const MAX_WARNINGS: usize = 20;
    for w in load_report.warnings.iter().take(MAX_WARNINGS) {
        eprintln_warning(w);
    }
    if load_report.warnings.len() > MAX_WARNINGS {
        eprintln_warning(&format!(
            "... and {} more scene warnings",
            load_report.warnings.len() - MAX_WARNINGS
        ));
    }
    let scene = Arc::new(scene);
    let height = args
        .height
        .or_else(|| scene.camera.height_for(args.width))
        .unwrap_or(args.width);
    if height > MAX_IMAGE_SIDE {
        return Err(CliError::usage(format!(
            "--width {} with the camera's aspect gives a height of {height}, above {MAX_IMAGE_SIDE}; pass --height",
            args.width
        )));
    }
    let opts = FrameOptions {
        width: args.width,
        height,
        max_depth: args.depth,
        triangles: scene.triangle_count() as u64,
    };

    let bar = progress_bar();
    bar.set_prefix(cfg.name.clone());
    bar.set_message("building stages");
    let mut on_progress = |p: Progress| advance(&bar, &p);
    let rendered = match &gpu {
        None => {
            let t_build = Instant::now();
            let stages = crsh_cpu::build_stages(&cfg, &scene)
                .map_err(|e| stage_error(e, &format!("building pipeline `{}`", cfg.name)))?;
            let build_stages_ms = ms_since(t_build);
            let reference = reference
                .as_ref()
                .map(|r| crsh_cpu::build_intersector(&r.intersect, &scene))
                .transpose()
                .map_err(|e| stage_error(e, "building the reference intersector"))?;
            let frame = render_frame(&Cpu, &stages, &opts, reference.as_deref(), &mut on_progress)
                .map_err(|e| CliError::runtime(format!("render failed: {e}")))?;
            Rendered {
                image: frame.image,
                stats: frame.stats,
                build_stages_ms,
                adapter: None,
            }
        }
        Some(backend) => {
            let t_build = Instant::now();
            let gscene = GpuScene::new(backend, &scene).map_err(|e| {
                CliError::runtime(format!("uploading the scene to the device: {e}"))
            })?;
            let stages = crsh_wgpu::build_stages(&cfg, &gscene).map_err(|e| {
                stage_error(e, &format!("building pipeline `{}` on wgpu", cfg.name))
            })?;
            let build_stages_ms = ms_since(t_build);
            let reference = reference
                .as_ref()
                .map(|r| HostIntersector::build(&r.intersect, &gscene))
                .transpose()
                .map_err(|e| stage_error(e, "building the reference intersector"))?;
            let frame = render_frame(
                backend,
                &stages,
                &opts,
                reference.as_ref().map(|r| r as &dyn Intersector<Wgpu>),
                &mut on_progress,
            )
            .map_err(|e| CliError::runtime(format!("render failed: {e}")))?;
            let image = backend
                .download(&frame.image)
                .map_err(|e| CliError::runtime(format!("reading the image back: {e}")))?;
            Rendered {
                image,
                stats: frame.stats,
                build_stages_ms,
                adapter: Some(AdapterReport::of(backend.context().info())),
            }
        }
    };
    let frame = rendered;
    let build_stages_ms = frame.build_stages_ms;
    let rgba = to_rgba8(&frame.image);

    let accuracy = match &reference {
        None => None,
        Some(ref_cfg) => {
            bar.set_prefix(format!("reference {}", ref_cfg.intersect.kind));
            let t0 = Instant::now();
            let ref_frame =
                crsh_cpu::render(&scene, ref_cfg, &opts, None, &mut |p| advance(&bar, &p))
                    .map_err(|e| CliError::runtime(format!("reference render failed: {e}")))?;
            let ref_ms = ms_since(t0);
            let ref_rgba = to_rgba8(&ref_frame.image);
            let counts = frame.stats.accuracy.clone().unwrap_or_default();
            Some(accuracy_report(
                &ref_cfg.intersect.kind,
                &counts,
                &rgba,
                &ref_rgba,
                ref_ms,
            ))
        }
    };
    bar.finish_and_clear();

    output::write_png(&args.out, args.width, height, &rgba)?;
    let report = StatsReport::new(
        RunInfo {
            scene: SceneInfo::of(&scene, &args.scene),
            config: &cfg,
            backend: args.backend.name(),
            adapter: frame.adapter.clone(),
            threads,
            width: args.width,
            height,
            max_depth: args.depth,
            output: args.out.display().to_string(),
            setup: SetupTimes {
                scene_load_ms,
                build_stages_ms,
            },
        },
        &frame.stats,
        accuracy,
    );
    if let Some(path) = &args.stats {
        output::write_text(path, &(report.to_json() + "\n"))?;
    }
    let wrote = match &args.stats {
        Some(s) => format!("wrote     {} and {}\n", args.out.display(), s.display()),
        None => format!("wrote     {}\n", args.out.display()),
    };
    output::print_stdout(&(report.summary() + &wrote))
}

/// What a render produced, whichever backend ran it.
struct Rendered {
    /// Linear RGBA on the host.
    image: Vec<[f32; 4]>,
    stats: crsh_core::Stats,
    build_stages_ms: f64,
    adapter: Option<AdapterReport>,
}

/// The resolved pipeline: a preset name or a pipeline TOML file, `--set` overrides applied in
/// order, then checked against `catalogue` with defaults filled in.
pub fn pipeline_config(
    pipeline: &str,
    sets: &[String],
    catalogue: &[StageVariantInfo],
) -> CliResult<PipelineConfig> {
    let mut cfg = if let Some(cfg) = crsh_cpu::preset(pipeline) {
        cfg
    } else if pipeline.ends_with(".toml") || Path::new(pipeline).is_file() {
        let text = std::fs::read_to_string(pipeline)
            .map_err(|e| CliError::runtime(format!("cannot read pipeline file {pipeline}: {e}")))?;
        toml::from_str::<PipelineConfig>(&text)
            .map_err(|e| CliError::runtime(format!("pipeline file {pipeline}: {e}")))?
    } else {
        return Err(CliError::usage(format!(
            "unknown pipeline `{pipeline}` (presets: {}; or a pipeline .toml file)",
            preset_names().join(", ")
        )));
    };
    for s in sets {
        cfg.set(s)
            .map_err(|e| CliError::usage(format!("--set {s}: {e}")))?;
    }
    cfg.resolve(catalogue)
        .map_err(|e| CliError::usage(format!("pipeline `{}`: {e}", cfg.name)))?;
    Ok(cfg)
}

/// The names of the CPU presets.
pub fn preset_names() -> Vec<String> {
    crsh_cpu::PRESETS.iter().map(|p| p.to_string()).collect()
}

/// The reference pipeline of `--reference NAME`: the same primary, ray generation and shading
/// (with their parameters) as `cfg`, every ray traced against the whole scene by the
/// intersector `name` (no hash / sort / hierarchy / traverse stages).
pub fn reference_config(
    cfg: &PipelineConfig,
    name: &str,
    catalogue: &[StageVariantInfo],
) -> CliResult<PipelineConfig> {
    let mut r = cfg.clone();
    r.name = format!("{}-reference-{name}", cfg.name);
    r.hash = None;
    r.sort = None;
    r.hierarchy = None;
    r.traverse = None;
    r.intersect = crsh_core::StageSpec::new(name);
    r.resolve(catalogue)
        .map_err(|e| CliError::usage(format!("--reference {name}: {e}")))?;
    Ok(r)
}

/// Builds the global rayon pool (`--threads`) and returns its size.
pub(crate) fn configure_threads(threads: Option<u64>) -> CliResult<usize> {
    if let Some(n) = threads {
        rayon::ThreadPoolBuilder::new()
            .num_threads(n as usize)
            .build_global()
            .map_err(|e| CliError::runtime(format!("--threads {n}: {e}")))?;
    }
    Ok(rayon::current_num_threads())
}

/// A stage-construction error: a parameter value a stage rejects (NaN, out of range, a variant
/// the backend lacks) is a usage error; anything else (allocation, backend) a runtime one.
pub(crate) fn stage_error(e: CoreError, context: &str) -> CliError {
    let msg = format!("{context}: {e}");
    match e {
        CoreError::InvalidParam { .. }
        | CoreError::UnknownVariant { .. }
        | CoreError::Unsupported { .. } => CliError::usage(msg),
        CoreError::InvalidInput(_) | CoreError::Backend(_) => CliError::runtime(msg),
    }
}

fn ms_since(t: Instant) -> f64 {
    t.elapsed().as_secs_f64() * 1e3
}

/// Compares the two 8-bit images and shapes the accuracy report.
pub(crate) fn accuracy_report(
    reference: &str,
    counts: &crsh_core::AccuracyCounts,
    rgba: &[u8],
    ref_rgba: &[u8],
    ref_ms: f64,
) -> AccuracyReport {
    let psnr = psnr_rgba8(rgba, ref_rgba);
    let pixels_differing = rgba
        .chunks_exact(4)
        .zip(ref_rgba.chunks_exact(4))
        .filter(|(a, b)| a[..3] != b[..3])
        .count() as u64;
    AccuracyReport {
        reference: reference.to_string(),
        hit_agreement: counts.hit_agreement(),
        psnr_db: psnr.is_finite().then_some(psnr),
        images_identical: pixels_differing == 0,
        pixels_differing,
        rays_compared: counts.rays,
        agreeing: counts.agreeing,
        hit_miss_mismatches: counts.hit_miss_mismatches,
        nearest_mismatches: counts.nearest_mismatches,
        mean_abs_t_error: counts.mean_abs_t_error(),
        reference_render_ms: ref_ms,
    }
}

/// The error for `--backend wgpu` without a usable device, naming the adapters that were found.
fn wgpu_unavailable(e: &crsh_wgpu::GpuError) -> CliError {
    let adapters = crsh_wgpu::enumerate_adapters();
    let found = if adapters.is_empty() {
        "no wgpu adapter was found on this machine".to_string()
    } else {
        format!(
            "wgpu adapters found: {}",
            adapters
                .iter()
                .map(crate::listing::adapter_line)
                .collect::<Vec<_>>()
                .join("; ")
        )
    };
    CliError::runtime(format!(
        "--backend wgpu: cannot open a device: {e} ({found}); use --backend cpu"
    ))
}

/// Prints `warning: ...` on stderr (a closed stderr is ignored).
fn eprintln_warning(w: &str) {
    use std::io::Write;
    let _ = writeln!(std::io::stderr(), "warning: {w}");
}

/// A progress bar on stderr, hidden when stderr is not a terminal.
fn progress_bar() -> ProgressBar {
    let bar = ProgressBar::with_draw_target(Some(1), ProgressDrawTarget::hidden());
    if std::io::stderr().is_terminal() {
        bar.set_draw_target(ProgressDrawTarget::stderr());
        if let Ok(style) =
            ProgressStyle::with_template("{prefix:.bold} [{bar:30}] {pos}/{len} {msg} ({elapsed})")
        {
            bar.set_style(style.progress_chars("=> "));
        }
        bar.enable_steady_tick(Duration::from_millis(200));
    }
    bar
}

fn advance(bar: &ProgressBar, p: &Progress) {
    bar.set_length(p.total_steps as u64);
    bar.set_position(p.step as u64);
    bar.set_message(p.message.clone());
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn accuracy_of_identical_and_different_images() {
        let counts = crsh_core::AccuracyCounts {
            rays: 10,
            agreeing: 9,
            hit_miss_mismatches: 1,
            nearest_mismatches: 0,
            ..Default::default()
        };
        let a = vec![10u8, 20, 30, 255, 40, 50, 60, 255];
        let same = accuracy_report("brute", &counts, &a, &a, 1.0);
        assert_eq!(same.psnr_db, None);
        assert!(same.images_identical);
        assert_eq!(same.pixels_differing, 0);
        assert!((same.hit_agreement - 0.9).abs() < 1e-12);
        let mut b = a.clone();
        b[4] = 41;
        let diff = accuracy_report("brute", &counts, &a, &b, 1.0);
        assert!(!diff.images_identical);
        assert_eq!(diff.pixels_differing, 1);
        assert!(diff.psnr_db.unwrap() > 40.0);
    }
}
