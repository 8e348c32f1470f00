//! Seed 004's tile cones through the real pipeline: the `tile_cone` preset (raster primaries,
//! Whitted rays, `tile` hash, `radix` sort, `tile_cone` hierarchy, `crsh` traversal without
//! mesh culling, `brute` final tests) is exact on the built-in scenes (every traced ray agrees
//! with brute force, the same image), every node of every batch holds its rays (checked in
//! `f64`), the cones cull, and the frame does not depend on the thread count.

use std::sync::{Arc, Mutex, OnceLock};

use crsh_core::{
    render_frame, CoreError, Frame, FrameOptions, FrameSize, HierarchyBuilder, PipelineConfig, Ray,
    RayHierarchy, RayKind, Registry, Result, StageContext, StageSpec, Stats,
};
use crsh_cpu::hierarchy::tile_cone::{check_containment, TileConeBuilder, TileConeParams};
use crsh_cpu::intersect::brute::BruteForce;
use crsh_cpu::{with_threads, Cpu};
use crsh_scene::Scene;

const SIZE: u32 = 48;
const DEPTH: u32 = 3;

fn registry() -> &'static Registry<Cpu> {
    static REGISTRY: OnceLock<Registry<Cpu>> = OnceLock::new();
    REGISTRY.get_or_init(Registry::<Cpu>::builtin)
}

fn builtin(name: &str) -> Arc<Scene> {
    Arc::new(crsh_scene::builtin::build(name).unwrap())
}

fn config(name: &str, sets: &[&str]) -> PipelineConfig {
    let mut cfg = registry().preset(name).expect("preset exists");
    for s in sets {
        cfg.set(s).unwrap();
    }
    cfg
}

fn frame(scene: &Arc<Scene>, cfg: &PipelineConfig, reference: Option<&str>) -> Frame<Cpu> {
    frame_at(scene, cfg, SIZE, reference)
}

fn frame_at(
    scene: &Arc<Scene>,
    cfg: &PipelineConfig,
    size: u32,
    reference: Option<&str>,
) -> Frame<Cpu> {
    let ctx = StageContext::new(&Cpu, scene, FrameSize::new(size, size).unwrap());
    let opts = FrameOptions::default().with_max_depth(DEPTH);
    let reference = reference.map(StageSpec::new);
    registry()
        .render(&ctx, cfg, &opts, reference.as_ref(), &mut |_| {})
        .unwrap_or_else(|e| panic!("{} with {}: {e}", scene.name, cfg.name))
}

fn bits(image: &[[f32; 4]]) -> Vec<u32> {
    image.iter().flatten().map(|c| c.to_bits()).collect()
}

/// What one hierarchy build saw.
#[derive(Clone, Debug)]
struct Built {
    kind: RayKind,
    rays: usize,
    nodes: usize,
    full: usize,
}

/// The tile cone builder, checking every hierarchy it builds (containment in `f64`) and
/// recording its size.
struct Checking {
    inner: TileConeBuilder,
    log: Arc<Mutex<Vec<Built>>>,
}

impl HierarchyBuilder<Cpu> for Checking {
    fn name(&self) -> &str {
        "tile_cone"
    }

    fn build(
        &self,
        backend: &Cpu,
        rays: &Vec<Ray>,
        order: Vec<u32>,
        stats: &mut Stats,
    ) -> Result<RayHierarchy<Cpu>> {
        let h = self.inner.build(backend, rays, order, stats)?;
        let offsets = h.leaf_offsets.as_ref().expect("tile cones have offsets");
        assert_eq!(h.levels.len(), 1);
        let full = check_containment(rays, &h.order, offsets, &h.levels[0], &h.reach[0])
            .map_err(CoreError::InvalidInput)?;
        if let Some(r) = rays.first() {
            self.log.lock().unwrap().push(Built {
                kind: r.ray_kind(),
                rays: rays.len(),
                nodes: h.levels[0].len(),
                full,
            });
        }
        Ok(h)
    }
}

/// Renders `scene` with the `tile_cone` preset and the [`Checking`] builder, against a
/// brute-force reference; returns the frame and the builds.
fn checked_frame(scene: &Arc<Scene>, sets: &[&str]) -> (Frame<Cpu>, Vec<Built>) {
    let cfg = config("tile_cone", sets);
    let ctx = StageContext::new(&Cpu, scene, FrameSize::new(SIZE, SIZE).unwrap());
    let mut pipeline = registry().build(&ctx, &cfg).unwrap();
    let h = cfg.hierarchy.as_ref().unwrap();
    let params = TileConeParams::new(
        h.i64("tile_size").unwrap() as u32,
        h.f64("min_half_angle_deg").unwrap(),
    )
    .unwrap();
    let log = Arc::new(Mutex::new(Vec::new()));
    pipeline.stages.hierarchy = Some(Box::new(Checking {
        inner: TileConeBuilder::with_params(ctx.frame, params),
        log: Arc::clone(&log),
    }));
    let opts = FrameOptions::default().with_max_depth(DEPTH);
    let reference = BruteForce::from_scene(scene);
    let f = render_frame(&Cpu, &pipeline, &opts, Some(&reference), &mut |_| {})
        .unwrap_or_else(|e| panic!("{} {sets:?}: {e}", scene.name));
    let built = log.lock().unwrap().clone();
    (f, built)
}

#[test]
fn the_preset_is_exact_and_its_cones_hold_their_rays_on_the_builtin_scenes() {
    for name in ["cornell-mirrors", "office-boxes"] {
        let scene = builtin(name);
        let brute = frame(&scene, &config("brute", &[]), None);
        let tc = frame(&scene, &config("tile_cone", &[]), Some("brute"));
        let acc = tc.stats.accuracy.clone().expect("reference given");
        assert!(acc.rays > 0);
        assert_eq!(acc.hit_agreement(), 1.0, "{name}: {acc:?}");
        assert_eq!(tc.stats.rays, brute.stats.rays, "{name}");
        assert!(
            bits(&tc.image) == bits(&brute.image),
            "{name}: image differs from brute force"
        );
        assert_eq!(tc.stats.stages["hash"], "tile");
        assert_eq!(tc.stats.stages["hierarchy"], "tile_cone");
        assert!(
            tc.stats.tests.ray_triangle < brute.stats.tests.ray_triangle,
            "{name}: {:?} vs {:?}",
            tc.stats.tests,
            brute.stats.tests
        );
        for l in &tc.stats.levels {
            assert_eq!(l.tests, l.hits + l.misses, "{name}: {l:?}");
        }
        // The same frame with every hierarchy checked in f64 (containment, offsets, reach).
        let (checked, built) = checked_frame(&scene, &[]);
        assert!(bits(&checked.image) == bits(&tc.image), "{name}");
        assert_eq!(checked.stats.tests, tc.stats.tests, "{name}");
        assert!(!built.is_empty());
        let kinds: Vec<RayKind> = built.iter().map(|b| b.kind).collect();
        assert!(kinds.contains(&RayKind::Shadow) && kinds.contains(&RayKind::Reflection));
        if name == "office-boxes" {
            assert!(kinds.contains(&RayKind::Refraction), "{kinds:?}");
        }
        for b in &built {
            eprintln!(
                "{name}: {:?} batch of {} rays: {} tile cones, {} of them π",
                b.kind, b.rays, b.nodes, b.full
            );
            // 3×3 tiles of 16 at 48²; shadow rays one node per light and tile at most.
            let lights = scene.lights.len().max(1);
            let groups = if b.kind == RayKind::Shadow {
                9 * lights
            } else {
                9
            };
            assert!(b.nodes <= groups, "{name}: {b:?}");
        }
        let s = &tc.stats;
        eprintln!(
            "{name}: tile_cone tests {:?}; brute ray-triangle {}; per kind {:?}",
            s.tests, brute.stats.tests.ray_triangle, s.per_kind
        );
    }
}

#[test]
fn other_tile_sizes_and_unsorted_rays_are_exact_too() {
    let scene = builtin("cornell-mirrors");
    let brute = frame(&scene, &config("brute", &[]), None);
    let unsorted = {
        let mut cfg = config("tile_cone", &[]);
        cfg.hash = None;
        cfg.sort = None;
        cfg
    };
    let cases = [
        (
            "tile 8",
            config("tile_cone", &["hash.tile_size=8", "hierarchy.tile_size=8"]),
        ),
        (
            "tile 32",
            config(
                "tile_cone",
                &["hash.tile_size=32", "hierarchy.tile_size=32"],
            ),
        ),
        // Hasher and builder tiles differ: nodes are pieces of the hasher's tiles.
        (
            "tile 16 / 8",
            config("tile_cone", &["hierarchy.tile_size=8"]),
        ),
        ("generation order", unsorted),
        (
            "min angle 1°",
            config("tile_cone", &["hierarchy.min_half_angle_deg=1"]),
        ),
    ];
    for (what, cfg) in cases {
        let f = frame(&scene, &cfg, Some("brute"));
        let acc = f.stats.accuracy.clone().unwrap();
        assert_eq!(acc.hit_agreement(), 1.0, "{what}: {acc:?}");
        assert!(bits(&f.image) == bits(&brute.image), "{what}");
        eprintln!(
            "cornell-mirrors {what}: ray-triangle {} bounds {}",
            f.stats.tests.ray_triangle, f.stats.tests.bounds
        );
    }
    let (_, built) = checked_frame(&scene, &["hash.tile_size=8", "hierarchy.tile_size=8"]);
    assert!(built
        .iter()
        .all(|b| b.nodes <= 36 * scene.lights.len().max(1)));
}

#[test]
fn tile_cones_cull_most_ray_triangle_tests_on_cornell_mirrors() {
    // At 48² a 16-pixel tile spans a third of the image, so its reflection rays fan out over
    // 90° and more: 128² (64 tiles, the paper's 256² has 256) is where the cones cull. The
    // brute-force figure N×M is counted without tracing it.
    let scene = builtin("cornell-mirrors");
    let tc = frame_at(&scene, &config("tile_cone", &[]), 128, None);
    let tris = scene.triangle_count() as u64;
    let mut nm = 0;
    for kind in ["reflection", "shadow"] {
        let t = &tc.stats.per_kind[kind];
        eprintln!(
            "cornell-mirrors 128² {kind}: {} rays, ray-triangle {} ({:.1}% of N×M {}), \
             {:.1} tests/ray, tile-cone tests {}",
            t.rays,
            t.ray_triangle,
            100.0 * t.ray_triangle as f64 / (t.rays * tris) as f64,
            t.rays * tris,
            t.ray_triangle as f64 / t.rays as f64,
            t.bounds
        );
        assert!(
            t.ray_triangle * 2 < t.rays * tris,
            "{kind}: {} of {}",
            t.ray_triangle,
            t.rays * tris
        );
        nm += t.rays * tris;
    }
    let s = &tc.stats.tests;
    eprintln!("cornell-mirrors 128²: {s:?}");
    assert_eq!(s.brute_force, nm);
    assert!(s.ray_triangle * 3 < s.brute_force, "{s:?}");
    assert!(s.total * 3 < s.brute_force, "{s:?}");
    // Smaller tiles are more coherent at this size.
    let t8 = frame_at(
        &scene,
        &config("tile_cone", &["hash.tile_size=8", "hierarchy.tile_size=8"]),
        128,
        None,
    );
    eprintln!("cornell-mirrors 128², tiles of 8: {:?}", t8.stats.tests);
    assert!(t8.stats.tests.ray_triangle < s.ray_triangle);
}

#[test]
fn the_frame_does_not_depend_on_the_thread_count() {
    let scene = builtin("office-boxes");
    let cfg = config("tile_cone", &[]);
    let one = with_threads(1, || frame(&scene, &cfg, None)).unwrap();
    let two = with_threads(2, || frame(&scene, &cfg, None)).unwrap();
    assert!(bits(&one.image) == bits(&two.image));
    assert_eq!(one.stats.tests, two.stats.tests);
    assert_eq!(one.stats.levels, two.stats.levels);
}
