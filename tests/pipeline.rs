//! The whole CPU Whitted pipeline: brute force and BVH agree hit for hit and pixel for pixel
//! on every built-in scene and on the shared Cornell boxes, every ray kind occurs where it
//! should, raster and ray-cast primaries agree, the output does not depend on the thread
//! count, and a lit quad has exactly the radiance eq. 3.19 predicts.

use std::path::Path;
use std::sync::Arc;

use crsh_core::glam::{DVec3, Vec3};
use crsh_core::metrics::{psnr_rgba8, to_rgba8};
use crsh_core::{
    CoreError, Frame, FrameOptions, FrameSize, PipelineConfig, Progress, Registry, StageContext,
    StageSpec,
};
use crsh_cpu::{with_threads, Cpu};
use crsh_scene::{Camera, Light, Material, Scene, SceneBuilder};

const SIZE: u32 = 64;

/// Image size and bounce depth of a frame.
struct Opts {
    width: u32,
    height: u32,
    max_depth: u32,
}

fn opts(width: u32, height: u32, max_depth: u32) -> Opts {
    Opts {
        width,
        height,
        max_depth,
    }
}

/// The CPU backend's built-in registry, built once.
fn registry() -> &'static Registry<Cpu> {
    static REGISTRY: std::sync::OnceLock<Registry<Cpu>> = std::sync::OnceLock::new();
    REGISTRY.get_or_init(Registry::<Cpu>::builtin)
}

/// The names of the built-in presets this build can construct (the Embree ones need the
/// `embree` feature; the others are reported as skipped).
fn presets() -> Vec<String> {
    let registry = registry();
    for p in registry.presets() {
        if let Some(why) = registry.unavailable(&p.config) {
            println!("SKIP preset {}: {why}", p.name);
        }
    }
    registry
        .available_presets()
        .map(|p| p.name.clone())
        .collect()
}

/// One frame of `scene` with `cfg` through the registry (`reference` traces every batch again).
fn render(
    scene: &Arc<Scene>,
    cfg: &PipelineConfig,
    o: &Opts,
    reference: Option<&StageSpec>,
    progress: &mut dyn FnMut(Progress),
) -> Result<Frame<Cpu>, CoreError> {
    let ctx = StageContext::new(&Cpu, scene, FrameSize::new(o.width, o.height)?);
    let fo = FrameOptions::default().with_max_depth(o.max_depth);
    registry().render(&ctx, cfg, &fo, reference, progress)
}

/// The preset `name` with the `--set` overrides `sets`.
fn config(name: &str, sets: &[&str]) -> PipelineConfig {
    let mut cfg = registry().preset(name).expect("preset exists");
    for s in sets {
        cfg.set(s).unwrap();
    }
    cfg
}

fn frame(
    scene: &Arc<Scene>,
    cfg: &PipelineConfig,
    o: &Opts,
    reference: Option<&str>,
) -> Frame<Cpu> {
    let reference = reference.map(StageSpec::new);
    render(scene, cfg, o, reference.as_ref(), &mut |_| {})
        .unwrap_or_else(|e| panic!("{} with {}: {e}", scene.name, cfg.name))
}

fn builtin(name: &str) -> Arc<Scene> {
    Arc::new(crsh_scene::builtin::build(name).unwrap())
}

fn load(path: &Path) -> Arc<Scene> {
    Arc::new(crsh_scene::load_path(path).unwrap_or_else(|e| panic!("{e}")))
}

fn bits(image: &[[f32; 4]]) -> Vec<u32> {
    image.iter().flatten().map(|c| c.to_bits()).collect()
}

/// Renders `scene` with the bvh pipeline checked against a brute-force reference, and with
/// the brute pipeline; both must agree on every traced ray and give the same image.
fn check_brute_and_bvh_agree(scene: &Arc<Scene>) -> Frame<Cpu> {
    let o = opts(SIZE, SIZE, 3);
    let bvh = frame(scene, &config("bvh", &[]), &o, Some("brute"));
    let acc = bvh.stats.accuracy.clone().expect("reference given");
    assert!(acc.rays > 0);
    assert_eq!(
        acc.hit_agreement(),
        1.0,
        "{}: bvh vs brute reference: {acc:?}",
        scene.name
    );
    let brute = frame(scene, &config("brute", &[]), &o, Some("bvh"));
    assert_eq!(brute.stats.accuracy.clone().unwrap().hit_agreement(), 1.0);
    assert_eq!(bvh.stats.rays, brute.stats.rays, "{}", scene.name);
    assert!(
        bits(&bvh.image) == bits(&brute.image),
        "{}: brute and bvh images differ",
        scene.name
    );
    // Brute force tests every nearest-hit ray against every triangle (shadow rays may stop
    // at the first occluder), so it never exceeds the N×M figure.
    let tris = scene.triangle_count() as u64;
    for kind in ["reflection", "refraction"] {
        if let Some(k) = brute.stats.per_kind.get(kind) {
            assert_eq!(k.ray_triangle, k.rays * tris, "{} {kind}", scene.name);
        }
    }
    let secondary: u64 = ["shadow", "reflection", "refraction"]
        .iter()
        .filter_map(|k| brute.stats.per_kind.get(*k))
        .map(|k| k.ray_triangle)
        .sum();
    assert!(secondary <= brute.stats.tests.brute_force);
    assert!(
        bvh.stats.tests.ray_triangle < brute.stats.tests.ray_triangle,
        "{}: the BVH should prune",
        scene.name
    );
    bvh
}

#[test]
fn brute_and_bvh_agree_on_every_builtin_scene() {
    for name in crsh_scene::builtin::NAMES {
        let f = check_brute_and_bvh_agree(&builtin(name));
        assert!(f.stats.rays.shadow > 0, "{name}: no shadow rays");
        assert!(
            f.image.iter().any(|p| p[0] + p[1] + p[2] > 0.0),
            "{name}: black image"
        );
    }
}

#[test]
fn brute_and_bvh_agree_on_the_shared_cornell_boxes() {
    for path in crsh_tests::shared_scenes_in("cornell", "toml") {
        check_brute_and_bvh_agree(&load(&path));
    }
}

/// The ray-space hierarchy pipelines (seed 000's CRSH and its RAH baseline) are exact: the
/// same hits as a brute-force reference on every traced ray and the same image, with fewer
/// ray-triangle tests, and per-level counters that add up.
fn check_hierarchy_pipelines_are_exact(scene: &Arc<Scene>) {
    check_hierarchy_pipelines_against(scene, "brute", SIZE);
}

/// [`check_hierarchy_pipelines_are_exact`] with `reference` (`brute`, or `bvh`, which is
/// itself checked against brute force above) tracing the same rays and rendering the
/// reference image, at `size`².
fn check_hierarchy_pipelines_against(scene: &Arc<Scene>, reference: &str, size: u32) {
    let o = opts(size, size, 3);
    let brute = frame(scene, &config(reference, &[]), &o, None);
    for (name, sets) in [
        ("crsh", &[][..]),
        ("rah", &[][..]),
        ("crsh", &["hash.kind=morton", "sort.kind=radix"][..]),
        ("crsh", &["hash.layout=concat"][..]),
        (
            "crsh",
            &[
                "hierarchy.subdivision=16",
                "hierarchy.depth=3",
                "traverse.candidate_budget_mb=0.01",
            ][..],
        ),
    ] {
        let f = frame(scene, &config(name, sets), &o, Some(reference));
        let acc = f.stats.accuracy.clone().unwrap();
        assert_eq!(
            acc.hit_agreement(),
            1.0,
            "{} {name} {sets:?}: {acc:?}",
            scene.name
        );
        assert_eq!(f.stats.rays, brute.stats.rays, "{} {name}", scene.name);
        assert!(
            bits(&f.image) == bits(&brute.image),
            "{} {name} {sets:?}: image differs from the {reference} pipeline's",
            scene.name
        );
        assert!(
            f.stats.tests.total < f.stats.tests.brute_force,
            "{} {name}: the hierarchy should prune",
            scene.name
        );
        if reference == "brute" {
            assert!(
                f.stats.tests.ray_triangle < brute.stats.tests.ray_triangle,
                "{} {name}: fewer ray-triangle tests than brute force",
                scene.name
            );
        }
        assert!(!f.stats.levels.is_empty(), "{name}: no level counters");
        for l in &f.stats.levels {
            assert_eq!(l.tests, l.hits + l.misses, "{name}: {l:?}");
        }
        for key in ["hierarchy_creation", "traversal", "final_tests", "trimming"] {
            assert!(
                f.stats.timings_ms.contains_key(key),
                "{name}: no {key} timing"
            );
        }
    }
}

#[test]
fn crsh_and_rah_are_exact_on_every_builtin_scene() {
    for name in crsh_scene::builtin::NAMES {
        check_hierarchy_pipelines_are_exact(&builtin(name));
    }
}

#[test]
fn crsh_and_rah_are_exact_on_the_shared_cornell_boxes() {
    for path in crsh_tests::shared_scenes_in("cornell", "toml") {
        check_hierarchy_pipelines_are_exact(&load(&path));
    }
}

/// Every other shared manifest (Sponza, the dining room, the bunny, the dragon: 48K-270K
/// triangles), against the BVH pipeline at a small size so that it stays quick.
#[test]
fn crsh_and_rah_are_exact_on_the_large_shared_scenes() {
    let Some(dir) = crsh_tests::scenes_dir() else {
        return;
    };
    let mut subs: Vec<String> = std::fs::read_dir(&dir)
        .map(|d| {
            d.filter_map(|e| e.ok())
                .filter(|e| e.path().is_dir())
                .map(|e| e.file_name().to_string_lossy().into_owned())
                .filter(|n| n != "cornell")
                .collect()
        })
        .unwrap_or_default();
    subs.sort();
    for sub in subs {
        for path in crsh_tests::shared_scenes_in(&sub, "toml") {
            match crsh_scene::load_path(&path) {
                Ok(scene) => check_hierarchy_pipelines_against(&Arc::new(scene), "bvh", 32),
                // The PLY and glTF manifests wait for their loaders; any other error fails.
                Err(e @ crsh_scene::SceneError::UnsupportedFormat { .. }) => {
                    println!("SKIP: {e}")
                }
                Err(e) => panic!("{e}"),
            }
        }
    }
}

#[test]
fn every_ray_kind_occurs_where_expected() {
    let f = frame(
        &builtin("cornell-mirrors"),
        &config("bvh", &[]),
        &opts(SIZE, SIZE, 3),
        None,
    );
    assert!(f.stats.rays.reflection > 0 && f.stats.rays.shadow > 0);
    assert_eq!(f.stats.rays.primary, (SIZE * SIZE) as u64);
    // Mirror walls inside a closed box: every bounce finds a wall, so there are reflections
    // at every depth (more reflection rays than one bounce's worth of pixels).
    assert!(f.stats.rays.reflection > (SIZE * SIZE) as u64);
    // Depth 0: no secondary bounce at all.
    let f0 = frame(
        &builtin("cornell-mirrors"),
        &config("bvh", &[]),
        &opts(SIZE, SIZE, 0),
        None,
    );
    assert_eq!(f0.stats.rays.reflection + f0.stats.rays.refraction, 0);
    assert!(f0.stats.rays.shadow > 0);

    // A glass pane in front of a wall: refraction rays (and the pane's own reflections).
    let scene = glass_scene();
    let f = frame(&scene, &config("bvh", &[]), &opts(SIZE, SIZE, 2), None);
    assert!(f.stats.rays.refraction > 0, "{:?}", f.stats.rays);
    assert!(f.stats.rays.reflection > 0);

    if let Some(path) = crsh_tests::shared_scene("cornell/cornell-sphere.toml") {
        let f = frame(
            &load(&path),
            &config("bvh", &[]),
            &opts(SIZE, SIZE, 3),
            None,
        );
        assert!(f.stats.rays.reflection > 0 && f.stats.rays.refraction > 0);
    }
    if let Some(path) = crsh_tests::shared_scene("cornell/cornell-mirror.toml") {
        let f = frame(
            &load(&path),
            &config("bvh", &[]),
            &opts(SIZE, SIZE, 3),
            None,
        );
        assert!(f.stats.rays.reflection > 0);
    }
}

/// A white back wall at z = -1 with a glass pane (ior 1.5) in front of it at z = 0, covering
/// the middle of the view; one light near the camera.
fn glass_scene() -> Arc<Scene> {
    let quad = |z: f32, s: f32| {
        [
            Vec3::new(-s, -s, z),
            Vec3::new(s, -s, z),
            Vec3::new(s, s, z),
            Vec3::new(-s, s, z),
        ]
    };
    let mut b = SceneBuilder::new("glass-pane");
    let wall = b.material(Material::default());
    let glass = b.material(Material {
        name: "glass".into(),
        diffuse: Vec3::splat(0.05),
        transparency: 0.8,
        reflectivity: 0.1,
        ior: 1.5,
        ..Material::default()
    });
    b.mesh(
        "wall",
        &quad(-1.0, 3.0),
        None,
        &[[0, 1, 2], [0, 2, 3]],
        wall,
    );
    b.mesh(
        "pane",
        &quad(0.0, 0.6),
        None,
        &[[0, 1, 2], [0, 2, 3]],
        glass,
    );
    b.light(Light {
        position: Vec3::new(0.5, 0.5, 3.0),
        color: Vec3::ONE,
        intensity: 1.0,
        attenuation: [1.0, 0.0, 0.0],
        radius: 0.0,
    });
    b.camera(Camera {
        eye: Vec3::new(0.3, 0.2, 3.0),
        target: Vec3::new(0.0, 0.0, -1.0),
        up: Vec3::Y,
        vfov_deg: 50.0,
        aspect: None,
    });
    Arc::new(b.build("glass-pane").unwrap())
}

#[test]
fn raster_and_raycast_primaries_give_the_same_image() {
    for name in crsh_scene::builtin::NAMES {
        let scene = builtin(name);
        let o = opts(SIZE, SIZE, 3);
        let raster = frame(&scene, &config("bvh", &[]), &o, None);
        let cast = frame(&scene, &config("bvh", &["primary.kind=raycast"]), &o, None);
        let (a, b) = (to_rgba8(&raster.image), to_rgba8(&cast.image));
        // Pixels on triangle edges may see the neighbouring triangle; nothing else differs.
        let differing = a
            .chunks_exact(4)
            .zip(b.chunks_exact(4))
            .filter(|(p, q)| p.iter().zip(*q).any(|(x, y)| x.abs_diff(*y) > 2))
            .count();
        let psnr = psnr_rgba8(&a, &b);
        assert!(
            differing * 50 <= (SIZE * SIZE) as usize && psnr > 30.0,
            "{name}: {differing} pixels differ, PSNR {psnr:.1} dB"
        );
    }
}

/// Every test is attributed to a ray kind, and brute force counts exactly the rays that went
/// through intersection: camera rays only when the primary stage casts them.
#[test]
fn counters_add_up_for_raster_and_raycast_primaries() {
    let scene = builtin("office-boxes");
    let tris = scene.triangle_count() as u64;
    let o = opts(SIZE, SIZE, 2);
    for (sets, casts) in [(&[][..], false), (&["primary.kind=raycast"][..], true)] {
        let s = frame(&scene, &config("bvh", sets), &o, None).stats;
        let secondary = s.rays.shadow + s.rays.reflection + s.rays.refraction;
        let pixels = u64::from(SIZE * SIZE);
        let traced = secondary + if casts { pixels } else { 0 };
        assert_eq!(s.traced_rays, traced, "raycast primaries: {casts}");
        assert_eq!(s.tests.brute_force, traced * tris);
        let (bounds, tri_tests): (u64, u64) = s
            .per_kind
            .values()
            .fold((0, 0), |(b, t), k| (b + k.bounds, t + k.ray_triangle));
        assert_eq!((bounds, tri_tests), (s.tests.bounds, s.tests.ray_triangle));
        assert_eq!(s.tests.total, s.tests.bounds + s.tests.ray_triangle);
        let primary = &s.per_kind["primary"];
        assert_eq!(primary.rays, pixels);
        assert_eq!(primary.bounds + primary.ray_triangle > 0, casts);
        assert_eq!(primary.trace_ms > 0.0, casts);
    }
}

#[test]
fn output_does_not_depend_on_the_thread_count() {
    for name in crsh_scene::builtin::NAMES {
        let scene = builtin(name);
        for preset in presets() {
            let cfg = config(&preset, &[]);
            let run = |threads| {
                with_threads(threads, || frame(&scene, &cfg, &opts(SIZE, 48, 3), None)).unwrap()
            };
            let (one, three) = (run(1), run(3));
            assert!(
                bits(&one.image) == bits(&three.image),
                "{name} {preset}: images differ between 1 and 3 threads"
            );
            assert_eq!(one.stats.rays, three.stats.rays, "{name} {preset}");
            assert_eq!(one.stats.tests, three.stats.tests, "{name} {preset}");
            assert_eq!(one.stats.per_kind.len(), three.stats.per_kind.len());
            for (k, v) in &one.stats.per_kind {
                let w = &three.stats.per_kind[k];
                assert_eq!(
                    (v.rays, v.bounds, v.ray_triangle),
                    (w.rays, w.bounds, w.ray_triangle)
                );
            }
        }
    }
}

#[test]
fn culling_and_shadow_origin_are_pure_optimisations() {
    let scene = builtin("office-boxes");
    let o = opts(SIZE, SIZE, 2);
    let base = frame(&scene, &config("bvh", &[]), &o, None);
    let unculled = frame(
        &scene,
        &config("bvh", &["raygen.cull_backfacing=false"]),
        &o,
        None,
    );
    assert!(unculled.stats.rays.shadow > base.stats.rays.shadow);
    assert!(bits(&base.image) == bits(&unculled.image));
    // Starting shadow rays at the surface tests the same segments the other way round.
    let surface = frame(
        &scene,
        &config("bvh", &["raygen.shadow_origin=surface"]),
        &o,
        None,
    );
    assert_eq!(surface.stats.rays, base.stats.rays);
    let psnr = psnr_rgba8(&to_rgba8(&base.image), &to_rgba8(&surface.image));
    assert!(psnr > 45.0, "PSNR {psnr}");
}

/// The order a batch is traced in changes the speed, never the answer: shuffled batches
/// (`raygen.order = shuffled`) and batches sorted for a whole-scene tracer (hash and sort
/// without a hierarchy) give the generation-order image bit for bit and every ray's hit, for
/// a whole-scene tracer, a ray hierarchy, and the AO and diffuse generators.
#[test]
fn ray_order_changes_speed_not_hits() {
    let mut cases: Vec<(&str, &str, Vec<&str>)> = vec![
        ("office-boxes", "bvh", vec![]),
        ("office-boxes", "crsh", vec![]),
        ("office-boxes", "dual", vec![]),
        ("cornell-mirrors", "bvh", vec![]),
        (
            "office-boxes",
            "bvh",
            vec!["raygen.kind=ao", "shade.kind=ao"],
        ),
        (
            "office-boxes",
            "kdtree",
            vec!["raygen.kind=diffuse", "shade.kind=diffuse"],
        ),
    ];
    if registry()
        .available_presets()
        .any(|p| p.name == "embree_packets")
    {
        cases.push(("office-boxes", "embree_packets", vec![]));
    } else {
        println!("SKIP embree_packets under a shuffled order: built without the embree feature");
    }
    let o = opts(SIZE, SIZE, 2);
    for (scene, preset, sets) in cases {
        let scene = builtin(scene);
        let base = frame(&scene, &config(preset, &sets), &o, Some("brute"));
        let variants: [&[&str]; 3] = [
            &["raygen.order=shuffled"],
            &["raygen.order=shuffled", "raygen.order_seed=99"],
            &["hash.kind=thesis", "sort.kind=radix"],
        ];
        for extra in variants {
            if preset != "bvh" && extra[0].starts_with("hash") {
                continue;
            }
            let all: Vec<&str> = sets.iter().chain(extra).copied().collect();
            let cfg = config(preset, &all);
            let other = frame(&scene, &cfg, &o, Some("brute"));
            let what = format!("{} {preset} {all:?}", scene.name);
            assert!(
                bits(&base.image) == bits(&other.image),
                "{what}: image differs"
            );
            assert_eq!(base.stats.rays, other.stats.rays, "{what}");
            let acc = other.stats.accuracy.unwrap();
            assert_eq!(acc.agreeing, acc.rays, "{what}: {acc:?}");
            assert_eq!(
                other.stats.timings_ms.contains_key("reordering"),
                extra[0].starts_with("hash"),
                "{what}"
            );
        }
    }
}

/// A quad lit head-on by one light at a known distance, no ambient: every pixel that sees the
/// quad has the radiance of eq. 3.19 (diffuse + specular with attenuation), computed here
/// independently in f64 from the camera ray through the pixel centre.
#[test]
fn lit_quad_has_the_radiance_of_eq_3_19() {
    let (diffuse, specular, shininess) = (Vec3::new(0.6, 0.5, 0.4), Vec3::splat(0.3), 10.0f32);
    let light = Light {
        position: Vec3::new(0.0, 0.0, 2.0),
        color: Vec3::new(1.0, 0.9, 0.8),
        intensity: 2.0,
        attenuation: [1.0, 0.5, 0.25],
        radius: 0.0,
    };
    let mut b = SceneBuilder::new("lit-quad");
    let m = b.material(Material {
        diffuse,
        specular,
        shininess,
        ..Material::default()
    });
    let s = 1.0;
    b.mesh(
        "quad",
        &[
            Vec3::new(-s, -s, 0.0),
            Vec3::new(s, -s, 0.0),
            Vec3::new(s, s, 0.0),
            Vec3::new(-s, s, 0.0),
        ],
        None,
        &[[0, 1, 2], [0, 2, 3]],
        m,
    );
    b.light(light.clone());
    let camera = Camera {
        eye: Vec3::new(0.0, 0.0, 3.0),
        target: Vec3::ZERO,
        up: Vec3::Y,
        vfov_deg: 45.0,
        aspect: None,
    };
    b.camera(camera.clone());
    let scene = Arc::new(b.build("lit-quad").unwrap());
    let (w, h) = (48u32, 40u32);
    for preset in presets() {
        let f = frame(
            &scene,
            &config(&preset, &["shade.ambient=0"]),
            &opts(w, h, 3),
            None,
        );
        let mut lit = 0;
        for y in 0..h {
            for x in 0..w {
                let px = f.image[(y * w + x) as usize];
                let dir = camera
                    .direction(x as f32 + 0.5, y as f32 + 0.5, w, h)
                    .as_dvec3();
                let eye = camera.eye.as_dvec3();
                let p = eye + dir * (-eye.z / dir.z);
                let expect = if p.x.abs().max(p.y.abs()) < 0.99 {
                    lit += 1;
                    eq_3_19(p, dir, &light, diffuse, specular, shininess as f64)
                } else if p.x.abs().max(p.y.abs()) > 1.01 {
                    DVec3::ZERO
                } else {
                    continue; // on the quad's border
                };
                for k in 0..3 {
                    assert!(
                        (px[k] as f64 - expect[k]).abs() < 1e-4,
                        "{preset} pixel ({x}, {y}): {px:?} vs {expect}"
                    );
                }
                assert_eq!(px[3], 1.0);
            }
        }
        assert!(lit > (w * h / 3) as usize);
        assert_eq!(f.stats.rays.reflection + f.stats.rays.refraction, 0);
    }
}

/// Eq. 3.19a-i for one light at hit point `p` seen along the unit `view` direction, normal +z.
fn eq_3_19(
    p: DVec3,
    view: DVec3,
    light: &Light,
    diffuse: Vec3,
    specular: Vec3,
    shininess: f64,
) -> DVec3 {
    let n = DVec3::Z;
    let to_light = light.position.as_dvec3() - p;
    let dist = to_light.length(); // 3.19b
    let l = to_light / dist; // 3.19a
    let [c, lin, quad] = light.attenuation.map(f64::from);
    let att = 1.0 / (c + dist * lin + dist * dist * quad); // 3.19c
    let half = (l - view).normalize(); // 3.19d-e
    let fd = l.dot(n).clamp(0.0, 1.0); // 3.19f
    let fs = half.dot(n).max(0.0).powf(shininess).clamp(0.0, 1.0); // 3.19g
    let lc = light.color.as_dvec3() * light.intensity as f64;
    diffuse.as_dvec3() * lc * fd * att + specular.as_dvec3() * lc * fs * att // 3.19h-i
}

#[test]
fn bad_pipelines_are_errors_not_panics() {
    let scene = builtin("cornell-mirrors");
    let o = opts(8, 8, 1);
    let run = |cfg: &PipelineConfig, reference: Option<&StageSpec>| {
        render(&scene, cfg, &o, reference, &mut |_| {}).map(|_| ())
    };
    let unknown = config("bvh", &["intersect.kind=octree"]);
    assert!(matches!(
        run(&unknown, None),
        Err(CoreError::UnknownVariant { .. })
    ));
    let unknown_hash = config("crsh", &["hash.kind=zorder"]);
    let err = run(&unknown_hash, None).unwrap_err();
    assert!(matches!(err, CoreError::UnknownVariant { .. }));
    assert!(
        err.to_string().contains("thesis"),
        "lists the known hashers: {err}"
    );
    // A hasher without a sorter is a configuration error, found when the pipeline is built
    // and naming the slots.
    let hash_without_sort = config("bvh", &["hash.kind=thesis"]);
    let err = run(&hash_without_sort, None).unwrap_err();
    assert!(
        matches!(&err, CoreError::Incompatible { slots, .. } if slots == "hash, sort"),
        "{err}"
    );
    // The object BVH and the f64 reference answer whole-scene queries only, not a
    // hierarchy's candidate pairs: the pipeline is rejected when it is built, from the
    // catalogue, before any stage (a BVH build) is constructed.
    let ctx = StageContext::new(&Cpu, &scene, FrameSize::new(8, 8).unwrap());
    for kind in ["intersect.kind=bvh", "intersect.kind=brute64"] {
        let under_hierarchy = config("crsh", &[kind]);
        let err = run(&under_hierarchy, None).unwrap_err();
        assert!(
            matches!(&err, CoreError::Incompatible { slots, .. } if slots == "hierarchy, intersect"),
            "{err}"
        );
        assert!(matches!(
            registry().build(&ctx, &under_hierarchy),
            Err(CoreError::Incompatible { .. })
        ));
    }
    // A hash without a sorter, a hierarchy without a traverser.
    for sets in [&["sort=off"][..], &["traverse=off"]] {
        let err = run(&config("crsh", sets), None).unwrap_err();
        assert!(
            matches!(err, CoreError::Incompatible { .. }),
            "{sets:?}: {err}"
        );
    }
    // Values outside a parameter's range are refused before any stage is built.
    for bad in [
        "shade.ambient=nan",
        "hierarchy.subdivision=1",
        "raygen.epsilon=0.5",
    ] {
        let err = run(&config("crsh", &[bad]), None).unwrap_err();
        assert!(
            matches!(err, CoreError::InvalidParam { .. }),
            "{bad}: {err}"
        );
    }
    let bad_param = config("bvh", &["raygen.epsilon=bright"]);
    assert!(matches!(
        run(&bad_param, None),
        Err(CoreError::InvalidParam { .. })
    ));
    let bad_choice = config("bvh", &["intersect.build_quality=perfect"]);
    assert!(run(&bad_choice, None).is_err());
    assert!(run(&config("bvh", &[]), Some(&StageSpec::new("oracle"))).is_err());
    let zero = render(
        &scene,
        &config("bvh", &[]),
        &opts(0, 8, 1),
        None,
        &mut |_| {},
    );
    assert!(matches!(zero, Err(CoreError::InvalidInput(_))));
}

#[test]
fn progress_is_reported_and_timings_recorded() {
    let scene = builtin("cornell-mirrors");
    let mut steps = Vec::new();
    let f = render(
        &scene,
        &config("brute", &[]),
        &opts(16, 16, 2),
        None,
        &mut |p| steps.push((p.step, p.total_steps)),
    )
    .unwrap();
    assert!(steps.len() > 3);
    assert!(steps.windows(2).all(|w| w[0].0 <= w[1].0));
    let (last, total) = *steps.last().unwrap();
    assert_eq!(last, total);
    for key in [
        "total",
        "primary",
        "ray_creation",
        "intersection",
        "shading",
    ] {
        assert!(f.stats.timings_ms.contains_key(key), "no timing for {key}");
    }
    assert_eq!(
        f.stats.tests.brute_force,
        (f.stats.rays.total() - f.stats.rays.primary) * scene.triangle_count() as u64
    );
}

/// The `f32` pipelines against the `f64` reference (`brute64`): on the built-in scenes they
/// agree on every ray's hit or miss and nearest triangle, and their distances differ by
/// rounding only.
#[test]
fn f32_pipelines_match_the_f64_reference_on_the_builtin_scenes() {
    for name in crsh_scene::builtin::NAMES {
        let scene = builtin(name);
        for pipeline in ["bvh", "crsh", "rah"] {
            let f = frame(
                &scene,
                &config(pipeline, &[]),
                &opts(48, 48, 3),
                Some("brute64"),
            );
            let acc = f.stats.accuracy.clone().expect("reference given");
            assert!(
                acc.rays > 0 && acc.t_compared > 0,
                "{name} {pipeline}: {acc:?}"
            );
            assert!(acc.hit_agreement() >= 0.9999, "{name} {pipeline}: {acc:?}");
            assert!(
                acc.mean_abs_t_error() < 1e-5 * scene.bounds.diagonal().max(1.0) as f64,
                "{name} {pipeline}: mean |t| error {}",
                acc.mean_abs_t_error()
            );
        }
    }
}

/// Every exact pipeline can run every ray-triangle test (`intersect.test`), and under one test
/// they all return the same hits as brute force with that test, bit for bit (the same image),
/// and agree with the f64 reference up to rounding.
#[test]
fn every_exact_pipeline_agrees_with_brute_force_under_each_triangle_test() {
    let o = opts(40, 40, 3);
    for name in crsh_scene::builtin::NAMES {
        let scene = builtin(name);
        for test in ["watertight", "projected"] {
            let set = format!("intersect.test={test}");
            let mut reference = StageSpec::new("brute");
            reference
                .params
                .insert("test".into(), crsh_core::ParamValue::Str(test.into()));
            let brute = render(
                &scene,
                &config("brute", &[&set]),
                &o,
                Some(&StageSpec::new("brute64")),
                &mut |_| {},
            )
            .unwrap();
            let acc = brute.stats.accuracy.clone().unwrap();
            assert!(acc.hit_agreement() >= 0.9999, "{name} {test}: {acc:?}");
            for pipeline in ["bvh", "crsh", "rah"] {
                let f = render(
                    &scene,
                    &config(pipeline, &[&set]),
                    &o,
                    Some(&reference),
                    &mut |_| {},
                )
                .unwrap_or_else(|e| panic!("{name} {pipeline} {test}: {e}"));
                let acc = f.stats.accuracy.clone().unwrap();
                assert_eq!(
                    acc.hit_agreement(),
                    1.0,
                    "{name} {pipeline} {test}: {acc:?}"
                );
                assert_eq!(f.stats.rays, brute.stats.rays, "{name} {pipeline} {test}");
                assert!(
                    bits(&f.image) == bits(&brute.image),
                    "{name} {pipeline} {test}: image differs from brute force's"
                );
            }
        }
    }
}
