//! The GPU thesis hash against the CPU twin. The device quantizes in f32 (see
//! `crsh_wgpu::hash::thesis`), so keys are compared for what that allows: nearly all identical,
//! and every differing key explained by rounding at a cell boundary, i.e. equal to the CPU key
//! of the same ray nudged by a few ULPs.
//!
//! Without an adapter every test prints `SKIP:` and passes, unless `CRSH_REQUIRE_GPU=1`.

use std::sync::Arc;

use crsh_core::glam::Vec3;
use crsh_core::{Backend, Hasher, ParamValue, PipelineConfig, Ray, RayKind, Stats};
use crsh_cpu::Cpu;
use crsh_scene::Scene;
use crsh_wgpu::hash::thesis::ThesisHasher;
use crsh_wgpu::GpuScene;

fn spec(layout: &str) -> crsh_core::StageSpec {
    let mut cfg = crsh_cpu::preset("crsh").unwrap();
    cfg.hash
        .as_mut()
        .unwrap()
        .params
        .insert("layout".into(), ParamValue::Str(layout.into()));
    cfg.resolve(&crsh_cpu::catalogue()).unwrap();
    cfg.hash.unwrap()
}

fn rays_of(s: &Arc<Scene>) -> Vec<Ray> {
    let cfg: PipelineConfig = crsh_cpu::preset("crsh").unwrap();
    let stages = crsh_cpu::build_stages(&cfg, s).unwrap();
    let mut st = Stats::default();
    let g = stages.primary.gbuffer(&Cpu, 48, 36, &mut st).unwrap();
    let mut rays = Vec::new();
    for kind in [RayKind::Shadow, RayKind::Reflection, RayKind::Refraction] {
        rays.extend(stages.raygen.generate(&Cpu, &g, kind, &mut st).unwrap());
    }
    // Axis-aligned and seam directions (θ = 0, π; φ = ±π), zero components.
    for (i, d) in [
        Vec3::X,
        -Vec3::X,
        Vec3::Y,
        -Vec3::Y,
        Vec3::Z,
        -Vec3::Z,
        Vec3::new(-1.0, 0.0, 0.3),
        Vec3::new(-1.0, -0.0, -0.3),
    ]
    .iter()
    .enumerate()
    {
        rays.push(Ray {
            origin: s.bounds.min + (s.bounds.max - s.bounds.min) * (i as f32 / 8.0),
            t_min: 0.0,
            dir: *d,
            t_max: f32::INFINITY,
            throughput: Vec3::ONE,
            kind: RayKind::Reflection as u32,
            pixel: 0,
            light: u32::MAX,
            depth: 1,
            source: 0,
        });
    }
    rays
}

/// Whether `got` is the CPU key of `r` with one origin or direction component nudged by up to
/// 256 ULPs (about 1.5e-5 relative, a sixth of a 16-bit angle cell).
fn explained(cpu: &crsh_cpu::hash::thesis::ThesisHasher, r: &Ray, got: u64) -> bool {
    let nudge = |x: f32, k: i32| f32::from_bits((x.to_bits() as i32 + k) as u32);
    for k in [-256, -64, -16, -4, -1, 1, 4, 16, 64, 256] {
        for axis in 0..3 {
            for which in 0..2 {
                let mut q = *r;
                if which == 0 {
                    q.dir[axis] = nudge(q.dir[axis], k);
                } else {
                    q.origin[axis] = nudge(q.origin[axis], k);
                }
                if cpu.key(&q).ok() == Some(got) {
                    return true;
                }
            }
        }
    }
    false
}

#[test]
fn thesis_keys_match_the_cpu_up_to_cell_boundaries() {
    let Some(b) =
        crsh_wgpu::testing::shared_backend("thesis_keys_match_the_cpu_up_to_cell_boundaries")
    else {
        return;
    };
    for name in ["cornell-mirrors", "office-boxes"] {
        let s = Arc::new(crsh_scene::builtin::build(name).unwrap());
        let g = GpuScene::new(&b, &s).unwrap();
        let rays = rays_of(&s);
        for layout in ["interleave", "concat"] {
            let sp = spec(layout);
            let cpu = crsh_cpu::hash::thesis::ThesisHasher::new(&s, &sp).unwrap();
            let gpu = ThesisHasher::new(&g, &sp).unwrap();
            assert_eq!(
                Hasher::<Cpu>::key_bits(&cpu),
                Hasher::<crsh_wgpu::Wgpu>::key_bits(&gpu)
            );
            let want = cpu.hash(&Cpu, &rays, &mut Stats::default()).unwrap();
            let got = b
                .download(
                    &gpu.hash(&b, &b.upload(&rays).unwrap(), &mut Stats::default())
                        .unwrap(),
                )
                .unwrap();
            let mut differ = 0;
            for (i, (g, w)) in got.iter().zip(&want).enumerate() {
                if g != w {
                    differ += 1;
                    assert!(
                        explained(&cpu, &rays[i], *g),
                        "{name} {layout}: ray {i} {:?}: gpu {g:#x} cpu {w:#x}",
                        rays[i]
                    );
                }
            }
            println!("{name} {layout}: {differ} of {} keys differ", rays.len());
            assert!(
                differ * 100 <= rays.len(),
                "{name} {layout}: {differ} of {} keys differ",
                rays.len()
            );
        }
    }
}

#[test]
fn bad_rays_are_errors() {
    let Some(b) = crsh_wgpu::testing::shared_backend("bad_rays_are_errors") else {
        return;
    };
    let s = Arc::new(crsh_scene::builtin::build("cornell-mirrors").unwrap());
    let g = GpuScene::new(&b, &s).unwrap();
    let gpu = ThesisHasher::new(&g, &spec("interleave")).unwrap();
    let mut rays = rays_of(&s);
    let i = rays
        .iter()
        .position(|r| r.kind == RayKind::Shadow as u32)
        .unwrap();
    rays[i].light = 99;
    let e = gpu
        .hash(&b, &b.upload(&rays).unwrap(), &mut Stats::default())
        .unwrap_err();
    assert!(e.to_string().contains(&format!("ray {i}")), "{e}");
}
