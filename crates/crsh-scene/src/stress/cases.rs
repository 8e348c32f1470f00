//! The default suite's case builders (see the module docs of [`super`] for the families).

use std::sync::Arc;

use crsh_core::{Ray, RayKind};
use glam::{DQuat, DVec3, Vec3};

use super::meshes::{self, TriMesh};
use super::{probe_ray, Expect, FrameTruth, Probe, StressCase};
use crate::model::{Camera, Light, Material, Scene, SceneBuilder};
use crate::rng::SplitMix64;

/// Image side of the frame probes.
const FRAME_SIDE: u32 = 40;

/// The default suite, in a fixed order (every case deterministic, small enough for CI).
pub fn cases() -> Vec<StressCase> {
    let mut out = vec![
        closed(
            "closed/icosphere",
            meshes::icosphere(3),
            &[DVec3::ZERO, DVec3::new(0.31, -0.22, 0.13)],
            1.0,
            DVec3::ZERO,
        ),
        closed_torus(),
        closed(
            "closed/cube",
            meshes::shared_edge_cube(8),
            &[DVec3::ZERO, DVec3::new(0.3, -0.2, 0.1)],
            1.0,
            DVec3::ZERO,
        ),
        fan_edges(),
        grazing(),
    ];
    for deg in [1.0, 5.0, 30.0, 60.0, 89.0] {
        out.push(acne_plane(
            &format!("acne/plane-{deg}deg"),
            deg,
            1.0,
            DVec3::ZERO,
            4.0,
        ));
    }
    // The same plane at 30° with the light 1000 half-sizes away: the offset is relative to the
    // scene (the plane), but the shadow rays are long.
    out.push(acne_plane(
        "acne/far-light-30deg",
        30.0,
        1.0,
        DVec3::ZERO,
        1000.0,
    ));
    out.extend([slivers(), needles(), zero_area(), coplanar()]);
    for exp in [3, 5, 7] {
        let t = 10f64.powi(exp);
        let shift = DVec3::new(t, 0.5 * t, 0.25 * t);
        out.push(closed(
            &format!("far/icosphere-1e{exp}"),
            meshes::icosphere(4),
            &[DVec3::ZERO, DVec3::new(0.31, -0.22, 0.13)],
            64.0,
            shift,
        ));
        out.push(acne_plane(
            &format!("far/plane-1e{exp}"),
            30.0,
            50.0,
            shift,
            4.0,
        ));
    }
    for exp in [-4, 4] {
        let s = 10f64.powi(exp);
        out.push(closed(
            &format!("scale/icosphere-1e{exp}"),
            meshes::icosphere(3),
            &[DVec3::ZERO, DVec3::new(0.31, -0.22, 0.13)],
            s,
            DVec3::ZERO,
        ));
        out.push(acne_plane(
            &format!("scale/plane-1e{exp}"),
            30.0,
            s,
            DVec3::ZERO,
            4.0,
        ));
    }
    out.extend([
        curved_mirror(),
        opposite_bundles(),
        stadium(),
        invalid_rays(),
        one_triangle(),
        all_miss(),
        rejected(
            "invalid/empty-scene",
            "a scene with no triangles must be rejected with an error",
            |b| {
                b.mesh("nothing", &[], None, &[], 0);
            },
        ),
        rejected(
            "invalid/nan-vertex",
            "a mesh with a NaN vertex must be rejected with an error",
            |b| {
                b.mesh(
                    "nan",
                    &[Vec3::ZERO, Vec3::X, Vec3::new(f32::NAN, 1.0, 0.0)],
                    None,
                    &[[0, 1, 2]],
                    0,
                );
            },
        ),
    ]);
    out
}

fn family(name: &str) -> &'static str {
    const FAMILIES: [&str; 9] = [
        "closed",
        "edges",
        "acne",
        "degenerate",
        "far",
        "scale",
        "bundles",
        "stadium",
        "invalid",
    ];
    let head = name.split('/').next().unwrap_or(name);
    FAMILIES.into_iter().find(|f| *f == head).unwrap_or("other")
}

fn light(position: Vec3) -> Light {
    Light {
        position,
        color: Vec3::ONE,
        intensity: 1.0,
        attenuation: [1.0, 0.0, 0.0],
        radius: 0.0,
    }
}

fn camera(eye: Vec3, target: Vec3, up: Vec3, vfov_deg: f32) -> Camera {
    Camera {
        eye,
        target,
        up,
        vfov_deg,
        aspect: None,
    }
}

fn mirror(reflectivity: f32) -> Material {
    Material {
        name: "mirror".into(),
        reflectivity,
        specular: Vec3::splat(0.3),
        shininess: 32.0,
        ..Material::default()
    }
}

/// Builds a scene from `(name, mesh, material)` parts.
fn scene(
    name: &str,
    parts: &[(&str, &TriMesh, Material)],
    lights: &[Light],
    cam: Camera,
) -> Result<Arc<Scene>, String> {
    let mut b = SceneBuilder::new(name);
    for (mesh_name, mesh, material) in parts {
        let m = b.material(material.clone());
        b.mesh(*mesh_name, &mesh.positions, None, &mesh.indices, m);
    }
    for l in lights {
        b.light(l.clone());
    }
    b.camera(cam);
    b.build(name).map(Arc::new).map_err(|e| e.to_string())
}

/// An explicit-ray case: closest-hit (reflection-kind) rays traced as given, each with its
/// expectation.
fn ray_case(
    name: &str,
    about: String,
    scene: Result<Arc<Scene>, String>,
    rays: Vec<Ray>,
    expect: Vec<Expect>,
) -> StressCase {
    StressCase {
        name: name.into(),
        family: family(name),
        about,
        scene,
        probe: Probe::Rays {
            kind: RayKind::Reflection,
            rays,
            expect,
        },
    }
}

/// A camera looking at `centre` from `offset` away (used only by frame probes; ray probes set
/// one because every scene needs one).
fn look_at(centre: DVec3, offset: DVec3) -> Camera {
    camera((centre + offset).as_vec3(), centre.as_vec3(), Vec3::Y, 50.0)
}

fn unit_dir(from: DVec3, to: DVec3) -> Vec3 {
    (to - from).normalize().as_vec3()
}

fn random_unit(rng: &mut SplitMix64) -> DVec3 {
    loop {
        let v = DVec3::new(
            rng.range_f32(-1.0, 1.0) as f64,
            rng.range_f32(-1.0, 1.0) as f64,
            rng.range_f32(-1.0, 1.0) as f64,
        );
        let l = v.length_squared();
        if l > 1e-4 && l <= 1.0 {
            return v / l.sqrt();
        }
    }
}

/// Every vertex and edge midpoint of `mesh` (in `f64`, from its rounded `f32` vertices),
/// thinned to at most `cap` evenly spaced ones.
fn vertex_and_edge_targets(mesh: &TriMesh, cap: usize) -> Vec<DVec3> {
    let p = |i: u32| mesh.positions[i as usize].as_dvec3();
    let mut all: Vec<DVec3> = mesh.positions.iter().map(|v| v.as_dvec3()).collect();
    all.extend(mesh.edges().into_iter().map(|(a, b)| (p(a) + p(b)) * 0.5));
    let step = all.len().div_ceil(cap).max(1);
    all.into_iter().step_by(step).collect()
}

/// Rays from each origin (all inside `mesh`) to its vertices and edge midpoints, and in random
/// directions: every one must hit.
fn interior_rays(
    mesh: &TriMesh,
    origins: &[DVec3],
    cap: usize,
    seed: u64,
) -> (Vec<Ray>, Vec<Expect>) {
    let targets = vertex_and_edge_targets(mesh, cap);
    let mut rng = SplitMix64::new(seed);
    let mut rays = Vec::new();
    for &o in origins {
        let o32 = o.as_vec3();
        let o = o32.as_dvec3();
        for &t in &targets {
            let n = rays.len() as u32;
            rays.push(probe_ray(
                RayKind::Reflection,
                o32,
                unit_dir(o, t),
                0.0,
                f32::INFINITY,
                n,
            ));
        }
        for _ in 0..cap / 8 {
            let n = rays.len() as u32;
            let d = random_unit(&mut rng).as_vec3();
            rays.push(probe_ray(
                RayKind::Reflection,
                o32,
                d,
                0.0,
                f32::INFINITY,
                n,
            ));
        }
    }
    let expect = vec![Expect::MustHit; rays.len()];
    (rays, expect)
}

/// A closed `mesh` (around the origin) scaled by `s` and moved by `shift`; rays from `origins`
/// (in the mesh's own frame, also scaled and moved).
fn closed(name: &str, mesh: TriMesh, origins: &[DVec3], s: f64, shift: DVec3) -> StressCase {
    let mesh = mesh.scaled_translated(s, shift);
    let origins: Vec<DVec3> = origins.iter().map(|&o| o * s + shift).collect();
    let (rays, expect) = interior_rays(&mesh, &origins, 1500, 0x5eed_c105);
    let tris = mesh.indices.len();
    ray_case(
        name,
        format!(
            "{} rays from inside a closed mesh of {tris} shared-vertex triangles (scale {s:e}, \
             moved by {:e}) at its vertices, edge midpoints and random directions: all must hit",
            rays.len(),
            shift.max_element()
        ),
        scene(
            name,
            &[("closed", &mesh, Material::default())],
            &[light((shift + DVec3::splat(3.0 * s)).as_vec3())],
            look_at(shift, DVec3::new(0.0, 0.0, 4.0 * s)),
        ),
        rays,
        expect,
    )
}

fn closed_torus() -> StressCase {
    let name = "closed/torus";
    let mesh = meshes::torus(1.0, 0.3, 48, 16);
    // Origins on the tube's centre circle; targets: vertices and edge midpoints of the stretch
    // of tube around each origin, so that the ray meets the wall right there.
    let mut rays = Vec::new();
    let targets = vertex_and_edge_targets(&mesh, usize::MAX);
    let mut rng = SplitMix64::new(0x7041);
    for k in 0..4 {
        let u = 0.4 + k as f64 * 1.57;
        let o = DVec3::new(u.cos(), u.sin(), 0.05 * k as f64);
        let o32 = o.as_vec3();
        let o = o32.as_dvec3();
        for &t in &targets {
            let du = (t.y.atan2(t.x) - u + std::f64::consts::PI).rem_euclid(std::f64::consts::TAU)
                - std::f64::consts::PI;
            if du.abs() < 0.3 {
                let n = rays.len() as u32;
                rays.push(probe_ray(
                    RayKind::Reflection,
                    o32,
                    unit_dir(o, t),
                    0.0,
                    f32::INFINITY,
                    n,
                ));
            }
        }
        for _ in 0..100 {
            let n = rays.len() as u32;
            let d = random_unit(&mut rng).as_vec3();
            rays.push(probe_ray(
                RayKind::Reflection,
                o32,
                d,
                0.0,
                f32::INFINITY,
                n,
            ));
        }
    }
    let expect = vec![Expect::MustHit; rays.len()];
    ray_case(
        name,
        format!(
            "{} rays from inside the tube of a torus ({} shared-vertex triangles) at nearby \
             vertices, edge midpoints and random directions: all must hit",
            rays.len(),
            mesh.indices.len()
        ),
        scene(
            name,
            &[("torus", &mesh, Material::default())],
            &[light(Vec3::new(2.0, 2.0, 3.0))],
            look_at(DVec3::ZERO, DVec3::new(0.0, 0.0, 4.0)),
        ),
        rays,
        expect,
    )
}

fn fan_edges() -> StressCase {
    let name = "edges/fan";
    let mesh = meshes::fan();
    let mut targets = vec![DVec3::ZERO];
    for rim in meshes::FAN_RIM {
        for k in 1..8 {
            let f = k as f64 / 8.0;
            targets.push(DVec3::new(rim[0] as f64 * f, rim[1] as f64 * f, 0.0));
        }
    }
    let mut rng = SplitMix64::new(0xfa9);
    let mut rays = Vec::new();
    for i in 0..64 {
        let side = if i % 2 == 0 { 1.0 } else { -1.0 };
        let o = DVec3::new(
            rng.range_f32(-3.0, 3.0) as f64,
            rng.range_f32(-3.0, 3.0) as f64,
            side * rng.range_f32(0.05, 3.0) as f64,
        );
        let o32 = o.as_vec3();
        for &t in &targets {
            let n = rays.len() as u32;
            rays.push(probe_ray(
                RayKind::Reflection,
                o32,
                unit_dir(o32.as_dvec3(), t),
                0.0,
                f32::INFINITY,
                n,
            ));
        }
    }
    let expect = vec![Expect::MustHit; rays.len()];
    ray_case(
        name,
        format!(
            "{} rays from both sides aimed exactly at the centre vertex and the shared edges of \
             an 8-triangle fan: all must hit",
            rays.len()
        ),
        scene(
            name,
            &[("fan", &mesh, Material::default())],
            &[light(Vec3::new(0.0, 0.0, 3.0))],
            look_at(DVec3::ZERO, DVec3::new(0.0, -2.0, 3.0)),
        ),
        rays,
        expect,
    )
}

fn grazing() -> StressCase {
    let name = "edges/grazing";
    // Two triangles (a square split along its diagonal), plus a second square 0.5 below.
    let top = meshes::grid_plane(1);
    let low = meshes::grid_plane(1).map(|p| p + DVec3::new(0.0, 0.0, -0.5));
    let mut rng = SplitMix64::new(0x96a2);
    let mut rays = Vec::new();
    for slope_exp in 1..=8 {
        // slope 1e-1 .. 1e-7, then exactly in the plane (slope 0, origin in the plane).
        let slope = if slope_exp == 8 {
            0.0
        } else {
            10f64.powi(-slope_exp)
        };
        for _ in 0..200 {
            let target = DVec3::new(
                rng.range_f32(-0.99, 0.99) as f64,
                rng.range_f32(-0.99, 0.99) as f64,
                0.0,
            );
            let a = rng.range_f32(0.0, std::f32::consts::TAU) as f64;
            let d = DVec3::new(a.cos(), a.sin(), -slope).normalize();
            let o32 = (target - d * 5.0).as_vec3();
            let n = rays.len() as u32;
            rays.push(probe_ray(
                RayKind::Reflection,
                o32,
                d.as_vec3(),
                0.0,
                f32::INFINITY,
                n,
            ));
        }
    }
    let expect = vec![Expect::Reference; rays.len()];
    ray_case(
        name,
        format!(
            "{} grazing rays at slopes 1e-1..1e-7 and 0 onto a two-triangle square above another: \
             the f64 reference decides",
            rays.len()
        ),
        scene(
            name,
            &[
                ("top", &top, Material::default()),
                ("low", &low, Material::default()),
            ],
            &[light(Vec3::new(0.0, 0.0, 3.0))],
            look_at(DVec3::ZERO, DVec3::new(0.0, -2.0, 3.0)),
        ),
        rays,
        expect,
    )
}

/// The fixed tilt of the acne planes, so that their vertices are not axis-aligned.
fn tilt() -> DQuat {
    DQuat::from_axis_angle(DVec3::new(1.0, 2.0, 3.0).normalize(), 0.7)
}

/// A 16×16-quad mirror plane of half-size `half`, tilted, moved by `shift`, lit from `deg`
/// degrees above it by a light `light_dist` half-sizes from its centre; the camera looks down
/// on it.
fn acne_plane(name: &str, deg: f64, half: f64, shift: DVec3, light_dist: f64) -> StressCase {
    let q = tilt();
    let mesh = meshes::grid_plane(16).map(|p| q * (p * half) + shift);
    let elev = deg.to_radians();
    let light_dir = q * DVec3::new(elev.cos(), 0.0, elev.sin());
    let light_pos = (shift + light_dir * (light_dist * half)).as_vec3();
    let eye = shift + q * DVec3::new(0.0, -1.2 * half, 2.0 * half);
    let cam = camera(
        eye.as_vec3(),
        shift.as_vec3(),
        (q * DVec3::Y).as_vec3(),
        60.0,
    );
    StressCase {
        name: name.into(),
        family: family(name),
        about: format!(
            "a tilted 512-triangle mirror plane (half-size {half:e}, moved by {:e}) lit at \
             {deg}° by a light {light_dist} half-sizes away: nothing can occlude or reflect, so \
             every secondary-ray hit is acne",
            shift.max_element()
        ),
        scene: scene(
            name,
            &[("plane", &mesh, mirror(0.5))],
            &[light(light_pos)],
            cam,
        ),
        probe: Probe::Frame {
            width: FRAME_SIDE,
            height: FRAME_SIDE,
            truth: FrameTruth::Unoccluded,
        },
    }
}

/// Rays straight down (from `z = 1`) onto random points of the unit square and onto points of
/// its shared edges `edge_points`; every one must hit.
fn down_rays(points: impl IntoIterator<Item = DVec3>) -> (Vec<Ray>, Vec<Expect>) {
    let rays: Vec<Ray> = points
        .into_iter()
        .enumerate()
        .map(|(i, p)| {
            let o = DVec3::new(p.x, p.y, 1.0).as_vec3();
            probe_ray(
                RayKind::Reflection,
                o,
                -Vec3::Z,
                0.0,
                f32::INFINITY,
                i as u32,
            )
        })
        .collect();
    let expect = vec![Expect::MustHit; rays.len()];
    (rays, expect)
}

fn slivers() -> StressCase {
    let name = "degenerate/slivers";
    let n = 2048;
    let mesh = meshes::sliver_square(n);
    let mut rng = SplitMix64::new(0x511);
    let mut pts = Vec::new();
    for k in 0..1000 {
        // On a shared strip edge, on a shared diagonal, and at random.
        let i = 1.0 + rng.below(n as usize - 1) as f64;
        let y = rng.range_f32(0.01, 0.99) as f64;
        pts.push(DVec3::new(i / n as f64, y, 0.0));
        let f = rng.range_f32(0.01, 0.99) as f64;
        pts.push(DVec3::new((i + f) / n as f64, f, 0.0));
        if k % 2 == 0 {
            pts.push(DVec3::new(rng.range_f32(0.01, 0.99) as f64, y, 0.0));
        }
    }
    let (rays, expect) = down_rays(pts);
    ray_case(
        name,
        format!(
            "{} rays straight down onto a unit square made of {} slivers (aspect {n}:1), many \
             exactly on shared edges: all must hit",
            rays.len(),
            2 * n
        ),
        scene(
            name,
            &[("slivers", &mesh, Material::default())],
            &[light(Vec3::new(0.5, 0.5, 3.0))],
            look_at(DVec3::new(0.5, 0.5, 0.0), DVec3::new(0.0, -1.0, 2.0)),
        ),
        rays,
        expect,
    )
}

fn needles() -> StressCase {
    let name = "degenerate/needles";
    let (n, length, width) = (256u32, 1000.0, 1e-2);
    let mesh = meshes::needle_fan(n, length, width);
    let mut rng = SplitMix64::new(0x9eed);
    let mut pts = Vec::new();
    for _ in 0..1500 {
        // A point on an inner shared edge, away from the wedge's outer edges.
        let i = (n / 8) as usize + rng.below((3 * n / 4) as usize);
        let y = width * (i as f64 / n as f64 - 0.5);
        let f = rng.range_f32(0.1, 0.9) as f64;
        pts.push(
            DVec3::new(length, 0.0, 0.0)
                + f * (DVec3::new(0.0, y, 0.0) - DVec3::new(length, 0.0, 0.0)),
        );
    }
    let (rays, expect) = down_rays(pts);
    ray_case(
        name,
        format!(
            "{} rays straight down onto shared edges of {n} needles ({length} long, the fan \
             {width} wide): all must hit",
            rays.len()
        ),
        scene(
            name,
            &[("needles", &mesh, Material::default())],
            &[light(Vec3::new(500.0, 0.0, 100.0))],
            look_at(DVec3::new(500.0, 0.0, 0.0), DVec3::new(0.0, -300.0, 800.0)),
        ),
        rays,
        expect,
    )
}

fn zero_area() -> StressCase {
    let name = "degenerate/zero-area";
    // Zero-area triangles (collinear, two equal vertices, three equal vertices) in and near
    // z = 0, then one big ground triangle at z = -1 (the last triangle id).
    let v = |x: f32, y: f32, z: f32| Vec3::new(x, y, z);
    let degenerate = TriMesh {
        positions: vec![
            v(-1.0, -1.0, 0.0),
            v(0.0, 0.0, 0.0),
            v(1.0, 1.0, 0.0),
            v(-1.0, 1.0, 0.0),
            v(1.0, -1.0, 0.0),
            v(0.5, -0.5, 0.25),
            v(0.0, 0.5, 0.0),
            v(0.0, -0.75, 0.5),
            v(0.0, -0.75, -0.5),
        ],
        indices: vec![
            [0, 1, 2], // collinear diagonal
            [3, 1, 4], // collinear anti-diagonal
            [0, 0, 2], // two equal vertices
            [6, 6, 6], // a point
            [7, 8, 7], // a vertical segment
            [3, 3, 4],
        ],
    };
    let ground = TriMesh {
        positions: vec![
            v(-10.0, -10.0, -1.0),
            v(30.0, -10.0, -1.0),
            v(-10.0, 30.0, -1.0),
        ],
        indices: vec![[0, 1, 2]],
    };
    let ground_id = degenerate.indices.len() as u32;
    let mut rng = SplitMix64::new(0xde9);
    let mut pts: Vec<DVec3> = vec![
        DVec3::new(0.0, 0.0, 0.0),
        DVec3::new(0.0, 0.5, 0.0),
        DVec3::new(0.0, -0.75, 0.0),
        DVec3::new(-1.0, 1.0, 0.0),
        DVec3::new(1.0, -1.0, 0.0),
    ];
    for _ in 0..400 {
        let s = rng.range_f32(-1.0, 1.0) as f64;
        pts.push(DVec3::new(s, s, 0.0));
        pts.push(DVec3::new(-s, s, 0.0));
    }
    let mut rays = Vec::new();
    for p in pts {
        let n = rays.len() as u32;
        rays.push(probe_ray(
            RayKind::Reflection,
            DVec3::new(p.x, p.y, 1.0).as_vec3(),
            -Vec3::Z,
            0.0,
            f32::INFINITY,
            n,
        ));
    }
    let expect = vec![
        Expect::Nearest {
            tri: ground_id,
            t: 2.0
        };
        rays.len()
    ];
    ray_case(
        name,
        format!(
            "{} rays straight down through 6 zero-area triangles (collinear, repeated vertices, a \
             point, a segment) onto a ground triangle at t = 2: degenerate triangles are never hit",
            rays.len()
        ),
        scene(
            name,
            &[
                ("degenerate", &degenerate, Material::default()),
                ("ground", &ground, Material::default()),
            ],
            &[light(Vec3::new(0.0, 0.0, 3.0))],
            look_at(DVec3::ZERO, DVec3::new(0.0, -2.0, 3.0)),
        ),
        rays,
        expect,
    )
}

fn coplanar() -> StressCase {
    let name = "degenerate/coplanar";
    let v = |x: f32, y: f32, z: f32| Vec3::new(x, y, z);
    let mesh = TriMesh {
        positions: vec![
            v(0.0, 0.0, 0.0),
            v(1.0, 0.0, 0.0),
            v(0.0, 1.0, 0.0),
            v(0.2, 0.2, 0.0),
            v(1.2, 0.2, 0.0),
            v(0.2, 1.2, 0.0),
            v(0.0, 0.0, 1e-7),
            v(1.0, 0.0, 1e-7),
            v(0.0, 1.0, 1e-7),
        ],
        indices: vec![
            [0, 1, 2], // the triangle
            [0, 1, 2], // coincident copy
            [0, 2, 1], // coincident, opposite winding
            [3, 4, 5], // coplanar, overlapping
            [6, 7, 8], // 1e-7 above
        ],
    };
    let mut rng = SplitMix64::new(0xc0);
    let mut rays = Vec::new();
    for i in 0..1200 {
        let p = DVec3::new(
            rng.range_f32(0.0, 1.2) as f64,
            rng.range_f32(0.0, 1.2) as f64,
            0.0,
        );
        let side = if i % 3 == 0 { -1.0 } else { 1.0 };
        let d = DVec3::new(
            rng.range_f32(-0.5, 0.5) as f64,
            rng.range_f32(-0.5, 0.5) as f64,
            -side,
        )
        .normalize();
        let o = (p - d * 2.0).as_vec3();
        let n = rays.len() as u32;
        rays.push(probe_ray(
            RayKind::Reflection,
            o,
            d.as_vec3(),
            0.0,
            f32::INFINITY,
            n,
        ));
    }
    let expect = vec![Expect::Reference; rays.len()];
    ray_case(
        name,
        format!(
            "{} rays from both sides onto coincident (same and opposite winding), overlapping \
             coplanar and 1e-7-apart triangles: the f64 reference decides",
            rays.len()
        ),
        scene(
            name,
            &[("coplanar", &mesh, Material::default())],
            &[light(Vec3::new(0.0, 0.0, 3.0))],
            look_at(DVec3::new(0.5, 0.5, 0.0), DVec3::new(0.0, -2.0, 3.0)),
        ),
        rays,
        expect,
    )
}

fn curved_mirror() -> StressCase {
    let name = "bundles/curved-mirror";
    let ball = meshes::icosphere(2).map(|p| p * 0.5);
    let room = meshes::inward_box(Vec3::splat(-4.0), Vec3::splat(4.0));
    StressCase {
        name: name.into(),
        family: family(name),
        about: "a small mirror icosphere filling the view inside a closed room: reflection rays \
                fan out over every direction (cone angles near and past 90°); the f64 reference \
                decides"
            .into(),
        scene: scene(
            name,
            &[
                ("mirror-ball", &ball, mirror(0.9)),
                ("room", &room, Material::default()),
            ],
            &[light(Vec3::new(2.0, 3.0, 2.5))],
            camera(Vec3::new(0.0, 0.2, 1.6), Vec3::ZERO, Vec3::Y, 45.0),
        ),
        probe: Probe::Frame {
            width: FRAME_SIDE,
            height: FRAME_SIDE,
            truth: FrameTruth::Reference,
        },
    }
}

fn opposite_bundles() -> StressCase {
    let name = "bundles/opposite";
    let room = meshes::shared_edge_cube(4).map(|p| p * 2.0);
    let mut rng = SplitMix64::new(0x0990_517e);
    let mut rays = Vec::new();
    for _ in 0..16 {
        let o = DVec3::new(
            rng.range_f32(-1.5, 1.5) as f64,
            rng.range_f32(-1.5, 1.5) as f64,
            rng.range_f32(-1.5, 1.5) as f64,
        )
        .as_vec3();
        for _ in 0..64 {
            // Consecutive rays share the origin and point in opposite directions, so the nodes
            // of an unsorted hierarchy hold opposite directions.
            let d = random_unit(&mut rng).as_vec3();
            for d in [d, -d] {
                let n = rays.len() as u32;
                rays.push(probe_ray(RayKind::Reflection, o, d, 0.0, f32::INFINITY, n));
            }
        }
    }
    let expect = vec![Expect::Reference; rays.len()];
    ray_case(
        name,
        format!(
            "{} rays in opposite pairs from 16 points inside a closed box (cone unions \
             degenerate): the f64 reference decides",
            rays.len()
        ),
        scene(
            name,
            &[("box", &room, Material::default())],
            &[light(Vec3::new(0.0, 1.5, 0.0))],
            look_at(DVec3::ZERO, DVec3::new(0.0, 0.0, 1.0)),
        ),
        rays,
        expect,
    )
}

fn stadium() -> StressCase {
    let name = "stadium/teapot";
    let teapot = meshes::bumpy_sphere(4, 0.08);
    let stadium = meshes::inward_box(Vec3::splat(-1000.0), Vec3::splat(1000.0));
    StressCase {
        name: name.into(),
        family: family(name),
        about: format!(
            "a detailed bumpy mirror sphere ({} triangles, radius 1) inside a 2000-wide box: \
             tiny detail in a huge sparse scene; the f64 reference decides",
            teapot.indices.len()
        ),
        scene: scene(
            name,
            &[
                ("teapot", &teapot, mirror(0.8)),
                ("stadium", &stadium, Material::default()),
            ],
            &[light(Vec3::new(3.0, 5.0, 4.0))],
            camera(Vec3::new(0.0, 0.5, 2.6), Vec3::ZERO, Vec3::Y, 45.0),
        ),
        probe: Probe::Frame {
            width: FRAME_SIDE,
            height: FRAME_SIDE,
            truth: FrameTruth::Reference,
        },
    }
}

/// The triangle of the `invalid/*` ray cases: `(-1,-1,0), (1,-1,0), (0,1,0)`, facing `+z`.
fn single_triangle() -> TriMesh {
    TriMesh {
        positions: vec![
            Vec3::new(-1.0, -1.0, 0.0),
            Vec3::new(1.0, -1.0, 0.0),
            Vec3::new(0.0, 1.0, 0.0),
        ],
        indices: vec![[0, 1, 2]],
    }
}

fn invalid_rays() -> StressCase {
    let name = "invalid/nan-inf-rays";
    let (nan, inf) = (f32::NAN, f32::INFINITY);
    let o = Vec3::new(0.0, -0.25, 1.0);
    let d = -Vec3::Z;
    // (origin, direction, t_min, t_max), each aimed at the triangle but for one bad component.
    let specs: Vec<(Vec3, Vec3, f32, f32)> = vec![
        (Vec3::new(nan, -0.25, 1.0), d, 0.0, inf),
        (Vec3::new(0.0, nan, 1.0), d, 0.0, inf),
        (Vec3::new(0.0, -0.25, nan), d, 0.0, inf),
        (Vec3::new(inf, -0.25, 1.0), d, 0.0, inf),
        (Vec3::new(0.0, -inf, 1.0), d, 0.0, inf),
        (Vec3::new(0.0, -0.25, inf), d, 0.0, inf),
        (o, Vec3::new(nan, 0.0, -1.0), 0.0, inf),
        (o, Vec3::new(0.0, 0.0, nan), 0.0, inf),
        (o, Vec3::splat(nan), 0.0, inf),
        (o, Vec3::new(inf, 0.0, -1.0), 0.0, inf),
        (o, Vec3::new(0.0, 0.0, -inf), 0.0, inf),
        (o, Vec3::ZERO, 0.0, inf),
        (o, d, nan, inf),
        (o, d, 0.0, nan),
        (o, d, nan, nan),
        (Vec3::splat(nan), Vec3::splat(nan), nan, nan),
    ];
    let rays: Vec<Ray> = specs
        .iter()
        .enumerate()
        .map(|(i, &(o, d, a, b))| probe_ray(RayKind::Reflection, o, d, a, b, i as u32))
        .collect();
    let expect = vec![Expect::Invalid; rays.len()];
    ray_case(
        name,
        format!(
            "{} rays aimed at one triangle with a NaN or infinite origin, direction or interval, \
             or a zero direction: misses or an error, never a hit or a panic",
            rays.len()
        ),
        scene(
            name,
            &[("triangle", &single_triangle(), Material::default())],
            &[light(Vec3::new(0.0, 0.0, 3.0))],
            look_at(DVec3::ZERO, DVec3::new(0.0, -2.0, 3.0)),
        ),
        rays,
        expect,
    )
}

fn one_triangle() -> StressCase {
    let name = "invalid/one-triangle";
    let mut rng = SplitMix64::new(0x0e);
    let mut rays = Vec::new();
    let mut expect = Vec::new();
    for i in 0..400u32 {
        // A point inside the triangle (barycentric, away from the edges), or beside it.
        let (a, b) = (rng.range_f32(0.05, 0.9), rng.range_f32(0.05, 0.9));
        let (a, b) = if a + b > 0.95 {
            (0.95 - b, 0.95 - a)
        } else {
            (a, b)
        };
        let [p0, p1, p2] = single_triangle().positions[..] else {
            unreachable!()
        };
        let inside = p0 + a * (p1 - p0) + b * (p2 - p0);
        let n = rays.len() as u32;
        match i % 4 {
            0 | 1 => {
                rays.push(probe_ray(
                    RayKind::Reflection,
                    inside + Vec3::Z,
                    -Vec3::Z,
                    0.0,
                    f32::INFINITY,
                    n,
                ));
                expect.push(Expect::Nearest { tri: 0, t: 1.0 });
            }
            2 => {
                // Pointing away, or stopping short of the triangle.
                let (d, t_max) = if i % 8 == 2 {
                    (Vec3::Z, f32::INFINITY)
                } else {
                    (-Vec3::Z, 0.5)
                };
                rays.push(probe_ray(
                    RayKind::Reflection,
                    inside + Vec3::Z,
                    d,
                    0.0,
                    t_max,
                    n,
                ));
                expect.push(Expect::Miss);
            }
            _ => {
                let beside = Vec3::new(rng.range_f32(1.1, 3.0), rng.range_f32(-3.0, 3.0), 1.0);
                rays.push(probe_ray(
                    RayKind::Reflection,
                    beside,
                    -Vec3::Z,
                    0.0,
                    f32::INFINITY,
                    n,
                ));
                expect.push(Expect::Miss);
            }
        }
    }
    ray_case(
        name,
        format!(
            "{} rays onto a one-triangle scene: half hit it at t = 1, the others point away, stop \
             short or pass beside it",
            rays.len()
        ),
        scene(
            name,
            &[("triangle", &single_triangle(), Material::default())],
            &[light(Vec3::new(0.0, 0.0, 3.0))],
            look_at(DVec3::ZERO, DVec3::new(0.0, -2.0, 3.0)),
        ),
        rays,
        expect,
    )
}

fn all_miss() -> StressCase {
    let name = "invalid/all-miss";
    let mesh = meshes::icosphere(2);
    let mut rng = SplitMix64::new(0xa11);
    let mut rays = Vec::new();
    for _ in 0..1000 {
        // From a point outside the unit sphere, away from it or tangent to a larger sphere.
        let p = random_unit(&mut rng) * rng.range_f32(1.5, 4.0) as f64;
        let away = (p + random_unit(&mut rng) * 0.5 * p.length()).normalize();
        let d = if away.dot(p) > 0.0 {
            away
        } else {
            p.normalize()
        };
        let n = rays.len() as u32;
        rays.push(probe_ray(
            RayKind::Reflection,
            p.as_vec3(),
            d.as_vec3(),
            0.0,
            f32::INFINITY,
            n,
        ));
    }
    let expect = vec![Expect::Miss; rays.len()];
    ray_case(
        name,
        format!(
            "{} rays leaving an icosphere's surroundings: every one misses",
            rays.len()
        ),
        scene(
            name,
            &[("sphere", &mesh, Material::default())],
            &[light(Vec3::new(0.0, 0.0, 3.0))],
            look_at(DVec3::ZERO, DVec3::new(0.0, 0.0, 4.0)),
        ),
        rays,
        expect,
    )
}

/// A case whose scene [`SceneBuilder`] must reject (`fill` adds the offending mesh).
fn rejected(name: &str, about: &str, fill: impl FnOnce(&mut SceneBuilder)) -> StressCase {
    let mut b = SceneBuilder::new(name);
    b.material(Material::default());
    b.light(light(Vec3::new(0.0, 0.0, 3.0)));
    b.camera(look_at(DVec3::ZERO, DVec3::new(0.0, 0.0, 4.0)));
    fill(&mut b);
    ray_case(
        name,
        about.into(),
        b.build(name).map(Arc::new).map_err(|e| e.to_string()),
        Vec::new(),
        Vec::new(),
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::stress::Probe;

    #[test]
    fn suite_is_deterministic_and_well_formed() {
        let (a, b) = (cases(), cases());
        assert_eq!(a.len(), b.len());
        let mut names = std::collections::BTreeSet::new();
        for (x, y) in a.iter().zip(&b) {
            assert!(names.insert(x.name.clone()), "{} twice", x.name);
            assert_ne!(x.family, "other", "{}", x.name);
            assert!(x.name.starts_with(x.family));
            match (&x.probe, &y.probe) {
                (
                    Probe::Rays {
                        rays: r1,
                        expect: e1,
                        ..
                    },
                    Probe::Rays {
                        rays: r2,
                        expect: e2,
                        ..
                    },
                ) => {
                    assert_eq!(r1.len(), e1.len(), "{}", x.name);
                    assert_eq!(
                        bytemuck::cast_slice::<Ray, u8>(r1),
                        bytemuck::cast_slice::<Ray, u8>(r2)
                    );
                    assert_eq!(e1.len(), e2.len());
                    if x.scene.is_ok() {
                        assert!(!r1.is_empty(), "{} has no rays", x.name);
                    }
                }
                (Probe::Frame { .. }, Probe::Frame { .. }) => {}
                _ => panic!("{}: probes differ", x.name),
            }
        }
    }

    #[test]
    fn only_the_rejection_cases_fail_to_build() {
        for c in cases() {
            let rejected = c.name == "invalid/empty-scene" || c.name == "invalid/nan-vertex";
            assert_eq!(
                c.scene.is_err(),
                rejected,
                "{}: {:?}",
                c.name,
                c.scene.as_ref().err()
            );
            if let Err(e) = &c.scene {
                assert!(e.contains("empty scene") || e.contains("non-finite"), "{e}");
            }
        }
    }

    #[test]
    fn interior_origins_are_inside_and_targets_on_the_mesh() {
        // The closed cases' rays start inside their meshes: every ray origin is nearer the
        // centre than any vertex (the meshes are star-shaped around the centre).
        for c in cases().iter().filter(|c| {
            (c.family == "closed" || c.name.contains("icosphere")) && c.name != "closed/torus"
        }) {
            let (Ok(scene), Probe::Rays { rays, .. }) = (&c.scene, &c.probe) else {
                panic!()
            };
            let centre = scene.bounds.center();
            let inner = scene
                .positions
                .iter()
                .map(|p| p.distance(centre))
                .fold(f32::INFINITY, f32::min);
            assert!(
                rays.iter().all(|r| r.origin.distance(centre) < inner),
                "{}",
                c.name
            );
        }
        // The zero-area case really has zero-area triangles, and only they are degenerate.
        let c = cases()
            .into_iter()
            .find(|c| c.name == "degenerate/zero-area")
            .unwrap();
        assert_eq!(c.scene.unwrap().degenerate_triangles, 6);
    }
}
