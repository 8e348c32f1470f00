//! Every formula of the CPU Whitted pipeline against hand-computed values: shadow, reflection
//! and refraction rays (seed 000 eq. 3.1-3.7, Snell's law, total internal reflection), the
//! epsilon policy, attenuation (eq. 3.19c), the Phong factors (eq. 3.19a-i) and barycentric
//! normal interpolation (eq. 3.17-3.18).

use std::sync::Arc;

use crsh_core::glam::{DVec3, Vec3};
use crsh_core::{Hit, PipelineConfig, Ray, RayKind, Surface};
use crsh_cpu::raygen::whitted::{reflect, refract, refraction_direction, Whitted};
use crsh_cpu::shade::phong::{phong_light, Phong};
use crsh_scene::{Camera, Light, Material, Scene, SceneBuilder};

const SQRT_8: f32 = 2.828_427;

/// A scene with the square `[-1, 1]²` at z = 0 (normal +z, material `mat`) plus the given
/// lights; its bounding-box diagonal is √8.
fn quad_scene(mat: Material, lights: &[Light]) -> Arc<Scene> {
    let mut b = SceneBuilder::new("quad");
    let m = b.material(mat);
    b.mesh(
        "quad",
        &[
            Vec3::new(-1.0, -1.0, 0.0),
            Vec3::new(1.0, -1.0, 0.0),
            Vec3::new(1.0, 1.0, 0.0),
            Vec3::new(-1.0, 1.0, 0.0),
        ],
        None,
        &[[0, 1, 2], [0, 2, 3]],
        m,
    );
    for l in lights {
        b.light(l.clone());
    }
    b.camera(Camera {
        eye: Vec3::new(0.0, 0.0, 5.0),
        target: Vec3::ZERO,
        up: Vec3::Y,
        vfov_deg: 40.0,
        aspect: None,
    });
    Arc::new(b.build("quad").expect("valid scene"))
}

fn point_light(position: Vec3, attenuation: [f32; 3]) -> Light {
    Light {
        position,
        color: Vec3::ONE,
        intensity: 1.0,
        attenuation,
        radius: 0.0,
    }
}

/// The brute-force preset resolved with the `--set` overrides `sets`.
fn config(sets: &[&str]) -> PipelineConfig {
    let registry = crsh_core::Registry::<crsh_cpu::Cpu>::builtin();
    let mut cfg = registry.preset("brute").unwrap();
    for s in sets {
        cfg.set(s).unwrap();
    }
    registry.resolve(&mut cfg).unwrap();
    cfg
}

fn whitted(scene: &Arc<Scene>, sets: &[&str]) -> Whitted {
    Whitted::new(scene, &config(sets).raygen).unwrap()
}

/// A surface record at `p` with shading and geometric normal `n` (facing the incoming ray),
/// arriving along `incident`.
fn surface(p: Vec3, n: Vec3, incident: Vec3, front: bool) -> Surface {
    Surface {
        position: p,
        tri: 0,
        normal: n,
        material: 0,
        incident,
        pixel: 7,
        throughput: Vec3::new(1.0, 0.5, 0.25),
        depth: 1,
        geo_normal: n,
        flags: if front { Surface::FRONT_FACE } else { 0 },
    }
}

fn assert_vec(a: Vec3, b: Vec3, tol: f32) {
    assert!((a - b).length() <= tol, "{a} vs {b}");
}

fn glass(ior: f32) -> Material {
    Material {
        transparency: 0.9,
        ior,
        ..Material::default()
    }
}

/// Sine of the angle between a unit direction and the unit normal.
fn sin_to(d: Vec3, n: Vec3) -> f64 {
    d.as_dvec3().cross(n.as_dvec3()).length()
}

/// Unit direction `angle` degrees from `-n` in the x-z plane (arriving at a surface of normal
/// `n = ±z`).
fn arriving(angle_deg: f64, n: Vec3) -> Vec3 {
    let a = angle_deg.to_radians();
    (DVec3::new(a.sin(), 0.0, 0.0) - n.as_dvec3() * a.cos()).as_vec3()
}

#[test]
fn shadow_ray_from_the_light_eq_3_1_3_2() {
    let l = Vec3::new(0.0, 3.0, 4.0);
    let scene = quad_scene(Material::default(), &[point_light(l, [1.0, 0.0, 0.0])]);
    let g = whitted(&scene, &[]);
    let off = 1e-5 * SQRT_8;
    assert!((g.offset() - off).abs() < 1e-10);
    let s = surface(Vec3::ZERO, Vec3::Z, -Vec3::Z, true);
    let rays = g.rays(&[s], RayKind::Shadow).unwrap();
    assert_eq!(rays.len(), 1);
    let r = rays[0];
    // eq. 3.1: o = l; eq. 3.2: d = (p − o)/|p − o| with p offset towards the light.
    assert_eq!(r.origin, l);
    let p = Vec3::new(0.0, 0.0, off);
    assert_vec(r.dir, (p - l).normalize(), 1e-7);
    assert_vec(r.dir, Vec3::new(0.0, -0.6, -0.8), 1e-5);
    assert!((r.t_min - off).abs() < 1e-9);
    assert!((r.t_max - ((p - l).length() - off)).abs() < 1e-6);
    assert_eq!((r.light, r.source, r.pixel, r.depth), (0, 0, 7, 2));
    assert_eq!(r.ray_kind(), RayKind::Shadow);
    // The throughput is the weight of this light's term in the image.
    assert_eq!(r.throughput, s.throughput);

    // The other convention: from the offset point towards the light, the same segment.
    let g = whitted(&scene, &["raygen.shadow_origin=surface"]);
    let r2 = g.rays(&[s], RayKind::Shadow).unwrap()[0];
    assert_vec(r2.origin, p, 1e-7);
    assert_vec(r2.dir, Vec3::new(0.0, 0.6, 0.8), 1e-5);
    assert!((r2.t_max - r.t_max).abs() < 1e-6 && r2.t_min == r.t_min);
}

#[test]
fn no_shadow_ray_to_a_light_behind_the_surface() {
    let lights = [
        point_light(Vec3::new(0.5, 0.0, -2.0), [1.0, 0.0, 0.0]),
        point_light(Vec3::new(3.0, 0.0, 0.0), [1.0, 0.0, 0.0]), // in the surface's plane
    ];
    let scene = quad_scene(Material::default(), &lights);
    let s = surface(Vec3::ZERO, Vec3::Z, -Vec3::Z, true);
    assert!(whitted(&scene, &[])
        .rays(&[s], RayKind::Shadow)
        .unwrap()
        .is_empty());
    let rays = whitted(&scene, &["raygen.cull_backfacing=false"])
        .rays(&[s], RayKind::Shadow)
        .unwrap();
    assert_eq!(rays.len(), 2);
}

#[test]
fn reflection_direction_eq_3_3_3_4() {
    let mirror = Material {
        reflectivity: 0.8,
        ..Material::default()
    };
    let scene = quad_scene(mirror, &[]);
    let g = whitted(&scene, &[]);
    let i = Vec3::new(1.0, 0.0, -1.0).normalize();
    let p = Vec3::new(0.2, -0.3, 0.0);
    let r = g
        .rays(&[surface(p, Vec3::Z, i, true)], RayKind::Reflection)
        .unwrap()[0];
    assert_vec(r.dir, Vec3::new(1.0, 0.0, 1.0).normalize(), 1e-6);
    assert_vec(
        reflect(i, Vec3::Z),
        Vec3::new(1.0, 0.0, 1.0).normalize(),
        1e-6,
    );
    // eq. 3.3: o = p, moved off the surface to the side the ray leaves into.
    assert_vec(r.origin, p + Vec3::Z * g.offset(), 1e-7);
    assert_eq!(r.t_min, g.offset());
    assert_eq!(r.t_max, f32::INFINITY);
    assert_vec(r.throughput, Vec3::new(0.8, 0.4, 0.2), 1e-6);
    assert_eq!(
        (r.ray_kind(), r.light, r.depth),
        (RayKind::Reflection, u32::MAX, 2)
    );
    // A diffuse surface spawns no reflection or refraction ray.
    let plain = quad_scene(Material::default(), &[]);
    let s = surface(p, Vec3::Z, i, true);
    assert!(whitted(&plain, &[])
        .rays(&[s], RayKind::Reflection)
        .unwrap()
        .is_empty());
    assert!(whitted(&plain, &[])
        .rays(&[s], RayKind::Refraction)
        .unwrap()
        .is_empty());
}

#[test]
fn refraction_entering_obeys_snell_eq_3_5_3_7() {
    let ior = 1.5f32;
    let scene = quad_scene(glass(ior), &[]);
    let g = whitted(&scene, &[]);
    for angle in [0.0, 10.0, 30.0, 45.0, 60.0, 80.0, 89.0] {
        let i = arriving(angle, Vec3::Z);
        let s = surface(Vec3::ZERO, Vec3::Z, i, true);
        let r = g.rays(&[s], RayKind::Refraction).unwrap()[0];
        assert_eq!(r.ray_kind(), RayKind::Refraction);
        assert!((r.dir.length() - 1.0).abs() < 1e-6);
        // Into the object, in the plane of incidence, bent towards the normal.
        assert!(r.dir.z < 0.0, "{angle}: {}", r.dir);
        assert!(r.dir.y.abs() < 1e-7);
        assert!(r.dir.x >= 0.0);
        // Snell: sin θi = ior · sin θt (η_air = 1).
        let (si, st) = (sin_to(i, Vec3::Z), sin_to(r.dir, Vec3::Z));
        assert!(
            (si - ior as f64 * st).abs() < 2e-6,
            "{angle}: {si} vs {ior}·{st}"
        );
        // The origin is moved below the surface, the side the ray leaves into.
        assert_vec(r.origin, -Vec3::Z * g.offset(), 1e-7);
        assert_vec(r.throughput, Vec3::new(0.9, 0.45, 0.225), 1e-6);
    }
    // Normal incidence passes straight through.
    assert_vec(
        refraction_direction(-Vec3::Z, Vec3::Z, ior, true),
        -Vec3::Z,
        1e-7,
    );
    // Hand value: 30° into glass of 1.5: sin θt = 0.5 / 1.5.
    let d = refraction_direction(arriving(30.0, Vec3::Z), Vec3::Z, 1.5, true);
    let st = 1.0f64 / 3.0;
    let expect = DVec3::new(st, 0.0, -(1.0 - st * st).sqrt()).as_vec3();
    assert_vec(d, expect, 1e-6);
}

#[test]
fn refraction_leaving_uses_the_inverse_ratio() {
    // Inside the glass, arriving at the back face of the quad from below (+z travel): the
    // normal on the ray's side is -z and the front-face flag is clear, so ri = ior.
    let ior = 1.5f32;
    let scene = quad_scene(glass(ior), &[]);
    let g = whitted(&scene, &[]);
    let n = -Vec3::Z;
    for angle in [0.0, 10.0, 25.0, 40.0, 41.5] {
        let i = arriving(angle, n);
        let r = g
            .rays(&[surface(Vec3::ZERO, n, i, false)], RayKind::Refraction)
            .unwrap()[0];
        assert!(r.dir.z > 0.0);
        let (si, st) = (sin_to(i, n), sin_to(r.dir, n));
        assert!(
            (ior as f64 * si - st).abs() < 2e-5,
            "{angle}: {ior}·{si} vs {st}"
        );
        assert_vec(r.origin, Vec3::Z * g.offset(), 1e-7);
    }
}

#[test]
fn total_internal_reflection_past_the_critical_angle() {
    let ior = 1.5f32;
    let critical = (1.0 / ior as f64).asin().to_degrees(); // 41.81°
    let n = -Vec3::Z;
    assert!(refract(arriving(critical - 0.1, n), n, ior).is_some());
    assert!(refract(arriving(critical + 0.1, n), n, ior).is_none());
    // From the outside there is no critical angle.
    assert!(refract(arriving(89.9, Vec3::Z), Vec3::Z, 1.0 / ior).is_some());

    let scene = quad_scene(glass(ior), &[]);
    let g = whitted(&scene, &[]);
    for angle in [45.0, 60.0, 80.0] {
        let i = arriving(angle, n);
        let r = g
            .rays(&[surface(Vec3::ZERO, n, i, false)], RayKind::Refraction)
            .unwrap()[0];
        // Mirror direction (eq. 3.4), still a refraction ray with the transparency weight.
        assert_vec(r.dir, Vec3::new(i.x, i.y, -i.z), 1e-6);
        assert_eq!(r.ray_kind(), RayKind::Refraction);
        assert_vec(r.throughput, Vec3::new(0.9, 0.45, 0.225), 1e-6);
        // It stays inside: the origin is moved to the incoming side (below the quad).
        assert_vec(r.origin, -Vec3::Z * g.offset(), 1e-7);
    }
}

#[test]
fn epsilon_scales_with_the_scene() {
    let scene = quad_scene(Material::default(), &[]);
    let g = whitted(&scene, &["raygen.epsilon=0.001"]);
    assert!((g.offset() - 0.001 * SQRT_8).abs() < 1e-8);
    // A negative epsilon is refused by the catalogue's range, and by the stage itself when a
    // spec reaches it unchecked.
    let registry = crsh_core::Registry::<crsh_cpu::Cpu>::builtin();
    let mut bad = registry.preset("bvh").unwrap();
    bad.set("raygen.epsilon=-1").unwrap();
    assert!(registry.resolve(&mut bad.clone()).is_err());
    assert!(Whitted::new(&scene, &bad.raygen).is_err());
}

#[test]
fn min_throughput_culls_weak_rays() {
    let m = Material {
        reflectivity: 0.3,
        ..Material::default()
    };
    let scene = quad_scene(m, &[]);
    let mut s = surface(Vec3::ZERO, Vec3::Z, -Vec3::Z, true);
    s.throughput = Vec3::splat(0.01); // reflection weight 0.003
    assert_eq!(
        whitted(&scene, &[])
            .rays(&[s], RayKind::Reflection)
            .unwrap()
            .len(),
        1
    );
    let g = whitted(&scene, &["raygen.min_throughput=0.004"]);
    assert!(g.rays(&[s], RayKind::Reflection).unwrap().is_empty());
}

#[test]
fn attenuation_eq_3_19c() {
    let l = point_light(Vec3::new(0.0, 0.0, 2.0), [1.0, 0.5, 0.25]);
    // 1 / (1 + 2·0.5 + 4·0.25) = 1/3
    assert!((l.attenuation_at(2.0) - 1.0 / 3.0).abs() < 1e-7);
    let diffuse = Vec3::new(0.9, 0.6, 0.3);
    let c = phong_light(
        Vec3::ZERO,
        Vec3::Z,
        Vec3::Z,
        -Vec3::Z,
        diffuse,
        Vec3::ZERO,
        1.0,
        &l,
    );
    assert_vec(c, diffuse / 3.0, 1e-7);
    // Colour and intensity scale it (eq. 3.19h).
    let l2 = Light {
        color: Vec3::new(1.0, 0.5, 2.0),
        intensity: 3.0,
        ..l
    };
    let c = phong_light(
        Vec3::ZERO,
        Vec3::Z,
        Vec3::Z,
        -Vec3::Z,
        diffuse,
        Vec3::ZERO,
        1.0,
        &l2,
    );
    assert_vec(c, Vec3::new(0.9, 0.3, 0.6), 1e-6);
}

#[test]
fn phong_factors_eq_3_19a_i() {
    let (diffuse, specular) = (Vec3::new(0.5, 0.4, 0.3), Vec3::new(0.2, 0.2, 0.2));
    // Light head-on at distance 1; viewer 60° off the normal in the x-z plane. The halfway
    // vector (eq. 3.19e) bisects them: 30° from the normal, so fs = cos(30°)^8 (eq. 3.19g).
    let l = point_light(Vec3::Z, [1.0, 0.0, 0.0]);
    let view = -DVec3::new(60f64.to_radians().sin(), 0.0, 60f64.to_radians().cos());
    let c = phong_light(
        Vec3::ZERO,
        Vec3::Z,
        Vec3::Z,
        view.as_vec3(),
        diffuse,
        specular,
        8.0,
        &l,
    );
    let fs = 30f64.to_radians().cos().powi(8) as f32; // 0.3164
    assert_vec(c, diffuse + specular * fs, 1e-6);

    // Light 45° off the normal, viewer at the mirror position: fd = cos 45°, fs = 1.
    let l = point_light(Vec3::new(-1.0, 0.0, 1.0) * 2.0, [0.0, 0.0, 1.0]);
    let view = Vec3::new(-1.0, 0.0, -1.0).normalize(); // from (1, 0, 1) towards the point
    let c = phong_light(
        Vec3::ZERO,
        Vec3::Z,
        Vec3::Z,
        view,
        diffuse,
        specular,
        50.0,
        &l,
    );
    let att = 1.0 / 8.0; // quadratic attenuation at distance √8
    let expect = (diffuse * std::f32::consts::FRAC_1_SQRT_2 + specular) * att;
    assert_vec(c, expect, 1e-6);

    // A light below the horizon gives nothing, diffuse or specular.
    let l = point_light(Vec3::new(1.0, 0.0, -0.1), [1.0, 0.0, 0.0]);
    let c = phong_light(
        Vec3::ZERO,
        Vec3::Z,
        Vec3::Z,
        view,
        diffuse,
        specular,
        1.0,
        &l,
    );
    assert_eq!(c, Vec3::ZERO);
}

#[test]
fn shading_weights_by_throughput_and_local_weight() {
    // One surface, two lights: one unoccluded, one occluded; ambient off.
    let lights = [
        point_light(Vec3::new(0.0, 0.0, 1.0), [1.0, 0.0, 0.0]),
        point_light(Vec3::new(0.0, 0.0, 3.0), [1.0, 0.0, 0.0]),
    ];
    let m = Material {
        diffuse: Vec3::new(0.5, 0.5, 1.0),
        reflectivity: 0.25,
        ..Material::default()
    };
    let scene = quad_scene(m, &lights);
    let mut cfg = config(&["shade.ambient=0"]);
    let g = Whitted::new(&scene, &cfg.raygen).unwrap();
    let sh = Phong::new(&scene, &cfg.shade).unwrap();
    let s = [surface(Vec3::ZERO, Vec3::Z, -Vec3::Z, true)];
    let rays = g.rays(&s, RayKind::Shadow).unwrap();
    assert_eq!(rays.len(), 2);
    let blocked = Hit {
        t: 0.5,
        tri: 1,
        u: 0.0,
        v: 0.0,
    };
    let mut img = vec![[0.0f32; 4]; 8];
    sh.shade(&s, &rays, &[Hit::MISS, blocked], &mut img)
        .unwrap();
    // diffuse · 1 (head-on, distance 1) · local weight 0.75 · throughput (1, 0.5, 0.25)
    let expect = [0.375, 0.1875, 0.1875, 1.0];
    for (a, b) in img[7].iter().zip(expect) {
        assert!((a - b).abs() < 1e-6, "{:?}", img[7]);
    }
    // With ambient 0.1 the fill light is added under the same weights.
    cfg.set("shade.ambient=0.1").unwrap();
    crsh_core::Registry::<crsh_cpu::Cpu>::builtin()
        .resolve(&mut cfg)
        .unwrap();
    let sh = Phong::new(&scene, &cfg.shade).unwrap();
    let mut img2 = vec![[0.0f32; 4]; 8];
    sh.shade(&s, &rays, &[Hit::MISS, blocked], &mut img2)
        .unwrap();
    let amb = Vec3::new(0.5, 0.5, 1.0) * 0.1 * 0.75 * Vec3::new(1.0, 0.5, 0.25);
    for k in 0..3 {
        assert!((img2[7][k] - img[7][k] - amb[k]).abs() < 1e-6);
    }
}

#[test]
fn barycentric_normal_interpolation_eq_3_17_3_18() {
    let (a, b, c) = (
        Vec3::new(-1.0, -1.0, 0.0),
        Vec3::new(2.0, -0.5, 0.5),
        Vec3::new(0.0, 1.5, -0.5),
    );
    let na = Vec3::new(0.0, 0.0, 1.0);
    let nb = Vec3::new(0.6, 0.0, 0.8);
    let nc = Vec3::new(0.0, 0.6, 0.8);
    let mut bld = SceneBuilder::new("tri");
    let m = bld.material(Material::default());
    bld.mesh("tri", &[a, b, c], Some(&[na, nb, nc]), &[[0, 1, 2]], m);
    bld.camera(Camera {
        eye: Vec3::new(0.0, 0.0, 5.0),
        target: Vec3::ZERO,
        up: Vec3::Y,
        vfov_deg: 40.0,
        aspect: None,
    });
    let scene = Arc::new(bld.build("tri").unwrap());
    let sh = Phong::new(&scene, &config(&[]).shade).unwrap();
    for (u, v) in [
        (0.2f32, 0.3f32),
        (0.6, 0.1),
        (0.05, 0.9),
        (1.0 / 3.0, 1.0 / 3.0),
    ] {
        let hit_p = a * (1.0 - u - v) + b * u + c * v;
        let ray = Ray::new(
            RayKind::Reflection,
            hit_p + Vec3::Z * 3.0,
            -Vec3::Z,
            0.0,
            f32::INFINITY,
        );
        let hit = Hit {
            t: 3.0,
            tri: 0,
            u,
            v,
        };
        let s = sh.next_surfaces(&[ray], &[hit]).unwrap()[0];
        assert_vec(s.position, hit_p, 1e-6);
        // eq. 3.17a-c as written (area ratios from the hit point), in f64.
        let (da, db, dc, dp) = (a.as_dvec3(), b.as_dvec3(), c.as_dvec3(), hit_p.as_dvec3());
        let abc = (db - da).cross(dc - da).length();
        let pbc = (db - dp).cross(dc - dp).length() / abc;
        let pca = (da - dp).cross(dc - dp).length() / abc;
        // eq. 3.18, normalized.
        let n = (na.as_dvec3() * pbc + nb.as_dvec3() * pca + nc.as_dvec3() * (1.0 - pbc - pca))
            .normalize();
        assert!(
            (s.normal.as_dvec3() - n).length() < 1e-5,
            "{} vs {n}",
            s.normal
        );
        assert!(s.front_face());
        assert_vec(s.geo_normal, (b - a).cross(c - a).normalize(), 1e-6);
    }
}
