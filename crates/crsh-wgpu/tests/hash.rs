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
    let mut cfg = crsh_wgpu::testing::cpu_preset("crsh");
    cfg.hash
        .as_mut()
        .unwrap()
        .params
        .insert("layout".into(), ParamValue::Str(layout.into()));
    crsh_wgpu::testing::cpu_registry()
        .resolve(&mut cfg)
        .unwrap();
    cfg.hash.unwrap()
}

/// The keys of `rays` by the CPU hasher and by its GPU twin (the batch kind does not matter to
/// either: both key every ray by its own kind).
fn keys(
    b: &crsh_wgpu::Wgpu,
    cpu: &dyn Hasher<Cpu>,
    gpu: &dyn Hasher<crsh_wgpu::Wgpu>,
    rays: &Vec<Ray>,
) -> (Vec<u64>, Vec<u64>) {
    let kind = RayKind::Shadow;
    let want = cpu.hash(&Cpu, rays, kind, &mut Stats::default()).unwrap();
    let on_device = b.upload(rays).unwrap();
    let got = gpu
        .hash(b, &on_device, kind, &mut Stats::default())
        .unwrap();
    (want, b.download(&got).unwrap())
}

fn rays_of(s: &Arc<Scene>) -> Vec<Ray> {
    let cfg: PipelineConfig = crsh_wgpu::testing::cpu_preset("crsh");
    let stages = crsh_wgpu::testing::cpu_stages(&cfg, s, 48, 36);
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
            let (want, got) = keys(&b, &cpu, &gpu, &rays);
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

/// The fields of an interleaved key (the inverse of `quantize::interleave`, MSB-first
/// round-robin over the fields that still have bits).
fn deinterleave(key: u64, widths: &[u32; 5]) -> [u64; 5] {
    let total: u32 = widths.iter().sum();
    let max = widths.iter().copied().max().unwrap_or(0);
    let mut out = [0u64; 5];
    let mut pos = total;
    for level in 0..max {
        for (f, &w) in widths.iter().enumerate() {
            if level < w {
                pos -= 1;
                out[f] = (out[f] << 1) | ((key >> pos) & 1);
            }
        }
    }
    out
}

/// Fields wider than f32 can quantize are refused, with the reason.
#[test]
fn fields_wider_than_20_bits_are_refused() {
    let Some(b) = crsh_wgpu::testing::shared_backend("fields_wider_than_20_bits_are_refused")
    else {
        return;
    };
    let s = Arc::new(crsh_scene::builtin::build("cornell-mirrors").unwrap());
    let g = GpuScene::new(&b, &s).unwrap();
    let mut sp = spec("interleave");
    sp.params.insert("shadow_bits".into(), ParamValue::Int(64));
    let e = ThesisHasher::new(&g, &sp).err().expect("refused");
    assert!(e.to_string().contains("32-bit field"), "{e}");
    let mut m = crsh_core::StageSpec::new("morton");
    m.params.insert("origin_bits".into(), ParamValue::Int(0));
    m.params
        .insert("direction_bits".into(), ParamValue::Int(64));
    assert!(crsh_wgpu::hash::morton_octa::MortonOcta::new(&g, &m).is_err());
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
        .hash(
            &b,
            &b.upload(&rays).unwrap(),
            RayKind::Shadow,
            &mut Stats::default(),
        )
        .unwrap_err();
    assert!(e.to_string().contains(&format!("ray {i}")), "{e}");
}

/// The Morton-octahedral keys, likewise: nearly all identical, every difference a cell
/// boundary.
#[test]
fn morton_keys_match_the_cpu_up_to_cell_boundaries() {
    use crsh_cpu::hash::morton_octa::MortonOcta as CpuMorton;
    use crsh_wgpu::hash::morton_octa::MortonOcta;
    let Some(b) =
        crsh_wgpu::testing::shared_backend("morton_keys_match_the_cpu_up_to_cell_boundaries")
    else {
        return;
    };
    for name in ["cornell-mirrors", "office-boxes"] {
        let s = Arc::new(crsh_scene::builtin::build(name).unwrap());
        let g = GpuScene::new(&b, &s).unwrap();
        let rays = rays_of(&s);
        for (ob, db) in [(10i64, 20i64), (20, 1), (3, 7), (0, 40)] {
            let mut sp = crsh_core::StageSpec::new("morton");
            sp.params.insert("origin_bits".into(), ParamValue::Int(ob));
            sp.params
                .insert("direction_bits".into(), ParamValue::Int(db));
            let cpu = CpuMorton::new(&s, &sp).unwrap();
            let gpu = MortonOcta::new(&g, &sp).unwrap();
            assert_eq!(
                Hasher::<Cpu>::key_bits(&cpu),
                Hasher::<crsh_wgpu::Wgpu>::key_bits(&gpu)
            );
            let (want, got) = keys(&b, &cpu, &gpu, &rays);
            let widths = cpu.widths();
            let mut differ = 0;
            for (i, (gk, wk)) in got.iter().zip(&want).enumerate() {
                if gk == wk {
                    continue;
                }
                differ += 1;
                // Every field within one cell of the CPU's: a boundary rounding, not a bug.
                let (gf, wf) = (deinterleave(*gk, &widths), deinterleave(*wk, &widths));
                assert!(
                    gf.iter().zip(&wf).all(|(a, b)| a.abs_diff(*b) <= 1),
                    "{name} {ob}/{db}: ray {i}: gpu fields {gf:?} cpu {wf:?}"
                );
            }
            println!(
                "{name} morton {ob}/{db}: {differ} of {} keys differ",
                rays.len()
            );
            // f32 quantization is off by up to ~2^(bits − 23) cells: wide fields (21-bit
            // origin axes) move a few percent of the keys, narrow ones (≤ 16 bits) almost none.
            let widest = ob.max((db + 1) / 2) as i32;
            let allowed = 0.01 + 4.0 * 2f64.powi(widest - 24);
            assert!(
                differ as f64 <= allowed * rays.len() as f64,
                "{name} {ob}/{db}: {differ} keys differ"
            );
        }
    }
}
