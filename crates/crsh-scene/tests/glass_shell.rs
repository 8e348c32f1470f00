//! The built-in `glass-shell` / `glass-shell-N` (seed 004 §5, §7): exact triangle counts, names
//! refused with errors, determinism, glass in every pixel, both spheres' orientation, and the
//! generations of refraction its paths reach (the module docs' table), exactly and on the mesh.

mod support;

use std::path::Path;

use crsh_scene::builtin::glass_shell;
use crsh_scene::builtin::glass_sphere::{self, UvGrid};
use crsh_scene::{builtin, load, load_animated, manifest, Scene};
use glam::DVec3;

/// (N, slices, stacks) of each sphere.
const GRIDS: &[(u32, u32, u32)] = &[
    (100, 5, 6),
    (500, 25, 6),
    (1000, 25, 11),
    (5000, 50, 26),
    (24, 3, 3),
    (32, 4, 3),
    (200, 10, 6),
    (200_000, 250, 201),
];

fn mesh(s: &Scene, i: usize, name: &str) -> std::ops::Range<usize> {
    let m = &s.meshes[i];
    assert_eq!(m.name, name);
    m.first_tri as usize..(m.first_tri + m.tri_count) as usize
}

fn outer(s: &Scene) -> std::ops::Range<usize> {
    mesh(s, 0, "glass-shell-outer")
}

fn inner(s: &Scene) -> std::ops::Range<usize> {
    mesh(s, 1, "glass-shell-inner")
}

#[test]
fn grids_and_triangle_counts_are_exact() {
    for &(n, slices, stacks) in GRIDS {
        let grid = glass_shell::grid_for_triangles(n).unwrap();
        assert_eq!(grid, UvGrid { slices, stacks }, "N = {n}");
        assert_eq!(2 * grid.triangles(), n);
        let s = builtin::build(&format!("glass-shell-{n}")).unwrap();
        assert_eq!(s.name, format!("glass-shell-{n}"));
        assert_eq!(s.triangle_count(), n as usize + 12, "N = {n}");
        assert_eq!(s.meshes.len(), 8);
        assert_eq!(outer(&s), 0..n as usize / 2);
        assert_eq!(inner(&s), n as usize / 2..n as usize);
        assert!(s.meshes[2..].iter().all(|m| m.tri_count == 2));
        assert_eq!(s.positions.len(), 2 * grid.vertices() as usize + 24);
        assert_eq!(s.degenerate_triangles, 0, "N = {n}");
    }
    let headline = load("glass-shell").unwrap();
    assert_eq!(headline.name, "glass-shell");
    assert_eq!(headline.triangle_count(), 5012);
    assert_eq!(headline.positions.len(), 2528);
    assert_eq!(
        headline.positions,
        load("glass-shell-5000").unwrap().positions
    );
}

#[test]
fn every_paper_count_loads_by_name_and_is_valid() {
    for n in glass_shell::PAPER_TRIANGLES {
        let name = format!("glass-shell-{n}");
        let (s, report) = crsh_scene::load_with_report(&name).unwrap();
        assert!(report.warnings.is_empty(), "{name}: {:?}", report.warnings);
        support::check_invariants(&s);
        let (anim, _) = load_animated(&name).unwrap();
        assert_eq!(anim.scene().positions, s.positions);
        assert!(builtin::is_static(&name));
    }
}

#[test]
fn bad_names_are_errors_naming_the_scene_and_the_allowed_values() {
    for name in [
        "glass-shell-7",
        "glass-shell-0",
        "glass-shell-8",
        "glass-shell-12",
        "glass-shell-16",
        "glass-shell-20",
        "glass-shell-22",
        "glass-shell-28",
        "glass-shell-102",
        "glass-shell-200004",
        "glass-shell-4294967296",
        "glass-shell-99999999999999999999999",
        "glass-shell-",
        "glass-shell-abc",
        "glass-shell-+500",
        "glass-shell-0500",
        "glass-shell--500",
        "glass-shell-5e3",
        "glass-shell-500 ",
        "glass-shell-N",
    ] {
        for e in [
            load(name).unwrap_err().to_string(),
            builtin::build(name).unwrap_err().to_string(),
            load_animated(name).unwrap_err().to_string(),
        ] {
            assert!(e.contains(&format!("'{name}'")), "{name}: {e}");
            assert!(
                e.contains("multiple of 4") && e.contains("200000"),
                "{name}: {e}"
            );
        }
        assert!(glass_shell::is_name(name) && builtin::is_name(name));
        assert!(!glass_sphere::is_name(name));
    }
    for n in [0, 7, 8, 16, 20, 22, 102, 200_004, u32::MAX] {
        assert!(glass_shell::builder(n).is_err(), "{n}");
    }
    // The smallest accepted N is 24 (N/4 = 6 = 3 × 2).
    assert!(glass_shell::builder(24).is_ok());
    assert!(!builtin::is_name("glass-shell-500.toml"));
    let e = load("glass-shell-500.toml").unwrap_err().to_string();
    assert!(!e.contains("multiple of 4"), "{e}");
    assert!(!builtin::is_name("glass-shells"));
    assert!(!glass_shell::is_name("glass-sphere-500"));
}

#[test]
fn builds_are_deterministic() {
    for name in ["glass-shell", "glass-shell-100", "glass-shell-1000"] {
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

#[test]
fn the_outer_sphere_corridor_light_and_camera_are_glass_spheres() {
    for n in [24, 100, 500, 5000] {
        let shell = builtin::build(&format!("glass-shell-{n}")).unwrap();
        let grid = glass_shell::grid_for_triangles(n).unwrap();
        let sphere = builtin::build(&format!("glass-sphere-{}", n / 2)).unwrap();
        assert_eq!(shell.camera, sphere.camera);
        assert_eq!(shell.camera, glass_sphere::camera(grid));
        assert_eq!(shell.lights, sphere.lights);
        assert_eq!(shell.materials, sphere.materials);
        assert_eq!(shell.bounds, sphere.bounds);
        let k = grid.vertices() as usize;
        assert_eq!(shell.positions[..k], sphere.positions[..k]);
        assert_eq!(shell.normals[..k], sphere.normals[..k]);
        assert_eq!(shell.positions[2 * k..], sphere.positions[k..]);
        assert_eq!(
            shell.indices[..n as usize / 2],
            sphere.indices[..n as usize / 2]
        );
        for (a, b) in shell.meshes[2..].iter().zip(&sphere.meshes[1..]) {
            assert_eq!(
                (&a.name, a.tri_count, a.aabb),
                (&b.name, b.tri_count, b.aabb)
            );
        }
    }
    // The paper's counts keep the full 24° except the 5 × 6 grid of N = 100.
    for (n, full) in [(100, false), (500, true), (1000, true), (5000, true)] {
        let vfov = builtin::build(&format!("glass-shell-{n}"))
            .unwrap()
            .camera
            .vfov_deg;
        assert_eq!(vfov == glass_sphere::VFOV_DEG, full, "N = {n}: {vfov}");
    }
}

/// Möller-Trumbore in f64, both faces, edges inclusive: the distance along `d`.
fn hit_t(o: DVec3, d: DVec3, [a, b, c]: [DVec3; 3]) -> Option<f64> {
    let (e1, e2) = (b - a, c - a);
    let p = d.cross(e2);
    let det = e1.dot(p);
    if det.abs() < 1e-18 {
        return None;
    }
    let s = o - a;
    let u = s.dot(p) / det;
    let q = s.cross(e1);
    let v = d.dot(q) / det;
    let t = e2.dot(q) / det;
    (u >= 0.0 && v >= 0.0 && u + v <= 1.0 && t > 1e-9).then_some(t)
}

fn tris(s: &Scene, range: std::ops::Range<usize>) -> Vec<[DVec3; 3]> {
    range.map(|t| s.triangle(t).map(|p| p.as_dvec3())).collect()
}

#[test]
fn the_shell_fills_every_pixel_of_a_square_frame() {
    const W: u32 = 64;
    for n in [24, 100, 500, 1000, 5000] {
        let s = builtin::build(&format!("glass-shell-{n}")).unwrap();
        let cam = &s.camera;
        let r_in = glass_shell::grid_for_triangles(n)
            .unwrap()
            .inscribed_radius();
        let o = cam.eye.as_dvec3();
        for y in 0..=W {
            for x in 0..=W {
                let d = cam.direction(x as f32, y as f32, W, W).as_dvec3();
                let dist = (o - d * o.dot(d)).length();
                assert!(
                    dist <= r_in - glass_sphere::COVER_MARGIN + 1e-5,
                    "N = {n}: corner ({x}, {y}) at {dist}, inscribed radius {r_in}"
                );
            }
        }
        let outer = tris(&s, outer(&s));
        for y in 0..W {
            for x in 0..W {
                let d = cam
                    .direction(x as f32 + 0.5, y as f32 + 0.5, W, W)
                    .as_dvec3();
                assert!(
                    outer.iter().any(|&t| hit_t(o, d, t).is_some()),
                    "N = {n}: pixel ({x}, {y}) misses the outer mesh"
                );
            }
        }
    }
}

#[test]
fn the_cavity_is_concentric_inside_the_outer_mesh_with_its_radius_rule() {
    for n in glass_shell::PAPER_TRIANGLES {
        let grid = glass_shell::grid_for_triangles(n).unwrap();
        assert_eq!(glass_shell::inner_radius(grid), glass_shell::INNER_RADIUS);
    }
    let coarse = glass_shell::grid_for_triangles(24).unwrap();
    let r = glass_shell::inner_radius(coarse);
    assert!((f64::from(r) - 0.8 * coarse.inscribed_radius()).abs() < 1e-6 && r < 0.35);
    for n in [24, 32, 100, 500, 5000] {
        let s = builtin::build(&format!("glass-shell-{n}")).unwrap();
        let r = glass_shell::inner_radius(glass_shell::grid_for_triangles(n).unwrap());
        let inner_verts: Vec<DVec3> = inner(&s)
            .flat_map(|t| s.indices[t])
            .map(|v| s.positions[v as usize].as_dvec3())
            .collect();
        // The cavity's vertices (its own, not repeated per triangle) average to the centre.
        let k = glass_shell::grid_for_triangles(n).unwrap().vertices() as usize;
        let centre = s.positions[k..2 * k]
            .iter()
            .map(|p| p.as_dvec3())
            .sum::<DVec3>()
            / k as f64;
        assert!(centre.length() < 1e-6, "N = {n}: concentric");
        // Every inner vertex is at radius r and strictly inside every outer face's plane.
        for v in &inner_verts {
            assert!((v.length() - f64::from(r)).abs() < 1e-6);
        }
        for [a, b, c] in tris(&s, outer(&s)) {
            let normal = (b - a).cross(c - a).normalize();
            let plane = normal.dot(a);
            assert!(inner_verts.iter().all(|v| normal.dot(*v) < plane - 0.05));
        }
    }
}

#[test]
fn normals_face_the_lower_index_outward_on_the_outer_and_inward_on_the_cavity() {
    for name in ["glass-shell-100", "glass-shell"] {
        let s = builtin::build(name).unwrap();
        for (range, sign) in [(outer(&s), 1.0), (inner(&s), -1.0)] {
            for t in range {
                let [a, b, c] = s.triangle(t);
                let n = (b - a).cross(c - a);
                assert!(
                    sign * n.dot((a + b + c) / 3.0) > 0.0,
                    "{name}: triangle {t} wound the wrong way"
                );
                for &v in &s.indices[t] {
                    let (p, nv) = (s.positions[v as usize], s.normals[v as usize]);
                    assert!((nv.length() - 1.0).abs() < 1e-6);
                    assert!(sign * nv.dot(p.normalize()) > 0.9999, "{name}: vertex {v}");
                }
            }
        }
        // One glass material for both spheres.
        assert_eq!(
            s.material_of(0),
            s.material_of(s.meshes[1].first_tri as usize)
        );
        let glass = s.material_of(0);
        assert_eq!(
            (glass.transparency, glass.reflectivity, glass.ior),
            (1.0, 0.0, 1.5)
        );
        assert_eq!(glass.diffuse, glass_sphere::GLASS_DIFFUSE);
        // The Whitted rule (front face = counter-clockwise seen from the ray = entering the
        // glass): a ray from the cavity meets the inner surface's front face, one from inside
        // the glass (radius 0.8) going inward its back face, one from the air outside the
        // outer surface's front face.
        let tris_of = |r: std::ops::Range<usize>| tris(&s, r);
        let front = |o: DVec3, d: DVec3, set: &[[DVec3; 3]]| {
            let hit = set
                .iter()
                .filter_map(|&t| hit_t(o, d, t).map(|dist| (dist, t)))
                .min_by(|a, b| a.0.total_cmp(&b.0))
                .expect("a hit");
            let [a, b, c] = hit.1;
            d.dot((b - a).cross(c - a)) < 0.0
        };
        let (inn, out) = (tris_of(inner(&s)), tris_of(outer(&s)));
        for d in [DVec3::X, DVec3::new(0.3, -0.5, 0.8).normalize()] {
            assert!(front(DVec3::ZERO, d, &inn), "{name}: cavity → glass enters");
            assert!(!front(d * 0.8, -d, &inn), "{name}: glass → cavity leaves");
            assert!(front(d * 3.0, -d, &out), "{name}: air → glass enters");
            assert!(!front(d * 0.8, d, &out), "{name}: glass → air leaves");
        }
    }
}

fn reflect(i: DVec3, n: DVec3) -> DVec3 {
    i - n * 2.0 * n.dot(i)
}

/// The Whitted generator's refraction: `n` faces the arriving ray, `ri = 1 / ior` entering
/// (front face), `ior` leaving; `None` under total internal reflection.
fn refract(i: DVec3, n: DVec3, ri: f64) -> Option<DVec3> {
    let cos_i = -i.dot(n);
    let k = 1.0 - ri * ri * (1.0 - cos_i * cos_i);
    (k >= 0.0).then(|| (i * ri + n * (ri * cos_i - k.sqrt())).normalize())
}

/// Per generation `k = 1..=8` (index `k − 1`), how many paths have a `k`-th refraction ray,
/// and how many paths are totally internally reflected at least once. `next` gives a ray's
/// nearest glass hit: its distance, the geometric normal of its counter-clockwise side and
/// the shading normal.
struct Alive {
    alive: [u32; 8],
    tir_paths: u32,
    paths: u32,
}

fn trace(
    s: &Scene,
    width: u32,
    next: impl Fn(DVec3, DVec3) -> Option<(f64, DVec3, DVec3)>,
) -> Alive {
    let ior = f64::from(s.material_of(0).ior);
    let cam = &s.camera;
    let mut out = Alive {
        alive: [0; 8],
        tir_paths: 0,
        paths: width * width,
    };
    for y in 0..width {
        for x in 0..width {
            let mut o = cam.eye.as_dvec3();
            let mut d = cam
                .direction(x as f32 + 0.5, y as f32 + 0.5, width, width)
                .as_dvec3()
                .normalize();
            let mut tir = false;
            for generation in 0..8 {
                let Some((t, geo, shading)) = next(o, d) else {
                    break;
                };
                // As the surface stage: both normals flipped to the side the ray came from.
                let front = d.dot(geo) < 0.0;
                let facing = if front { geo } else { -geo };
                let n = if shading.dot(facing) < 0.0 {
                    -shading
                } else {
                    shading
                };
                let ri = if front { 1.0 / ior } else { ior };
                o += d * t;
                d = refract(d, n, ri).unwrap_or_else(|| {
                    tir = true;
                    reflect(d, n).normalize()
                });
                out.alive[generation] += 1;
            }
            out.tir_paths += u32::from(tir);
        }
    }
    out
}

fn table(a: &Alive) -> String {
    let share = |c: u32| format!("{:.1} %", 100.0 * f64::from(c) / f64::from(a.paths));
    let cells: Vec<String> = a.alive.iter().map(|&c| share(c)).collect();
    format!(
        "alive at generations 1..8: {}; totally reflected: {}",
        cells.join(", "),
        share(a.tir_paths)
    )
}

/// The nearest hit of the exact spheres of radius 1 (outward) and `r` (inward).
fn analytic(r: f64) -> impl Fn(DVec3, DVec3) -> Option<(f64, DVec3, DVec3)> {
    move |o, d| {
        [(1.0, 1.0), (r, -1.0)]
            .into_iter()
            .filter_map(|(radius, sign)| {
                let b = o.dot(d);
                let disc = b * b - (o.dot(o) - radius * radius);
                if disc < 0.0 {
                    return None;
                }
                let t = [-b - disc.sqrt(), -b + disc.sqrt()]
                    .into_iter()
                    .find(|&t| t > 1e-9)?;
                let n = (o + d * t).normalize() * sign;
                Some((t, n, n))
            })
            .min_by(|a, b| a.0.total_cmp(&b.0))
    }
}

#[test]
fn the_alive_fractions_per_generation_are_as_documented() {
    let s = builtin::build("glass-shell").unwrap();
    let r = f64::from(glass_shell::INNER_RADIUS);
    assert_eq!(glass_shell::INNER_RADIUS, 0.6);
    let a = trace(&s, 256, analytic(r));
    eprintln!("glass-shell, exact spheres, 256²: {}", table(&a));
    let share = |c: u32| f64::from(c) / f64::from(a.paths);
    // Generations 1-3: every path; 4: the 72.5 % passing within r of the centre; none beyond.
    assert_eq!(a.alive[..3], [a.paths; 3]);
    assert!((0.72..0.73).contains(&share(a.alive[3])), "{}", table(&a));
    assert_eq!(a.alive[4..], [0; 4], "{}", table(&a));
    // The other 27.5 % are totally reflected at the cavity; together, every path.
    assert!((0.27..0.28).contains(&share(a.tir_paths)), "{}", table(&a));
    assert_eq!(a.alive[3] + a.tir_paths, a.paths);
    // Survival past generation 2, with some total internal reflection.
    assert!(share(a.alive[3]) >= 0.05 && a.tir_paths > 0);

    // The documented trade-off of other radii (0.5 and 0.75).
    let half = trace(&s, 256, analytic(0.5));
    assert!(
        (0.95..0.96).contains(&share(half.alive[2])),
        "{}",
        table(&half)
    );
    assert!(
        (0.49..0.50).contains(&share(half.alive[3])),
        "{}",
        table(&half)
    );
    let thin = trace(&s, 256, analytic(0.75));
    assert!(
        (0.95..0.96).contains(&share(thin.alive[3])),
        "{}",
        table(&thin)
    );
    assert!(
        (0.04..0.05).contains(&share(thin.tir_paths)),
        "{}",
        table(&thin)
    );
}

#[test]
fn the_mesh_reflects_totally_and_keeps_paths_to_generation_4() {
    // The faceted mesh of glass-shell-1000 (25 × 11 per sphere), brute force on its object
    // triangles with smooth shading normals as the Whitted generator sees them.
    let s = builtin::build("glass-shell-1000").unwrap();
    let object = tris(&s, 0..1000);
    let normals: Vec<[DVec3; 3]> = (0..1000)
        .map(|t| s.indices[t].map(|v| s.normals[v as usize].as_dvec3()))
        .collect();
    let a = trace(&s, 48, |o, d| {
        let (t, i) = object
            .iter()
            .enumerate()
            .filter_map(|(i, &tri)| hit_t(o, d, tri).map(|t| (t, i)))
            .min_by(|a, b| a.0.total_cmp(&b.0))?;
        let [p0, p1, p2] = object[i];
        let geo = (p1 - p0).cross(p2 - p0).normalize();
        // Barycentric weights of the hit point for the shading normal.
        let p = o + d * t;
        let area = |a: DVec3, b: DVec3, c: DVec3| (b - a).cross(c - a).dot(geo);
        let whole = area(p0, p1, p2);
        let w = [
            area(p, p1, p2) / whole,
            area(p0, p, p2) / whole,
            area(p0, p1, p) / whole,
        ];
        let [n0, n1, n2] = normals[i];
        Some((t, geo, (n0 * w[0] + n1 * w[1] + n2 * w[2]).normalize()))
    });
    eprintln!("glass-shell-1000, mesh, 48²: {}", table(&a));
    let share = |c: u32| f64::from(c) / f64::from(a.paths);
    assert_eq!(a.alive[..2], [a.paths; 2]);
    assert!(share(a.alive[2]) > 0.99, "{}", table(&a));
    assert!((0.65..0.80).contains(&share(a.alive[3])), "{}", table(&a));
    assert!(share(a.alive[4]) < 0.02, "{}", table(&a));
    assert!((0.2..0.35).contains(&share(a.tir_paths)), "{}", table(&a));
}

#[test]
fn summary_and_manifest_extends() {
    let s = builtin::build("glass-shell-500").unwrap();
    assert_eq!(
        s.summary().to_string(),
        "glass-shell-500: 512 triangles, 8 meshes, 7 materials, 1 lights"
    );
    let path = Path::new("shell-extends.toml");
    let m = manifest::Manifest::parse("extends = \"glass-shell-500\"\n", path).unwrap();
    let (anim, warnings) = manifest::build_animated(&m, path).unwrap();
    assert!(warnings.is_empty(), "{warnings:?}");
    assert_eq!(anim.scene().triangle_count(), 512);
    let bad = manifest::Manifest::parse("extends = \"glass-shell-502\"\n", path).unwrap();
    let e = manifest::build_animated(&bad, path)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("glass-shell-502") && e.contains("multiple of 4"),
        "{e}"
    );
}
