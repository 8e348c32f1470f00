//! The wgpu backend's stage catalogue and stage factory, and the host-side reference.
//!
//! The GPU variants carry the same names and parameters as their CPU twins, so one
//! [`PipelineConfig`] (a preset, a TOML file, an ablation cell) runs on either backend:
//! [`catalogue`] is the CPU catalogue restricted to the variants with a WGSL implementation
//! ([`GPU_VARIANTS`]); [`build_stages`] turns a resolved config into [`Stages<Wgpu>`];
//! [`render`] renders a frame, with the `--reference` intersector running on the host
//! ([`HostIntersector`]) so that accuracy is always measured against the CPU's exact answer.

use std::sync::Arc;

use crsh_core::{
    render_frame, CoreError, Frame, FrameOptions, Hit, HitMode, Intersector, PipelineConfig,
    Progress, Query, Ray, Result, StageKind, StageSpec, StageVariantInfo, Stages, Stats,
};
use crsh_cpu::Cpu;

use crate::backend::{GpuBuffer, Wgpu};
use crate::hash::morton_octa::MortonOcta;
use crate::hash::thesis::ThesisHasher;
use crate::hierarchy::sphere_cone::SphereConeBuilder;
use crate::intersect::brute::BruteForce;
use crate::intersect::bvh::CwBvh;
use crate::primary::raster::Raster;
use crate::raygen::whitted::Whitted;
use crate::scene::GpuScene;
use crate::shade::phong::Phong;
use crate::sort::compress::CompressSorter;
use crate::sort::radix::RadixSorter;
use crate::traverse::crsh::Crsh;
use crsh_core::{Hasher, HierarchyBuilder, PrimaryVisibility, RayGen, Shader, Sorter, Traverser};

/// The `(stage, variant)` pairs the wgpu backend implements.
pub const GPU_VARIANTS: &[(StageKind, &str)] = &[
    (StageKind::Primary, "raster"),
    (StageKind::Raygen, "whitted"),
    (StageKind::Intersect, "brute"),
    (StageKind::Intersect, "bvh"),
    (StageKind::Hash, "thesis"),
    (StageKind::Hash, "morton"),
    (StageKind::Sort, "radix"),
    (StageKind::Sort, "compress"),
    (StageKind::Hierarchy, "sphere_cone"),
    (StageKind::Traverse, "crsh"),
    (StageKind::Shade, "phong"),
];

/// Every stage variant the wgpu backend offers: the CPU catalogue's entries for
/// [`GPU_VARIANTS`], with the same parameters, defaults and documentation.
pub fn catalogue() -> Vec<StageVariantInfo> {
    crsh_cpu::catalogue()
        .into_iter()
        .filter(|v| GPU_VARIANTS.contains(&(v.stage, v.name)))
        .collect()
}

/// Checks that every stage of `cfg` (resolved or not) has a wgpu implementation: a variant
/// the CPU has but the GPU lacks is [`CoreError::Unsupported`] naming the GPU variants of that
/// stage, and so is a ray-triangle test other than `mt`. Unknown variants and parameters are left to [`PipelineConfig::resolve`].
pub fn check_supported(cfg: &PipelineConfig) -> Result<()> {
    for &slot in StageKind::ALL.iter() {
        let Some(spec) = cfg.slot(slot) else {
            continue;
        };
        if GPU_VARIANTS.contains(&(slot, spec.kind.as_str())) {
            continue;
        }
        let cpu_has = crsh_cpu::catalogue()
            .iter()
            .any(|v| v.stage == slot && v.name == spec.kind);
        if cpu_has {
            let gpu: Vec<&str> = GPU_VARIANTS
                .iter()
                .filter(|(s, _)| *s == slot)
                .map(|(_, n)| *n)
                .collect();
            return Err(CoreError::Unsupported {
                stage: slot.key(),
                variant: spec.kind.clone(),
                what: format!(
                    "the wgpu backend (its {} variants: {}); run it with --backend cpu",
                    slot.key(),
                    if gpu.is_empty() {
                        "none".to_string()
                    } else {
                        gpu.join(", ")
                    }
                ),
            });
        }
    }
    // Parameter values only the CPU implements.
    if let Some(test) = cfg.intersect.params.get("test") {
        let name = test.to_string();
        if name != "mt" {
            return Err(CoreError::Unsupported {
                stage: "intersect",
                variant: cfg.intersect.kind.clone(),
                what: format!(
                    "test `{name}` on the wgpu backend (only `mt` has a WGSL twin); run it with \
                     --backend cpu"
                ),
            });
        }
    }
    Ok(())
}

/// Builds the stages of `cfg` for `scene` on the wgpu backend: [`check_supported`], then a
/// clone of `cfg` is resolved against [`catalogue`] (defaults filled in).
pub fn build_stages(cfg: &PipelineConfig, scene: &Arc<GpuScene>) -> Result<Stages<Wgpu>> {
    check_supported(cfg)?;
    let mut cfg = cfg.clone();
    cfg.resolve(&catalogue())?;
    let unknown = |slot: StageKind, spec: &StageSpec| CoreError::Unsupported {
        stage: slot.key(),
        variant: spec.kind.clone(),
        what: "the wgpu backend".into(),
    };
    let primary: Box<dyn PrimaryVisibility<Wgpu>> = match cfg.primary.kind.as_str() {
        "raster" => Box::new(Raster::new(scene, &cfg.primary)?),
        _ => return Err(unknown(StageKind::Primary, &cfg.primary)),
    };
    let raygen: Box<dyn RayGen<Wgpu>> = match cfg.raygen.kind.as_str() {
        "whitted" => Box::new(Whitted::new(scene, &cfg.raygen)?),
        _ => return Err(unknown(StageKind::Raygen, &cfg.raygen)),
    };
    let shader: Box<dyn Shader<Wgpu>> = match cfg.shade.kind.as_str() {
        "phong" => Box::new(Phong::new(scene, &cfg.shade)?),
        _ => return Err(unknown(StageKind::Shade, &cfg.shade)),
    };
    let intersector: Box<dyn Intersector<Wgpu>> = match cfg.intersect.kind.as_str() {
        "brute" => Box::new(BruteForce::new(scene, &cfg.intersect)?),
        "bvh" => Box::new(CwBvh::new(scene, &cfg.intersect)?),
        _ => return Err(unknown(StageKind::Intersect, &cfg.intersect)),
    };
    let hasher: Option<Box<dyn Hasher<Wgpu>>> = match &cfg.hash {
        None => None,
        Some(spec) if spec.kind == "thesis" => Some(Box::new(ThesisHasher::new(scene, spec)?)),
        Some(spec) if spec.kind == "morton" => Some(Box::new(MortonOcta::new(scene, spec)?)),
        Some(spec) => return Err(unknown(StageKind::Hash, spec)),
    };
    let sorter: Option<Box<dyn Sorter<Wgpu>>> = match &cfg.sort {
        None => None,
        Some(spec) if spec.kind == "radix" => Some(Box::new(RadixSorter::new(scene, spec)?)),
        Some(spec) if spec.kind == "compress" => Some(Box::new(CompressSorter::new(scene, spec)?)),
        Some(spec) => return Err(unknown(StageKind::Sort, spec)),
    };
    let hierarchy: Option<Box<dyn HierarchyBuilder<Wgpu>>> = match &cfg.hierarchy {
        None => None,
        Some(spec) if spec.kind == "sphere_cone" => {
            Some(Box::new(SphereConeBuilder::new(scene, spec)?))
        }
        Some(spec) => return Err(unknown(StageKind::Hierarchy, spec)),
    };
    let traverser: Option<Box<dyn Traverser<Wgpu>>> = match &cfg.traverse {
        None => None,
        Some(spec) if spec.kind == "crsh" => Some(Box::new(Crsh::new(scene, spec)?)),
        Some(spec) => return Err(unknown(StageKind::Traverse, spec)),
    };
    if hierarchy.is_some() && !intersector.supports_candidates() {
        return Err(CoreError::Unsupported {
            stage: "intersect",
            variant: cfg.intersect.kind.clone(),
            what: "the final tests of a ray-space hierarchy".into(),
        });
    }
    Ok(Stages {
        primary,
        raygen,
        hasher,
        sorter,
        hierarchy,
        traverser,
        intersector,
        shader,
    })
}

/// A CPU intersector answering whole-scene queries for the wgpu backend: rays and hits are
/// downloaded, traced on the host, and the merged hits uploaded again. It is how the wgpu
/// backend gets its `--reference` (every reference variant, `brute64` included, which has no
/// GPU twin), so that agreement is measured against the CPU's answer on the very rays the GPU
/// pipeline traced.
pub struct HostIntersector {
    inner: Box<dyn Intersector<Cpu>>,
}

impl HostIntersector {
    /// Wraps a CPU intersector.
    pub fn new(inner: Box<dyn Intersector<Cpu>>) -> HostIntersector {
        HostIntersector { inner }
    }

    /// Builds the CPU intersector `spec` for the host scene of `scene`
    /// ([`crsh_cpu::build_intersector`]).
    pub fn build(spec: &StageSpec, scene: &GpuScene) -> Result<HostIntersector> {
        Ok(HostIntersector::new(crsh_cpu::build_intersector(
            spec,
            &scene.scene,
        )?))
    }
}

impl Intersector<Wgpu> for HostIntersector {
    fn name(&self) -> &str {
        self.inner.name()
    }

    fn supports_candidates(&self) -> bool {
        false
    }

    fn intersect(
        &self,
        backend: &Wgpu,
        rays: &GpuBuffer<Ray>,
        query: Query<'_, Wgpu>,
        mode: HitMode,
        hits: &mut GpuBuffer<Hit>,
        stats: &mut Stats,
    ) -> Result<()> {
        use crsh_core::Backend;
        if !matches!(query, Query::Scene) {
            return Err(CoreError::Unsupported {
                stage: "intersect",
                variant: format!("{} (on the host)", self.inner.name()),
                what: "candidate queries of a ray-space hierarchy on the wgpu backend".into(),
            });
        }
        let host_rays = backend.download(rays)?;
        let mut host_hits = backend.download(hits)?;
        self.inner
            .intersect(&Cpu, &host_rays, Query::Scene, mode, &mut host_hits, stats)?;
        *hits = backend.upload(&host_hits)?;
        Ok(())
    }
}

/// Renders one frame of `scene` with pipeline `cfg` on `scene`'s device: builds the stages
/// (and the `reference` intersector, on the host, whose agreement lands in
/// [`crsh_core::Stats::accuracy`]) and runs [`render_frame`]. `opts.triangles` is taken from
/// the scene.
pub fn render(
    scene: &Arc<GpuScene>,
    cfg: &PipelineConfig,
    opts: &FrameOptions,
    reference: Option<&StageSpec>,
    progress: &mut dyn FnMut(Progress),
) -> Result<Frame<Wgpu>> {
    let stages = build_stages(cfg, scene)?;
    let reference = reference
        .map(|r| HostIntersector::build(r, scene))
        .transpose()?;
    let opts = FrameOptions {
        triangles: scene.triangle_count() as u64,
        ..opts.clone()
    };
    render_frame(
        &scene.backend,
        &stages,
        &opts,
        reference.as_ref().map(|r| r as &dyn Intersector<Wgpu>),
        progress,
    )
}
