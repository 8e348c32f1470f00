//! `crsh render`: resolve the pipeline, load the scene, render (with the reference, if asked),
//! write the PNG and the stats, print the summary. The work is the library's
//! ([`crsh::Renderer`]); this module checks the command line early and reports.

use std::io::IsTerminal;
use std::path::Path;
use std::sync::Arc;
use std::time::{Duration, Instant};

use crsh::report::SetupTimes;
use crsh::{BackendKind, FramesReport, FramesRequest, Registries, RenderRequest, Renderer};
use crsh_core::{CoreError, PipelineConfig, Progress};
use crsh_wgpu::Wgpu;
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};

use crate::args::RenderArgs;
use crate::error::{CliError, CliResult};
use crate::output;

/// Runs `crsh render`.
pub fn run(args: &RenderArgs, registries: &Registries) -> CliResult<()> {
    output::check_png_path(&args.out)?;
    check_light_radius(args.light_radius, "--light-radius")?;
    if let Some(stats) = &args.stats {
        output::check_json_path(stats, "--stats")?;
    }
    check_run_files(args, registries)?;
    let backend = args.backend.kind();
    let cfg = pipeline_config(registries, &args.pipeline, &args.set, backend)?;
    // The reference always runs on the CPU (on the wgpu backend through the host), so it may
    // name any CPU intersector, brute64 included. Checked before any work.
    if let Some(name) = &args.reference {
        reference_config(registries, &cfg, name)?;
    }
    // Open the device before loading the scene: without an adapter, fail fast and clearly.
    let gpu = match backend {
        BackendKind::Cpu => None,
        BackendKind::Wgpu => Some(Wgpu::new().map_err(|e| wgpu_unavailable(&e))?),
    };
    configure_threads(args.threads)?;
    if let Some(frames) = args.frames {
        return run_frames(args, registries, &cfg, gpu.as_ref(), frames);
    }

    let t_load = Instant::now();
    let (scene, load_report) = crsh_scene::load_with_report(&args.scene)
        .map_err(|e| CliError::runtime(format!("cannot load scene `{}`: {e}", args.scene)))?;
    let scene_load_ms = t_load.elapsed().as_secs_f64() * 1e3;
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
    let mut scene = scene;
    if let Some(r) = args.light_radius {
        scene
            .set_light_radius(r)
            .map_err(|e| CliError::usage(format!("--light-radius {r}: {e}")))?;
    }
    let scene = Arc::new(scene);
    let renderer = match &gpu {
        None => Renderer::new(registries, Arc::clone(&scene)),
        Some(device) => Renderer::on_wgpu(registries, Arc::clone(&scene), device)
            .map_err(|e| CliError::runtime(format!("uploading the scene to the device: {e}")))?,
    };
    let frame = renderer
        .frame_size(args.width, args.height)
        .map_err(|e| CliError::usage(format!("--width {}: {e}", args.width)))?;
    let mut request = RenderRequest::new()
        .with_width(frame.width)
        .with_height(frame.height)
        .with_max_depth(args.depth);
    if let Some(r) = &args.reference {
        request = request.with_reference(r);
    }

    let bar = progress_bar();
    bar.set_prefix(cfg.name.clone());
    bar.set_message("building stages");
    let render = renderer
        .render(&cfg, &request, &mut |p: Progress| advance(&bar, &p))
        .map_err(|e| library_error(e, &format!("pipeline `{}`", cfg.name)))?;
    bar.finish_and_clear();

    render
        .write_png(&args.out)
        .map_err(|e| CliError::runtime(e.to_string()))?;
    let mut report = render.report(
        &scene,
        &args.scene,
        &args.out.display().to_string(),
        scene_load_ms,
    );
    report.allocator = crate::allocator::description();
    if let Some(path) = &args.stats {
        output::write_text(path, &(report.to_json() + "\n"))?;
    }
    let wrote = match &args.stats {
        Some(s) => format!("wrote     {} and {}\n", args.out.display(), s.display()),
        None => format!("wrote     {}\n", args.out.display()),
    };
    output::print_stdout(&(report.summary() + &wrote))
}

/// Refuses outputs (`--out`, or its numbered frames, and `--stats`) that would write over an
/// input of the run (the scene's files, a pipeline file) or over each other.
fn check_run_files(args: &RenderArgs, registries: &Registries) -> CliResult<()> {
    let mut files = output::RunFiles::new();
    files.scene(&args.scene);
    files.pipeline(registries, &args.pipeline);
    match args.frames {
        Some(n) => {
            for f in 0..n {
                files.output(&frame_path(&args.out, f), format!("--out (frame {f})"));
            }
        }
        None => files.output(&args.out, "--out"),
    }
    if let Some(stats) = &args.stats {
        files.output(stats, "--stats");
    }
    files.check()
}

/// Checks a light-radius override (`what` names it in the error): a finite distance `≥ 0`.
pub fn check_light_radius(radius: Option<f32>, what: &str) -> CliResult<()> {
    match radius {
        Some(r) if !(r.is_finite() && r >= 0.0) => Err(CliError::usage(format!(
            "{what} {r}: the light radius must be a finite distance >= 0 (0: point lights)"
        ))),
        _ => Ok(()),
    }
}

/// `OUT.png` → `OUT-0007.png` for frame 7.
pub fn frame_path(out: &Path, frame: u32) -> std::path::PathBuf {
    let stem = out
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "crsh".into());
    let ext = out
        .extension()
        .map(|e| e.to_string_lossy().into_owned())
        .unwrap_or_else(|| "png".into());
    out.with_file_name(format!("{stem}-{frame:04}.{ext}"))
}

/// `crsh render --frames N`: frames of an animated scene, each written as it is done.
fn run_frames(
    args: &RenderArgs,
    registries: &Registries,
    cfg: &PipelineConfig,
    gpu: Option<&Wgpu>,
    frames: u32,
) -> CliResult<()> {
    let t_load = Instant::now();
    let (mut anim, load_report) = crsh_scene::load_animated(&args.scene)
        .map_err(|e| CliError::runtime(format!("cannot load scene `{}`: {e}", args.scene)))?;
    if let Some(r) = args.light_radius {
        anim.set_light_radius(r)
            .map_err(|e| CliError::usage(format!("--light-radius {r}: {e}")))?;
    }
    let scene_load_ms = t_load.elapsed().as_secs_f64() * 1e3;
    for w in load_report.warnings.iter().take(20) {
        eprintln_warning(w);
    }
    if !anim.is_animated() {
        eprintln_warning(&format!(
            "scene `{}` does not move: every frame is the same",
            args.scene
        ));
    }
    // The frame size from the camera, checked before any work.
    let probe = Renderer::new(registries, Arc::new(anim.scene().clone()));
    let frame = probe
        .frame_size(args.width, args.height)
        .map_err(|e| CliError::usage(format!("--width {}: {e}", args.width)))?;
    drop(probe);
    let mut request = RenderRequest::new()
        .with_width(frame.width)
        .with_height(frame.height)
        .with_max_depth(args.depth);
    if let Some(r) = &args.reference {
        request = request.with_reference(r);
    }
    let request = FramesRequest::new(request, frames).with_reference_every(args.reference_every);
    let bar = progress_bar();
    bar.set_prefix(cfg.name.clone());
    let mut report = FramesReport::new(&anim, &args.scene, cfg);
    report.allocator = crate::allocator::description();
    let mut setup = SetupTimes::new(scene_load_ms);
    crsh::render_frames(
        registries,
        &anim,
        gpu,
        cfg,
        &request,
        &mut |f, p: Progress| {
            advance(
                &bar,
                &Progress {
                    message: format!("frame {f}/{frames}: {}", p.message),
                    ..p
                },
            )
        },
        &mut |f| {
            let path = frame_path(&args.out, f.frame);
            f.render.write_png(&path)?;
            setup.build_stages_ms = f.render.build_stages_ms;
            setup.stage_table_bytes = f.render.stage_table_bytes;
            report.push(&f, &path.display().to_string(), setup.clone());
            setup.scene_load_ms = 0.0;
            Ok(())
        },
    )
    .map_err(|e| library_error(e, &format!("pipeline `{}`", cfg.name)))?;
    bar.finish_and_clear();
    if let Some(path) = &args.stats {
        output::write_text(path, &(report.to_json() + "\n"))?;
    }
    let first = frame_path(&args.out, 0);
    let last = frame_path(&args.out, frames - 1);
    let wrote = match &args.stats {
        Some(s) => format!(
            "wrote     {} .. {} and {}\n",
            first.display(),
            last.display(),
            s.display()
        ),
        None => format!("wrote     {} .. {}\n", first.display(), last.display()),
    };
    output::print_stdout(&(report.summary() + &wrote))
}

/// The pipeline `pipeline` names — a preset of `registries` or a pipeline TOML file — with the
/// `--set` overrides applied in order, resolved against `backend`'s registry (defaults filled
/// in, slots checked). Unknown names and values are usage errors.
pub fn pipeline_config(
    registries: &Registries,
    pipeline: &str,
    sets: &[String],
    backend: BackendKind,
) -> CliResult<PipelineConfig> {
    let cfg = pipeline_unresolved(registries, pipeline, sets)?;
    registries
        .resolve(&cfg, backend)
        .map_err(|e| CliError::usage(format!("pipeline `{}`: {e}", cfg.name)))
}

/// The pipeline `pipeline` names with the `--set` overrides applied, not yet resolved against
/// a registry (so that each backend of an ablation can resolve it).
pub fn pipeline_unresolved(
    registries: &Registries,
    pipeline: &str,
    sets: &[String],
) -> CliResult<PipelineConfig> {
    let mut cfg = if let Some(cfg) = registries.preset(pipeline) {
        cfg
    } else if pipeline.ends_with(".toml") || Path::new(pipeline).is_file() {
        let text = std::fs::read_to_string(pipeline)
            .map_err(|e| CliError::runtime(format!("cannot read pipeline file {pipeline}: {e}")))?;
        toml::from_str::<PipelineConfig>(&text)
            .map_err(|e| CliError::runtime(format!("pipeline file {pipeline}: {e}")))?
    } else {
        return Err(CliError::usage(format!(
            "unknown pipeline `{pipeline}` (presets: {}; or a pipeline .toml file)",
            registries.preset_names().join(", ")
        )));
    };
    for s in sets {
        cfg.set(s)
            .map_err(|e| CliError::usage(format!("--set {s}: {e}")))?;
    }
    Ok(cfg)
}

/// The reference pipeline of `--reference NAME` ([`PipelineConfig::reference`]), resolved
/// against the CPU registry (the reference always runs on the CPU).
pub fn reference_config(
    registries: &Registries,
    cfg: &PipelineConfig,
    name: &str,
) -> CliResult<PipelineConfig> {
    registries
        .resolve(&cfg.reference(name), BackendKind::Cpu)
        .map_err(|e| CliError::usage(format!("--reference {name}: {e}")))
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

/// A stage error: a parameter value a stage rejects (NaN, out of range, a variant the backend
/// lacks, stages that do not fit) is a usage error; anything else (allocation, backend) a
/// runtime one.
pub(crate) fn stage_error(e: CoreError, context: &str) -> CliError {
    library_error(crsh::Error::Core(e), context)
}

/// A library error, as a usage or runtime error ([`crsh::Error::is_usage`]).
pub(crate) fn library_error(e: crsh::Error, context: &str) -> CliError {
    let msg = format!("{context}: {e}");
    if e.is_usage() {
        CliError::usage(msg)
    } else {
        CliError::runtime(msg)
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
