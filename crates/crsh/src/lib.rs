//! # crsh
//!
//! The library a crsh user depends on: the stage registries of both backends
//! ([`Registries`]), a [`Renderer`] (scene + pipeline description → frame, with the frame size
//! from the scene camera, brute-force figures, stage names and accuracy against a reference
//! filled in), the frame's reports ([`report`]: summary text, stats JSON, Mrays/s) and PNG
//! output ([`output`]). It re-exports the crates it builds on: [`crsh_core`] (stage traits,
//! pipeline descriptions, the registry type), [`crsh_scene`] (scenes), [`crsh_cpu`] and
//! [`crsh_wgpu`] (the backends).
//!
//! ```
//! use std::sync::Arc;
//! use crsh::{Registries, RenderRequest, Renderer};
//!
//! let registries = Registries::builtin();
//! let scene = Arc::new(crsh::crsh_scene::load("cornell-mirrors")?);
//! let renderer = Renderer::new(&registries, Arc::clone(&scene));
//! let mut cfg = registries.preset("crsh").expect("a built-in preset");
//! cfg.set("hierarchy.subdivision=16")?;
//! let request = RenderRequest::new()
//!     .with_width(32)
//!     .with_max_depth(1)
//!     .with_reference("brute");
//! let render = renderer.render(&cfg, &request, &mut |_| {})?;
//! assert_eq!(render.stats.stages["hash"], "thesis");
//! assert_eq!(render.accuracy.as_ref().unwrap().hit_agreement, 1.0);
//! let report = render.report(&scene, "cornell-mirrors", "", 0.0);
//! assert!(report.to_json().contains("\"tests\""));
//! println!("{}", report.summary());
//! render.write_png(&std::env::temp_dir().join("crsh-doc-example.png"))?;
//! # Ok::<(), crsh::Error>(())
//! ```
//!
//! To add a stage variant, register it in `registries.cpu` (or `registries.wgpu`) with the
//! `add_*` call of its slot; a pipeline then names it like a built-in one
//! (`cfg.set("hash.kind=NAME")`), and the `crsh` command line run through
//! `crsh_cli::main_with(registries)` offers it to `--set`, `crsh pipelines` and ablation
//! plans. See `examples/` in the repository.

#![warn(missing_docs)]

pub mod error;
pub mod frames;
pub mod output;
pub mod registries;
pub mod renderer;
pub mod report;

pub use crsh_core;
pub use crsh_cpu;
pub use crsh_scene;
pub use crsh_wgpu;

pub use crsh_core::{
    FrameOptions, FrameSize, ParamInfo, ParamValue, PipelineConfig, RayKind, Registry,
    StageContext, StageKind, StageSpec, StageVariantInfo, Stats,
};
pub use crsh_cpu::Cpu;
pub use crsh_scene::{AnimatedScene, Scene};
pub use crsh_wgpu::Wgpu;
pub use error::{Error, Result};
pub use frames::{render_frames, FrameRender, FramesReport, FramesRequest, UpdateReport};
pub use registries::{BackendKind, Registries};
pub use renderer::{Built, HostFrame, ReferenceFrame, Render, RenderRequest, Renderer};
pub use report::{AccuracyReport, AdapterReport, SceneInfo, SetupTimes, StatsReport};
