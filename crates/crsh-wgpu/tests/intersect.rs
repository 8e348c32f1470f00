//! The GPU intersectors against their CPU twins on the same rays: whole-scene queries (closest
//! and any hit, merging into existing hits), candidate queries on a hierarchy and candidates
//! built by the CPU stages, counters, and bad input.
//!
//! Without an adapter every test prints `SKIP:` and passes, unless `CRSH_REQUIRE_GPU=1`.

use std::sync::Arc;

use crsh_core::glam::{DVec3, Vec3};
use crsh_core::{
    Backend, CandidateBatch, FrameSize, HierarchyBuilder, Hit, HitMode, Intersector, Query, Ray,
    RayHierarchy, RayKind, Registry, StageContext, StageSpec, Stats, Traverser,
};
use crsh_cpu::Cpu;
use crsh_scene::Scene;
use crsh_wgpu::intersect::brute::BruteForce;
use crsh_wgpu::{GpuScene, Wgpu};

struct Lcg(u64);

impl Lcg {
    fn unit(&mut self) -> f32 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((self.0 >> 40) as f32 / (1u64 << 24) as f32) * 2.0 - 1.0
    }
}

/// Rays from points inside the scene's box in random directions; a third are finite segments
/// and some start from triangle vertices (exact edge and vertex cases).
fn rays(scene: &Scene, seed: u64, n: usize, kind: RayKind) -> Vec<Ray> {
    let mut g = Lcg(seed);
    let (lo, hi) = (scene.bounds.min, scene.bounds.max);
    (0..n)
        .map(|i| {
            let origin = if i % 7 == 0 {
                scene.triangle(i % scene.triangle_count())[i % 3]
            } else {
                lo + (hi - lo)
                    * Vec3::new(
                        g.unit() * 0.5 + 0.5,
                        g.unit() * 0.5 + 0.5,
                        g.unit() * 0.5 + 0.5,
                    )
            };
            let dir = Vec3::new(g.unit(), g.unit(), g.unit());
            let dir = if dir.length_squared() < 1e-6 {
                Vec3::X
            } else {
                dir
            };
            Ray {
                origin,
                t_min: if i % 7 == 0 { 1e-4 } else { 0.0 },
                dir,
                t_max: if i % 3 == 0 {
                    (hi - lo).length() * 0.3
                } else {
                    f32::INFINITY
                },
                throughput: Vec3::ONE,
                kind: kind as u32,
                pixel: i as u32,
                light: 0,
                depth: 1,
                source: i as u32,
            }
        })
        .collect()
}

fn scene(name: &str) -> Arc<Scene> {
    Arc::new(crsh_scene::builtin::build(name).unwrap())
}

/// Whether a GPU/CPU disagreement on `ray` is float rounding at an edge, a tie or a grazing
/// ray ([`crsh_wgpu::testing::rounding_explains`]).
fn explained(scene: &Scene, ray: &Ray, a: &Hit, b: &Hit) -> bool {
    crsh_wgpu::testing::rounding_explains(scene, ray, a, b)
}

fn compare(scene: &Scene, rays: &[Ray], got: &[Hit], want: &[Hit], mode: HitMode) -> usize {
    let mut mismatches = 0;
    for (i, (g, w)) in got.iter().zip(want).enumerate() {
        let same = match mode {
            HitMode::Any | HitMode::EdgeWidth(_) => g.is_hit() == w.is_hit(),
            HitMode::Closest => {
                g.tri == w.tri && (!w.is_hit() || (g.t - w.t).abs() <= 1e-5 * w.t.abs())
            }
        };
        if !same {
            mismatches += 1;
            assert!(
                explained(scene, &rays[i], g, w),
                "ray {i} {:?}: gpu {g:?} cpu {w:?} is not an edge case",
                rays[i]
            );
        }
    }
    mismatches
}

fn brute_spec(test: &str) -> StageSpec {
    let mut s = StageSpec::new("brute");
    s.params
        .insert("test".into(), crsh_core::ParamValue::Str(test.into()));
    s
}

fn gpu_scene(b: &Wgpu, s: &Arc<Scene>) -> Arc<GpuScene> {
    GpuScene::new(b, s).unwrap()
}

/// Hits to merge into: a mix of misses and an existing hit (triangle 3 at `t = 0.05`) on every
/// fifth ray, as candidate batches leave them.
fn start_hits(n: usize) -> Vec<Hit> {
    (0..n)
        .map(|i| {
            if i % 5 == 0 {
                Hit {
                    t: 0.05,
                    tri: 3,
                    u: 0.1,
                    v: 0.1,
                }
            } else {
                Hit::MISS
            }
        })
        .collect()
}

/// A whole-scene query of `rays` in `mode`, merging into `start`, on the GPU intersector and
/// its CPU twin: `(gpu hits, cpu hits, gpu stats, cpu stats)`.
fn scene_query(
    b: &Wgpu,
    gpu: &dyn Intersector<Wgpu>,
    cpu: &dyn Intersector<Cpu>,
    rays: &Vec<Ray>,
    start: &[Hit],
    mode: HitMode,
) -> (Vec<Hit>, Vec<Hit>, Stats, Stats) {
    let mut want = start.to_vec();
    let mut cpu_stats = Stats::default();
    cpu.intersect(&Cpu, rays, Query::Scene, mode, &mut want, &mut cpu_stats)
        .unwrap();
    let buf = b.upload(rays).unwrap();
    let mut hits = b.upload(start).unwrap();
    let mut stats = Stats::default();
    gpu.intersect(b, &buf, Query::Scene, mode, &mut hits, &mut stats)
        .unwrap();
    (b.download(&hits).unwrap(), want, stats, cpu_stats)
}

#[test]
fn brute_scene_queries_match_the_cpu() {
    let Some(b) = crsh_wgpu::testing::shared_backend("brute_scene_queries_match_the_cpu") else {
        return;
    };
    for name in ["cornell-mirrors", "office-boxes"] {
        let s = scene(name);
        let g = gpu_scene(&b, &s);
        let spec = brute_spec("mt");
        let gpu = BruteForce::new(&g, &spec).unwrap();
        let cpu = crsh_wgpu::testing::cpu_intersector(&StageSpec::new("brute"), &s);
        let rays = rays(&s, 5, 700, RayKind::Reflection);
        // Start from a mix of misses and existing hits (merging), as candidate batches do.
        let start = start_hits(rays.len());
        for mode in [HitMode::Closest, HitMode::Any] {
            let (got, want, stats, cpu_stats) = scene_query(&b, &gpu, &*cpu, &rays, &start, mode);
            let bad = compare(&s, &rays, &got, &want, mode);
            assert!(
                bad * 10_000 <= rays.len(),
                "{name} {mode:?}: {bad} mismatches"
            );
            assert!(want.iter().filter(|h| h.is_hit()).count() > rays.len() / 4);
            if bad == 0 {
                assert_eq!(stats.tests, cpu_stats.tests, "{name} {mode:?}: counters");
            }
            // Rays whose stored hit is closer than anything keep it.
            for i in (0..rays.len()).step_by(5) {
                if mode == HitMode::Closest && want[i].tri == 3 && want[i].t == 0.05 {
                    assert_eq!(got[i], want[i]);
                }
            }
        }
    }
}

/// Candidate queries on the CPU's own hierarchy and candidates, uploaded: the same hits and
/// level-0 counts as the CPU's candidate mode, batch after batch, without lane masks and with
/// random ones (all rays, none, random lanes; reversed batches with repeats whose masks merge).
#[test]
fn brute_candidate_queries_match_the_cpu() {
    let Some(b) = crsh_wgpu::testing::shared_backend("brute_candidate_queries_match_the_cpu")
    else {
        return;
    };
    for name in ["cornell-mirrors", "office-boxes"] {
        let s = scene(name);
        let g = gpu_scene(&b, &s);
        for (kind, mode) in [
            (RayKind::Reflection, HitMode::Closest),
            (RayKind::Shadow, HitMode::Any),
        ] {
            let rays = rays(&s, 9, 600, kind);
            let builder =
                crsh_cpu::hierarchy::sphere_cone::SphereConeBuilder::with_params(4, 2).unwrap();
            let order: Vec<u32> = (0..rays.len() as u32).collect();
            let mut st = Stats::default();
            let h_cpu = builder.build(&Cpu, &rays, order, &mut st).unwrap();
            // A small budget so that the traversal sends several batches.
            let trav = crsh_cpu::traverse::crsh::Crsh::with_options(&s, true, 0.01).unwrap();
            let mut batches: Vec<Vec<crsh_core::Candidate>> = Vec::new();
            trav.traverse(
                &Cpu,
                &rays,
                kind,
                &h_cpu,
                &mut |batch, _| {
                    batches.push(batch.pairs);
                    Ok(())
                },
                &mut st,
            )
            .unwrap();
            assert!(batches.len() > 1, "{name}: one batch only");
            let cpu = crsh_wgpu::testing::cpu_intersector(&StageSpec::new("brute"), &s);
            let gpu = BruteForce::new(&g, &brute_spec("mt")).unwrap();
            let h_gpu: RayHierarchy<Wgpu> = RayHierarchy {
                leaf_offsets: None,
                order: b.upload(&h_cpu.order).unwrap(),
                levels: h_cpu.levels.iter().map(|l| b.upload(l).unwrap()).collect(),
                subdivision: h_cpu.subdivision,
                reach: h_cpu.reach.iter().map(|l| b.upload(l).unwrap()).collect(),
            };
            for masked in [false, true] {
                let what = format!("{name} {kind:?} masks {masked}");
                let mut want = vec![Hit::MISS; rays.len()];
                let mut cpu_stats = Stats::default();
                let buf = b.upload(&rays).unwrap();
                let mut hits = b.filled(rays.len(), Hit::MISS).unwrap();
                let mut stats = Stats::default();
                for (i, pairs) in batches.iter().enumerate() {
                    // Masks: all lanes, none, or hashed bits of the node's 4 lanes.
                    let masks: Vec<u32> = (0..pairs.len())
                        .map(|k| match (k * 7 + i) % 4 {
                            0 => crsh_core::ALL_LANES,
                            1 => 0,
                            _ => ((k as u32).wrapping_mul(2_654_435_761) >> 7) & 0xf,
                        })
                        .collect();
                    let cb = if masked {
                        CandidateBatch::with_lanes(pairs.clone(), masks.clone())
                    } else {
                        CandidateBatch::new(pairs.clone())
                    };
                    cpu.intersect(
                        &Cpu,
                        &rays,
                        Query::Candidates {
                            hierarchy: &h_cpu,
                            batch: &cb,
                        },
                        mode,
                        &mut want,
                        &mut cpu_stats,
                    )
                    .unwrap();
                    // Every other batch reversed: the GPU intersector must sort it first; with
                    // masks, its pairs also come twice, split over two masks whose union is the
                    // CPU's.
                    let mut p = pairs.clone();
                    let mut m = masks.clone();
                    if i % 2 == 1 {
                        p.reverse();
                        m.reverse();
                        if masked {
                            let n = p.len();
                            for k in 0..n {
                                p.push(p[k]);
                                m.push(m[k] & 0b1010);
                                m[k] &= !0b1010;
                            }
                        }
                    }
                    let gb = if masked {
                        CandidateBatch::with_lanes(b.upload(&p).unwrap(), b.upload(&m).unwrap())
                    } else {
                        CandidateBatch::new(b.upload(&p).unwrap())
                    };
                    gpu.intersect(
                        &b,
                        &buf,
                        Query::Candidates {
                            hierarchy: &h_gpu,
                            batch: &gb,
                        },
                        mode,
                        &mut hits,
                        &mut stats,
                    )
                    .unwrap();
                }
                let got = b.download(&hits).unwrap();
                let bad = compare(&s, &rays, &got, &want, mode);
                assert!(bad * 10_000 <= rays.len(), "{what}: {bad} mismatches");
                assert!(got.iter().any(|h| h.is_hit()), "{what}: no hits");
                if bad == 0 {
                    assert_eq!(stats.tests, cpu_stats.tests, "{what}");
                    assert_eq!(stats.levels, cpu_stats.levels, "{what}");
                }
            }
        }
    }
}

/// The wgpu `bvh` against the CPU `bvh` (both with the registry's defaults: the same host
/// tree) on the built-in scenes, merging into a mix of misses and existing hits: the same hits
/// up to edge rounding and, where every hit agrees, the same counters, node and leaf visits
/// included (the CPU module doc's "Counting").
#[test]
fn bvh_scene_queries_match_the_cpu() {
    let Some(b) = crsh_wgpu::testing::shared_backend("bvh_scene_queries_match_the_cpu") else {
        return;
    };
    let gpu_registry = Registry::<Wgpu>::builtin();
    let mut counters_compared = 0;
    for name in crsh_scene::builtin::STATIC_NAMES {
        let s = scene(name);
        let g = gpu_scene(&b, &s);
        let frame = FrameSize::new(1, 1).unwrap();
        let gpu = gpu_registry
            .build_intersector(&StageContext::new(&b, &g, frame), &StageSpec::new("bvh"))
            .unwrap();
        let cpu = crsh_wgpu::testing::cpu_intersector(&StageSpec::new("bvh"), &s);
        let rays = rays(&s, 9, 1500, RayKind::Reflection);
        let start = start_hits(rays.len());
        for mode in [HitMode::Closest, HitMode::Any] {
            let (got, want, stats, cpu_stats) = scene_query(&b, &*gpu, &*cpu, &rays, &start, mode);
            let bad = compare(&s, &rays, &got, &want, mode);
            assert!(
                bad * 10_000 <= rays.len(),
                "{name} {mode:?}: {bad} mismatches"
            );
            let t = &cpu_stats.tests;
            assert!(
                t.inner_nodes >= rays.len() as u64 * 4 / 5,
                "{name} {mode:?}: {t:?}"
            );
            assert!(
                t.leaves > 0 && t.leaves <= t.ray_triangle,
                "{name} {mode:?}: {t:?}"
            );
            if bad == 0 {
                assert_eq!(stats.tests, cpu_stats.tests, "{name} {mode:?}: counters");
                counters_compared += 1;
            }
        }
    }
    assert!(counters_compared > 0, "no run to compare counters on");
}

#[test]
fn brute_rejects_bad_input() {
    let Some(b) = crsh_wgpu::testing::shared_backend("brute_rejects_bad_input") else {
        return;
    };
    let s = scene("cornell-mirrors");
    let g = gpu_scene(&b, &s);
    let gpu = BruteForce::new(&g, &brute_spec("mt")).unwrap();
    assert!(BruteForce::new(&g, &brute_spec("watertight")).is_err());
    let mut r = rays(&s, 1, 10, RayKind::Reflection);
    r[6].dir = Vec3::new(f32::NAN, 0.0, 1.0);
    let buf = b.upload(&r).unwrap();
    let mut hits = b.filled(10, Hit::MISS).unwrap();
    let e = gpu
        .intersect(
            &b,
            &buf,
            Query::Scene,
            HitMode::Closest,
            &mut hits,
            &mut Stats::default(),
        )
        .unwrap_err();
    assert!(e.to_string().contains("ray 6 is not valid"), "{e}");
    let mut short = b.filled(9, Hit::MISS).unwrap();
    assert!(gpu
        .intersect(
            &b,
            &buf,
            Query::Scene,
            HitMode::Closest,
            &mut short,
            &mut Stats::default()
        )
        .is_err());
}

/// A unit vector within `spread` radians of the unit `axis` (uniform in angle).
fn dir_near(g: &mut Lcg, axis: Vec3, spread: f32) -> Vec3 {
    let any = if axis.x.abs() < 0.9 { Vec3::X } else { Vec3::Y };
    let u = axis.cross(any).normalize();
    let v = axis.cross(u);
    let phi = g.unit() * std::f32::consts::PI;
    let theta = (g.unit() * 0.5 + 0.5) * spread;
    (axis * theta.cos() + (u * phi.cos() + v * phi.sin()) * theta.sin()).normalize()
}

/// A hand-made hierarchy with leaf offsets (seed 004's shape: one level, apex cones of sphere
/// radius 0, variable nodes, one empty, half-angles from 0 to π) over rays of `kind` in
/// `scene`: `(rays, order, offsets, nodes, reach)`. Each node's rays start on its cone's axis
/// at or ahead of the apex and point within its spread of the axis, so every point of every
/// ray lies in the node's cone (measured in f64 and widened); the spreads ≥ π/2 get π. The
/// order is a permutation of the rays, nodes contiguous in it.
#[allow(clippy::type_complexity)]
fn offsets_hierarchy(
    scene: &Scene,
    seed: u64,
    kind: RayKind,
) -> (
    Vec<Ray>,
    Vec<u32>,
    Vec<u32>,
    Vec<crsh_core::SphereCone>,
    Vec<f32>,
) {
    use crsh_core::{Cone, Sphere, SphereCone};
    let mut g = Lcg(seed);
    let (lo, hi) = (scene.bounds.min, scene.bounds.max);
    let diag = (hi - lo).length();
    let sizes = [1usize, 7, 64, 0, 3, 100, 17, 1, 40, 256, 2, 33, 5, 90];
    let spreads = [0.0f32, 0.01, 0.2, 0.6, 1.3, 2.0, 3.2];
    let mut by_pos: Vec<Ray> = Vec::new();
    let mut offsets = vec![0u32];
    let mut nodes = Vec::new();
    let mut reach = Vec::new();
    for (k, &size) in sizes.iter().enumerate() {
        let apex = lo
            + (hi - lo)
                * Vec3::new(
                    g.unit() * 0.5 + 0.5,
                    g.unit() * 0.5 + 0.5,
                    g.unit() * 0.5 + 0.5,
                );
        let axis = dir_near(&mut g, Vec3::Z, std::f32::consts::PI);
        let spread = spreads[k % spreads.len()];
        let finite = k % 2 == 0;
        let (mut widest, mut far) = (0.0f64, 0.0f64);
        for i in 0..size {
            // Origins on the axis ahead of the apex (all at the apex for every third node).
            let ahead = if k % 3 == 0 {
                0.0
            } else {
                (g.unit() * 0.5 + 0.5) * 0.2 * diag
            };
            let origin = apex + axis * ahead;
            let dir = dir_near(&mut g, axis, spread);
            let t_max = if finite { 0.4 * diag } else { f32::INFINITY };
            let (a, o, d) = (apex.as_dvec3(), origin.as_dvec3(), dir.as_dvec3());
            let angle = |v: DVec3| {
                v.cross(axis.as_dvec3())
                    .length()
                    .atan2(v.dot(axis.as_dvec3()))
            };
            widest = widest.max(angle(d));
            if o != a {
                widest = widest.max(angle(o - a));
            }
            far = far.max((o - a).length() + t_max as f64 * d.length());
            by_pos.push(Ray {
                origin,
                t_min: if i % 4 == 0 { 1e-4 } else { 0.0 },
                dir,
                t_max,
                throughput: Vec3::ONE,
                kind: kind as u32,
                pixel: by_pos.len() as u32,
                light: 0,
                depth: 1,
                source: by_pos.len() as u32,
            });
        }
        let half_angle = if widest * (1.0 + 1e-5) + 1e-5 >= std::f64::consts::FRAC_PI_2 {
            std::f32::consts::PI
        } else {
            (widest * (1.0 + 1e-5) + 1e-5) as f32
        };
        nodes.push(SphereCone {
            sphere: Sphere::new(apex, 0.0),
            cone: Cone { axis, half_angle },
        });
        reach.push(if far.is_finite() {
            ((far * (1.0 + 1e-6)) as f32).next_up()
        } else {
            f32::INFINITY
        });
        offsets.push(by_pos.len() as u32);
    }
    // Ray index of position p: a fixed shuffle, so nodes are contiguous in the order only.
    let n = by_pos.len();
    let mut perm: Vec<u32> = (0..n as u32).collect();
    for i in (1..n).rev() {
        let j = ((g.unit() * 0.5 + 0.5) * i as f32) as usize % (i + 1);
        perm.swap(i, j);
    }
    let mut rays = vec![by_pos[0]; n];
    for (p, &r) in perm.iter().enumerate() {
        rays[r as usize] = by_pos[p];
    }
    (rays, perm, offsets, nodes, reach)
}

/// Leaf offsets honoured by the consumers: a hand-made hierarchy with offsets (one level of
/// apex cones, variable and empty nodes, half-angles up to π), traversed by the GPU `crsh`
/// (with and without mesh culling, with and without reach, one and several batches) or the
/// GPU `dual` (objects `lbvh` and `grid`, one and several batches) and
/// intersected by the GPU `brute` candidate query, gives exactly the hits of the GPU's own
/// whole-scene brute force, and the CPU brute force's over `Query::Scene` up to edge rounding;
/// bad offsets are clear errors from both consumers.
#[test]
fn offsets_hierarchy_gives_the_brute_force_hits() {
    use crsh_core::{Candidate, CoreError};
    let Some(b) =
        crsh_wgpu::testing::shared_backend("offsets_hierarchy_gives_the_brute_force_hits")
    else {
        return;
    };
    for name in ["cornell-mirrors", "office-boxes"] {
        let s = scene(name);
        let g = gpu_scene(&b, &s);
        let gpu = BruteForce::new(&g, &brute_spec("mt")).unwrap();
        let cpu = crsh_wgpu::testing::cpu_intersector(&StageSpec::new("brute"), &s);
        for (kind, mode) in [
            (RayKind::Reflection, HitMode::Closest),
            (RayKind::Shadow, HitMode::Any),
        ] {
            let (rays, order, offsets, nodes, reach) = offsets_hierarchy(&s, 17, kind);
            let buf = b.upload(&rays).unwrap();
            let mut want = vec![Hit::MISS; rays.len()];
            cpu.intersect(
                &Cpu,
                &rays,
                Query::Scene,
                mode,
                &mut want,
                &mut Stats::default(),
            )
            .unwrap();
            let mut scene_hits = b.filled(rays.len(), Hit::MISS).unwrap();
            gpu.intersect(
                &b,
                &buf,
                Query::Scene,
                mode,
                &mut scene_hits,
                &mut Stats::default(),
            )
            .unwrap();
            let scene_hits = b.download(&scene_hits).unwrap();
            assert!(scene_hits.iter().any(|h| h.is_hit()), "{name}: no hits");
            // (mesh culling, budget, reach, the `dual` traverser: objects `lbvh` with culling,
            // `grid` without).
            for (culling, budget, with_reach, dual) in [
                (true, 64.0, true, false),
                (false, 64.0, false, false),
                (true, 0.002, true, false),
                (true, 64.0, true, true),
                (false, 64.0, false, true),
                (true, 0.002, true, true),
            ] {
                let what = format!("{name} {kind:?} culling {culling} budget {budget} dual {dual}");
                let h: RayHierarchy<Wgpu> = RayHierarchy {
                    order: b.upload(&order).unwrap(),
                    levels: vec![b.upload(&nodes).unwrap()],
                    subdivision: 256,
                    leaf_offsets: Some(b.upload(&offsets).unwrap()),
                    reach: if with_reach {
                        vec![b.upload(&reach).unwrap()]
                    } else {
                        Vec::new()
                    },
                };
                let mut spec = StageSpec::new("crsh");
                spec.params
                    .insert("mesh_culling".into(), crsh_core::ParamValue::Bool(culling));
                spec.params.insert(
                    "candidate_budget_mb".into(),
                    crsh_core::ParamValue::Float(budget),
                );
                let trav: Box<dyn Traverser<Wgpu>> = if dual {
                    let mut d = crsh_cpu::traverse::dual::info().defaults();
                    let objects = if culling { "lbvh" } else { "grid" };
                    d.params
                        .insert("objects".into(), crsh_core::ParamValue::Str(objects.into()));
                    d.params.insert(
                        "candidate_budget_mb".into(),
                        crsh_core::ParamValue::Float(budget),
                    );
                    Box::new(crsh_wgpu::traverse::dual::Dual::new(&g, &d).unwrap())
                } else {
                    Box::new(crsh_wgpu::traverse::crsh::Crsh::new(&g, &spec).unwrap())
                };
                let mut hits = b.filled(rays.len(), Hit::MISS).unwrap();
                let mut batches = 0;
                let mut stats = Stats::default();
                trav.traverse(
                    &b,
                    &buf,
                    kind,
                    &h,
                    &mut |batch, st| {
                        batches += 1;
                        let pairs: Vec<Candidate> = b.download(&batch.pairs).unwrap();
                        assert!(pairs.iter().all(|c| (c.node as usize) < nodes.len()));
                        gpu.intersect(
                            &b,
                            &buf,
                            Query::Candidates {
                                hierarchy: &h,
                                batch: &batch,
                            },
                            mode,
                            &mut hits,
                            st,
                        )
                    },
                    &mut stats,
                )
                .unwrap_or_else(|e| panic!("{what}: {e}"));
                if budget < 1.0 {
                    assert!(batches > 1, "{what}: one batch");
                }
                let got = b.download(&hits).unwrap();
                println!(
                    "{what}: {batches} batches, {} rays, {} hit, {} ray-triangle tests \
                     (brute force {})",
                    rays.len(),
                    got.iter().filter(|h| h.is_hit()).count(),
                    stats.tests.ray_triangle,
                    rays.len() * s.triangle_count()
                );
                // Any hit is the lowest-id hit when the candidates arrive in triangle order
                // (`crsh`'s batches, or one batch); `dual`'s batches of top nodes may find
                // another hit first.
                let any_order = dual && batches > 1 && mode == HitMode::Any;
                for (i, (g, w)) in got.iter().zip(&scene_hits).enumerate() {
                    if any_order {
                        assert_eq!(g.is_hit(), w.is_hit(), "{what}: ray {i}");
                    } else {
                        assert_eq!(g, w, "{what}: ray {i}: candidates vs whole scene");
                    }
                }
                let bad = compare(&s, &rays, &got, &want, mode);
                assert!(
                    bad * 1000 <= rays.len(),
                    "{what}: {bad} mismatches with the CPU"
                );
                // The candidates were fewer than brute force's.
                let brute = (rays.len() * s.triangle_count()) as u64;
                assert!(
                    stats.tests.ray_triangle < brute,
                    "{what}: no culling at all"
                );
            }
            // Bad offsets: clear errors, no panic.
            let bad_offsets: [Vec<u32>; 3] = [
                {
                    let mut o = offsets.clone();
                    o.swap(2, 3);
                    o
                },
                {
                    let mut o = offsets.clone();
                    *o.last_mut().unwrap() -= 1;
                    o
                },
                offsets[..offsets.len() - 1].to_vec(),
            ];
            let pairs = vec![Candidate { node: 1, tri: 0 }];
            let batch = CandidateBatch::new(b.upload(&pairs).unwrap());
            // The one-level hierarchy with leaf offsets `o`, and a candidate query on it.
            let with_offsets = |o: &[u32]| -> RayHierarchy<Wgpu> {
                RayHierarchy {
                    order: b.upload(&order).unwrap(),
                    levels: vec![b.upload(&nodes).unwrap()],
                    subdivision: 256,
                    leaf_offsets: Some(b.upload(o).unwrap()),
                    reach: Vec::new(),
                }
            };
            let query = |h: &RayHierarchy<Wgpu>, batch: &CandidateBatch<Wgpu>| {
                let mut hits = b.filled(rays.len(), Hit::MISS).unwrap();
                gpu.intersect(
                    &b,
                    &buf,
                    Query::Candidates {
                        hierarchy: h,
                        batch,
                    },
                    mode,
                    &mut hits,
                    &mut Stats::default(),
                )
            };
            for o in &bad_offsets {
                let h = with_offsets(o);
                let r = query(&h, &batch);
                assert!(
                    matches!(&r, Err(CoreError::InvalidInput(m)) if m.contains("offsets")),
                    "{o:?}: {r:?}"
                );
                let mut spec = StageSpec::new("crsh");
                spec.params
                    .insert("mesh_culling".into(), crsh_core::ParamValue::Bool(true));
                spec.params.insert(
                    "candidate_budget_mb".into(),
                    crsh_core::ParamValue::Float(64.0),
                );
                let trav = crsh_wgpu::traverse::crsh::Crsh::new(&g, &spec);
                let r = trav.unwrap().traverse(
                    &b,
                    &buf,
                    kind,
                    &h,
                    &mut |_, _| Ok(()),
                    &mut Stats::default(),
                );
                assert!(
                    matches!(&r, Err(CoreError::InvalidInput(m)) if m.contains("offsets")),
                    "traversal {o:?}: {r:?}"
                );
            }
            // Lane masks that do not fit: a partial mask on a node of more than 32 rays, and
            // a mask array of another length than the pairs'.
            let big = (0..offsets.len() - 1)
                .find(|&n| offsets[n + 1] - offsets[n] > 32)
                .expect("a node of more than 32 rays");
            let pair = b
                .upload(&[Candidate {
                    node: big as u32,
                    tri: 0,
                }])
                .unwrap();
            let masked = CandidateBatch::with_lanes(pair, b.upload(&[1u32]).unwrap());
            let r = query(&with_offsets(&offsets), &masked);
            assert!(
                matches!(&r, Err(CoreError::InvalidInput(m)) if m.contains("lane mask")),
                "{r:?}"
            );
            let masked = CandidateBatch::with_lanes(
                b.upload(&pairs).unwrap(),
                b.upload(&[1u32, 2]).unwrap(),
            );
            let r = query(&with_offsets(&offsets), &masked);
            assert!(
                matches!(&r, Err(CoreError::InvalidInput(m)) if m.contains("lane masks")),
                "{r:?}"
            );
        }
    }
}

/// Long loops: with 70,002 triangles, the only ones the rays can hit last, the whole-scene
/// query and a candidate query whose nodes each hold every triangle find every hit and count
/// what the CPU counts. (Mesa's lavapipe ends an invocation's loops after 65,535 iterations in
/// all, silently; the GPU `brute` splits its sweeps into windows so that none is cut.)
#[test]
fn brute_reaches_triangles_beyond_65535_iterations() {
    let Some(b) =
        crsh_wgpu::testing::shared_backend("brute_reaches_triangles_beyond_65535_iterations")
    else {
        return;
    };
    let mut builder = crsh_scene::SceneBuilder::new("long");
    let m = builder.material(crsh_scene::Material::default());
    builder.camera(crsh_scene::Camera {
        eye: Vec3::new(0.0, 0.0, 5.0),
        target: Vec3::ZERO,
        up: Vec3::Y,
        vfov_deg: 45.0,
        aspect: None,
    });
    // 70,000 small triangles off to the side, then a quad across the rays' path.
    let n_far = 70_000u32;
    let mut p = Vec::new();
    let mut idx = Vec::new();
    for i in 0..n_far {
        let c = Vec3::new(10.0 + (i % 300) as f32 * 0.01, (i / 300) as f32 * 0.01, 0.0);
        idx.push([p.len() as u32, p.len() as u32 + 1, p.len() as u32 + 2]);
        p.extend([c, c + Vec3::X * 0.005, c + Vec3::Y * 0.005]);
    }
    builder.mesh("far", &p, None, &idx, m);
    let quad = [
        Vec3::new(-1.0, -1.0, 0.0),
        Vec3::new(1.0, -1.0, 0.0),
        Vec3::new(1.0, 1.0, 0.0),
        Vec3::new(-1.0, 1.0, 0.0),
    ];
    builder.mesh("quad", &quad, None, &[[0, 1, 2], [0, 2, 3]], m);
    let s = Arc::new(builder.build("long").unwrap());
    let n_tris = s.triangle_count();
    assert_eq!(n_tris, n_far as usize + 2);
    let g = gpu_scene(&b, &s);
    let gpu = BruteForce::new(&g, &brute_spec("mt")).unwrap();
    let cpu = crsh_wgpu::testing::cpu_intersector(&StageSpec::new("brute"), &s);
    let mut lcg = Lcg(5);
    let rays: Vec<Ray> = (0..64)
        .map(|i| {
            let o = Vec3::new(lcg.unit() * 0.9, lcg.unit() * 0.9, 5.0);
            crsh_wgpu::testing::ray(o, -Vec3::Z, 0.0, f32::INFINITY, RayKind::Shadow, i)
        })
        .collect();
    let buf = b.upload(&rays).unwrap();
    // Eight nodes of eight rays, each paired with every triangle.
    let nodes: Vec<crsh_core::SphereCone> = vec![bytemuck::Zeroable::zeroed(); 8];
    let order: Vec<u32> = (0..64).collect();
    let pairs: Vec<crsh_core::Candidate> = (0..8u32)
        .flat_map(|node| (0..n_tris as u32).map(move |tri| crsh_core::Candidate { node, tri }))
        .collect();
    let h_cpu: RayHierarchy<Cpu> = RayHierarchy {
        order: order.clone(),
        levels: vec![nodes.clone()],
        subdivision: 8,
        leaf_offsets: None,
        reach: Vec::new(),
    };
    let h_gpu: RayHierarchy<Wgpu> = RayHierarchy {
        order: b.upload(&order).unwrap(),
        levels: vec![b.upload(&nodes).unwrap()],
        subdivision: 8,
        leaf_offsets: None,
        reach: Vec::new(),
    };
    for mode in [HitMode::Closest, HitMode::Any] {
        for candidates in [false, true] {
            let what = format!("{mode:?} candidates {candidates}");
            let mut want = vec![Hit::MISS; rays.len()];
            let mut cpu_stats = Stats::default();
            let mut got = b.filled(rays.len(), Hit::MISS).unwrap();
            let mut stats = Stats::default();
            if candidates {
                let cb = CandidateBatch::new(pairs.clone());
                let q = Query::Candidates {
                    hierarchy: &h_cpu,
                    batch: &cb,
                };
                cpu.intersect(&Cpu, &rays, q, mode, &mut want, &mut cpu_stats)
                    .unwrap();
                let gb = CandidateBatch::new(b.upload(&pairs).unwrap());
                let q = Query::Candidates {
                    hierarchy: &h_gpu,
                    batch: &gb,
                };
                gpu.intersect(&b, &buf, q, mode, &mut got, &mut stats)
                    .unwrap();
            } else {
                cpu.intersect(&Cpu, &rays, Query::Scene, mode, &mut want, &mut cpu_stats)
                    .unwrap();
                gpu.intersect(&b, &buf, Query::Scene, mode, &mut got, &mut stats)
                    .unwrap();
            }
            let got = b.download(&got).unwrap();
            assert!(
                want.iter().all(|h| h.tri >= n_far && h.is_hit()),
                "{what}: CPU hits"
            );
            for (i, (g, w)) in got.iter().zip(&want).enumerate() {
                assert_eq!(g.tri, w.tri, "{what}: ray {i}");
                assert_eq!(g.t, w.t, "{what}: ray {i}");
            }
            assert_eq!(stats.tests, cpu_stats.tests, "{what}");
        }
    }
}
