//! Seed 001's ray kinds on the device against their CPU twins:
//! - the `ao` and `diffuse` generators make the CPU's rays from the same surfaces (a built-in
//!   scene's G-buffer at depth 0, the path vertices one diffuse bounce deeper, and both in one
//!   batch), every offset policy, one and several samples: the same rays in the same order,
//!   origins and directions within a few 1e-7, everything else equal; with every origin-offset
//!   set (seed 001's hemispheres) the device's query gives the CPU's intervals and ended
//!   counts on the same rays, and the CPU generator's up to its directions' rounding
//!   ([`OFFSET_T_REL`]);
//! - the `ao` and `diffuse` shaders turn the same rays and hits into the CPU's image (AO bit
//!   for bit) and path vertices, and the ordered accumulation is its CPU twin;
//! - whole AO and diffuse frames agree between the backends, AO frames with `offsets = center`
//!   too (the device's hits exactly those of the CPU's brute force, the same rays ended);
//! - the pipeline check refuses `raygen=ao` with `shade=phong` on both backends; every
//!   `offsets` set is accepted on both.
//!
//! Without an adapter the device tests print `SKIP:` and pass, unless `CRSH_REQUIRE_GPU=1`.

use std::sync::Arc;

use crsh_core::glam::Vec3;
use crsh_core::metrics::{psnr_rgba8, to_rgba8};
use crsh_core::{
    Backend, CoreError, FrameOptions, FrameSize, Hit, HitMode, ParamValue, PipelineConfig,
    PrimaryVisibility, Query, Ray, RayGen, RayKind, Registry, Shader, StageContext, StageSpec,
    Stats, Surface,
};
use crsh_cpu::raygen::offsets::Offsets;
use crsh_cpu::Cpu;
use crsh_scene::Scene;
use crsh_wgpu::kernels::accumulate::{accumulate_cpu, AccumulateKernel, Contribution, ADD, ALPHA};
use crsh_wgpu::testing::{
    assert_boundary_cases, close_at, cpu_intersector, cpu_registry, rel_diff, shared_backend,
    TANGENT_ABS,
};
use crsh_wgpu::{GpuBuffer, GpuScene, HostIntersector, Wgpu};

const SCENES: [&str; 2] = ["cornell-mirrors", "office-boxes"];

/// A resolved pipeline `raygen` + `shade` on `intersect`, with `sets` applied.
fn config(raygen: &str, shade: &str, intersect: &str, sets: &[String]) -> PipelineConfig {
    let mut cfg = PipelineConfig::whitted(&format!("{raygen}+{shade}"), intersect);
    cfg.set(&format!("raygen.kind={raygen}")).unwrap();
    cfg.set(&format!("shade.kind={shade}")).unwrap();
    for s in sets {
        cfg.set(s).unwrap();
    }
    cpu_registry().resolve(&mut cfg).unwrap();
    cfg
}

fn builtin(name: &str) -> Arc<Scene> {
    Arc::new(crsh_scene::builtin::build(name).unwrap())
}

fn gbuffer(scene: &Arc<Scene>, w: u32, h: u32) -> Vec<Surface> {
    crsh_cpu::primary::raster::Raster::new(scene, &StageSpec::new("raster"))
        .unwrap()
        .gbuffer(&Cpu, w, h, &mut Stats::default())
        .unwrap()
}

/// The CPU's hits of `rays` (object BVH).
fn trace(scene: &Arc<Scene>, rays: &Vec<Ray>, mode: HitMode) -> Vec<Hit> {
    let bvh = cpu_intersector(&StageSpec::new("bvh"), scene);
    let mut hits = vec![Hit::MISS; rays.len()];
    bvh.intersect(
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

/// The path vertices one diffuse bounce below `surfaces` (CPU generator, tracer and shader):
/// depth 1, each carrying its path's sample index.
fn deeper(scene: &Arc<Scene>, surfaces: &Vec<Surface>, cfg: &PipelineConfig) -> Vec<Surface> {
    let gen = crsh_cpu::raygen::diffuse::Diffuse::new(scene, &cfg.raygen).unwrap();
    let rays = gen
        .generate(&Cpu, surfaces, RayKind::Diffuse, &mut Stats::default())
        .unwrap();
    let hits = trace(scene, &rays, HitMode::Closest);
    let shader = crsh_cpu::shade::diffuse::DiffuseShader::new(scene, &cfg.shade).unwrap();
    shader.next_surfaces(&rays, &hits).unwrap()
}

fn close(a: f32, b: f32, rel: f32) -> bool {
    a == b || (a - b).abs() <= rel * a.abs().max(b.abs()).max(1e-6)
}

/// Largest direction-component difference allowed: `rng.wgsl`'s directions are the CPU's up to
/// a few ULPs of `sqrt`, division and the sine / cosine polynomials (measured: 3e-7).
const DIR_TOL: f32 = 2e-6;

/// End to end (device generator against CPU generator) with origin offsets: the relative
/// difference allowed between intervals of rays whose origin or direction differ (by the
/// ULPs of `rng.wgsl`'s `sqrt` and sine / cosine polynomials, [`DIR_TOL`]); rays with equal
/// origin and direction must have equal intervals. The query amplifies a direction's rounding
/// near a chord's tangent (measured on lavapipe: up to 9.8e-5), and where a start or end lies on
/// a hemisphere's boundary (a Wächter start, 1.5e-5 above the floor, on the lifted base plane)
/// the rounding flips it in or out: the whole interval changes. Such rays ("flips", beyond
/// this tolerance) must stay under 1 in 200 per batch, plus one (lavapipe: 31 of 952,432 rays
/// over both built-in scenes, every set, AO and diffuse, changing 2 of 122,054 ended counts;
/// an NVIDIA H200, 2026-12-04, which fuses `a·b + c`: 2 of 1,164 in one batch); the query
/// itself is checked by the twin comparison ([`TWIN_T_REL`]).
const OFFSET_T_REL: f32 = 1e-4;

/// The difference allowed between the device's offsets and the CPU's applied to the very same
/// rays (the device generator's rays without offsets), relative to the larger of the interval
/// end and the ray's origin coordinates: the query's `sqrt` and divisions need not be correctly
/// rounded in WGSL and the compiler may fuse `a·b + c`, and the rounding of a point near the
/// origin is an absolute error on the scale of the origin, not of the short offset `t`
/// (measured on lavapipe: 0, bit for bit, and the same counts of rays ended; on an NVIDIA H200,
/// 2026-12-04: 6.6e-8 on a `t_min` of 0.033 from an origin at 0.97).
const TWIN_T_REL: f32 = 1e-6;

/// Relative tolerance of a shadow ray's interval end to end: its length goes through `sqrt`
/// and a division (lavapipe: equal; an NVIDIA H200, 2026-12-04: one ULP).
const SHADOW_T_REL: f32 = 1e-6;

/// The largest difference of origin and direction components seen, and of intervals
/// (relative); asserts the rest. `exact` (AO and diffuse rays): throughputs equal to the bit,
/// intervals within `t_rel` (0: equal); shadow rays (eq. 3.1-3.2 through `sqrt` and division)
/// get the Whitted tests' relative tolerance, or `t_rel` when larger.
fn check_rays(what: &str, got: &[Ray], want: &[Ray], exact: bool, t_rel: f32) -> (f32, f32) {
    assert_eq!(got.len(), want.len(), "{what}: ray count");
    let mut worst = 0.0f32;
    let mut worst_t = 0.0f32;
    for (i, (g, w)) in got.iter().zip(want).enumerate() {
        worst_t = worst_t.max(rel_diff(g.t_min, w.t_min).max(rel_diff(g.t_max, w.t_max)));
        assert_eq!(
            (g.kind, g.pixel, g.light, g.depth, g.source),
            (w.kind, w.pixel, w.light, w.depth, w.source),
            "{what}: ray {i} identity"
        );
        // Interval ends are computed from points on the scale of the origin.
        let scale = g.origin.abs().max_element();
        let ok = if exact {
            let d = (g.dir - w.dir).abs().max_element();
            worst = worst.max(d);
            (0..3).all(|k| close(g.origin[k], w.origin[k], 1e-6))
                && d <= DIR_TOL
                && g.throughput == w.throughput
                && close_at(g.t_min, w.t_min, t_rel, scale)
                && close_at(g.t_max, w.t_max, t_rel, scale)
        } else {
            let t_rel = t_rel.max(SHADOW_T_REL);
            (0..3).all(|k| {
                close(g.origin[k], w.origin[k], 1e-6)
                    && close(g.dir[k], w.dir[k], 1e-6)
                    && close(g.throughput[k], w.throughput[k], 1e-6)
            }) && close_at(g.t_min, w.t_min, t_rel, scale)
                && close_at(g.t_max, w.t_max, t_rel, scale)
        };
        assert!(ok, "{what}: ray {i}: gpu {g:?} cpu {w:?}");
    }
    (worst, worst_t)
}

/// What [`compare_generators`] saw: rays, the largest direction difference, the largest
/// relative interval difference, rays the offsets ended (equal on both backends).
#[derive(Default)]
struct Compared {
    rays: usize,
    dir: f32,
    t: f32,
    ended: u64,
    /// The largest relative interval difference between the device's offsets and the CPU's
    /// applied to the device's own rays.
    twin_t: f32,
    /// Rays whose interval is not the CPU's within the tolerance (a direction's rounding
    /// flipped a start or end across a hemisphere's boundary).
    flips: usize,
    /// |device − CPU| of the counts of rays ended.
    ended_differ: u64,
}

/// Generates every kind of `cfg.raygen` from `surfaces` with both generators and compares
/// the rays (intervals within `t_rel`) and the counts of rays the origin offsets ended.
fn compare_generators(
    b: &Wgpu,
    scene: &Arc<Scene>,
    g: &Arc<GpuScene>,
    cfg: &PipelineConfig,
    surfaces: &Vec<Surface>,
    what: &str,
    t_rel: f32,
) -> Compared {
    let (cpu, gpu): (Box<dyn RayGen<Cpu>>, Box<dyn RayGen<Wgpu>>) = match cfg.raygen.kind.as_str() {
        "ao" => (
            Box::new(crsh_cpu::raygen::ao::Ao::new(scene, &cfg.raygen).unwrap()),
            Box::new(crsh_wgpu::raygen::ao::Ao::new(g, &cfg.raygen).unwrap()),
        ),
        _ => (
            Box::new(crsh_cpu::raygen::diffuse::Diffuse::new(scene, &cfg.raygen).unwrap()),
            Box::new(crsh_wgpu::raygen::diffuse::Diffuse::new(g, &cfg.raygen).unwrap()),
        ),
    };
    assert_eq!(cpu.visibility_kind(), gpu.visibility_kind());
    assert_eq!(cpu.bounce_kinds(), gpu.bounce_kinds());
    // The device generator without offsets, whose rays the CPU's offsets then move: the
    // query's twin check on identical rays.
    let mut plain_spec = cfg.raygen.clone();
    plain_spec
        .params
        .insert("offsets".into(), ParamValue::Str("none".into()));
    let plain: Box<dyn RayGen<Wgpu>> = match cfg.raygen.kind.as_str() {
        "ao" => Box::new(crsh_wgpu::raygen::ao::Ao::new(g, &plain_spec).unwrap()),
        _ => Box::new(crsh_wgpu::raygen::diffuse::Diffuse::new(g, &plain_spec).unwrap()),
    };
    let offsets = Offsets::from_spec(scene, &cfg.raygen).unwrap();
    let from_light = cfg.raygen.str("shadow_origin").is_ok_and(|o| o == "light");
    let buf = b.upload(surfaces).unwrap();
    let mut kinds = vec![cpu.visibility_kind()];
    kinds.extend_from_slice(cpu.bounce_kinds());
    let mut c = Compared::default();
    for kind in kinds {
        let mut cpu_stats = Stats::default();
        let want = cpu.generate(&Cpu, surfaces, kind, &mut cpu_stats).unwrap();
        let mut stats = Stats::default();
        let out = gpu.generate(b, &buf, kind, &mut stats).unwrap();
        let got = b.download(&out).unwrap();
        let mut unmoved = b
            .download(
                &plain
                    .generate(b, &buf, kind, &mut Stats::default())
                    .unwrap(),
            )
            .unwrap();
        let mut twin_ended = 0;
        for r in &mut unmoved {
            let tri = surfaces[r.source as usize].tri;
            let kept = if kind == RayKind::Shadow && from_light {
                offsets.cut_end(tri, r)
            } else {
                offsets.apply(tri, r)
            };
            twin_ended += u64::from(!kept);
        }
        let here = format!("{what} {kind:?}");
        let ended = |s: &Stats| s.per_kind.get(kind.name()).map_or(0, |k| k.offset_ended);
        // The twin: the device's query and the CPU's on the same rays.
        assert_eq!(unmoved.len(), got.len(), "{here}: ray count");
        // Near a tangent or on a hemisphere's boundary the same query on the same ray may
        // round to another interval (`TANGENT_ABS`, `OFFSET_T_REL`): counted and bounded.
        let (mut tangents, mut twin_flips) = (0, 0);
        for (g, w) in got.iter().zip(&unmoved) {
            let scale = w.origin.abs().max_element();
            let within = |rel| {
                close_at(g.t_min, w.t_min, rel, scale) && close_at(g.t_max, w.t_max, rel, scale)
            };
            if within(TWIN_T_REL) {
                c.twin_t = c
                    .twin_t
                    .max(rel_diff(g.t_min, w.t_min).max(rel_diff(g.t_max, w.t_max)));
            } else if within(TANGENT_ABS) {
                tangents += 1;
            } else {
                twin_flips += 1;
            }
        }
        assert_boundary_cases(&format!("{here}, twin"), tangents, twin_flips, got.len());
        assert!(
            ended(&stats).abs_diff(twin_ended) <= twin_flips as u64,
            "{here}: rays ended: device {} twin {twin_ended} ({twin_flips} flips)",
            ended(&stats)
        );
        // End to end against the CPU generator: every field as without offsets; intervals
        // equal up to rounding where origin and direction are, else within `t_rel` or flipped (see
        // `OFFSET_T_REL`).
        let exact = kind != RayKind::Shadow;
        let loose = if t_rel > 0.0 { f32::INFINITY } else { 0.0 };
        let (dir, _) = check_rays(&here, &got, &want, exact, loose);
        let mut flips = 0;
        let mut tangents = 0;
        for (g, w) in got.iter().zip(&want) {
            let d = rel_diff(g.t_min, w.t_min).max(rel_diff(g.t_max, w.t_max));
            if (g.origin, g.dir) == (w.origin, w.dir) {
                // The same query on the same ray: equal up to its rounding (`TWIN_T_REL`;
                // `TANGENT_ABS` near a tangent; else a flip at a hemisphere's boundary).
                let scale = w.origin.abs().max_element();
                let within = |rel| {
                    close_at(g.t_min, w.t_min, rel, scale) && close_at(g.t_max, w.t_max, rel, scale)
                };
                if !within(TANGENT_ABS) {
                    flips += 1;
                } else if !within(TWIN_T_REL) {
                    tangents += 1;
                }
            } else if d <= t_rel.max(if exact { 0.0 } else { SHADOW_T_REL }) {
                c.t = c.t.max(d);
            } else {
                flips += 1;
            }
        }
        assert_boundary_cases(&here, tangents, flips, got.len());
        let (e_gpu, e_cpu) = (ended(&stats), ended(&cpu_stats));
        assert!(
            e_gpu.abs_diff(e_cpu) <= flips as u64,
            "{here}: rays ended by offsets: gpu {e_gpu} cpu {e_cpu} ({flips} flips)"
        );
        c.rays += got.len();
        c.dir = c.dir.max(dir);
        c.flips += flips;
        c.ended += e_cpu;
        c.ended_differ += e_gpu.abs_diff(e_cpu);
    }
    c
}

#[test]
fn ao_and_diffuse_rays_match_the_cpu() {
    let Some(b) = shared_backend("ao_and_diffuse_rays_match_the_cpu") else {
        return;
    };
    let mut worst = 0.0f32;
    for name in SCENES {
        let scene = builtin(name);
        let g = Arc::new(GpuScene::new(&b, &scene).unwrap());
        let primary = gbuffer(&scene, 40, 30);
        for samples in [1, 4] {
            let sets = |extra: &[String]| {
                let mut v = vec![format!("raygen.samples={samples}"), "raygen.seed=7".into()];
                v.extend_from_slice(extra);
                v
            };
            let base = config("diffuse", "diffuse", "bvh", &sets(&[]));
            let depth1 = deeper(&scene, &primary, &base);
            assert!(depth1.iter().any(|s| s.is_hit() && s.sample() > 0) == (samples > 1));
            let mut mixed = primary.clone();
            mixed.extend_from_slice(&depth1);
            for offset in ["normal", "scaled", "fixed", "wachter"] {
                for (raygen, extra) in [
                    ("ao", vec!["raygen.ao_length=0.05".to_string()]),
                    ("diffuse", vec!["raygen.shadow_origin=light".to_string()]),
                    ("diffuse", vec!["raygen.shadow_origin=surface".to_string()]),
                ] {
                    let mut extra = extra;
                    extra.push(format!("raygen.offset={offset}"));
                    let cfg = config(raygen, raygen, "bvh", &sets(&extra));
                    for (batch, surfaces) in [
                        ("depth 0", &primary),
                        ("depth 1", &depth1),
                        ("mixed", &mixed),
                    ] {
                        let what = format!("{name} {raygen} {extra:?} samples {samples} {batch}");
                        let c = compare_generators(&b, &scene, &g, &cfg, surfaces, &what, 0.0);
                        assert!(c.rays > 100, "{what}: only {} rays", c.rays);
                        assert_eq!(c.ended, 0, "{what}: offsets = none ended rays");
                        worst = worst.max(c.dir);
                    }
                }
            }
        }
    }
    println!("AO / diffuse ray directions: largest CPU-GPU component difference {worst:e}");
}

/// AO and diffuse rays (both shadow origins) with every hemisphere set and two offset
/// policies, at depth 0 and one diffuse bounce deeper: the CPU's query on the device's rays
/// gives the device's intervals and ended counts ([`TWIN_T_REL`]); against the CPU generator,
/// intervals within [`OFFSET_T_REL`] but for rare flips, and ended counts that differ by no
/// more than the flips.
#[test]
fn offset_rays_match_the_cpu() {
    let Some(b) = shared_backend("offset_rays_match_the_cpu") else {
        return;
    };
    let (mut worst_t, mut worst_dir) = (0.0f32, 0.0f32);
    for name in SCENES {
        let scene = builtin(name);
        let g = Arc::new(GpuScene::new(&b, &scene).unwrap());
        let primary = gbuffer(&scene, 40, 30);
        let sets = |extra: &[String]| {
            let mut v = vec!["raygen.samples=4".to_string(), "raygen.seed=3".into()];
            v.extend_from_slice(extra);
            v
        };
        let depth1 = deeper(
            &scene,
            &primary,
            &config("diffuse", "diffuse", "bvh", &sets(&[])),
        );
        let (mut rays, mut ended, mut twin, mut flips, mut ended_differ) = (0, 0, 0.0f32, 0, 0);
        for set in crsh_cpu::raygen::origin_offset::SET_NAMES {
            for offset in ["normal", "wachter"] {
                for (raygen, extra) in [
                    ("ao", "raygen.ao_length=0.05"),
                    ("diffuse", "raygen.shadow_origin=light"),
                    ("diffuse", "raygen.shadow_origin=surface"),
                ] {
                    let extra = vec![
                        extra.to_string(),
                        format!("raygen.offset={offset}"),
                        format!("raygen.offsets={set}"),
                    ];
                    let cfg = config(raygen, raygen, "bvh", &sets(&extra));
                    for (batch, surfaces) in [("depth 0", &primary), ("depth 1", &depth1)] {
                        let what = format!("{name} {raygen} {extra:?} {batch}");
                        let c =
                            compare_generators(&b, &scene, &g, &cfg, surfaces, &what, OFFSET_T_REL);
                        assert!(c.rays > 100, "{what}: only {} rays", c.rays);
                        rays += c.rays;
                        ended += c.ended;
                        twin = twin.max(c.twin_t);
                        flips += c.flips;
                        ended_differ += c.ended_differ;
                        worst_t = worst_t.max(c.t);
                        worst_dir = worst_dir.max(c.dir);
                    }
                }
            }
        }
        println!("{name}: {rays} rays, {ended} ended by offsets, {flips} intervals flipped, ended counts differ by {ended_differ}, twin query worst {twin:e}");
        assert!(ended > 0, "{name}: no ray ended by an offset");
    }
    println!(
        "AO / diffuse rays with offsets: largest relative t_min / t_max difference {worst_t:e}, \
         direction component {worst_dir:e}"
    );
}

#[test]
fn wrong_kinds_and_bad_surfaces_are_errors() {
    let Some(b) = shared_backend("wrong_kinds_and_bad_surfaces_are_errors") else {
        return;
    };
    let scene = builtin("cornell-mirrors");
    let g = Arc::new(GpuScene::new(&b, &scene).unwrap());
    let mut surfaces = gbuffer(&scene, 8, 8);
    let buf = b.upload(&surfaces).unwrap();
    let ao = crsh_wgpu::raygen::ao::Ao::new(&g, &config("ao", "ao", "bvh", &[]).raygen).unwrap();
    let diffuse_cfg = config("diffuse", "diffuse", "bvh", &[]);
    let diffuse = crsh_wgpu::raygen::diffuse::Diffuse::new(&g, &diffuse_cfg.raygen).unwrap();
    let whitted = crsh_wgpu::raygen::whitted::Whitted::new(
        &g,
        &config("whitted", "phong", "bvh", &[]).raygen,
    )
    .unwrap();
    let unsupported = |r: crsh_core::Result<GpuBuffer<Ray>>| {
        assert!(matches!(r, Err(CoreError::Unsupported { .. })));
    };
    let mut s = Stats::default();
    unsupported(ao.generate(&b, &buf, RayKind::Shadow, &mut s));
    unsupported(diffuse.generate(&b, &buf, RayKind::Reflection, &mut s));
    unsupported(diffuse.generate(&b, &buf, RayKind::Ao, &mut s));
    unsupported(whitted.generate(&b, &buf, RayKind::Ao, &mut s));
    unsupported(whitted.generate(&b, &buf, RayKind::Diffuse, &mut s));
    let empty = b.upload::<Surface>(&[]).unwrap();
    assert_eq!(
        ao.generate(&b, &empty, RayKind::Ao, &mut s).unwrap().len(),
        0
    );
    // A diffuse vertex whose material the scene lacks names its pixel, as on the CPU.
    let i = surfaces.iter().position(|s| s.is_hit()).unwrap();
    surfaces[i].material = 999;
    let e = diffuse
        .generate(&b, &b.upload(&surfaces).unwrap(), RayKind::Diffuse, &mut s)
        .unwrap_err();
    assert!(
        e.to_string()
            .contains(&format!("pixel {}", surfaces[i].pixel)),
        "{e}"
    );
    // AO rays need no material.
    assert!(ao
        .generate(&b, &b.upload(&surfaces).unwrap(), RayKind::Ao, &mut s)
        .is_ok());
}

/// The AO shader on the CPU's rays and hits: the CPU's image bit for bit, on an image that
/// already holds light, with background records and several records per pixel.
#[test]
fn ao_shader_matches_the_cpu_bit_for_bit() {
    let Some(b) = shared_backend("ao_shader_matches_the_cpu_bit_for_bit") else {
        return;
    };
    for name in SCENES {
        let scene = builtin(name);
        let g = Arc::new(GpuScene::new(&b, &scene).unwrap());
        let (w, h) = (32, 24);
        let cfg = config(
            "ao",
            "ao",
            "bvh",
            &[
                "raygen.samples=5".into(),
                "raygen.ao_length=0.2".into(),
                "shade.background=0.3".into(),
            ],
        );
        let mut surfaces = gbuffer(&scene, w, h);
        // Background records, and a second record for some pixels (several runs per pixel).
        for p in (0..w * h).step_by(7) {
            let t = Vec3::new(0.5, 0.25, 1.0 / 3.0);
            surfaces.push(Surface::background(p, -Vec3::Z, t, 0));
        }
        let copies: Vec<Surface> = surfaces.iter().step_by(3).copied().collect();
        surfaces.extend(copies);
        let gen = crsh_cpu::raygen::ao::Ao::new(&scene, &cfg.raygen).unwrap();
        let rays = gen
            .generate(&Cpu, &surfaces, RayKind::Ao, &mut Stats::default())
            .unwrap();
        let hits = trace(&scene, &rays, HitMode::Any);
        assert!(hits.iter().any(|h| h.is_hit()) && hits.iter().any(|h| !h.is_hit()));
        let start: Vec<[f32; 4]> = (0..w * h)
            .map(|i| {
                [
                    i as f32 * 0.001,
                    0.1,
                    0.0,
                    if i % 2 == 0 { 0.0 } else { 0.5 },
                ]
            })
            .collect();
        let mut want = start.clone();
        crsh_cpu::shade::ao::AoShader::new(&scene, &cfg.shade)
            .unwrap()
            .shade(&surfaces, &rays, &hits, &mut want)
            .unwrap();
        let shader = crsh_wgpu::shade::ao::AoShader::new(&g, &cfg.shade).unwrap();
        assert!(shader.shades(RayKind::Ao) && !shader.shades(RayKind::Shadow));
        let mut image = b.upload(&start).unwrap();
        shader
            .shade_direct(
                &b,
                &b.upload(&surfaces).unwrap(),
                &b.upload(&rays).unwrap(),
                &b.upload(&hits).unwrap(),
                crsh_core::HitMode::Any,
                &mut image,
                &mut Stats::default(),
            )
            .unwrap();
        let got = b.download(&image).unwrap();
        let bits = |im: &[[f32; 4]]| im.iter().flatten().map(|v| v.to_bits()).collect::<Vec<_>>();
        assert!(bits(&got) == bits(&want), "{name}: AO images differ");
        // Bad input is refused as on the CPU.
        let mut bad = rays.clone();
        bad[2].kind = RayKind::Shadow as u32;
        let e = shader
            .shade_direct(
                &b,
                &b.upload(&surfaces).unwrap(),
                &b.upload(&bad).unwrap(),
                &b.upload(&hits).unwrap(),
                crsh_core::HitMode::Any,
                &mut image,
                &mut Stats::default(),
            )
            .unwrap_err();
        assert!(e.to_string().contains("ray 2"), "{e}");
    }
}

/// The diffuse shader on the CPU's records, shadow rays and hits: the CPU's direct light
/// (Lambertian, emission, background) and the CPU's next path vertices (sample indices kept).
#[test]
fn diffuse_shader_matches_the_cpu() {
    let Some(b) = shared_backend("diffuse_shader_matches_the_cpu") else {
        return;
    };
    for name in SCENES {
        let scene = builtin(name);
        let g = Arc::new(GpuScene::new(&b, &scene).unwrap());
        let (w, h) = (32, 24);
        let cfg = config(
            "diffuse",
            "diffuse",
            "bvh",
            &["raygen.samples=3".into(), "shade.background=0.2".into()],
        );
        let primary = gbuffer(&scene, w, h);
        let gen = crsh_cpu::raygen::diffuse::Diffuse::new(&scene, &cfg.raygen).unwrap();
        let rays = gen
            .generate(&Cpu, &primary, RayKind::Diffuse, &mut Stats::default())
            .unwrap();
        let hits = trace(&scene, &rays, HitMode::Closest);
        let cpu = crsh_cpu::shade::diffuse::DiffuseShader::new(&scene, &cfg.shade).unwrap();
        let next = cpu.next_surfaces(&rays, &hits).unwrap();
        let gpu = crsh_wgpu::shade::diffuse::DiffuseShader::new(&g, &cfg.shade).unwrap();
        let resolved = gpu
            .resolve(
                &b,
                &b.upload(&rays).unwrap(),
                &b.upload(&hits).unwrap(),
                &mut Stats::default(),
            )
            .unwrap();
        let resolved = b.download(&resolved).unwrap();
        assert_eq!(resolved.len(), next.len());
        for (i, (g, c)) in resolved.iter().zip(&next).enumerate() {
            assert_eq!(
                (g.tri, g.material, g.flags, g.pixel, g.depth, g.throughput),
                (c.tri, c.material, c.flags, c.pixel, c.depth, c.throughput),
                "{name}: vertex {i}"
            );
            assert!(
                (g.position - c.position).abs().max_element() <= 1e-5
                    && (g.normal - c.normal).abs().max_element() <= 1e-5,
                "{name}: vertex {i}: gpu {g:?} cpu {c:?}"
            );
        }
        assert!(next.iter().any(|s| s.sample() == 2));
        // Direct light at the primaries and the vertices together (pixels repeat).
        let mut surfaces = primary.clone();
        surfaces.extend_from_slice(&next);
        let shadow = gen
            .generate(&Cpu, &surfaces, RayKind::Shadow, &mut Stats::default())
            .unwrap();
        let shadow_hits = trace(&scene, &shadow, HitMode::Any);
        let mut want = vec![[0.0f32; 4]; (w * h) as usize];
        cpu.shade_direct(
            &Cpu,
            &surfaces,
            &shadow,
            &shadow_hits,
            crsh_core::HitMode::Any,
            &mut want,
            &mut Stats::default(),
        )
        .unwrap();
        let mut image = b.filled((w * h) as usize, [0.0f32; 4]).unwrap();
        gpu.shade_direct(
            &b,
            &b.upload(&surfaces).unwrap(),
            &b.upload(&shadow).unwrap(),
            &b.upload(&shadow_hits).unwrap(),
            crsh_core::HitMode::Any,
            &mut image,
            &mut Stats::default(),
        )
        .unwrap();
        let got = b.download(&image).unwrap();
        for (i, (g, c)) in got.iter().zip(&want).enumerate() {
            for k in 0..4 {
                assert!(
                    (g[k] - c[k]).abs() <= 1e-5 * c[k].abs().max(1e-3),
                    "{name}: pixel {i}: gpu {g:?} cpu {c:?}"
                );
            }
        }
        assert!(want.iter().any(|p| p[0] > 0.0));
    }
}

/// The ordered accumulation against its CPU twin: runs of one pixel, scattered records,
/// records that only set alpha or add nothing, and records outside the image.
#[test]
fn ordered_accumulation_is_its_cpu_twin() {
    let Some(b) = shared_backend("ordered_accumulation_is_its_cpu_twin") else {
        return;
    };
    let ctx = b.context();
    let pixels = 300usize;
    let mut records = Vec::new();
    for i in 0..5000u32 {
        let w = crsh_core::rng::pcg4d([i, 1, 2, 3]);
        // Runs: a pixel repeats for a while, then jumps.
        let pixel = if w[0].is_multiple_of(4) {
            records
                .last()
                .map_or(0, |c: &Contribution| c.pixel % pixels as u32)
        } else {
            w[1] % (pixels as u32 + 3)
        };
        let v = crsh_core::rng::unit(w[2]) * 1e3 * (1.0 + (i % 13) as f32);
        records.push(Contribution {
            rgb: [v, v * 1e-4, 1.0 / (1.0 + v)],
            pixel,
            flags: [ADD, ALPHA, ADD | ALPHA, 0][(w[3] % 4) as usize],
            pad: [0; 3],
        });
    }
    let start: Vec<[f32; 4]> = (0..pixels)
        .map(|i| [0.1 * i as f32, 0.0, 1.0, 0.0])
        .collect();
    let mut want = start.clone();
    accumulate_cpu(&records, &mut want);
    let k = ctx.kernel(AccumulateKernel::new).unwrap();
    let contrib = b.upload(&records).unwrap();
    let heads = b.filled(pixels, 0u32).unwrap();
    let report = b.filled(4, 0u32).unwrap();
    let image = b.upload(&start).unwrap();
    let acc = k.bind(ctx, &contrib, &heads, &image, &report, 3);
    let run = |f: &dyn Fn(&mut wgpu::ComputePass<'_>)| {
        let mut enc = ctx
            .device()
            .create_command_encoder(&wgpu::CommandEncoderDescriptor::default());
        {
            let mut pass = ctx.compute_pass(&mut enc, "test accumulate");
            f(&mut pass);
        }
        ctx.queue().submit([enc.finish()]);
    };
    run(&|pass| k.count_heads(ctx, pass, &acc).unwrap());
    let rounds = b.download(&report).unwrap()[3];
    assert!(rounds > 5, "{rounds} rounds");
    run(&|pass| k.apply(ctx, pass, &acc, rounds).unwrap());
    let got = b.download(&image).unwrap();
    let bits = |im: &[[f32; 4]]| im.iter().flatten().map(|v| v.to_bits()).collect::<Vec<_>>();
    assert!(
        bits(&got) == bits(&want),
        "accumulation differs from the CPU's"
    );
}

const W: u32 = 48;
const H: u32 = 36;

/// One frame of `cfg` on the CPU.
fn cpu_frame(scene: &Arc<Scene>, cfg: &PipelineConfig, depth: u32) -> (Vec<[f32; 4]>, Stats) {
    let frame = FrameSize::new(W, H).unwrap();
    let f = cpu_registry()
        .render(
            &StageContext::new(&Cpu, scene, frame),
            cfg,
            &FrameOptions::new().with_max_depth(depth),
            None,
            &mut |_| {},
        )
        .unwrap_or_else(|e| panic!("{} on the CPU: {e}", cfg.name));
    (f.image, f.stats)
}

/// The CPU rasterizer's G-buffer, uploaded: a primary stage that lets a device frame start
/// from exactly the CPU frame's surfaces.
struct HostRaster(Arc<Scene>);

impl PrimaryVisibility<Wgpu> for HostRaster {
    fn name(&self) -> &str {
        "raster"
    }

    fn gbuffer(
        &self,
        backend: &Wgpu,
        width: u32,
        height: u32,
        _stats: &mut Stats,
    ) -> crsh_core::Result<GpuBuffer<Surface>> {
        backend.upload(&gbuffer(&self.0, width, height))
    }
}

/// Where a device frame's G-buffer comes from.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Primary {
    /// The wgpu rasterizer.
    Device,
    /// The CPU rasterizer's, uploaded ([`HostRaster`]).
    Host,
}

/// One frame of `cfg` on the device, every batch traced again by the CPU's brute force.
fn gpu_frame(
    b: &Wgpu,
    scene: &Arc<Scene>,
    cfg: &PipelineConfig,
    depth: u32,
    primary: Primary,
) -> (Vec<[f32; 4]>, Stats) {
    let g = Arc::new(GpuScene::new(b, scene).unwrap());
    let frame = FrameSize::new(W, H).unwrap();
    let mut pipeline = Registry::<Wgpu>::builtin()
        .build(&StageContext::new(b, &g, frame), cfg)
        .unwrap_or_else(|e| panic!("{} on wgpu: {e}", cfg.name));
    if primary == Primary::Host {
        pipeline.stages.primary = Box::new(HostRaster(Arc::clone(scene)));
    }
    let reference = HostIntersector::new(cpu_intersector(&StageSpec::new("brute"), scene));
    let f = pipeline
        .render(
            b,
            &FrameOptions::new().with_max_depth(depth),
            Some(&reference),
            &mut |_| {},
        )
        .unwrap_or_else(|e| panic!("{} on wgpu: {e}", cfg.name));
    (b.download(&f.image).unwrap(), f.stats)
}

/// Renders `cfg` on both backends and checks that they agree: the device's hits are the
/// CPU's on its own rays, the ray counts match, and the images differ in few pixels (grazing
/// rays whose direction rounding flips a hit, and with the device's rasterizer its depth
/// ties) by a PSNR of at least `min_psnr`. Returns (PSNR, fraction of differing pixels).
fn frames_agree(
    b: &Wgpu,
    scene: &Arc<Scene>,
    cfg: &PipelineConfig,
    depth: u32,
    primary: Primary,
    min_psnr: f64,
) -> (f64, f64) {
    frames_agree_with(b, scene, cfg, depth, primary, min_psnr, 0.9999).0
}

/// [`frames_agree`] with the device's hits agreeing with the CPU's brute force on at least
/// `min_agreement` of its rays; also returns both frames' statistics (CPU, device).
fn frames_agree_with(
    b: &Wgpu,
    scene: &Arc<Scene>,
    cfg: &PipelineConfig,
    depth: u32,
    primary: Primary,
    min_psnr: f64,
    min_agreement: f64,
) -> ((f64, f64), (Stats, Stats)) {
    let (cpu_image, cpu) = cpu_frame(scene, cfg, depth);
    let (gpu_image, gpu) = gpu_frame(b, scene, cfg, depth, primary);
    let what = format!("{} {} ({primary:?} G-buffer)", scene.name, cfg.name);
    let acc = gpu.accuracy.clone().expect("reference given");
    assert!(
        acc.rays > 0 && acc.hit_agreement() >= min_agreement,
        "{what}: device hits vs the CPU's brute force: {acc:?}"
    );
    for kind in RayKind::ALL {
        let (g, c) = (gpu.rays.get(kind) as f64, cpu.rays.get(kind) as f64);
        assert!(
            (g - c).abs() <= 0.01 * c.max(1.0) + 2.0,
            "{what}: {kind:?} rays gpu {g} cpu {c}"
        );
    }
    assert_eq!(gpu.stages, cpu.stages, "{what}: stages");
    let differ = gpu_image
        .iter()
        .zip(&cpu_image)
        .filter(|(g, c)| (0..4).any(|k| (g[k] - c[k]).abs() > 1e-4 * c[k].abs().max(1e-2)))
        .count() as f64
        / cpu_image.len() as f64;
    let psnr = psnr_rgba8(&to_rgba8(&gpu_image), &to_rgba8(&cpu_image));
    let largest = gpu_image
        .iter()
        .zip(&cpu_image)
        .flat_map(|(g, c)| (0..4).map(move |k| (g[k] - c[k]).abs()))
        .fold(0.0f32, f32::max);
    println!(
        "{what}: PSNR {psnr:.1} dB, {:.2} % of pixels differ, largest difference {largest:e}",
        differ * 100.0
    );
    assert!(
        psnr >= min_psnr && differ <= 0.03,
        "{what}: PSNR {psnr:.2} dB, {:.2} % of pixels differ",
        differ * 100.0
    );
    assert!(cpu_image.iter().any(|p| p[0] > 0.0), "{what}: black image");
    ((psnr, differ), (cpu, gpu))
}

/// The G-buffers the frame tests start from, on every scene: the CPU's (so the frames differ
/// only by the stages under test) and the wgpu rasterizer's own.
const PRIMARIES: [Primary; 2] = [Primary::Host, Primary::Device];

/// AO frames agree between the backends, without offsets and with `offsets = center` (default
/// offset policy); with offsets the device's hits are exactly the CPU brute force's on its own
/// rays (agreement 1.0) and the rays the offsets ended are the CPU frame's.
#[test]
fn ao_frames_agree_between_the_backends() {
    let Some(b) = shared_backend("ao_frames_agree_between_the_backends") else {
        return;
    };
    for name in SCENES {
        for offsets in ["none", "center"] {
            let sets = [
                "raygen.samples=4".to_string(),
                "raygen.ao_length=0.1".into(),
                format!("raygen.offsets={offsets}"),
                "shade.background=0.5".into(),
            ];
            let agreement = if offsets == "none" { 0.9999 } else { 1.0 };
            for intersect in ["bvh", "brute"] {
                let cfg = config("ao", "ao", intersect, &sets);
                for primary in PRIMARIES {
                    let (_, (cpu, gpu)) =
                        frames_agree_with(&b, &builtin(name), &cfg, 1, primary, 35.0, agreement);
                    let ended = |s: &Stats| s.per_kind.get("ao").map_or(0, |k| k.offset_ended);
                    let what = format!("{name} offsets={offsets} {intersect} {primary:?}");
                    println!("{what}: {} AO rays ended by offsets", ended(&cpu));
                    assert_eq!(ended(&gpu), ended(&cpu), "{what}: AO rays ended");
                    assert_eq!(ended(&cpu) > 0, offsets != "none", "{what}: AO rays ended");
                }
            }
        }
    }
}

#[test]
fn diffuse_frames_agree_between_the_backends() {
    let Some(b) = shared_backend("diffuse_frames_agree_between_the_backends") else {
        return;
    };
    for name in SCENES {
        let cfg = config(
            "diffuse",
            "diffuse",
            "bvh",
            &["raygen.samples=2".into(), "shade.background=0.1".into()],
        );
        for primary in PRIMARIES {
            frames_agree(&b, &builtin(name), &cfg, 2, primary, 35.0);
        }
    }
}

/// `raygen=ao` with `shade=phong` is refused on both backends (phong does not shade AO rays),
/// and so is `diffuse` with `ao` (ao shades AO rays only); every `offsets` set builds on the
/// device, an unknown one is refused as on the CPU.
#[test]
fn mismatched_stages_are_refused_and_offsets_accepted() {
    let scene = builtin("cornell-mirrors");
    let frame = FrameSize::new(8, 8).unwrap();
    let cpu_ctx = StageContext::new(&Cpu, &scene, frame);
    let pairs = [("ao", "phong"), ("diffuse", "ao"), ("whitted", "ao")];
    for (raygen, shade) in pairs {
        let cfg = config(raygen, shade, "bvh", &[]);
        let e = cpu_registry().build(&cpu_ctx, &cfg).err().unwrap();
        assert!(
            matches!(&e, CoreError::Incompatible { slots, .. } if slots == "raygen, shade"),
            "cpu {raygen}+{shade}: {e}"
        );
    }
    let Some(b) = shared_backend("mismatched_stages_are_refused_and_offsets_accepted") else {
        return;
    };
    let g = Arc::new(GpuScene::new(&b, &scene).unwrap());
    let gpu_ctx = StageContext::new(&b, &g, frame);
    let gpu = Registry::<Wgpu>::builtin();
    for (raygen, shade) in pairs {
        let cfg = config(raygen, shade, "bvh", &[]);
        let e = gpu.build(&gpu_ctx, &cfg).err().unwrap();
        assert!(
            matches!(&e, CoreError::Incompatible { slots, .. } if slots == "raygen, shade"),
            "wgpu {raygen}+{shade}: {e}"
        );
    }
    for (raygen, shade) in [("whitted", "phong"), ("ao", "ao"), ("diffuse", "diffuse")] {
        assert!(gpu
            .build(&gpu_ctx, &config(raygen, shade, "bvh", &[]))
            .is_ok());
        for offsets in crsh_cpu::raygen::origin_offset::SET_NAMES {
            let cfg = config(raygen, shade, "bvh", &[format!("raygen.offsets={offsets}")]);
            if let Err(e) = gpu.build(&gpu_ctx, &cfg) {
                panic!("wgpu {raygen} offsets={offsets}: {e}");
            }
        }
        let mut cfg = config(raygen, shade, "bvh", &[]);
        cfg.raygen.params.insert(
            "offsets".into(),
            crsh_core::ParamValue::Str("nearest".into()),
        );
        assert!(
            gpu.build(&gpu_ctx, &cfg).is_err(),
            "wgpu {raygen} offsets=nearest"
        );
    }
}
