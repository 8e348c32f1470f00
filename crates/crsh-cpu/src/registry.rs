//! The CPU backend's built-in stage variants and presets, registered through the same
//! [`Registry`] calls a third party uses: [`Registry::<Cpu>::builtin`] runs
//! [`BuiltinVariants::register_builtin`] below, which calls each variant module's `register`
//! (its catalogue entry and constructor live beside the stage) and then adds the presets.
//!
//! ```
//! use crsh_core::{Registry, StageKind};
//! use crsh_cpu::Cpu;
//!
//! let registry = Registry::<Cpu>::builtin();
//! assert!(registry.variant(StageKind::Hash, "thesis").is_some());
//! assert_eq!(registry.preset("crsh").unwrap().hash.unwrap().kind, "thesis");
//! ```

use crsh_core::{
    BuiltinVariants, CoreError, ParamValue, PipelineConfig, Registry, Result, StageSpec,
};

use crate::backend::Cpu;

impl BuiltinVariants for Cpu {
    fn register_builtin(registry: &mut Registry<Cpu>) -> Result<()> {
        // Pipeline order; `crsh pipelines` lists the variants in this order.
        crate::primary::raster::register(registry)?;
        crate::primary::raycast::register(registry)?;
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
        crate::intersect::brute::register(registry)?;
        crate::intersect::brute64::register(registry)?;
        crate::intersect::bvh::register(registry)?;
        crate::intersect::bvh2::register(registry)?;
        crate::intersect::grid::register(registry)?;
        crate::shade::phong::register(registry)?;
        crate::shade::ao::register(registry)?;
        crate::shade::diffuse::register(registry)?;
        add_presets(registry)
    }
}

/// The presets `brute`, `bvh`, `crsh` and `rah` (raster primaries, Whitted ray generation and
/// Phong shading; they differ in how rays are traced), added to `registry`, whose variants
/// they use. The wgpu backend registers the same ones.
pub fn add_presets<B: crsh_core::Backend>(registry: &mut Registry<B>) -> Result<()> {
    for (name, doc, cfg) in presets() {
        registry.add_preset(name, doc, cfg)?;
    }
    Ok(())
}

/// The preset definitions (unresolved): `(name, doc, config)`.
fn presets() -> Vec<(&'static str, &'static str, PipelineConfig)> {
    let hierarchy_pipeline = |name: &str, sorted: bool| {
        let mut cfg = PipelineConfig::whitted(name, "brute");
        if sorted {
            cfg.hash = Some(StageSpec::new("thesis"));
            cfg.sort = Some(StageSpec::new("compress"));
        }
        cfg.hierarchy = Some(StageSpec::new("sphere_cone"));
        let mut traverse = StageSpec::new("crsh");
        traverse
            .params
            .insert("mesh_culling".into(), ParamValue::Bool(sorted));
        cfg.traverse = Some(traverse);
        cfg
    };
    vec![
        (
            "brute",
            "every ray against every triangle (the exact reference)",
            PipelineConfig::whitted("brute", "brute"),
        ),
        (
            "bvh",
            "the obvhs CWBVH: the object-hierarchy baseline",
            PipelineConfig::whitted("bvh", "bvh"),
        ),
        (
            "grid",
            "seed 002's uniform grid (eq. 1 resolution, five-pass build, 3D-DDA): the spatial \
             subdivision rebuilt every frame, weak on a detailed object in a huge sparse scene",
            PipelineConfig::whitted("grid", "grid"),
        ),
        (
            "crsh",
            "seed 000's Coherent Ray-Space Hierarchy: thesis hashes, compress-sort-decompress, \
             sphere-cone hierarchy (subdivision 8, depth 2), traversal with whole-mesh culling, \
             final tests on the surviving candidates",
            hierarchy_pipeline("crsh", true),
        ),
        (
            "rah",
            "Roger et al.'s ray-space hierarchy (seed 000 §2.4): the same hierarchy over rays \
             in generation order (no hashing or sorting), no mesh culling",
            hierarchy_pipeline("rah", false),
        ),
    ]
}

/// Runs `f` on a dedicated rayon pool of `threads` worker threads (0: rayon's default, one per
/// core), so that every CPU stage `f` runs uses that many threads: the CLI's `--threads`, and
/// the determinism tests (the output does not depend on the count).
pub fn with_threads<T: Send>(threads: usize, f: impl FnOnce() -> T + Send) -> Result<T> {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .map_err(|e| CoreError::Backend(format!("cannot start {threads} worker threads: {e}")))?;
    Ok(pool.install(f))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crsh_core::StageKind;

    #[test]
    fn presets_resolve_against_the_registry() {
        let registry = Registry::<Cpu>::builtin();
        let names: Vec<&str> = registry.presets().iter().map(|p| p.name.as_str()).collect();
        assert_eq!(names, ["brute", "bvh", "grid", "crsh", "rah"]);
        for p in registry.presets() {
            let cfg = &p.config;
            let name = p.name.as_str();
            assert_eq!(cfg.name, name);
            let expect = if ["brute", "bvh", "grid"].contains(&name) {
                name
            } else {
                "brute"
            };
            assert_eq!(cfg.intersect.kind, expect);
            assert_eq!(cfg.hierarchy.is_some(), ["crsh", "rah"].contains(&name));
            assert_eq!(cfg.hash.is_some(), name == "crsh");
            if let Some(t) = &cfg.traverse {
                assert_eq!(t.bool("mesh_culling").unwrap(), name == "crsh");
            }
            assert_eq!(cfg.raygen.str("shadow_origin").unwrap(), "light");
            assert_eq!(cfg.shade.f64("ambient").unwrap(), 0.05);
        }
        assert!(registry.preset("kdtree").is_none());
    }

    #[test]
    fn the_grid_preset_is_the_whitted_pipeline_on_the_grid() {
        let registry = Registry::<Cpu>::builtin();
        let cfg = registry.preset("grid").unwrap();
        assert_eq!(cfg.intersect.kind, "grid");
        assert!(cfg.hierarchy.is_none() && cfg.hash.is_none());
        assert_eq!(cfg.raygen, registry.preset("bvh").unwrap().raygen);
    }

    #[test]
    fn thread_pools_have_the_size_asked_for() {
        assert_eq!(with_threads(3, rayon::current_num_threads).unwrap(), 3);
        assert_eq!(with_threads(1, rayon::current_num_threads).unwrap(), 1);
    }

    #[test]
    fn registry_is_well_formed_and_every_slot_is_filled() {
        let registry = Registry::<Cpu>::builtin();
        for v in registry.variants() {
            v.validate().unwrap();
        }
        for slot in StageKind::ALL {
            assert!(
                registry.variants().iter().any(|v| v.stage == slot),
                "no variant for {slot}"
            );
        }
        // Whole-scene-only intersectors are marked so before anything is built.
        for (name, scene_only) in [
            ("brute", false),
            ("bvh", true),
            ("bvh2", true),
            ("brute64", true),
        ] {
            let v = registry.variant(StageKind::Intersect, name).unwrap();
            assert_eq!(v.scene_only, scene_only, "{name}");
        }
        // Registering a built-in again is refused.
        let mut again = registry.clone();
        assert!(crate::hash::thesis::register(&mut again).is_err());
    }
}
