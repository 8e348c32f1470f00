//! The built-in `glass-sphere` / `glass-sphere-N` (seed 004 §7): exact triangle counts, names
//! refused with errors, determinism, glass in every pixel, the geometry's orientation.

mod support;

use std::path::Path;

use crsh_scene::builtin::glass_sphere::{self, UvGrid};
use crsh_scene::{builtin, load, load_animated, manifest, Camera, Scene};
use glam::{DVec3, Vec3};

/// The paper's counts and a few others: (N, slices, stacks).
const GRIDS: &[(u32, u32, u32)] = &[
    (100, 10, 6),
    (500, 25, 11),
    (1000, 25, 21),
    (5000, 50, 51),
    (12, 3, 3),
    (16, 4, 3),
    (64, 8, 5),
    (200, 10, 11),
    (10_000, 100, 51),
    (19_996, 4999, 3),
    (200_000, 400, 251),
];

fn sphere_mesh(s: &Scene) -> std::ops::Range<usize> {
    let m = &s.meshes[0];
    assert_eq!(m.name, "glass-sphere");
    m.first_tri as usize..(m.first_tri + m.tri_count) as usize
}

#[test]
fn grids_and_triangle_counts_are_exact() {
    for &(n, slices, stacks) in GRIDS {
        let grid = UvGrid::for_triangles(n).unwrap();
        assert_eq!(grid, UvGrid { slices, stacks }, "N = {n}");
        assert_eq!(grid.triangles(), n);
        let s = builtin::build(&format!("glass-sphere-{n}")).unwrap();
        assert_eq!(s.name, format!("glass-sphere-{n}"));
        assert_eq!(s.triangle_count(), n as usize + 12, "N = {n}");
        assert_eq!(s.meshes.len(), 7);
        assert_eq!(s.meshes[0].tri_count, n);
        assert!(s.meshes[1..].iter().all(|m| m.tri_count == 2));
        assert_eq!(s.positions.len(), grid.vertices() as usize + 24);
        assert_eq!(s.degenerate_triangles, 0, "N = {n}");
    }
    let headline = load("glass-sphere").unwrap();
    assert_eq!(headline.name, "glass-sphere");
    assert_eq!(headline.triangle_count(), 5012);
    assert_eq!(
        headline.positions,
        load("glass-sphere-5000").unwrap().positions
    );
}

#[test]
fn every_paper_count_loads_by_name_and_is_valid() {
    for n in glass_sphere::PAPER_TRIANGLES {
        let name = format!("glass-sphere-{n}");
        let (s, report) = crsh_scene::load_with_report(&name).unwrap();
        assert!(report.warnings.is_empty(), "{name}: {:?}", report.warnings);
        support::check_invariants(&s);
        let (anim, _) = load_animated(&name).unwrap();
        assert_eq!(anim.scene().positions, s.positions);
    }
}

#[test]
fn the_tie_rule_picks_fewer_slices() {
    // 5000 / 2 = 2500: 50 × 50 (ratio 1) and 100 × 25 (ratio 4) are both a factor 2 from 2.
    assert_eq!(
        UvGrid::for_triangles(5000).unwrap(),
        UvGrid {
            slices: 50,
            stacks: 51
        }
    );
    // 16 / 2 = 8: only 4 × 2 (8 × 1 and 2 × 4 break the minimums).
    assert_eq!(UvGrid::for_triangles(16).unwrap().slices, 4);
}

#[test]
fn bad_names_are_errors_naming_the_scene_and_the_allowed_values() {
    for name in [
        "glass-sphere-7",
        "glass-sphere-0",
        "glass-sphere-6",
        "glass-sphere-8",
        "glass-sphere-10",
        "glass-sphere-9998",
        "glass-sphere-200002",
        "glass-sphere-4294967296",
        "glass-sphere-99999999999999999999999",
        "glass-sphere-",
        "glass-sphere-abc",
        "glass-sphere-+500",
        "glass-sphere-0500",
        "glass-sphere--500",
        "glass-sphere-5e3",
        "glass-sphere-500 ",
        "glass-sphere-N",
    ] {
        for e in [
            load(name).unwrap_err().to_string(),
            builtin::build(name).unwrap_err().to_string(),
            load_animated(name).unwrap_err().to_string(),
        ] {
            assert!(e.contains(&format!("'{name}'")), "{name}: {e}");
            assert!(e.contains("N even") && e.contains("200000"), "{name}: {e}");
        }
        assert!(glass_sphere::is_name(name) && builtin::is_name(name));
    }
    // Counts out of range are refused by the builder too.
    for n in [0, 7, 8, 10, 200_002, u32::MAX] {
        assert!(glass_sphere::builder(n).is_err(), "{n}");
    }
    // A file that merely starts like the name stays a file.
    assert!(!builtin::is_name("glass-sphere-500.toml"));
    let e = load("glass-sphere-500.toml").unwrap_err().to_string();
    assert!(!e.contains("N even"), "{e}");
    assert!(!builtin::is_name("glass-spheres"));
}

#[test]
fn builds_are_deterministic() {
    for name in ["glass-sphere", "glass-sphere-100", "glass-sphere-1000"] {
        let (a, b) = (builtin::build(name).unwrap(), builtin::build(name).unwrap());
        assert_eq!(a.positions, b.positions);
        assert_eq!(a.normals, b.normals);
        assert_eq!(a.indices, b.indices);
        assert_eq!(a.tri_spheres, b.tri_spheres);
        assert_eq!(a.meshes, b.meshes);
        assert_eq!(a.materials, b.materials);
        assert_eq!(a.lights, b.lights);
        assert_eq!(a.camera, b.camera);
    }
}

/// Distance from the origin of the line through `eye` along unit `d`.
fn miss_distance(eye: Vec3, d: Vec3) -> f64 {
    let (e, d) = (eye.as_dvec3(), d.as_dvec3());
    (e - d * e.dot(d)).length()
}

/// Möller-Trumbore in f64, both faces, edges inclusive.
fn hits(o: DVec3, d: DVec3, [a, b, c]: [Vec3; 3]) -> bool {
    let (a, b, c) = (a.as_dvec3(), b.as_dvec3(), c.as_dvec3());
    let (e1, e2) = (b - a, c - a);
    let p = d.cross(e2);
    let det = e1.dot(p);
    if det.abs() < 1e-18 {
        return false;
    }
    let s = o - a;
    let u = s.dot(p) / det;
    let q = s.cross(e1);
    let v = d.dot(q) / det;
    let t = e2.dot(q) / det;
    u >= 0.0 && v >= 0.0 && u + v <= 1.0 && t > 0.0
}

#[test]
fn the_sphere_fills_every_pixel_of_a_square_frame() {
    const W: u32 = 64;
    for n in [12, 16, 64, 100, 500, 1000, 5000, 19_996] {
        let s = builtin::build(&format!("glass-sphere-{n}")).unwrap();
        let cam = &s.camera;
        let r_in = UvGrid::for_triangles(n).unwrap().inscribed_radius();
        if glass_sphere::PAPER_TRIANGLES.contains(&n) {
            assert_eq!(cam.vfov_deg, glass_sphere::VFOV_DEG, "N = {n}");
        }
        assert!(cam.vfov_deg <= glass_sphere::VFOV_DEG);
        // Every pixel corner's ray passes inside the unit sphere and inside the mesh's
        // inscribed ball, with the margin.
        for y in 0..=W {
            for x in 0..=W {
                let d = cam.direction(x as f32, y as f32, W, W);
                let dist = miss_distance(cam.eye, d);
                assert!(dist < 1.0, "N = {n}: corner ({x}, {y}) at {dist}");
                assert!(
                    dist <= r_in - glass_sphere::COVER_MARGIN + 1e-5,
                    "N = {n}: corner ({x}, {y}) at {dist}, inscribed radius {r_in}"
                );
            }
        }
        // Every pixel centre's ray hits a triangle of the actual mesh.
        let tris: Vec<[Vec3; 3]> = sphere_mesh(&s).map(|t| s.triangle(t)).collect();
        let o = cam.eye.as_dvec3();
        // (The test can fail: rays away from the sphere or past its silhouette miss.)
        let tan = (1.05f64 / 3.0).asin().tan();
        let (up, right) = (DVec3::new(0.0, tan, -1.0), DVec3::new(tan, 0.0, -1.0));
        for d in [DVec3::Z, up.normalize(), right.normalize()] {
            assert!(!tris.iter().any(|&t| hits(o, d, t)), "N = {n}: {d} hits");
        }
        for y in 0..W {
            for x in 0..W {
                let d = cam
                    .direction(x as f32 + 0.5, y as f32 + 0.5, W, W)
                    .as_dvec3();
                assert!(
                    tris.iter().any(|&t| hits(o, d, t)),
                    "N = {n}: pixel ({x}, {y}) misses the mesh"
                );
            }
        }
    }
}

#[test]
fn the_documented_camera_margins_hold() {
    let cam = builtin::build("glass-sphere").unwrap().camera;
    assert_eq!(
        (cam.eye, cam.target, cam.up, cam.aspect),
        (Vec3::new(0.0, 0.0, 3.0), Vec3::ZERO, Vec3::Y, Some(1.0))
    );
    assert_eq!(cam.height_for(256), Some(256));
    let half = (cam.vfov_deg as f64 / 2.0).to_radians();
    let corner = (2f64.sqrt() * half.tan()).atan().to_degrees();
    let limit = (1.0f64 / 3.0).asin().to_degrees();
    assert!((corner - 16.73).abs() < 0.01, "{corner}");
    assert!((limit - 19.47).abs() < 0.01 && limit - corner > 2.7);
    assert!((glass_sphere::covering_vfov_deg(1.0) - 28.07).abs() < 0.01);
    // Landscape frames: the unit sphere covers up to width / height 1.329, not 4:3.
    let covers = |cam: &Camera, w: u32, h: u32, radius: f64| {
        [
            (0.0, 0.0),
            (w as f32, 0.0),
            (0.0, h as f32),
            (w as f32, h as f32),
        ]
        .iter()
        .all(|&(x, y)| miss_distance(cam.eye, cam.direction(x, y, w, h)) < radius)
    };
    assert!(covers(&cam, 1320, 1000, 1.0));
    assert!(!covers(&cam, 1340, 1000, 1.0));
    assert!(covers(&cam, 1000, 1900, 1.0), "portrait");
    // The mesh's inscribed ball: up to about 1.14 for N = 100, 1.29 for 500, 1.30 for 1000 and
    // 1.32 for 5000 (the camera is the same for the four).
    for (n, widest) in [(100, 1140), (500, 1285), (1000, 1300), (5000, 1320)] {
        let r = UvGrid::for_triangles(n).unwrap().inscribed_radius();
        assert_eq!(glass_sphere::camera(UvGrid::for_triangles(n).unwrap()), cam);
        assert!(covers(&cam, widest, 1000, r), "N = {n}");
        assert!(!covers(&cam, widest + 10, 1000, r), "N = {n}");
    }
}

#[test]
fn the_mesh_is_convex_with_the_documented_inscribed_radius() {
    for (n, documented) in [(100, 0.9216), (500, 0.9820), (1000, 0.9893), (5000, 0.9976)] {
        let s = builtin::build(&format!("glass-sphere-{n}")).unwrap();
        let range = sphere_mesh(&s);
        let grid = UvGrid::for_triangles(n).unwrap();
        let r_in = grid.inscribed_radius();
        assert!((r_in - documented).abs() < 1e-4, "N = {n}: {r_in}");
        let verts: Vec<DVec3> = s.positions[..grid.vertices() as usize]
            .iter()
            .map(|p| p.as_dvec3())
            .collect();
        let mut nearest = f64::INFINITY;
        for t in range {
            let [a, b, c] = s.triangle(t).map(|p| p.as_dvec3());
            let normal = (b - a).cross(c - a).normalize();
            let plane = normal.dot(a);
            nearest = nearest.min(plane);
            // Every vertex of the sphere lies on the inner side of every face's plane.
            assert!(
                verts.iter().all(|v| normal.dot(*v) <= plane + 1e-6),
                "N = {n}: triangle {t} is not a hull face"
            );
        }
        assert!(
            (nearest - r_in).abs() < 1e-5,
            "N = {n}: {nearest} vs {r_in}"
        );
    }
}

#[test]
fn sphere_normals_are_unit_and_outward_and_walls_face_inward() {
    for name in ["glass-sphere-100", "glass-sphere"] {
        let s = builtin::build(name).unwrap();
        for t in sphere_mesh(&s) {
            let [a, b, c] = s.triangle(t);
            let n = (b - a).cross(c - a);
            assert!(
                n.dot((a + b + c) / 3.0) > 0.0,
                "{name}: triangle {t} faces inward"
            );
            for &v in &s.indices[t] {
                let (p, nv) = (s.positions[v as usize], s.normals[v as usize]);
                assert!((nv.length() - 1.0).abs() < 1e-6);
                assert!((p.length() - 1.0).abs() < 1e-6);
                assert!(nv.dot(p) > 0.9999, "{name}: vertex {v}");
            }
        }
        let glass = s.material_of(0);
        assert!(glass.is_transparent() && !glass.is_mirror() && !glass.is_emitter());
        assert_eq!(
            (glass.transparency, glass.reflectivity, glass.ior),
            (1.0, 0.0, 1.5)
        );
        assert!(glass.diffuse.max_element() <= 0.05 && glass.diffuse.min_element() > 0.0);
        assert_eq!(glass.specular, Vec3::ZERO);
        glass.validate().unwrap();
        let mut colours = Vec::new();
        let mut centres = Vec::new();
        for m in &s.meshes[1..] {
            let mat = s.material_of(m.first_tri as usize);
            assert!(!mat.is_transparent() && !mat.is_mirror(), "{}", m.name);
            assert!(mat.diffuse.min_element() > 0.05, "{}", m.name);
            assert!(
                !colours.contains(&mat.diffuse),
                "{}: colours differ",
                m.name
            );
            colours.push(mat.diffuse);
            centres.push(m.aabb.center());
            for t in m.first_tri..m.first_tri + m.tri_count {
                let [a, b, c] = s.triangle(t as usize);
                let n = (b - a).cross(c - a).normalize();
                assert!(n.dot(-(a + b + c) / 3.0) > 0.0, "{} faces outward", m.name);
                for &v in &s.indices[t as usize] {
                    assert!(s.normals[v as usize].dot(n) > 0.999);
                }
            }
        }
        // The six walls close the box: each is a whole face of it.
        let (lo, hi) = (glass_sphere::ROOM_MIN, glass_sphere::ROOM_MAX);
        assert_eq!((s.bounds.min, s.bounds.max), (lo, hi));
        let mid = (lo + hi) / 2.0;
        for axis in 0..3 {
            for level in [lo[axis], hi[axis]] {
                let mut face = mid;
                face[axis] = level;
                assert!(
                    centres.iter().any(|c| (*c - face).length() < 1e-6),
                    "{name}: no wall at {face}"
                );
            }
        }
        // The sphere and the eye are inside.
        assert!(lo.cmplt(Vec3::splat(-1.0)).all() && hi.cmpgt(Vec3::ONE).all());
        let eye = s.camera.eye;
        assert!(eye.cmpgt(lo).all() && eye.cmplt(hi).all());
        // One light inside the box, off the camera's axis, not behind the sphere.
        assert_eq!(s.lights.len(), 1);
        let l = s.lights[0].position;
        assert!(l.cmpgt(lo).all() && l.cmplt(hi).all() && l.length() > 1.0);
        let axis_dist = miss_distance(s.camera.eye, -Vec3::Z).max(0.0);
        assert!(axis_dist < 1e-9);
        assert!(Vec3::new(l.x, l.y, 0.0).length() > 1.0, "off axis");
        assert!(l.z > 0.0, "in front of the sphere");
    }
}

#[test]
fn summary_is_sane() {
    let s = builtin::build("glass-sphere-500").unwrap();
    let sum = s.summary();
    assert_eq!(
        (
            sum.triangles,
            sum.vertices,
            sum.meshes,
            sum.materials,
            sum.lights,
            sum.degenerate_triangles
        ),
        (512, 2 + 25 * 10 + 24, 7, 7, 1, 0)
    );
    assert_eq!(
        sum.to_string(),
        "glass-sphere-500: 512 triangles, 7 meshes, 7 materials, 1 lights"
    );
}

#[test]
fn a_manifest_extends_a_sized_glass_sphere() {
    let path = Path::new("glass-extends.toml");
    let m = manifest::Manifest::parse("extends = \"glass-sphere-500\"\n", path).unwrap();
    let (anim, warnings) = manifest::build_animated(&m, path).unwrap();
    assert!(warnings.is_empty(), "{warnings:?}");
    let s = anim.scene();
    assert_eq!(s.triangle_count(), 512);
    assert_eq!(s.camera, builtin::build("glass-sphere-500").unwrap().camera);
    let bad = manifest::Manifest::parse("extends = \"glass-sphere-501\"\n", path).unwrap();
    let e = manifest::build_animated(&bad, path)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("glass-sphere-501") && e.contains("N even"),
        "{e}"
    );
}

#[test]
fn the_full_field_of_view_is_kept_except_for_coarse_and_three_stack_meshes() {
    let mut kept = 0;
    for n in (86..=5000).step_by(2) {
        let Ok(grid) = UvGrid::for_triangles(n) else {
            continue;
        };
        let vfov = glass_sphere::camera(grid).vfov_deg;
        assert_eq!(vfov == glass_sphere::VFOV_DEG, grid.stacks > 3, "N = {n}");
        kept += usize::from(grid.stacks > 3);
    }
    assert!(kept > 1000, "{kept}");
    let twelve = glass_sphere::camera(UvGrid::for_triangles(12).unwrap()).vfov_deg;
    assert!((twelve - 11.2).abs() < 0.05, "{twelve}");
}
