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
        crate::hierarchy::auto_shape::register(registry)?;
        crate::hierarchy::tile_cone::register(registry)?;
        crate::traverse::crsh::register(registry)?;
        crate::traverse::dual::register(registry)?;
        crate::intersect::brute::register(registry)?;
        crate::intersect::brute64::register(registry)?;
        crate::intersect::bvh::register(registry)?;
        crate::intersect::bvh2::register(registry)?;
        crate::intersect::grid::register(registry)?;
        crate::intersect::kdtree::register(registry)?;
        crate::intersect::embree::register(registry)?;
        crate::shade::phong::register(registry)?;
        crate::shade::ao::register(registry)?;
        crate::shade::diffuse::register(registry)?;
        add_presets(registry)
    }
}

/// The presets `brute`, `bvh`, `grid`, `kdtree`, `crsh`, `rah`, `tile_cone`, `dual`,
/// `dual_inline`, `dual_screen` and `dual_screen_bvh` (raster primaries, Whitted ray generation and Phong
/// shading; they differ in how rays are traced), added to `registry`, whose variants they
/// use. The wgpu backend registers the same ones less [`CPU_ONLY_PRESETS`]
/// ([`add_gpu_presets`]).
pub fn add_presets<B: crsh_core::Backend>(registry: &mut Registry<B>) -> Result<()> {
    for (name, doc, cfg) in presets() {
        registry.add_preset(name, doc, cfg)?;
    }
    Ok(())
}

/// The presets with a setting the wgpu backend lacks (`dual_inline`, `dual_screen`,
/// `dual_screen_bvh`: inline final tests; `embree`, `embree_packets`, `embree_sorted`: a CPU
/// library).
pub const CPU_ONLY_PRESETS: [&str; 6] = [
    "dual_inline",
    "dual_screen",
    "dual_screen_bvh",
    "embree",
    "embree_packets",
    "embree_sorted",
];

/// [`add_presets`] less [`CPU_ONLY_PRESETS`]: the wgpu backend's presets.
pub fn add_gpu_presets<B: crsh_core::Backend>(registry: &mut Registry<B>) -> Result<()> {
    for (name, doc, cfg) in presets() {
        if !CPU_ONLY_PRESETS.contains(&name) {
            registry.add_preset(name, doc, cfg)?;
        }
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
            "embree",
            "Intel Embree 3, single rays (rtcIntersect1/rtcOccluded1) over its high-quality \
             (spatial-split) BVH: the tracer CPU renderers use, the anchor to beat (needs the \
             `embree` feature; CPU only)",
            embree_pipeline("embree", "single", false),
        ),
        (
            "embree_packets",
            "Intel Embree 3, 16-wide packets of consecutive rays (rtcIntersect16/rtcOccluded16) \
             with the coherent flag, high-quality BVH: Embree's fastest mode on coherent rays \
             (needs the `embree` feature; CPU only)",
            embree_pipeline("embree_packets", "packet16", true),
        ),
        (
            "embree_sorted",
            "the `embree_packets` preset fed by crsh's ray sorting: each batch hashed \
             (thesis hashes) and radix-sorted, traced in key order in 16-wide coherent \
             packets, the hits put back in the batch's order (needs the `embree` feature; \
             CPU only)",
            embree_sorted_pipeline(),
        ),
        (
            "grid",
            "seed 002's uniform grid (eq. 1 resolution, five-pass build, 3D-DDA): the spatial \
             subdivision rebuilt every frame, weak on a detailed object in a huge sparse scene",
            PipelineConfig::whitted("grid", "grid"),
        ),
        (
            "kdtree",
            "seed 003's SAH kd-tree (perfect splits, C_isect = 5 C_trav), rays traced one by one (`intersect.traversal` picks seed 003's packets, frusta, MFT or cones)",
            PipelineConfig::whitted("kdtree", "kdtree"),
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
        (
            "tile_cone",
            "seed 004's hierarchical ray engine (Szécsi 2006): rays sorted by 16×16 screen \
             tile, one enclosing cone per tile (§4, apex sign corrected), every triangle's \
             sphere tested against every tile cone (no mesh culling), final tests on the \
             survivors",
            tile_cone_pipeline(),
        ),
        (
            "dual",
            "issue 17's ray hierarchy against an object hierarchy: thesis hashes, radix sort, \
             sphere-cone hierarchy (subdivision 16, depth 3, leaf cones from extreme rays), the \
             dual traversal over a per-frame Morton LBVH (box tests, single rays), final tests \
             on the candidates",
            dual_pipeline(),
        ),
        (
            "dual_inline",
            "the `dual` preset with inline final tests: the traversal tests each (lowest node, \
             triangle) pair as soon as it finds it, so an any-hit ray leaves it at its first \
             hit and a closest-hit ray's segment ends at its nearest hit so far (CPU only)",
            dual_inline_pipeline(),
        ),
        (
            "dual_screen",
            "the `dual_inline` preset with screen-ordered keys: rays sorted by 4×4 pixel \
             tiles in Z-order (the `tile` hash, `order = morton`) instead of the thesis \
             hashes, so every lowest node of 16 rays is a 4×4 block and the nodes above are \
             16×16 and 64×64 blocks (CPU only)",
            dual_screen_pipeline(),
        ),
        (
            "dual_screen_bvh",
            "the `dual_screen` preset over obvhs's binary BVH instead of the Morton LBVH \
             (`traverse.objects = bvh`, PLOC `fast`: about 60 ms more to build on Sponza and \
             the dining room, fewer tests and a faster traversal there) and with lowest \
             spheres centred on their origins' box (`hierarchy.leaf_sphere = box`, no Welzl \
             iterations) and lowest nodes of 32 rays, two 4×4 tiles (`hierarchy.subdivision \
             = 32`: fewer nodes to build and pair), its lowest nodes of 60° and wider traced \
             ray by ray through the same tree in obvhs's 8-wide form (`traverse.wide_cone = \
             60`); for static scenes, where the object hierarchy is built once (CPU only)",
            dual_screen_bvh_pipeline(),
        ),
    ]
}

/// A Whitted pipeline `name` on the `embree` intersector with query `mode` and coherent
/// flag `coherent` (build quality `high`).
fn embree_pipeline(name: &str, mode: &str, coherent: bool) -> PipelineConfig {
    let mut cfg = PipelineConfig::whitted(name, "embree");
    cfg.intersect
        .params
        .insert("mode".into(), ParamValue::Str(mode.into()));
    cfg.intersect
        .params
        .insert("coherent".into(), ParamValue::Bool(coherent));
    cfg
}

/// The `embree_sorted` preset's pipeline: [`embree_pipeline`] in 16-wide coherent packets
/// behind the `thesis` hash and the `radix` sort, with no ray hierarchy, so Embree's packets
/// are filled from rays of neighbouring keys instead of neighbouring generation indices.
fn embree_sorted_pipeline() -> PipelineConfig {
    let mut cfg = embree_pipeline("embree_sorted", "packet16", true);
    cfg.hash = Some(StageSpec::new("thesis"));
    cfg.sort = Some(StageSpec::new("radix"));
    cfg
}

/// The `dual_screen_bvh` preset's pipeline: [`dual_screen_pipeline`] with `traverse.objects =
/// bvh`, `traverse.wide_cone = 60`, `hierarchy.leaf_sphere = box` and `hierarchy.subdivision =
/// 32` (README, "Object side on obvhs's BVH", "Lowest nodes of 32 rays" and "Wide ray nodes
/// through an 8-wide BVH"). The LBVH is the cheaper rebuild for moving
/// geometry; over a BVH built once this is the fastest ray-hierarchy pipeline measured for
/// issue 17 on the CPU.
fn dual_screen_bvh_pipeline() -> PipelineConfig {
    let mut cfg = dual_screen_pipeline();
    if let Some(t) = cfg.traverse.as_mut() {
        t.params
            .insert("objects".into(), ParamValue::Str("bvh".into()));
        t.params.insert("wide_cone".into(), ParamValue::Float(60.0));
    }
    if let Some(h) = cfg.hierarchy.as_mut() {
        h.params
            .insert("leaf_sphere".into(), ParamValue::Str("box".into()));
        h.params.insert("subdivision".into(), ParamValue::Int(32));
    }
    cfg
}

/// The `dual_screen` preset's pipeline: [`dual_inline_pipeline`] with the `tile` hash over
/// 4×4 tiles in Z-order (README, "Screen-ordered keys"). Its keys cost a few multiplications
/// and a bit interleave per ray where the thesis hash takes a direction, two `atan2` and table
/// searches, and on the dining room and cornell-mirror its nodes need fewer tests; on Sponza's
/// shadow rays the thesis hash's direction order needs fewer.
fn dual_screen_pipeline() -> PipelineConfig {
    let mut cfg = dual_inline_pipeline();
    let mut hash = StageSpec::new("tile");
    hash.params.insert("tile_size".into(), ParamValue::Int(4));
    hash.params
        .insert("order".into(), ParamValue::Str("morton".into()));
    cfg.hash = Some(hash);
    cfg
}

/// The `dual_inline` preset's pipeline: [`dual_pipeline`] with `traverse.final_tests = inline`,
/// the fastest ray-hierarchy pipeline measured for issue 17 on the CPU (README, "Inline final
/// tests"). The wgpu traversal has no inline tests ([`CPU_ONLY_PRESETS`]).
fn dual_inline_pipeline() -> PipelineConfig {
    let mut cfg = dual_pipeline();
    if let Some(t) = cfg.traverse.as_mut() {
        t.params
            .insert("final_tests".into(), ParamValue::Str("inline".into()));
    }
    cfg
}

/// The `dual` preset's pipeline, the fastest ray-hierarchy pipeline measured for issue 17 that
/// runs on both backends (README, "The `dual` preset"; on the CPU [`dual_inline_pipeline`] is
/// faster): `thesis` hash, `radix` sort (on the
/// CPU the same order as `compress` in half the time: shadow keys rarely repeat, so the chunks
/// are nearly as many as the rays), `sphere_cone` at subdivision 16 and depth 3 (the shape
/// `auto_shape`'s pre-pass picks on Sponza, the dining room and cornell-mirror, without the
/// pre-pass; `auto_shape` has no wgpu twin, this preset runs on both backends) with lowest
/// cones from extreme rays (`leaf_cone = extremes`: no sequential chain per node, and fewer
/// tests on those scenes), `dual` with its defaults (LBVH objects, box test, single rays) and
/// `brute` final tests.
fn dual_pipeline() -> PipelineConfig {
    let mut cfg = PipelineConfig::whitted("dual", "brute");
    cfg.hash = Some(StageSpec::new("thesis"));
    cfg.sort = Some(StageSpec::new("radix"));
    let mut hierarchy = StageSpec::new("sphere_cone");
    hierarchy
        .params
        .insert("subdivision".into(), ParamValue::Int(16));
    hierarchy.params.insert("depth".into(), ParamValue::Int(3));
    hierarchy
        .params
        .insert("leaf_cone".into(), ParamValue::Str("extremes".into()));
    cfg.hierarchy = Some(hierarchy);
    cfg.traverse = Some(StageSpec::new("dual"));
    cfg
}

/// The `tile_cone` preset's pipeline: `tile` hash and `tile_cone` hierarchy with 16-pixel
/// tiles (seed 004 §7), `radix` sort (stable, so tiles keep generation order), `crsh`
/// traversal without mesh culling (the paper culls per triangle only), `brute` final tests.
fn tile_cone_pipeline() -> PipelineConfig {
    let tile = ParamValue::Int(crate::hash::tile::DEFAULT_TILE_SIZE as i64);
    let mut cfg = PipelineConfig::whitted("tile_cone", "brute");
    let mut hash = StageSpec::new("tile");
    hash.params.insert("tile_size".into(), tile.clone());
    cfg.hash = Some(hash);
    cfg.sort = Some(StageSpec::new("radix"));
    let mut hierarchy = StageSpec::new("tile_cone");
    hierarchy.params.insert("tile_size".into(), tile);
    cfg.hierarchy = Some(hierarchy);
    let mut traverse = StageSpec::new("crsh");
    traverse
        .params
        .insert("mesh_culling".into(), ParamValue::Bool(false));
    cfg.traverse = Some(traverse);
    cfg
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
        assert_eq!(
            names,
            [
                "brute",
                "bvh",
                "embree",
                "embree_packets",
                "embree_sorted",
                "grid",
                "kdtree",
                "crsh",
                "rah",
                "tile_cone",
                "dual",
                "dual_inline",
                "dual_screen",
                "dual_screen_bvh"
            ]
        );
        for p in registry.presets() {
            let cfg = &p.config;
            let name = p.name.as_str();
            assert_eq!(cfg.name, name);
            let expect = if ["brute", "bvh", "grid", "kdtree"].contains(&name) {
                name
            } else if name.starts_with("embree") {
                "embree"
            } else {
                "brute"
            };
            assert_eq!(cfg.intersect.kind, expect);
            let hierarchies = [
                "crsh",
                "rah",
                "tile_cone",
                "dual",
                "dual_inline",
                "dual_screen",
                "dual_screen_bvh",
            ];
            assert_eq!(cfg.hierarchy.is_some(), hierarchies.contains(&name));
            let hashed = [
                "embree_sorted",
                "crsh",
                "tile_cone",
                "dual",
                "dual_inline",
                "dual_screen",
                "dual_screen_bvh",
            ];
            assert_eq!(cfg.hash.is_some(), hashed.contains(&name));
            if let Some(t) = cfg.traverse.as_ref().filter(|t| t.kind == "crsh") {
                assert_eq!(t.bool("mesh_culling").unwrap(), name == "crsh");
            }
            assert_eq!(cfg.raygen.str("shadow_origin").unwrap(), "light");
            assert_eq!(cfg.shade.f64("ambient").unwrap(), 0.05);
        }
        // The Embree presets are listed in every build, and available with the feature only.
        let available: Vec<&str> = registry
            .available_presets()
            .map(|p| p.name.as_str())
            .collect();
        for name in ["embree", "embree_packets", "embree_sorted"] {
            let cfg = registry.preset(name).unwrap();
            assert_eq!(
                available.contains(&name),
                crate::intersect::embree::AVAILABLE
            );
            let why = registry.unavailable(&cfg);
            assert_eq!(
                why.is_none(),
                crate::intersect::embree::AVAILABLE,
                "{why:?}"
            );
        }
        assert_eq!(
            available.len() + 3 * usize::from(!crate::intersect::embree::AVAILABLE),
            names.len()
        );
    }

    #[test]
    fn the_dual_preset_is_issue_17s_pipeline() {
        let registry = Registry::<Cpu>::builtin();
        let cfg = registry.preset("dual").unwrap();
        assert_eq!(cfg.hash.as_ref().unwrap().kind, "thesis");
        assert_eq!(cfg.sort.as_ref().unwrap().kind, "radix");
        let h = cfg.hierarchy.as_ref().unwrap();
        assert_eq!(
            (
                h.kind.as_str(),
                h.i64("subdivision").unwrap(),
                h.i64("depth").unwrap()
            ),
            ("sphere_cone", 16, 3)
        );
        assert_eq!(h.str("leaf_cone").unwrap(), "extremes");
        let t = cfg.traverse.as_ref().unwrap();
        assert_eq!(t.kind, "dual");
        assert_eq!(t.str("objects").unwrap(), "lbvh");
        assert!(t.bool("box_test").unwrap() && t.bool("single_rays").unwrap());
        assert_eq!(t.str("final_tests").unwrap(), "batched");
        assert_eq!(cfg.intersect.kind, "brute");
        // `dual_inline` is the same pipeline with inline final tests.
        let mut inline = registry.preset("dual_inline").unwrap();
        let it = inline.traverse.as_mut().unwrap();
        assert_eq!(it.str("final_tests").unwrap(), "inline");
        it.params
            .insert("final_tests".into(), ParamValue::Str("batched".into()));
        inline.name = cfg.name.clone();
        assert_eq!(inline, cfg);
        // `dual_screen` is `dual_inline` with 4×4 tiles in Z-order as keys.
        let inline = registry.preset("dual_inline").unwrap();
        let mut screen = registry.preset("dual_screen").unwrap();
        let h = screen.hash.as_ref().unwrap();
        assert_eq!(
            (
                h.kind.as_str(),
                h.i64("tile_size").unwrap(),
                h.str("order").unwrap()
            ),
            ("tile", 4, "morton")
        );
        screen.hash = inline.hash.clone();
        screen.name = inline.name.clone();
        assert_eq!(screen, inline);
        // `dual_screen_bvh` is `dual_screen` over obvhs's BVH, with wide lowest nodes traced
        // through its 8-wide form, box-centred lowest spheres and lowest nodes of 32 rays.
        let screen = registry.preset("dual_screen").unwrap();
        let mut over_bvh = registry.preset("dual_screen_bvh").unwrap();
        let t = over_bvh.traverse.as_mut().unwrap();
        assert_eq!(t.str("objects").unwrap(), "bvh");
        t.params
            .insert("objects".into(), ParamValue::Str("lbvh".into()));
        assert_eq!(t.f64("wide_cone").unwrap(), 60.0);
        t.params
            .insert("wide_cone".into(), ParamValue::Float(180.0));
        let h = over_bvh.hierarchy.as_mut().unwrap();
        assert_eq!(h.str("leaf_sphere").unwrap(), "box");
        h.params
            .insert("leaf_sphere".into(), ParamValue::Str("welzl".into()));
        assert_eq!(h.i64("subdivision").unwrap(), 32);
        h.params.insert("subdivision".into(), ParamValue::Int(16));
        over_bvh.name = screen.name.clone();
        assert_eq!(over_bvh, screen);
    }

    #[test]
    fn the_tile_cone_preset_is_seed_004s_engine() {
        let registry = Registry::<Cpu>::builtin();
        let cfg = registry.preset("tile_cone").unwrap();
        let hash = cfg.hash.as_ref().unwrap();
        let hierarchy = cfg.hierarchy.as_ref().unwrap();
        assert_eq!(
            (hash.kind.as_str(), hash.i64("tile_size").unwrap()),
            ("tile", 16)
        );
        assert_eq!(cfg.sort.as_ref().unwrap().kind, "radix");
        assert_eq!(hierarchy.kind, "tile_cone");
        assert_eq!(hierarchy.i64("tile_size").unwrap(), 16);
        assert_eq!(hierarchy.f64("min_half_angle_deg").unwrap(), 1.0);
        let traverse = cfg.traverse.as_ref().unwrap();
        assert_eq!(traverse.kind, "crsh");
        assert!(!traverse.bool("mesh_culling").unwrap());
        assert_eq!(cfg.intersect.kind, "brute");
        assert_eq!(cfg.primary.kind, "raster");
        assert_eq!(cfg.raygen, registry.preset("crsh").unwrap().raygen);
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
    fn the_kdtree_preset_is_the_whitted_pipeline_on_the_sah_kd_tree() {
        let registry = Registry::<Cpu>::builtin();
        let cfg = registry.preset("kdtree").unwrap();
        let x = &cfg.intersect;
        assert_eq!(x.kind, "kdtree");
        assert_eq!(x.str("build").unwrap(), "sah");
        assert_eq!(
            (x.f64("c_trav").unwrap(), x.f64("c_isect").unwrap()),
            (1.0, 5.0)
        );
        assert_eq!(x.i64("max_depth").unwrap(), 0);
        assert_eq!(x.str("test").unwrap(), "mt");
        assert!(cfg.hierarchy.is_none() && cfg.hash.is_none());
        assert_eq!(cfg.raygen, registry.preset("bvh").unwrap().raygen);
        // Whole-scene only: a hierarchy pipeline cannot use it.
        let mut rah = registry.preset("rah").unwrap();
        rah.intersect = StageSpec::new("kdtree");
        assert!(registry.resolve(&mut rah).is_err());
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
            ("grid", true),
            ("kdtree", true),
        ] {
            let v = registry.variant(StageKind::Intersect, name).unwrap();
            assert_eq!(v.scene_only, scene_only, "{name}");
        }
        // Registering a built-in again is refused.
        let mut again = registry.clone();
        assert!(crate::hash::thesis::register(&mut again).is_err());
    }
}
