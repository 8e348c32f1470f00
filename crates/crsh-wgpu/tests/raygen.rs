//! GPU ray generation against the CPU twin on the same surfaces: the CPU raster's G-buffer of
//! both built-in scenes, plus hand-made surfaces (lights behind the surface, total internal
//! reflection, grazing incidence, background records, a throughput below the threshold, a
//! light on the surface), every ray kind × offset policy × shadow origin: same rays in the
//! same order, equal fields within a stated float tolerance; and with every origin-offset set
//! (seed 001's hemispheres, `offsets = center | vertex | median | polygon`), both shadow
//! origins, the same rays (intervals within [`OFFSET_T_REL`] but for rare near-tangent and
//! boundary cases, [`TANGENT_ABS`]) and the same counts of rays the offsets ended (up to those
//! boundary cases).
//!
//! Without an adapter every test prints `SKIP:` and passes, unless `CRSH_REQUIRE_GPU=1`.

use std::sync::Arc;

use crsh_core::glam::Vec3;
use crsh_core::{Backend, ParamValue, PipelineConfig, Ray, RayGen, RayKind, Stats, Surface};
use crsh_cpu::Cpu;
use crsh_scene::Scene;
use crsh_wgpu::raygen::whitted::Whitted;
use crsh_wgpu::testing::{assert_boundary_cases, close_at, rel_diff, TANGENT_ABS};
use crsh_wgpu::GpuScene;

fn spec(sets: &[(&str, ParamValue)]) -> crsh_core::StageSpec {
    let mut cfg = PipelineConfig::whitted("t", "brute");
    for (k, v) in sets {
        cfg.raygen.params.insert((*k).into(), v.clone());
    }
    crsh_wgpu::testing::cpu_registry()
        .resolve(&mut cfg)
        .unwrap();
    cfg.raygen
}

fn gbuffer(scene: &Arc<Scene>, w: u32, h: u32) -> Vec<Surface> {
    let cfg = crsh_wgpu::testing::cpu_preset("brute");
    let stages = crsh_wgpu::testing::cpu_stages(&cfg, scene, w, h);
    stages
        .primary
        .gbuffer(&Cpu, w, h, &mut Stats::default())
        .unwrap()
}

/// Close within `rel` of the larger magnitude (or both tiny). The tolerances used below are a
/// few ULPs: WGSL's `sqrt` and division may differ from the correctly rounded CPU results.
fn close(a: f32, b: f32, rel: f32) -> bool {
    a == b || (a - b).abs() <= rel * a.abs().max(b.abs()).max(1e-6)
}

/// Relative tolerance of a Whitted ray's interval: a shadow segment's length goes through
/// `sqrt` and a division, which WGSL need not round correctly (lavapipe: equal; an NVIDIA H200,
/// 2026-12-04: one ULP, 1.1e-7 relative), so a few ULPs.
const T_REL: f32 = 1e-6;

fn check_rays(what: &str, got: &[Ray], want: &[Ray]) {
    check_rays_t(what, got, want, T_REL);
}

/// [`check_rays`] with intervals (`t_min`, `t_max`) within `t_rel` ([`close_at`], on the scale
/// of the origin); returns the largest
/// relative interval difference seen.
fn check_rays_t(what: &str, got: &[Ray], want: &[Ray], t_rel: f32) -> f32 {
    assert_eq!(got.len(), want.len(), "{what}: ray count");
    let mut worst = 0.0f32;
    for (i, (g, w)) in got.iter().zip(want).enumerate() {
        worst = worst.max(rel_diff(g.t_min, w.t_min).max(rel_diff(g.t_max, w.t_max)));
        assert_eq!(
            (g.kind, g.pixel, g.light, g.depth, g.source),
            (w.kind, w.pixel, w.light, w.depth, w.source),
            "{what}: ray {i} identity"
        );
        let ok = (0..3).all(|k| {
            close(g.origin[k], w.origin[k], 1e-6)
                && close(g.dir[k], w.dir[k], 1e-6)
                && close(g.throughput[k], w.throughput[k], 1e-6)
        }) && close_at(g.t_min, w.t_min, t_rel, g.origin.abs().max_element())
            && close_at(g.t_max, w.t_max, t_rel, g.origin.abs().max_element());
        assert!(ok, "{what}: ray {i}: gpu {g:?} cpu {w:?}");
    }
    worst
}

/// The relative difference allowed between the device's and the CPU's `t_min` / `t_max` with
/// origin offsets: the hemisphere query's `sqrt` and divisions (which WGSL need not round
/// correctly) and the device compiler's freedom to fuse `a·b + c` may move its results by a
/// few ULPs (measured on lavapipe: 0, every Whitted ray bit for bit, and equal ended counts;
/// `offset_rays_match_the_cpu_on_the_builtin_scenes` prints it).
const OFFSET_T_REL: f32 = 1e-6;

/// `got` with the intervals of tangents and flips ([`TANGENT_ABS`]) replaced by `want`'s, and
/// the count of flips (each changes the count of rays the offsets ended by at most one);
/// asserts their bounds ([`assert_boundary_cases`]).
fn forgive_tangents_and_flips(what: &str, got: &[Ray], want: &[Ray]) -> (Vec<Ray>, u64) {
    let mut out = got.to_vec();
    let (mut tangents, mut flips) = (0, 0);
    for (g, w) in out.iter_mut().zip(want) {
        let scale = w.origin.abs().max_element();
        let off = |a: f32, b: f32, rel: f32| {
            a != b && (a - b).abs() > rel * a.abs().max(b.abs()).max(scale).max(1e-6)
        };
        let beyond = off(g.t_min, w.t_min, OFFSET_T_REL) || off(g.t_max, w.t_max, OFFSET_T_REL);
        if beyond {
            if !off(g.t_min, w.t_min, TANGENT_ABS) && !off(g.t_max, w.t_max, TANGENT_ABS) {
                tangents += 1;
            } else {
                flips += 1;
            }
            (g.t_min, g.t_max) = (w.t_min, w.t_max);
        }
    }
    assert_boundary_cases(what, tangents, flips, got.len());
    (out, flips as u64)
}

fn run_all(b: &crsh_wgpu::Wgpu, scene: &Arc<Scene>, surfaces: &[Surface], what: &str) -> usize {
    let g = GpuScene::new(b, scene).unwrap();
    let buf = b.upload(surfaces).unwrap();
    let mut total = 0;
    for offset in ["normal", "scaled", "fixed", "wachter"] {
        for origin in ["light", "surface"] {
            let s = spec(&[
                ("offset", ParamValue::Str(offset.into())),
                ("shadow_origin", ParamValue::Str(origin.into())),
            ]);
            let cpu = crsh_cpu::raygen::whitted::Whitted::new(scene, &s).unwrap();
            let gpu = Whitted::new(&g, &s).unwrap();
            for kind in [RayKind::Shadow, RayKind::Reflection, RayKind::Refraction] {
                let want = cpu.rays(surfaces, kind).unwrap();
                let mut stats = Stats::default();
                let out = gpu.generate(b, &buf, kind, &mut stats).unwrap();
                let got = b.download(&out).unwrap();
                check_rays(&format!("{what} {offset} {origin} {kind:?}"), &got, &want);
                total += got.len();
            }
        }
    }
    total
}

#[test]
fn rays_match_the_cpu_on_the_builtin_scenes() {
    let Some(b) = crsh_wgpu::testing::shared_backend("rays_match_the_cpu_on_the_builtin_scenes")
    else {
        return;
    };
    for name in ["cornell-mirrors", "office-boxes"] {
        let scene = Arc::new(crsh_scene::builtin::build(name).unwrap());
        let surfaces = gbuffer(&scene, 40, 30);
        let n = run_all(&b, &scene, &surfaces, name);
        assert!(n > 1000, "{name}: only {n} rays");
    }
}

/// Whitted rays with every hemisphere set, both shadow origins and two offset policies: the
/// CPU's rays (intervals within [`OFFSET_T_REL`], [`forgive_tangents_and_flips`]) and the CPU's
/// counts of rays the offsets ended, per kind. Returns (rays, ended rays, rays whose interval the offsets changed,
/// largest relative interval difference).
fn run_offsets(
    b: &crsh_wgpu::Wgpu,
    scene: &Arc<Scene>,
    surfaces: &[Surface],
    what: &str,
) -> (usize, u64, usize, f32) {
    let g = GpuScene::new(b, scene).unwrap();
    let buf = b.upload(surfaces).unwrap();
    let (mut total, mut ended, mut moved, mut worst) = (0, 0, 0, 0.0f32);
    for set in crsh_cpu::raygen::origin_offset::SET_NAMES {
        for offset in ["normal", "wachter"] {
            for origin in ["light", "surface"] {
                let params = |offsets: &str| {
                    spec(&[
                        ("offset", ParamValue::Str(offset.into())),
                        ("shadow_origin", ParamValue::Str(origin.into())),
                        ("offsets", ParamValue::Str(offsets.into())),
                    ])
                };
                let s = params(set);
                let plain =
                    crsh_cpu::raygen::whitted::Whitted::new(scene, &params("none")).unwrap();
                let cpu = crsh_cpu::raygen::whitted::Whitted::new(scene, &s).unwrap();
                let gpu = Whitted::new(&g, &s).unwrap();
                for kind in [RayKind::Shadow, RayKind::Reflection, RayKind::Refraction] {
                    let here = format!("{what} {set} {offset} {origin} {kind:?}");
                    let mut cpu_stats = Stats::default();
                    let want = cpu
                        .generate(&Cpu, &surfaces.to_vec(), kind, &mut cpu_stats)
                        .unwrap();
                    let mut gpu_stats = Stats::default();
                    let out = gpu.generate(b, &buf, kind, &mut gpu_stats).unwrap();
                    let got = b.download(&out).unwrap();
                    let (got, flips) = forgive_tangents_and_flips(&here, &got, &want);
                    worst = worst.max(check_rays_t(&here, &got, &want, OFFSET_T_REL));
                    let count =
                        |s: &Stats| s.per_kind.get(kind.name()).map_or(0, |k| k.offset_ended);
                    assert!(
                        count(&gpu_stats).abs_diff(count(&cpu_stats)) <= flips,
                        "{here}: rays ended: gpu {} cpu {} ({flips} flips)",
                        count(&gpu_stats),
                        count(&cpu_stats)
                    );
                    ended += count(&cpu_stats);
                    let before = plain.rays(surfaces, kind).unwrap();
                    moved += before
                        .iter()
                        .zip(&want)
                        .filter(|(a, b)| (a.t_min, a.t_max) != (b.t_min, b.t_max))
                        .count();
                    total += got.len();
                }
            }
        }
    }
    (total, ended, moved, worst)
}

#[test]
fn offset_rays_match_the_cpu_on_the_builtin_scenes() {
    let Some(b) =
        crsh_wgpu::testing::shared_backend("offset_rays_match_the_cpu_on_the_builtin_scenes")
    else {
        return;
    };
    let mut worst = 0.0f32;
    for name in ["cornell-mirrors", "office-boxes"] {
        let scene = Arc::new(crsh_scene::builtin::build(name).unwrap());
        let surfaces = gbuffer(&scene, 40, 30);
        let (n, ended, moved, w) = run_offsets(&b, &scene, &surfaces, name);
        println!("{name}: {n} rays, {moved} intervals moved by offsets, {ended} ended");
        // Closed rooms: reflection and refraction rays always reach a wall and shadow rays a
        // light well away from the surfaces, so few or no Whitted rays are ended outright
        // (the AO tests, with short rays, end many); the counts are compared all the same.
        assert!(
            n > 1000 && moved > n / 10,
            "{name}: {n} rays, {moved} moved"
        );
        worst = worst.max(w);
    }
    println!("Whitted rays with offsets: largest relative t_min / t_max difference {worst:e}");
}

#[test]
fn rays_match_the_cpu_on_hand_made_surfaces() {
    let Some(b) = crsh_wgpu::testing::shared_backend("rays_match_the_cpu_on_hand_made_surfaces")
    else {
        return;
    };
    // cornell-mirrors has a mirror and a glass material; use each material on a few records.
    let scene = Arc::new(crsh_scene::builtin::build("cornell-mirrors").unwrap());
    let light = scene.lights[0].position;
    let mut surfaces = Vec::new();
    let mut pixel = 0;
    for material in 0..scene.materials.len() as u32 {
        for (pos, normal, incident, front, throughput) in [
            // Facing the light.
            (
                light - Vec3::new(0.3, 1.0, 0.2),
                Vec3::Y,
                Vec3::new(0.0, -1.0, 0.1).normalize(),
                true,
                Vec3::ONE,
            ),
            // Light behind the surface (culled), and grazing incidence.
            (
                light - Vec3::new(0.0, 0.5, 0.0),
                -Vec3::Y,
                Vec3::new(1.0, -1e-4, 0.0).normalize(),
                true,
                Vec3::ONE,
            ),
            // Inside glass at a steep angle: total internal reflection.
            (
                Vec3::new(0.1, 0.2, 0.3),
                Vec3::X,
                Vec3::new(-0.2, 0.97, 0.0).normalize(),
                false,
                Vec3::ONE,
            ),
            // Throughput below the threshold.
            (Vec3::ZERO, Vec3::Z, -Vec3::Z, true, Vec3::splat(1e-5)),
            // The light on the surface point itself (no shadow ray).
            (light, Vec3::Y, -Vec3::Y, true, Vec3::ONE),
            // Far from the origin (ULP-sized offsets).
            (
                Vec3::new(3e4, -2e4, 1e3),
                Vec3::new(0.6, 0.8, 0.0),
                Vec3::new(-0.6, -0.8, 0.0),
                true,
                Vec3::ONE,
            ),
        ] {
            surfaces.push(Surface {
                position: pos,
                tri: 0,
                normal,
                material,
                incident,
                pixel,
                throughput,
                depth: 1,
                geo_normal: normal,
                flags: if front { Surface::FRONT_FACE } else { 0 },
            });
            pixel += 1;
        }
        surfaces.push(Surface::background(pixel, Vec3::Z, Vec3::ONE, 1));
        pixel += 1;
    }
    assert!(run_all(&b, &scene, &surfaces, "hand-made") > 10);
}

#[test]
fn bad_surfaces_are_errors() {
    let Some(b) = crsh_wgpu::testing::shared_backend("bad_surfaces_are_errors") else {
        return;
    };
    let scene = Arc::new(crsh_scene::builtin::build("cornell-mirrors").unwrap());
    let g = GpuScene::new(&b, &scene).unwrap();
    let gpu = Whitted::new(&g, &spec(&[])).unwrap();
    let mut surfaces = gbuffer(&scene, 8, 8);
    let i = surfaces.iter().position(|s| s.is_hit()).unwrap();
    surfaces[i].material = 999;
    let buf = b.upload(&surfaces).unwrap();
    let e = gpu
        .generate(&b, &buf, RayKind::Shadow, &mut Stats::default())
        .unwrap_err();
    assert!(
        e.to_string()
            .contains(&format!("pixel {}", surfaces[i].pixel)),
        "{e}"
    );
    assert!(gpu
        .generate(&b, &buf, RayKind::Primary, &mut Stats::default())
        .is_err());
    let empty = b.upload::<Surface>(&[]).unwrap();
    assert_eq!(
        gpu.generate(&b, &empty, RayKind::Shadow, &mut Stats::default())
            .unwrap()
            .len(),
        0
    );
}
