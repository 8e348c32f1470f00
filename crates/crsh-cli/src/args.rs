//! Command-line arguments (clap derive).

use std::path::PathBuf;

use clap::{Args, Parser, Subcommand, ValueEnum};
use crsh_core::pipeline::MAX_IMAGE_SIDE;

/// Largest `--depth` accepted: deeper Whitted trees only add rays that carry no light.
pub const MAX_DEPTH: u32 = crsh_core::MAX_DEPTH;

/// Largest `--threads` accepted.
pub const MAX_THREADS: usize = 1024;

/// crsh traces secondary rays (shadow, reflection, refraction) with the Coherent Ray-Space
/// Hierarchy and reports exactly how much work each stage did.
#[derive(Debug, Parser)]
#[command(name = "crsh", version, about, long_about = None, propagate_version = true)]
pub struct Cli {
    /// What to do.
    #[command(subcommand)]
    pub command: Command,
}

/// The subcommands.
#[derive(Debug, Subcommand)]
pub enum Command {
    /// Render a scene, print a summary and optionally write a stats JSON file.
    Render(RenderArgs),
    /// List the built-in scenes and the scene manifests found in a directory.
    Scenes(ScenesArgs),
    /// List the pipeline presets and every stage variant with its parameters.
    Pipelines(PipelinesArgs),
    /// List the GPU adapters wgpu can see.
    Adapters(AdaptersArgs),
    /// Print seed 000's evaluation tables (per-level tests, totals against brute force, stage
    /// times) for scenes × pipelines × hierarchy configurations.
    Tables(TablesArgs),
    /// Run a matrix of scenes × pipelines × parameters × backends; write CSV, JSON, charts
    /// and an HTML report (or compare two runs with --compare).
    Ablate(crate::ablate::AblateArgs),
    /// Run the stability suite (closed meshes, shared edges, acne, slivers, far and scaled
    /// scenes, wide bundles, invalid rays) against pipelines × intersect tests × offset
    /// policies; print the table and write CSV / Markdown / JSON.
    Stress(crate::stress::StressArgs),
    /// Time the uniform grid's rebuild (serial, parallel, per pass) on random triangle soups
    /// of 5K-500K triangles and print it next to seed 002's table 1 (§5.1).
    GridBuild(crate::grid_build::GridBuildArgs),
}

/// Where a pipeline runs.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum BackendChoice {
    /// The CPU backend (rayon).
    Cpu,
    /// The wgpu backend (a GPU, or Mesa's lavapipe without one).
    Wgpu,
}

impl BackendChoice {
    /// The library's backend.
    pub fn kind(self) -> crsh::BackendKind {
        match self {
            BackendChoice::Cpu => crsh::BackendKind::Cpu,
            BackendChoice::Wgpu => crsh::BackendKind::Wgpu,
        }
    }
}

/// `crsh render`.
#[derive(Debug, Args)]
pub struct RenderArgs {
    /// Scene: a built-in name (see `crsh scenes`), a TOML manifest or an OBJ file.
    #[arg(
        long,
        default_value = "cornell-mirrors",
        value_name = "NAME|MANIFEST.toml|MESH.obj"
    )]
    pub scene: String,

    /// Pipeline: a preset name (see `crsh pipelines`) or a pipeline TOML file
    /// (a serialized `PipelineConfig`).
    #[arg(long, default_value = "bvh", value_name = "PRESET|PIPELINE.toml")]
    pub pipeline: String,

    /// Where the pipeline runs.
    #[arg(long, value_enum, default_value_t = BackendChoice::Cpu)]
    pub backend: BackendChoice,

    /// Image width in pixels.
    #[arg(long, default_value_t = 512, value_parser = clap::value_parser!(u32).range(1..=MAX_IMAGE_SIDE as i64))]
    pub width: u32,

    /// Image height in pixels [default: width / the camera's framing aspect when the scene's
    /// manifest gives one, else the width (square)].
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..=MAX_IMAGE_SIDE as i64))]
    pub height: Option<u32>,

    /// Reflection / refraction bounces after the primary hit (0: direct light only).
    #[arg(long, default_value_t = 3, value_parser = clap::value_parser!(u32).range(0..=MAX_DEPTH as i64))]
    pub depth: u32,

    /// Output image (8-bit sRGB PNG).
    #[arg(long, default_value = "crsh.png", value_name = "FILE.png")]
    pub out: PathBuf,

    /// Also write the frame's statistics as JSON to this file (see README, "Stats JSON").
    #[arg(long, value_name = "FILE.json")]
    pub stats: Option<PathBuf>,

    /// Trace every batch again with this intersector (e.g. `brute`, the exact reference) and
    /// render a full reference image: reports hit agreement and PSNR.
    #[arg(long, value_name = "INTERSECTOR")]
    pub reference: Option<String>,

    /// Override a pipeline setting: `STAGE.kind=VARIANT`, `STAGE.PARAM=VALUE` or
    /// `STAGE=off` for optional stages (repeatable; see `crsh pipelines`).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub set: Vec<String>,

    /// Worker threads (default: rayon's choice, i.e. `RAYON_NUM_THREADS` or one per core).
    #[arg(long, value_parser = clap::value_parser!(u64).range(1..=MAX_THREADS as u64))]
    pub threads: Option<u64>,

    /// Set every light's radius (scene units) after loading, for soft shadows (seed 003 §5:
    /// `--set raygen.shadow=samples` or `edge_width`); the scene's own radii otherwise
    /// (manifest `radius`, default 0: point lights).
    #[arg(long, value_name = "R")]
    pub light_radius: Option<f32>,

    /// Render frames 0..N-1 of an animated scene (a manifest with moving `[[instances]]`, or
    /// `cornell-mirrors-animated`): numbered PNGs (`OUT-0000.png`, ...), the scene update and
    /// the pipeline rebuild timed per frame, and a stats JSON with one row per frame.
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u32).range(1..=crsh::frames::MAX_FRAMES as i64))]
    pub frames: Option<u32>,

    /// With --frames and --reference: check every K-th frame against the reference (frame 0
    /// included).
    #[arg(long, value_name = "K", default_value_t = 1, requires = "frames", value_parser = clap::value_parser!(u32).range(1..))]
    pub reference_every: u32,
}

/// `crsh tables`.
#[derive(Debug, Args)]
pub struct TablesArgs {
    /// Scenes (built-in names, manifests or OBJ files), comma-separated or repeated.
    #[arg(
        long = "scene",
        value_delimiter = ',',
        required = true,
        value_name = "SCENE"
    )]
    pub scenes: Vec<String>,

    /// Pipelines (presets or pipeline TOML files), comma-separated. Pipelines with a
    /// ray-space hierarchy run once per configuration, the others (`bvh`, `brute`) once per
    /// scene as baselines.
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "crsh,rah",
        value_name = "PIPELINE"
    )]
    pub pipelines: Vec<String>,

    /// Hierarchy subdivisions to run (`hierarchy.subdivision`), comma-separated.
    #[arg(long, value_delimiter = ',', default_value = "8", value_name = "N")]
    pub subdivision: Vec<u32>,

    /// Hierarchy depths to run (`hierarchy.depth`), comma-separated.
    #[arg(long, value_delimiter = ',', default_value = "2", value_name = "D")]
    pub depth: Vec<u32>,

    /// Image width in pixels (the thesis used 512).
    #[arg(long, default_value_t = 512, value_parser = clap::value_parser!(u32).range(1..=MAX_IMAGE_SIDE as i64))]
    pub width: u32,

    /// Image height [default: width / the camera's framing aspect, else the width].
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..=MAX_IMAGE_SIDE as i64))]
    pub height: Option<u32>,

    /// Reflection / refraction bounces after the primary hit (`crsh render --depth`).
    #[arg(long, default_value_t = 3, value_parser = clap::value_parser!(u32).range(0..=MAX_DEPTH as i64))]
    pub bounces: u32,

    /// Override a setting of every pipeline (`STAGE.PARAM=VALUE`, repeatable).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub set: Vec<String>,

    /// Also trace every batch with this intersector and report the hit agreement.
    #[arg(long, value_name = "INTERSECTOR")]
    pub reference: Option<String>,

    /// Frames per cell; stage times are the median (the thesis averaged 58 frames).
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..=1000))]
    pub repeat: u32,

    /// Also write the Markdown to this file.
    #[arg(long, value_name = "FILE.md")]
    pub out: Option<PathBuf>,

    /// Write `levels.csv`, `totals.csv` and `times.csv` into this existing directory.
    #[arg(long, value_name = "DIR")]
    pub csv: Option<PathBuf>,

    /// Worker threads (default: one per core).
    #[arg(long, value_parser = clap::value_parser!(u64).range(1..=MAX_THREADS as u64))]
    pub threads: Option<u64>,

    /// Do not print a line per finished run on stderr.
    #[arg(long)]
    pub quiet: bool,
}

/// `crsh scenes`.
#[derive(Debug, Args)]
pub struct ScenesArgs {
    /// Directory searched (recursively) for scene manifests.
    #[arg(
        long,
        env = "CRSH_SCENES",
        default_value = "../shared/scenes",
        value_name = "DIR"
    )]
    pub scenes_dir: PathBuf,

    /// Print JSON instead of text.
    #[arg(long)]
    pub json: bool,
}

/// `crsh pipelines`.
#[derive(Debug, Args)]
pub struct PipelinesArgs {
    /// Print JSON instead of text.
    #[arg(long)]
    pub json: bool,
}

/// `crsh adapters`.
#[derive(Debug, Args)]
pub struct AdaptersArgs {
    /// Print JSON instead of text.
    #[arg(long)]
    pub json: bool,
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::CommandFactory;

    #[test]
    fn clap_definition_is_consistent() {
        Cli::command().debug_assert();
    }

    #[test]
    fn render_defaults() {
        let cli = Cli::try_parse_from(["crsh", "render"]).unwrap();
        let Command::Render(r) = cli.command else {
            panic!("expected render");
        };
        assert_eq!(r.scene, "cornell-mirrors");
        assert_eq!(r.pipeline, "bvh");
        assert_eq!((r.width, r.height, r.depth), (512, None, 3));
        assert_eq!(r.backend, BackendChoice::Cpu);
        assert_eq!(r.out, PathBuf::from("crsh.png"));
        assert!(r.stats.is_none() && r.reference.is_none() && r.threads.is_none());
    }

    #[test]
    fn sizes_are_range_checked() {
        for bad in [
            &["crsh", "render", "--width", "0"][..],
            &["crsh", "render", "--height", "100000"],
            &["crsh", "render", "--depth", "1000"],
            &["crsh", "render", "--threads", "0"],
            &["crsh", "render", "--width", "-3"],
            &["crsh", "render", "--backend", "metal"],
        ] {
            assert!(
                Cli::try_parse_from(bad).is_err(),
                "{bad:?} should be rejected"
            );
        }
        let ok = Cli::try_parse_from([
            "crsh", "render", "--width", "16384", "--set", "a=b", "--set", "c=d",
        ]);
        let Command::Render(r) = ok.unwrap().command else {
            panic!("expected render");
        };
        assert_eq!(r.width, 16384);
        assert_eq!(r.set, vec!["a=b".to_string(), "c=d".to_string()]);
    }
}
