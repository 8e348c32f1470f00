//! The wgpu backend's built-in stage variants and presets, and the host-side reference.
//!
//! The GPU variants carry the names, parameters and documentation of their CPU twins (each
//! module registers itself under its twin's catalogue entry), so one [`PipelineConfig`] (a
//! preset, a TOML file, an ablation cell) runs on either backend; the presets are the CPU's.
//! Where a GPU variant implements less than its twin, its entry says so: `brute` and `bvh`
//! offer only the `mt` triangle test. A variant the CPU has and the GPU lacks is simply not in
//! [`Registry::<Wgpu>::builtin`](Registry::builtin), so resolving a pipeline against it fails
//! before any device work (the `crsh` library turns that into "no wgpu twin" errors).
//!
//! [`HostIntersector`] runs a CPU intersector on the GPU pipeline's rays: the `--reference` of
//! the wgpu backend, so that accuracy is always measured against the CPU's exact answer.
//!
//! ```
//! use crsh_core::{Registry, StageKind};
//! use crsh_wgpu::Wgpu;
//!
//! let gpu = Registry::<Wgpu>::builtin();
//! assert!(gpu.variant(StageKind::Traverse, "crsh").is_some());
//! assert!(gpu.variant(StageKind::Intersect, "brute64").is_none()); // the host reference only
//! let test = &gpu.variant(StageKind::Intersect, "bvh").unwrap().params;
//! assert_eq!(test.iter().find(|p| p.name == "test").unwrap().choices, &["mt"]);
//! ```

use crsh_core::{
    BuiltinVariants, CoreError, Hit, HitMode, Intersector, Query, Ray, Registry, Result,
    StageVariantInfo, Stats,
};
use crsh_cpu::Cpu;

use crate::backend::{GpuBuffer, Wgpu};

#[cfg(doc)]
use crsh_core::PipelineConfig;

impl BuiltinVariants for Wgpu {
    fn register_builtin(registry: &mut Registry<Wgpu>) -> Result<()> {
        crate::primary::raster::register(registry)?;
        crate::raygen::whitted::register(registry)?;
        crate::raygen::ao::register(registry)?;
        crate::raygen::diffuse::register(registry)?;
        crate::hash::thesis::register(registry)?;
        crate::hash::morton_octa::register(registry)?;
        crate::hash::tile::register(registry)?;
        crate::sort::compress::register(registry)?;
        crate::sort::radix::register(registry)?;
        crate::hierarchy::sphere_cone::register(registry)?;
        crate::hierarchy::tile_cone::register(registry)?;
        crate::traverse::crsh::register(registry)?;
        crate::traverse::dual::register(registry)?;
        crate::intersect::brute::register(registry)?;
        crate::intersect::bvh::register(registry)?;
        crate::intersect::grid::register(registry)?;
        crate::intersect::kdtree::register(registry)?;
        crate::shade::phong::register(registry)?;
        crate::shade::ao::register(registry)?;
        crate::shade::diffuse::register(registry)?;
        crsh_cpu::registry::add_gpu_presets(registry)
    }
}

/// The triangle tests with a WGSL twin (`kernels/mt.wgsl`).
pub const GPU_TRIANGLE_TESTS: &[&str] = &["mt"];

/// `info` (a CPU intersector's catalogue entry) with its `test` parameter narrowed to the
/// triangle tests the GPU implements ([`GPU_TRIANGLE_TESTS`]).
pub fn mt_only(mut info: StageVariantInfo) -> StageVariantInfo {
    for p in &mut info.params {
        if p.name == "test" {
            p.choices = GPU_TRIANGLE_TESTS;
        }
    }
    info
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
    /// Wraps a CPU intersector (e.g. from
    /// [`Registry::<Cpu>::build_intersector`](Registry::build_intersector) on the host scene).
    pub fn new(inner: Box<dyn Intersector<Cpu>>) -> HostIntersector {
        HostIntersector { inner }
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

#[cfg(test)]
mod tests {
    use super::*;
    use crsh_core::StageKind;

    #[test]
    fn every_gpu_variant_has_its_cpu_twins_entry() {
        let cpu = Registry::<Cpu>::builtin();
        let gpu = Registry::<Wgpu>::builtin();
        for v in gpu.variants() {
            let twin = cpu
                .variant(v.stage, v.name)
                .unwrap_or_else(|| panic!("{} {} has no CPU twin", v.stage, v.name));
            assert_eq!(v.doc, twin.doc);
            assert_eq!(v.scene_only, twin.scene_only);
            let names = |i: &StageVariantInfo| i.params.iter().map(|p| p.name).collect::<Vec<_>>();
            assert_eq!(names(v), names(twin), "{}", v.name);
        }
        for p in cpu.presets() {
            if crsh_cpu::registry::CPU_ONLY_PRESETS.contains(&p.name.as_str()) {
                assert!(gpu.preset(&p.name).is_none(), "{}", p.name);
                let mut cfg = p.config.clone();
                let e = gpu.resolve(&mut cfg).unwrap_err();
                // The wgpu catalogue narrows the setting away, or has no such variant (the
                // `Registries` front end turns this into "not on the wgpu backend").
                let why = if p.config.intersect.kind == "embree" {
                    "unknown intersect variant `embree`"
                } else {
                    "final_tests"
                };
                assert!(e.to_string().contains(why), "{}: {e}", p.name);
                continue;
            }
            assert_eq!(gpu.preset(&p.name).as_ref(), Some(&p.config), "{}", p.name);
            // Every preset resolves against the GPU's variants (seed 004's `tile_cone` too).
            let mut cfg = p.config.clone();
            gpu.resolve(&mut cfg)
                .unwrap_or_else(|e| panic!("{}: {e}", p.name));
        }
        assert!(gpu.preset("tile_cone").is_some());
        for slot in StageKind::ALL {
            if !slot.optional() {
                assert!(gpu.variants().iter().any(|v| v.stage == slot), "{slot}");
            }
        }
    }
}
