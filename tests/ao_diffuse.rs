//! Seed 001's ray kinds on the CPU: ambient-occlusion and diffuse pipelines (raygen `ao` +
//! shade `ao`, raygen `diffuse` + shade `diffuse`) give the same image through brute force and
//! both BVHs, whatever the thread count; their ray counts are what the generators promise;
//! AO is 1 under an open sky and 0 inside a closed box; the diffuse direct light of a lit quad
//! is the Lambertian formula; and a generator paired with a shader that cannot shade its rays
//! is refused.

use std::sync::Arc;

use crsh_core::glam::Vec3;
use crsh_core::{
    CoreError, Frame, FrameOptions, FrameSize, PipelineConfig, Registry, StageContext, StageSpec,
};
use crsh_cpu::{with_threads, Cpu};
use crsh_scene::{Camera, Light, Material, Scene, SceneBuilder};

const SIZE: u32 = 48;

fn registry() -> &'static Registry<Cpu> {
    static REGISTRY: std::sync::OnceLock<Registry<Cpu>> = std::sync::OnceLock::new();
    REGISTRY.get_or_init(Registry::<Cpu>::builtin)
}

/// Preset `preset` with raygen and shader `kind` (`ao` or `diffuse`) and the `--set`s.
fn config(preset: &str, kind: &str, sets: &[&str]) -> PipelineConfig {
    let mut cfg = registry().preset(preset).expect("preset exists");
    cfg.set(&format!("raygen.kind={kind}")).unwrap();
    cfg.set(&format!("shade.kind={kind}")).unwrap();
    for s in sets {
        cfg.set(s).unwrap();
    }
    cfg
}

fn try_render(
    scene: &Arc<Scene>,
    cfg: &PipelineConfig,
    depth: u32,
    reference: Option<&str>,
) -> Result<Frame<Cpu>, CoreError> {
    let ctx = StageContext::new(&Cpu, scene, FrameSize::new(SIZE, SIZE)?);
    let fo = FrameOptions::default().with_max_depth(depth);
    let reference = reference.map(StageSpec::new);
    registry().render(&ctx, cfg, &fo, reference.as_ref(), &mut |_| {})
}

fn render(
    scene: &Arc<Scene>,
    cfg: &PipelineConfig,
    depth: u32,
    reference: Option<&str>,
) -> Frame<Cpu> {
    try_render(scene, cfg, depth, reference)
        .unwrap_or_else(|e| panic!("{} with {}: {e}", scene.name, cfg.name))
}

fn bits(image: &[[f32; 4]]) -> Vec<u32> {
    image.iter().flatten().map(|c| c.to_bits()).collect()
}

fn builtin(name: &str) -> Arc<Scene> {
    Arc::new(crsh_scene::builtin::build(name).unwrap())
}

fn hit_pixels(f: &Frame<Cpu>) -> u64 {
    f.stats.per_kind.get("primary").map_or(0, |k| k.rays)
}

#[test]
fn ao_and_diffuse_images_agree_across_intersectors_and_thread_counts() {
    for name in crsh_scene::builtin::STATIC_NAMES {
        let scene = builtin(name);
        for (kind, sets, depth) in [
            ("ao", &["raygen.samples=3", "raygen.ao_length=0.25"][..], 0),
            ("diffuse", &["raygen.samples=2"][..], 2),
        ] {
            let brute = render(&scene, &config("brute", kind, sets), depth, None);
            let bvh = render(&scene, &config("bvh", kind, sets), depth, Some("brute"));
            let bvh2 = with_threads(1, || {
                render(
                    &scene,
                    &config("bvh", kind, &[sets, &["intersect.kind=bvh2"][..]].concat()),
                    depth,
                    Some("brute"),
                )
            })
            .unwrap();
            for f in [&bvh, &bvh2] {
                assert_eq!(
                    f.stats.accuracy.clone().unwrap().hit_agreement(),
                    1.0,
                    "{name} {kind}"
                );
                assert_eq!(f.stats.rays, brute.stats.rays, "{name} {kind}");
                assert!(
                    bits(&f.image) == bits(&brute.image),
                    "{name} {kind}: image differs from brute force's"
                );
            }
            assert!(bvh.stats.tests.inner_nodes > 0 && bvh.stats.tests.leaves > 0);
            assert!(bvh2.stats.tests.inner_nodes > bvh.stats.tests.inner_nodes);
            assert!(
                brute.image.iter().any(|p| p[0] > 0.0),
                "{name} {kind}: black"
            );
        }
    }
}

#[test]
fn ray_counts_follow_the_generators() {
    let scene = builtin("cornell-mirrors");
    let f = render(&scene, &config("bvh", "ao", &["raygen.samples=4"]), 3, None);
    // Background pixels spawn nothing; every hit spawns `samples` rays; no bounces.
    let ao = f.stats.rays.ao;
    assert!(ao > 0 && ao.is_multiple_of(4), "{ao}");
    assert!(ao <= 4 * SIZE as u64 * SIZE as u64);
    assert_eq!(
        f.stats.rays.shadow + f.stats.rays.reflection + f.stats.rays.diffuse,
        0
    );
    let _ = hit_pixels(&f);

    let d0 = render(
        &scene,
        &config("bvh", "diffuse", &["raygen.samples=3"]),
        0,
        None,
    );
    let d1 = render(
        &scene,
        &config("bvh", "diffuse", &["raygen.samples=3"]),
        1,
        None,
    );
    let d3 = render(
        &scene,
        &config("bvh", "diffuse", &["raygen.samples=3"]),
        3,
        None,
    );
    assert_eq!(d0.stats.rays.diffuse, 0);
    // The first bounce: 3 rays per hit pixel (the same hits as AO's).
    assert_eq!(d1.stats.rays.diffuse, 3 * ao / 4);
    assert!(d3.stats.rays.diffuse > d1.stats.rays.diffuse);
    assert!(d3.stats.rays.shadow > d1.stats.rays.shadow);
    // Indirect light only adds.
    let sum = |f: &Frame<Cpu>| {
        f.image
            .iter()
            .map(|p| (p[0] + p[1] + p[2]) as f64)
            .sum::<f64>()
    };
    assert!(sum(&d3) > sum(&d1) && sum(&d1) > sum(&d0));
}

/// A quad facing +z under a camera above it, lit by `lights`.
fn quad(lights: &[Light], with_lid: bool) -> Arc<Scene> {
    let mut b = SceneBuilder::new("quad");
    let m = b.material(Material {
        diffuse: Vec3::splat(0.5),
        ..Material::default()
    });
    let square = |z: f32, up: bool| {
        let v = [
            Vec3::new(-1.0, -1.0, z),
            Vec3::new(1.0, -1.0, z),
            Vec3::new(1.0, 1.0, z),
            Vec3::new(-1.0, 1.0, z),
        ];
        let tris = if up {
            [[0, 1, 2], [0, 2, 3]]
        } else {
            [[0, 2, 1], [0, 3, 2]]
        };
        (v, tris)
    };
    let (v, t) = square(0.0, true);
    b.mesh("floor", &v, None, &t, m);
    if with_lid {
        // A box around the floor: lid and four walls, all facing inwards.
        let (v, t) = square(0.5, false);
        b.mesh("lid", &v, None, &t, m);
        for (i, (a, c)) in [
            (Vec3::new(-1.0, -1.0, 0.0), Vec3::new(1.0, -1.0, 0.0)),
            (Vec3::new(1.0, -1.0, 0.0), Vec3::new(1.0, 1.0, 0.0)),
            (Vec3::new(1.0, 1.0, 0.0), Vec3::new(-1.0, 1.0, 0.0)),
            (Vec3::new(-1.0, 1.0, 0.0), Vec3::new(-1.0, -1.0, 0.0)),
        ]
        .into_iter()
        .enumerate()
        {
            let up = Vec3::new(0.0, 0.0, 0.5);
            let v = [a, c, c + up, a + up];
            b.mesh(format!("wall{i}"), &v, None, &[[0, 1, 2], [0, 2, 3]], m);
        }
    }
    for l in lights {
        b.light(l.clone());
    }
    b.camera(Camera {
        eye: Vec3::new(0.0, 0.0, if with_lid { 0.45 } else { 3.0 }),
        target: Vec3::ZERO,
        up: Vec3::Y,
        vfov_deg: 30.0,
        aspect: None,
    });
    Arc::new(b.build("quad").expect("valid scene"))
}

#[test]
fn ao_is_one_under_an_open_sky_and_zero_in_a_closed_box() {
    let open = quad(&[], false);
    let f = render(&open, &config("bvh", "ao", &["raygen.samples=4"]), 0, None);
    let hits: Vec<_> = f.image.iter().filter(|p| p[0] > 0.0).collect();
    assert!(!hits.is_empty());
    for p in hits {
        assert_eq!(p[0], 1.0, "nothing above the quad occludes");
    }
    // Inside a closed box every AO ray long enough meets a wall, whatever its direction: the
    // camera sits inside the lid.
    let closed = quad(&[], true);
    let f = render(
        &closed,
        &config("bvh", "ao", &["raygen.samples=4", "raygen.ao_length=2"]),
        0,
        Some("brute"),
    );
    assert!(f.stats.rays.ao > 0);
    assert!(
        f.image.iter().all(|p| p[0] == 0.0),
        "every AO ray is occluded"
    );
}

#[test]
fn diffuse_direct_light_is_lambertian() {
    let light = Light {
        position: Vec3::new(0.0, 0.0, 2.0),
        color: Vec3::ONE,
        intensity: 3.0,
        attenuation: [1.0, 0.0, 0.0],
        radius: 0.0,
    };
    let scene = quad(&[light], false);
    let f = render(&scene, &config("bvh", "diffuse", &[]), 0, None);
    // The centre pixel sees the quad's centre, straight under the light: albedo / π · I · cos 0.
    let c = f.image[(SIZE / 2 * SIZE + SIZE / 2) as usize];
    let want = 0.5 / std::f32::consts::PI * 3.0;
    assert!((c[0] - want).abs() < 1e-3 * want, "{} vs {want}", c[0]);
}

#[test]
fn a_shader_that_cannot_shade_the_generators_rays_is_refused() {
    let scene = builtin("cornell-mirrors");
    let mut cfg = config("bvh", "ao", &[]);
    cfg.set("shade.kind=phong").unwrap();
    let err = try_render(&scene, &cfg, 0, None).err().expect("refused");
    assert!(
        matches!(err, CoreError::Incompatible { .. }) && err.to_string().contains("ao"),
        "{err}"
    );
}
