//! Test support shared by this crate's tests, the workspace tests and the CLI's: one device per
//! process, or a printed skip.

use std::sync::{Arc, OnceLock};

use crsh_core::glam::Vec3;
use crsh_core::{
    FrameSize, Intersector, PipelineConfig, Ray, RayKind, Registry, StageContext, StageSpec, Stages,
};
use crsh_cpu::Cpu;
use crsh_scene::Scene;

use crate::adapter::GpuContext;
use crate::backend::Wgpu;

/// The CPU twins' registry, built once.
pub fn cpu_registry() -> &'static Registry<Cpu> {
    static REGISTRY: OnceLock<Registry<Cpu>> = OnceLock::new();
    REGISTRY.get_or_init(Registry::<Cpu>::builtin)
}

/// The CPU preset `name`, resolved. Panics when there is none (a test bug).
pub fn cpu_preset(name: &str) -> PipelineConfig {
    cpu_registry()
        .preset(name)
        .unwrap_or_else(|| panic!("no preset `{name}`"))
}

/// The stages of `cfg` built by the CPU registry for `scene` at `width × height`.
pub fn cpu_stages(
    cfg: &PipelineConfig,
    scene: &Arc<Scene>,
    width: u32,
    height: u32,
) -> Stages<Cpu> {
    let frame = FrameSize::new(width, height).expect("valid test frame");
    cpu_registry()
        .build(&StageContext::new(&Cpu, scene, frame), cfg)
        .unwrap_or_else(|e| panic!("building {}: {e}", cfg.name))
        .stages
}

/// The CPU intersector `spec` for `scene`.
pub fn cpu_intersector(spec: &StageSpec, scene: &Arc<Scene>) -> Box<dyn Intersector<Cpu>> {
    let frame = FrameSize::new(1, 1).expect("valid frame");
    cpu_registry()
        .build_intersector(&StageContext::new(&Cpu, scene, frame), spec)
        .unwrap_or_else(|e| panic!("building intersector {}: {e}", spec.kind))
}

/// Whether `CRSH_REQUIRE_GPU=1`: a missing adapter is then a failure rather than a skip.
pub fn gpu_required() -> bool {
    std::env::var("CRSH_REQUIRE_GPU").as_deref() == Ok("1")
}

/// The process-wide device for tests, or `None` after printing `SKIP: no wgpu adapter (...)`
/// naming `test`. Panics when [`gpu_required`] and no adapter can be opened.
pub fn shared_context(test: &str) -> Option<Arc<GpuContext>> {
    static CTX: OnceLock<Result<Arc<GpuContext>, String>> = OnceLock::new();
    let ctx = CTX.get_or_init(|| GpuContext::new().map(Arc::new).map_err(|e| e.to_string()));
    match ctx {
        Ok(ctx) => Some(Arc::clone(ctx)),
        Err(e) => {
            if gpu_required() {
                panic!("CRSH_REQUIRE_GPU=1 but no usable wgpu adapter for `{test}`: {e}");
            }
            println!("SKIP: no wgpu adapter ({e}) in `{test}`");
            None
        }
    }
}

/// [`shared_context`] as a [`Wgpu`] backend.
pub fn shared_backend(test: &str) -> Option<Wgpu> {
    shared_context(test).map(Wgpu::from_context)
}

/// A ray of `kind` from `origin` along `dir` over `[t_min, t_max]`, pixel and source `i`,
/// depth 1, throughput one, light 0.
pub fn ray(origin: Vec3, dir: Vec3, t_min: f32, t_max: f32, kind: RayKind, i: u32) -> Ray {
    Ray {
        pixel: i,
        light: 0,
        source: i,
        ..Ray::new(kind, origin, dir, t_min, t_max)
    }
}
