//! Shadow acne through the real pipeline (raster primaries → `whitted` → `brute`) for each
//! `raygen.offset` policy: a finely tessellated, tilted plane lit from elevations 1° to 89°,
//! with no occluder, so every shadow ray that hits anything is acne; the same scene translated
//! by 1e3 and 1e5 (where a constant `t_min` falls below the rounding error of the hit points).

use std::sync::Arc;

use crsh_core::glam::Vec3;
use crsh_core::{trace_batch, FrameSize, PipelineConfig, RayKind, Registry, StageContext, Stats};
use crsh_cpu::Cpu;
use crsh_scene::{Camera, Light, Material, Scene, SceneBuilder};

/// Quads per side of the plane.
const GRID: u32 = 24;
/// Side of the plane in scene units.
const SIZE: f32 = 10.0;
/// Image side in pixels (one shadow ray per pixel: 4096 rays).
const WIDTH: u32 = 64;
/// Light elevations above the plane, in degrees.
const ELEVATIONS: [f32; 5] = [1.0, 5.0, 30.0, 60.0, 89.0];
/// Translations of the whole scene along (1, 1, 1).
const TRANSLATIONS: [f32; 3] = [0.0, 1e3, 1e5];

/// The plane (normal tilted off every axis, vertices rounded to f32 after the translation, so
/// neighbouring triangles are not exactly coplanar), lit by one light at `elevation_deg`
/// above it at distance 20 from its centre, seen from above.
fn lit_plane(elevation_deg: f32, translation: f32) -> Arc<Scene> {
    let n = Vec3::new(0.2, 1.0, 0.35).normalize();
    let u = n.cross(Vec3::Z).normalize();
    let v = n.cross(u);
    let centre = Vec3::splat(translation);
    let mut positions = Vec::new();
    for j in 0..=GRID {
        for i in 0..=GRID {
            let x = (i as f32 / GRID as f32 - 0.5) * SIZE;
            let y = (j as f32 / GRID as f32 - 0.5) * SIZE;
            positions.push(centre + u * x + v * y);
        }
    }
    let mut indices = Vec::new();
    for j in 0..GRID {
        for i in 0..GRID {
            let a = j * (GRID + 1) + i;
            let (b, c, d) = (a + 1, a + GRID + 2, a + GRID + 1);
            indices.push([a, b, c]);
            indices.push([a, c, d]);
        }
    }
    let e = elevation_deg.to_radians();
    let mut b = SceneBuilder::new("lit-plane");
    b.material(Material::default());
    b.light(Light {
        position: centre + (u * e.cos() + n * e.sin()) * 20.0,
        color: Vec3::ONE,
        intensity: 1.0,
        attenuation: [1.0, 0.0, 0.0],
        radius: 0.0,
    });
    b.camera(Camera {
        eye: centre + n * 12.0,
        target: centre,
        up: v,
        vfov_deg: 45.0,
        aspect: None,
    });
    b.mesh("plane", &positions, None, &indices, 0);
    Arc::new(b.build("lit plane").unwrap())
}

/// Shadow rays of the frame, and how many of them hit anything (acne: nothing occludes).
fn acne(scene: &Arc<Scene>, sets: &[&str]) -> (usize, usize) {
    acne_from(scene, sets, |_| true, false)
}

/// [`acne`] over the shadow rays whose source surface's triangle passes `from`; with
/// `open_at_light`, the rays' interval is opened to `t_min = 0` before tracing (the light end
/// of the light convention: what the `wachter` gap there prevents).
fn acne_from(
    scene: &Arc<Scene>,
    sets: &[&str],
    from: impl Fn(u32) -> bool,
    open_at_light: bool,
) -> (usize, usize) {
    let mut cfg = PipelineConfig::whitted("acne", "brute");
    for s in sets {
        cfg.set(s).unwrap();
    }
    let ctx = StageContext::new(&Cpu, scene, FrameSize::new(WIDTH, WIDTH).unwrap());
    let pipeline = Registry::<Cpu>::builtin().build(&ctx, &cfg).unwrap();
    let stages = &pipeline.stages;
    let mut stats = Stats::default();
    let gbuffer = stages
        .primary
        .gbuffer(&Cpu, WIDTH, WIDTH, &mut stats)
        .unwrap();
    let mut rays = stages
        .raygen
        .generate(&Cpu, &gbuffer, RayKind::Shadow, &mut stats)
        .unwrap();
    rays.retain(|r| from(gbuffer[r.source as usize].tri));
    if open_at_light {
        for r in &mut rays {
            r.t_min = 0.0;
        }
    }
    let hits = trace_batch(&Cpu, stages, RayKind::Shadow, &rays, &mut stats).unwrap();
    (rays.len(), hits.iter().filter(|h| h.is_hit()).count())
}

const POLICIES: [(&str, &[&str]); 6] = [
    ("normal", &[]),
    ("scaled", &["raygen.offset=scaled"]),
    ("fixed 1e-4", &["raygen.offset=fixed"]),
    (
        "fixed 0",
        &["raygen.offset=fixed", "raygen.fixed_epsilon=0"],
    ),
    ("wachter", &["raygen.offset=wachter"]),
    (
        "wachter/s",
        &["raygen.offset=wachter", "raygen.shadow_origin=surface"],
    ),
];

#[test]
fn shadow_acne_per_offset_policy_on_a_lit_plane() {
    // counts[policy][translation][elevation]
    let mut counts = vec![vec![vec![0usize; ELEVATIONS.len()]; TRANSLATIONS.len()]; POLICIES.len()];
    for (ti, &t) in TRANSLATIONS.iter().enumerate() {
        for (ei, &e) in ELEVATIONS.iter().enumerate() {
            let scene = lit_plane(e, t);
            for (pi, (name, sets)) in POLICIES.iter().enumerate() {
                let (rays, hits) = acne(&scene, sets);
                assert!(
                    rays > WIDTH as usize * WIDTH as usize / 2,
                    "{name}: {rays} rays"
                );
                counts[pi][ti][ei] = hits;
            }
        }
    }
    for (pi, (name, _)) in POLICIES.iter().enumerate() {
        for (ti, t) in TRANSLATIONS.iter().enumerate() {
            println!(
                "{name:>10} translation {t:>6}: acne {:?} at {ELEVATIONS:?}°",
                counts[pi][ti]
            );
        }
    }
    let policy = |name: &str| POLICIES.iter().position(|p| p.0 == name).unwrap();
    // Wächter & Binder's offset: no acne at any angle or translation, in both conventions.
    for name in ["wachter", "wachter/s"] {
        assert!(
            counts[policy(name)].iter().flatten().all(|&c| c == 0),
            "{name}: {:?}",
            counts[policy(name)]
        );
    }
    // The default relative normal offset (1e-5 × diagonal ≈ 1.4e-4): none untranslated, none
    // at 1e3 from 30° up; it does get acne at 1e5, where a ULP (2^-7) dwarfs the offset.
    let normal = &counts[policy("normal")];
    assert!(normal[0].iter().all(|&c| c == 0), "{normal:?}");
    assert!(normal[1][2..].iter().all(|&c| c == 0), "{normal:?}");
    assert!(normal[2].iter().all(|&c| c > 0), "{normal:?}");
    // No offset at all: acne everywhere.
    let zero = &counts[policy("fixed 0")];
    assert!(zero.iter().flatten().all(|&c| c > 0), "{zero:?}");
    // A constant 1e-4 serves the untranslated plane from 5° up, not the translated one.
    let fixed = &counts[policy("fixed 1e-4")];
    assert!(fixed[0][1..].iter().all(|&c| c == 0), "{fixed:?}");
    assert!(fixed[1..].iter().flatten().all(|&c| c > 0), "{fixed:?}");
}

/// A floor (`y = 0`, `z ∈ [0.5, 10.5]`, apart from the wall so that no shadow segment runs
/// inside the wall's plane) in front of a wall (`z = 0`) with the light ON the wall's
/// surface, rotated off the axes (so the light is on the wall only up to rounding) and
/// translated by `translation` along (1, 1, 1): nothing lies between the light and any floor
/// point, but every shadow ray starts (or ends) inside the wall's plane.
fn light_on_a_wall(translation: f32, light_x: f32) -> Arc<Scene> {
    let rot = crsh_core::glam::Quat::from_axis_angle(Vec3::new(1.0, 2.0, 3.0).normalize(), 0.7);
    let c = Vec3::splat(translation);
    let at = |p: Vec3| c + rot * p;
    let mut positions = Vec::new();
    let mut indices = Vec::new();
    let mut grid = |corner: Vec3, du: Vec3, dv: Vec3| {
        let base = positions.len() as u32;
        for j in 0..=GRID {
            for i in 0..=GRID {
                positions.push(at(corner
                    + du * (i as f32 / GRID as f32)
                    + dv * (j as f32 / GRID as f32)));
            }
        }
        for j in 0..GRID {
            for i in 0..GRID {
                let a = base + j * (GRID + 1) + i;
                indices.push([a, a + GRID + 1, a + GRID + 2]);
                indices.push([a, a + GRID + 2, a + 1]);
            }
        }
    };
    // Floor, normal +y; wall, normal +z (towards the floor).
    grid(
        Vec3::new(-5.0, 0.0, 0.5),
        Vec3::new(0.0, 0.0, 10.0),
        Vec3::new(10.0, 0.0, 0.0),
    );
    grid(
        Vec3::new(-5.0, 0.0, 0.0),
        Vec3::new(10.0, 0.0, 0.0),
        Vec3::new(0.0, 10.0, 0.0),
    );
    let mut b = SceneBuilder::new("light-on-a-wall");
    b.material(Material::default());
    b.light(Light {
        position: at(Vec3::new(light_x, 2.0, 0.0)),
        color: Vec3::ONE,
        intensity: 1.0,
        attenuation: [1.0, 0.0, 0.0],
        radius: 0.0,
    });
    b.camera(Camera {
        eye: at(Vec3::new(0.0, 12.0, 6.0)),
        target: at(Vec3::new(0.0, 0.0, 5.0)),
        up: rot * Vec3::Z,
        vfov_deg: 45.0,
        aspect: None,
    });
    b.mesh("floor-and-wall", &positions, None, &indices, 0);
    Arc::new(b.build("light on a wall").unwrap())
}

#[test]
fn wachter_light_on_a_wall_does_not_shadow_itself() {
    // Rays from the floor only: a wall point lies in the plane of the light, a degenerate
    // grazing segment (and a contribution of cos ≈ 0) whatever the policy.
    let floor = |tri: u32| tri < 2 * GRID * GRID;
    let mut gapless = Vec::new();
    for t in [0.0, 1e3] {
        for k in 0..8 {
            let x = -3.0 + 0.77 * k as f32;
            let scene = light_on_a_wall(t, x);
            for origin in ["light", "surface"] {
                let set = format!("raygen.shadow_origin={origin}");
                let (rays, hits) =
                    acne_from(&scene, &["raygen.offset=wachter", &set], floor, false);
                assert!(rays > 1000, "{rays}");
                assert_eq!(
                    hits, 0,
                    "translation {t}, light x {x}, shadow_origin {origin}"
                );
            }
            // What the gap at the light end is for: the same rays with the open interval at
            // 0 there may find the wall, depending on which side of it the rounded light is.
            gapless.push(acne_from(&scene, &["raygen.offset=wachter"], floor, true).1);
        }
    }
    println!("light on a wall, t_min = 0 at the light, per light position: {gapless:?}");
    // Measured: about half the positions (the light rounded to the wall's back) shadow the
    // whole floor without the gap.
    assert!(gapless.iter().any(|&n| n > 0), "{gapless:?}");
}
