//! Seed 004's tile cones on the device (Szécsi, "The Hierarchical Ray Engine", §4): the `tile`
//! hasher and the `tile_cone` hierarchy builder, checked against the spec's properties on the
//! downloaded output (the CPU twins are written on another branch; the comparison with them
//! comes after the merge):
//! - `tile` keys equal a reference formula written here, for several frames (non-divisible
//!   ones included), tile sizes, light counts and kinds, pixels outside the frame included;
//! - `tile_cone` nodes contain every ray (checked in f64), the leaf offsets are the runs of
//!   equal groups, the reach bounds every segment, on real Whitted batches of the built-in
//!   scenes and on random ray soups;
//! - an end-to-end wgpu frame of raster, whitted, tile, radix, tile_cone, crsh and brute agrees
//!   with brute force on every ray.
//!
//! Without an adapter every test prints `SKIP:` and passes, unless `CRSH_REQUIRE_GPU=1`.

use std::sync::Arc;

use crsh_core::glam::Vec3;
use crsh_core::{
    Backend, FrameSize, Hasher, HitMode, Query, Ray, RayKind, StageSpec, Stats, Surface,
};
use crsh_cpu::Cpu;
use crsh_scene::Scene;
use crsh_wgpu::hash::tile::Tile;
use crsh_wgpu::GpuScene;

struct Lcg(u64);

impl Lcg {
    fn next(&mut self) -> u64 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        self.0 >> 11
    }

    fn below(&mut self, n: u64) -> u64 {
        self.next() % n.max(1)
    }
}

fn builtin(name: &str) -> Arc<Scene> {
    Arc::new(crsh_scene::builtin::build(name).unwrap())
}

/// The spec's key of a ray, written out: tile `(y / ts)·tiles_x + x / ts`, shadow rays
/// `light·tiles + tile`, and the all-ones key of `key_bits` outside the frame (the device's
/// convention).
fn reference_key(r: &Ray, w: u32, h: u32, ts: u32, key_bits: u32) -> u64 {
    let (x, y) = (r.pixel % w, r.pixel / w);
    if y >= h {
        return if key_bits == 64 {
            u64::MAX
        } else {
            (1u64 << key_bits) - 1
        };
    }
    let tiles_x = u64::from(w.div_ceil(ts));
    let tiles = tiles_x * u64::from(h.div_ceil(ts));
    let tile = u64::from(y / ts) * tiles_x + u64::from(x / ts);
    if r.kind == RayKind::Shadow as u32 {
        u64::from(r.light) * tiles + tile
    } else {
        tile
    }
}

/// The spec's key width: the bit length of `max(1, lights)·tiles − 1`, at least 1.
fn reference_key_bits(w: u32, h: u32, ts: u32, lights: usize) -> u32 {
    let tiles = u64::from(w.div_ceil(ts)) * u64::from(h.div_ceil(ts));
    let largest = lights.max(1) as u64 * tiles - 1;
    (64 - largest.leading_zeros()).max(1)
}

fn ray_at(pixel: u32, kind: RayKind, light: u32, origin: Vec3, dir: Vec3) -> Ray {
    Ray {
        origin,
        t_min: 0.0,
        dir,
        t_max: f32::INFINITY,
        throughput: Vec3::ONE,
        kind: kind as u32,
        pixel,
        light,
        depth: 1,
        source: pixel,
    }
}

/// The CPU Whitted batches of `scene` at `w × h`: shadow, reflection and refraction rays from
/// the raster G-buffer, and those of one bounce deeper (the reflection and refraction hits
/// resolved by the CPU's brute force and Phong shader), each with its kind.
fn whitted_batches(scene: &Arc<Scene>, w: u32, h: u32) -> Vec<(RayKind, Vec<Ray>)> {
    let cfg = crsh_wgpu::testing::cpu_preset("brute");
    let stages = crsh_wgpu::testing::cpu_stages(&cfg, scene, w, h);
    let brute = crsh_wgpu::testing::cpu_intersector(&StageSpec::new("brute"), scene);
    let mut st = Stats::default();
    let g: Vec<Surface> = stages.primary.gbuffer(&Cpu, w, h, &mut st).unwrap();
    let mut out = Vec::new();
    let mut surfaces = vec![g];
    for depth in 0..2 {
        let mut next = Vec::new();
        for s in &surfaces {
            for kind in [RayKind::Shadow, RayKind::Reflection, RayKind::Refraction] {
                let rays = stages.raygen.generate(&Cpu, s, kind, &mut st).unwrap();
                if rays.is_empty() {
                    continue;
                }
                if depth == 0 && kind != RayKind::Shadow {
                    let mut hits = vec![crsh_core::Hit::MISS; rays.len()];
                    brute
                        .intersect(
                            &Cpu,
                            &rays,
                            Query::Scene,
                            HitMode::Closest,
                            &mut hits,
                            &mut st,
                        )
                        .unwrap();
                    next.push(stages.shader.resolve(&Cpu, &rays, &hits, &mut st).unwrap());
                }
                out.push((kind, rays));
            }
        }
        surfaces = next;
    }
    out
}

/// `tile` keys equal the reference formula: random pixels (a tenth outside the frame) of every
/// kind with light indices up to 2³² − 1, frames divisible or not by the tile, tile sizes 1 to
/// 4096, 0 to 3 lights; and the Whitted batches of the built-in scenes with the registry's
/// hasher.
#[test]
fn tile_keys_equal_the_reference_formula() {
    let Some(b) = crsh_wgpu::testing::shared_backend("tile_keys_equal_the_reference_formula")
    else {
        return;
    };
    let mut g = Lcg(3);
    let mut checked = 0;
    for (w, h) in [(100, 37), (48, 36), (1, 1), (16384, 16384), (7, 300)] {
        let frame = FrameSize::new(w, h).unwrap();
        for ts in [1, 8, 16, 32, 4096] {
            for lights in [0usize, 1, 3] {
                let tile = Tile::with_params(frame, ts, lights).unwrap();
                let bits = reference_key_bits(w, h, ts, lights);
                assert_eq!(tile.key_bits(), bits, "{w}x{h} tile {ts} lights {lights}");
                let pixels = u64::from(w) * u64::from(h);
                let rays: Vec<Ray> = (0..500)
                    .map(|i| {
                        let pixel = if i % 10 == 0 {
                            (pixels + g.below(1000)).min(u64::from(u32::MAX)) as u32
                        } else {
                            g.below(pixels) as u32
                        };
                        let kind = RayKind::ALL[i % RayKind::ALL.len()];
                        let light = match i % 4 {
                            0 => u32::MAX,
                            1 => g.below(1 << 32) as u32,
                            _ => g.below(lights.max(1) as u64) as u32,
                        };
                        ray_at(pixel, kind, light, Vec3::ZERO, Vec3::X)
                    })
                    .collect();
                let keys = tile
                    .hash(
                        &b,
                        &b.upload(&rays).unwrap(),
                        RayKind::Shadow,
                        &mut Stats::default(),
                    )
                    .unwrap();
                let keys = b.download(&keys).unwrap();
                for (r, k) in rays.iter().zip(&keys) {
                    assert_eq!(
                        *k,
                        reference_key(r, w, h, ts, bits),
                        "{w}x{h} tile {ts} lights {lights}: {r:?}"
                    );
                    checked += 1;
                }
            }
        }
    }
    // Real batches, with the hasher the registry builds from a resolved spec.
    for name in ["cornell-mirrors", "office-boxes"] {
        let s = builtin(name);
        let gs = GpuScene::new(&b, &s).unwrap();
        let (w, h) = (48, 36);
        for ts in [1, 16] {
            let mut spec = crsh_wgpu::hash::tile::info().defaults();
            spec.params
                .insert("tile_size".into(), crsh_core::ParamValue::Int(ts as i64));
            let tile = Tile::new(&gs, FrameSize::new(w, h).unwrap(), &spec).unwrap();
            let bits = reference_key_bits(w, h, ts, s.lights.len());
            assert_eq!(tile.key_bits(), bits);
            for (kind, rays) in whitted_batches(&s, w, h) {
                let keys = tile
                    .hash(&b, &b.upload(&rays).unwrap(), kind, &mut Stats::default())
                    .unwrap();
                let keys = b.download(&keys).unwrap();
                for (r, k) in rays.iter().zip(&keys) {
                    assert_eq!(*k, reference_key(r, w, h, ts, bits), "{name} {kind:?}");
                    assert!(*k < 1u64 << bits);
                    checked += 1;
                }
            }
        }
    }
    println!("{checked} keys checked");
}
