//! The GPU hashes against their CPU twins: every key equal bit for bit (both sides quantize
//! with `crsh_core::quantize`'s exact scheme, see `crsh_wgpu::hash::thesis`), on the built-in
//! scenes, the shared scenes when present, and rays placed on cell boundaries.
//!
//! Without an adapter every test prints `SKIP:` and passes, unless `CRSH_REQUIRE_GPU=1`.

use std::path::PathBuf;
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

/// The built-in scenes, then the shared scenes' manifests (`CRSH_SCENES`, else
/// `<workspace>/../shared/scenes`; skipped with a printed reason when absent).
fn scenes() -> Vec<(String, Arc<Scene>)> {
    let mut out: Vec<(String, Arc<Scene>)> = ["cornell-mirrors", "office-boxes"]
        .iter()
        .map(|n| {
            (
                n.to_string(),
                Arc::new(crsh_scene::builtin::build(n).unwrap()),
            )
        })
        .collect();
    let dir = std::env::var_os("CRSH_SCENES")
        .map(PathBuf::from)
        .unwrap_or_else(|| {
            PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/scenes")
        });
    let Ok(entries) = std::fs::read_dir(&dir) else {
        println!(
            "SKIP: shared scenes not found at {} (set CRSH_SCENES)",
            dir.display()
        );
        return out;
    };
    let mut paths: Vec<PathBuf> = entries
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter_map(|d| std::fs::read_dir(d).ok())
        .flat_map(|e| e.filter_map(|e| e.ok().map(|e| e.path())))
        .filter(|p| p.extension().is_some_and(|e| e == "toml"))
        .collect();
    paths.sort();
    for p in paths {
        match crsh_scene::load_path(&p) {
            Ok(s) => out.push((p.display().to_string(), Arc::new(s))),
            Err(e) => println!("SKIP: {} ({e})", p.display()),
        }
    }
    out
}

/// Rays built to sit on or next to cell boundaries: origins at the boundaries of the origin
/// cells (and one ULP either side), directions at the `θ` and `φ` boundaries, the octahedral
/// diagonals and folds, with tiny, subnormal, zero, signed-zero, huge and non-finite
/// components; shadow rays towards light 0 from both ends.
fn boundary_rays(s: &Scene) -> Vec<Ray> {
    let (lo, hi) = (s.bounds.min, s.bounds.max);
    let ulp = |x: f32, k: i32| f32::from_bits((x.to_bits() as i32 + k) as u32);
    let mut dirs = vec![
        Vec3::ZERO,
        Vec3::NAN,
        Vec3::new(1.0, f32::INFINITY, 0.0),
        Vec3::new(1e-40, -1e-40, 1e-39),
        Vec3::new(1.0, 1e-40, -1e-12),
        Vec3::new(-1.0, -0.0, 0.0),
        Vec3::new(-1.0, 0.0, -0.0),
        Vec3::new(-0.0, -0.0, -1.0),
        Vec3::new(0.0, 0.0, 1e-30),
        Vec3::new(3e38, -3e38, 1e38),
        Vec3::new(1.0, 1.0, 1.0),
        Vec3::new(-1.0, 1.0, -1.0),
        Vec3::new(0.5, -0.5, -0.0),
    ];
    for bits in [1u32, 3, 7, 8, 10, 16] {
        let n = 1u32 << bits;
        for k in 0..n.min(64) {
            let k = k * (n / n.min(64));
            let t = std::f64::consts::PI * k as f64 / n as f64;
            let p = -std::f64::consts::PI + 2.0 * std::f64::consts::PI * k as f64 / n as f64;
            let on = [
                Vec3::new(t.sin() as f32 * 0.6, t.sin() as f32 * 0.8, t.cos() as f32),
                Vec3::new(p.cos() as f32, p.sin() as f32, 0.25),
                Vec3::new(p.cos() as f32 * 3.0, p.sin() as f32 * 3.0, -1.0),
                Vec3::new(-1.0 + 2.0 * k as f32 / n as f32, 0.3, 0.7),
            ];
            for d in on {
                dirs.push(d);
                for a in 0..3 {
                    for u in [-1, 1] {
                        let mut e = d;
                        e[a] = ulp(e[a], u);
                        dirs.push(e);
                    }
                }
            }
        }
    }
    let mut origins = vec![
        lo,
        hi,
        (lo + hi) * 0.5,
        Vec3::splat(f32::NAN),
        lo - Vec3::ONE,
    ];
    for bits in [1u32, 3, 6, 10, 20] {
        for k in 0..16u32 {
            let c: [f32; 3] = std::array::from_fn(|i| {
                let q = crsh_core::quantize::UniformCells::new(lo[i], hi[i], bits);
                let x = lo[i] + (k as f32 * 97.0 % (1u32 << bits) as f32) / q.scale.max(1e-30);
                ulp(x, k as i32 % 3 - 1)
            });
            origins.push(Vec3::from_array(c));
        }
    }
    let ray = |origin: Vec3, dir: Vec3, kind: RayKind, light: u32, t_max: f32| Ray {
        origin,
        t_min: 0.0,
        dir,
        t_max,
        throughput: Vec3::ONE,
        kind: kind as u32,
        pixel: 0,
        light,
        depth: 1,
        source: 0,
    };
    let mut rays = Vec::new();
    for (i, d) in dirs.iter().enumerate() {
        let o = origins[i % origins.len()];
        rays.push(ray(o, *d, RayKind::Reflection, u32::MAX, f32::INFINITY));
        rays.push(ray(o, *d, RayKind::Refraction, u32::MAX, 1.0));
        if !s.lights.is_empty() && d.is_finite() && d.abs().max_element() < 1e30 {
            let l = s.lights[0].position;
            rays.push(ray(l, *d, RayKind::Shadow, 0, 0.5));
            // Towards the light from a point: the hashed direction is −dir.
            rays.push(ray(l - *d, *d, RayKind::Shadow, 0, 1.0));
        }
    }
    for o in origins {
        rays.push(ray(
            o,
            Vec3::new(0.3, -0.4, 0.5),
            RayKind::Reflection,
            u32::MAX,
            1.0,
        ));
    }
    rays
}

/// Asserts that `got` equals `want` key for key, naming how many differ and the first.
fn assert_same_keys(what: &str, rays: &[Ray], want: &[u64], got: &[u64]) {
    assert_eq!(want.len(), got.len(), "{what}");
    let differ: Vec<usize> = (0..want.len()).filter(|&i| want[i] != got[i]).collect();
    if let Some(&i) = differ.first() {
        panic!(
            "{what}: {} of {} keys differ; first: ray {i} {:?}: gpu {:#x} cpu {:#x}",
            differ.len(),
            want.len(),
            rays[i],
            got[i],
            want[i]
        );
    }
    println!("{what}: all {} keys equal the CPU's", want.len());
}

#[test]
fn thesis_keys_equal_the_cpu_bit_for_bit() {
    let Some(b) = crsh_wgpu::testing::shared_backend("thesis_keys_equal_the_cpu_bit_for_bit")
    else {
        return;
    };
    for (name, s) in scenes() {
        let g = GpuScene::new(&b, &s).unwrap();
        let mut rays = rays_of(&s);
        rays.extend(boundary_rays(&s));
        for layout in ["interleave", "concat"] {
            for bits in [None, Some((10, 40, 40)), Some((1, 3, 4))] {
                let mut sp = spec(layout);
                if let Some((o, d, sh)) = bits {
                    for (k, v) in [
                        ("origin_bits", o),
                        ("direction_bits", d),
                        ("shadow_bits", sh),
                    ] {
                        sp.params.insert(k.into(), ParamValue::Int(v));
                    }
                }
                let cpu = crsh_cpu::hash::thesis::ThesisHasher::new(&s, &sp).unwrap();
                let gpu = ThesisHasher::new(&g, &sp).unwrap();
                assert_eq!(
                    Hasher::<Cpu>::key_bits(&cpu),
                    Hasher::<crsh_wgpu::Wgpu>::key_bits(&gpu)
                );
                let (want, got) = keys(&b, &cpu, &gpu, &rays);
                let what = format!("{name} thesis {layout} {bits:?}");
                assert_same_keys(&what, &rays, &want, &got);
            }
        }
    }
}

/// Direction fields wider than the boundary tables are refused, with the reason.
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
    assert!(e.to_string().contains("32-bit direction field"), "{e}");
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

/// The Morton-octahedral keys, likewise: every key equals the CPU's.
#[test]
fn morton_keys_equal_the_cpu_bit_for_bit() {
    use crsh_cpu::hash::morton_octa::MortonOcta as CpuMorton;
    use crsh_wgpu::hash::morton_octa::MortonOcta;
    let Some(b) = crsh_wgpu::testing::shared_backend("morton_keys_equal_the_cpu_bit_for_bit")
    else {
        return;
    };
    for (name, s) in scenes() {
        let g = GpuScene::new(&b, &s).unwrap();
        let mut rays = rays_of(&s);
        rays.extend(boundary_rays(&s));
        for (ob, db) in [(10i64, 20i64), (20, 1), (3, 7), (0, 40), (21, 1), (1, 2)] {
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
            assert_same_keys(&format!("{name} morton {ob}/{db}"), &rays, &want, &got);
        }
    }
}
