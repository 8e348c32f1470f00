//! Seed 004's hierarchical ray engine on the CPU, through the frame driver: the `tile_cone`
//! preset follows refraction through the generations of `glass-shell` (total internal
//! reflection at the cavity, paths alive to generation 4, none after) with the brute-force
//! hits and image, and the per-generation counters (rays alive, tests, cone half-angles) add
//! up to the frame's totals.

use std::sync::Arc;

use crsh_core::{
    Frame, FrameOptions, FrameSize, PipelineConfig, Registry, StageContext, StageSpec,
    HALF_ANGLE_BIN_EDGES_DEG,
};
use crsh_cpu::Cpu;
use crsh_scene::Scene;

const SIZE: u32 = 40;

fn registry() -> &'static Registry<Cpu> {
    static REGISTRY: std::sync::OnceLock<Registry<Cpu>> = std::sync::OnceLock::new();
    REGISTRY.get_or_init(Registry::<Cpu>::builtin)
}

fn render(scene: &Arc<Scene>, cfg: &PipelineConfig, depth: u32) -> Frame<Cpu> {
    let ctx = StageContext::new(&Cpu, scene, FrameSize::new(SIZE, SIZE).unwrap());
    let fo = FrameOptions::default().with_max_depth(depth);
    registry()
        .render(&ctx, cfg, &fo, Some(&StageSpec::new("brute")), &mut |_| {})
        .unwrap_or_else(|e| panic!("{} with {}: {e}", scene.name, cfg.name))
}

fn bits(image: &[[f32; 4]]) -> Vec<u32> {
    image.iter().flatten().map(|c| c.to_bits()).collect()
}

#[test]
fn tile_cones_follow_refraction_through_the_generations_exactly() {
    let scene = Arc::new(crsh_scene::builtin::build("glass-shell-500").unwrap());
    let tile = registry().preset("tile_cone").unwrap();
    let brute = registry().preset("brute").unwrap();
    let depth = 6;
    let got = render(&scene, &tile, depth);
    let want = render(&scene, &brute, depth);
    let acc = got.stats.accuracy.as_ref().unwrap();
    assert_eq!(acc.hit_agreement(), 1.0, "{acc:?}");
    assert_eq!(bits(&got.image), bits(&want.image));

    let s = &got.stats;
    // Every pixel sees the shell, so every pixel's path enters it; the shell keeps paths to
    // generation 4 (the cavity reflects some totally and they leave a generation earlier),
    // and none lives longer.
    let alive = |g: u32| -> u64 {
        s.generations
            .iter()
            .filter(|e| e.generation == g && e.ray_kind == "refraction")
            .map(|e| e.rays)
            .sum()
    };
    let pixels = (SIZE * SIZE) as u64;
    assert_eq!(alive(1), pixels);
    assert_eq!(alive(2), pixels);
    assert!(alive(3) > pixels / 2, "{}", alive(3));
    assert!(
        alive(4) > 0 && alive(4) < alive(3),
        "{} {}",
        alive(4),
        alive(3)
    );
    assert_eq!(alive(5) + alive(6), 0);
    // The counters add up: rays and tests per generation sum to the frame's, and every node
    // lands in one histogram bin.
    let traced: u64 = s
        .generations
        .iter()
        .filter(|g| g.generation > 0)
        .map(|g| g.rays)
        .sum();
    assert_eq!(traced, s.traced_rays);
    let tests: u64 = s
        .generations
        .iter()
        .map(|g| g.bounds + g.ray_triangle)
        .sum();
    assert_eq!(tests, s.tests.total);
    for g in s
        .generations
        .iter()
        .filter(|g| g.generation > 0 && g.rays > 0)
    {
        assert!(g.nodes > 0, "{g:?}");
        assert_eq!(
            g.half_angle_histogram.len(),
            HALF_ANGLE_BIN_EDGES_DEG.len() + 1
        );
        assert_eq!(g.half_angle_histogram.iter().sum::<u64>(), g.nodes, "{g:?}");
        assert!(g.mean_half_angle_deg() <= g.max_half_angle_deg);
    }
    // The cones cull: fewer tests than brute force needs.
    assert!(s.tests.total < s.tests.brute_force / 2, "{:?}", s.tests);
    // Brute force has no hierarchy: no nodes in any generation.
    assert!(want.stats.generations.iter().all(|g| g.nodes == 0));
}
