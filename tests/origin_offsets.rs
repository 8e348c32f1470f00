//! Seed 001's origin offsets are conservative: with every hemisphere set, every ray's hit or
//! miss (and its nearest triangle and `t`) equals the un-offset ray's, for AO rays of short
//! and long lengths, diffuse rays at the first and a deeper bounce, reflection, refraction and
//! shadow rays from the light (`t_max` cut) and from the surface (`t_min` raised). Checked on
//! the built-in scenes, the shared Cornell boxes, the bunny and the dragon (skipped with a
//! printed reason when `../shared/scenes` is absent), against brute force where it is
//! affordable and the BVH (itself equal to brute force bit for bit) elsewhere. The offsets
//! must also do something: some rays get their start raised or end cut.

use std::sync::Arc;

use crsh_core::{
    Backend, FrameSize, Hit, HitMode, Intersector, PipelineConfig, Query, Ray, RayKind, Registry,
    StageContext, Stages, Stats, Surface,
};
use crsh_cpu::Cpu;
use crsh_scene::Scene;

const SETS: [&str; 4] = ["center", "vertex", "median", "polygon"];

fn registry() -> &'static Registry<Cpu> {
    static REGISTRY: std::sync::OnceLock<Registry<Cpu>> = std::sync::OnceLock::new();
    REGISTRY.get_or_init(Registry::<Cpu>::builtin)
}

/// The `bvh` preset with `--set`s.
fn config(sets: &[String]) -> PipelineConfig {
    let mut cfg = registry().preset("bvh").unwrap();
    for s in sets {
        cfg.set(s).unwrap();
    }
    cfg
}

fn stages(scene: &Arc<Scene>, size: u32, sets: &[String]) -> Stages<Cpu> {
    let frame = FrameSize::new(size, size).unwrap();
    let cfg = config(sets);
    registry()
        .build(&StageContext::new(&Cpu, scene, frame), &cfg)
        .unwrap_or_else(|e| panic!("{}: {sets:?}: {e}", scene.name))
        .stages
}

/// The ray settings: `(label, --sets, kinds, deeper)` where `deeper` also checks the rays of
/// the next path vertices (resolved from the un-offset rays' hits).
fn settings() -> Vec<(&'static str, Vec<String>, Vec<RayKind>, bool)> {
    let s = |v: &[&str]| v.iter().map(|x| x.to_string()).collect::<Vec<_>>();
    vec![
        (
            "ao 1%",
            s(&[
                "raygen.kind=ao",
                "shade.kind=ao",
                "raygen.samples=2",
                "raygen.ao_length=0.01",
            ]),
            vec![RayKind::Ao],
            false,
        ),
        (
            "ao 25%",
            s(&["raygen.kind=ao", "shade.kind=ao", "raygen.ao_length=0.25"]),
            vec![RayKind::Ao],
            false,
        ),
        (
            "diffuse",
            s(&[
                "raygen.kind=diffuse",
                "shade.kind=diffuse",
                "raygen.samples=2",
            ]),
            vec![RayKind::Diffuse, RayKind::Shadow],
            true,
        ),
        (
            "whitted, shadows from the light",
            s(&[]),
            vec![RayKind::Shadow, RayKind::Reflection, RayKind::Refraction],
            true,
        ),
        (
            "whitted, shadows from the surface",
            s(&["raygen.shadow_origin=surface"]),
            vec![RayKind::Shadow],
            false,
        ),
    ]
}

fn trace(x: &dyn Intersector<Cpu>, rays: &Vec<Ray>, mode: HitMode) -> Vec<Hit> {
    let mut hits = Cpu.filled(rays.len(), Hit::MISS).unwrap();
    x.intersect(
        &Cpu,
        rays,
        Query::Scene,
        mode,
        &mut hits,
        &mut Stats::default(),
    )
    .unwrap();
    hits
}

/// What one scene's check saw: rays compared, rays whose interval the offsets narrowed, and
/// rays they emptied.
#[derive(Default, Debug)]
struct Seen {
    rays: u64,
    narrowed: u64,
    emptied: u64,
}

/// Compares the rays of `kind` from `surfaces` made without and with the offsets, traced by
/// `exact`.
fn compare(
    what: &str,
    base: &Stages<Cpu>,
    offset: &Stages<Cpu>,
    exact: &dyn Intersector<Cpu>,
    surfaces: &Vec<Surface>,
    kind: RayKind,
    seen: &mut Seen,
) -> (Vec<Ray>, Vec<Hit>) {
    let mut st = Stats::default();
    let r0 = base.raygen.generate(&Cpu, surfaces, kind, &mut st).unwrap();
    let r1 = offset
        .raygen
        .generate(&Cpu, surfaces, kind, &mut st)
        .unwrap();
    assert_eq!(
        r0.len(),
        r1.len(),
        "{what} {kind:?}: the offsets drop no ray"
    );
    let mode = kind.hit_mode();
    let h0 = trace(exact, &r0, mode);
    let h1 = trace(exact, &r1, mode);
    for (i, ((a, b), (ha, hb))) in r0.iter().zip(&r1).zip(h0.iter().zip(&h1)).enumerate() {
        assert!(
            a.origin == b.origin
                && a.dir == b.dir
                && a.source == b.source
                && a.pixel == b.pixel
                && b.t_min >= a.t_min
                && b.t_max <= a.t_max,
            "{what} {kind:?} ray {i}: the offset may only narrow the interval: {a:?} vs {b:?}"
        );
        seen.rays += 1;
        if b.t_min > a.t_min || b.t_max < a.t_max {
            seen.narrowed += 1;
        }
        if b.t_min >= b.t_max && a.t_min < a.t_max {
            seen.emptied += 1;
        }
        assert_eq!(
            ha.is_hit(),
            hb.is_hit(),
            "{what} {kind:?} ray {i} ({b:?}): hit {ha:?} without the offset, {hb:?} with it"
        );
        if mode == HitMode::Closest {
            assert!(
                ha.tri == hb.tri && ha.t.to_bits() == hb.t.to_bits(),
                "{what} {kind:?} ray {i}: nearest {ha:?} without the offset, {hb:?} with it"
            );
        }
    }
    (r0, h0)
}

/// Every setting and every set on `scene` at `size`², traced by `exact` (`brute` or `bvh`).
fn check(scene: &Arc<Scene>, size: u32, exact: &str) {
    let xcfg = {
        let mut c = registry().preset(exact).unwrap();
        c.hierarchy = None;
        c
    };
    let frame = FrameSize::new(size, size).unwrap();
    let x = registry()
        .build(&StageContext::new(&Cpu, scene, frame), &xcfg)
        .unwrap()
        .stages
        .intersector;
    for set in SETS {
        let mut seen = Seen::default();
        for (label, sets, kinds, deeper) in settings() {
            let base = stages(scene, size, &sets);
            let mut with = sets.clone();
            with.push(format!("raygen.offsets={set}"));
            let offset = stages(scene, size, &with);
            let what = format!("{} {label} {set}", scene.name);
            let g = base
                .primary
                .gbuffer(&Cpu, size, size, &mut Stats::default())
                .unwrap();
            for &kind in &kinds {
                let (rays, hits) = compare(&what, &base, &offset, x.as_ref(), &g, kind, &mut seen);
                if deeper && kind.hit_mode() == HitMode::Closest && !rays.is_empty() {
                    let next = base
                        .shader
                        .resolve(&Cpu, &rays, &hits, &mut Stats::default())
                        .unwrap();
                    for &k in &kinds {
                        compare(
                            &format!("{what} (bounce 2)"),
                            &base,
                            &offset,
                            x.as_ref(),
                            &next,
                            k,
                            &mut seen,
                        );
                    }
                }
            }
        }
        println!("{} {set}: {seen:?}", scene.name);
        assert!(seen.rays > 0);
        assert!(
            seen.narrowed > 0,
            "{} {set}: the offsets narrowed no ray: {seen:?}",
            scene.name
        );
    }
}

#[test]
fn offsets_keep_every_hit_on_the_builtin_scenes() {
    for name in crsh_scene::builtin::STATIC_NAMES {
        check(
            &Arc::new(crsh_scene::builtin::build(name).unwrap()),
            40,
            "brute",
        );
    }
}

#[test]
fn offsets_keep_every_hit_on_a_random_soup() {
    // Triangles of every orientation crossing each other: hemispheres next to intersecting,
    // touching and nearly coplanar geometry.
    let scene = crsh_scene::random::triangle_soup(3000, 7).expect("random soup");
    check(&Arc::new(scene), 64, "bvh");
}

#[test]
fn offsets_keep_every_hit_on_the_shared_cornell_boxes() {
    for path in crsh_tests::shared_scenes_in("cornell", "toml") {
        let scene = Arc::new(crsh_scene::load_path(&path).unwrap());
        check(&scene, 48, "brute");
    }
}

#[test]
fn offsets_keep_every_hit_on_the_bunny_and_the_dragon() {
    for rel in ["bunny/bunny.toml", "dragon/dragon.toml"] {
        let Some(path) = crsh_tests::shared_scene(rel) else {
            continue;
        };
        let scene = Arc::new(crsh_scene::load_path(&path).unwrap());
        check(&scene, 48, "bvh");
    }
}
