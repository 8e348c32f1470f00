//! Seed 004's tile cones on the device (Szécsi, "The Hierarchical Ray Engine", §4): the `tile`
//! hasher and the `tile_cone` hierarchy builder, checked against the CPU twins
//! (`crsh_cpu::hash::tile`, `crsh_cpu::hierarchy::tile_cone`) and the spec's properties on the
//! downloaded output:
//! - `tile` keys equal the CPU `TileHasher`'s exactly (frames divisible or not, tile sizes,
//!   light counts, kinds, tiles in rows and in Z-order), and rays the CPU refuses (pixel
//!   outside the frame, shadow ray of a light the scene lacks) get the all-ones key of
//!   `key_bits`;
//! - `tile_cone` offsets equal the CPU `build_nodes`' exactly, nodes' half-angles agree within
//!   rounding but for a few (see [`Agreement`]), the reach within the guards; the
//!   device's nodes contain every ray (the CPU's `check_containment`, in f64), on real Whitted
//!   batches of the built-in scenes and on random ray soups;
//! - an end-to-end wgpu frame of raster, whitted, tile, radix, tile_cone, crsh and brute agrees
//!   with brute force on every ray.
//!
//! Without an adapter every test prints `SKIP:` and passes, unless `CRSH_REQUIRE_GPU=1`.

use std::sync::Arc;

use crsh_core::glam::{DVec3, Vec3};
use crsh_core::{
    Backend, FrameOptions, FrameSize, Hasher, HierarchyBuilder, HitMode, Query, Ray, RayHierarchy,
    RayKind, Registry, SphereCone, StageContext, StageSpec, Stats, Surface,
};
use crsh_cpu::hash::tile::{TileGrid, TileHasher, TileOrder};
use crsh_cpu::hierarchy::tile_cone::{build_nodes, check_containment, TileConeParams};
use crsh_cpu::Cpu;
use crsh_scene::Scene;
use crsh_wgpu::hash::tile::Tile;
use crsh_wgpu::hierarchy::tile_cone::TileConeBuilder;
use crsh_wgpu::{GpuScene, HostIntersector, Wgpu};

struct Lcg(u64);

impl Lcg {
    fn next(&mut self) -> u64 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        self.0 >> 11
    }

    /// Uniform in [-1, 1).
    fn unit(&mut self) -> f32 {
        ((self.next() >> 29) as f32 / (1u64 << 24) as f32) * 2.0 - 1.0
    }

    fn vec(&mut self) -> Vec3 {
        Vec3::new(self.unit(), self.unit(), self.unit())
    }

    /// A unit vector, uniform enough for soups.
    fn dir(&mut self) -> Vec3 {
        loop {
            let v = self.vec();
            if v.length_squared() > 1e-3 && v.length_squared() <= 1.0 {
                return v.normalize();
            }
        }
    }

    fn below(&mut self, n: u64) -> u64 {
        self.next() % n.max(1)
    }
}

fn builtin(name: &str) -> Arc<Scene> {
    Arc::new(crsh_scene::builtin::build(name).unwrap())
}

/// The CPU twin's key of a ray for `lights` lights (`None`: the CPU refuses the ray, the
/// device writes the all-ones key of `key_bits`).
fn cpu_key(grid: &TileGrid, lights: usize, r: &Ray) -> Option<u64> {
    if r.kind == RayKind::Shadow as u32 && r.light as usize >= lights {
        return None;
    }
    grid.group(r)
}

/// The CPU `TileHasher`'s keys of `rays` (all of them valid).
fn cpu_keys(grid: TileGrid, lights: usize, rays: &[Ray], kind: RayKind) -> Vec<u64> {
    TileHasher::with_grid(grid, lights)
        .hash(&Cpu, &rays.to_vec(), kind, &mut Stats::default())
        .unwrap()
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

/// `tile` keys equal the CPU `TileHasher`'s exactly: random pixels (a tenth outside the
/// frame) of every kind with light indices up to 2³² − 1, frames divisible or not by the tile,
/// tile sizes 1 to 4096, 0 to 3 lights (the rays the CPU refuses get the all-ones key); and
/// the Whitted batches of the built-in scenes with the registry's hasher.
#[test]
fn tile_keys_equal_the_cpu_twins() {
    let Some(b) = crsh_wgpu::testing::shared_backend("tile_keys_equal_the_cpu_twins") else {
        return;
    };
    let mut g = Lcg(3);
    let (mut checked, mut refused) = (0, 0);
    for (w, h) in [(100, 37), (48, 36), (1, 1), (16384, 16384), (7, 300)] {
        let frame = FrameSize::new(w, h).unwrap();
        for (ts, order) in [1, 8, 16, 32, 4096]
            .into_iter()
            .flat_map(|ts| [(ts, TileOrder::Rows), (ts, TileOrder::Morton)])
        {
            let grid = TileGrid::new(frame, ts).unwrap().with_order(order);
            for lights in [0usize, 1, 3] {
                let tile = Tile::with_grid(grid, lights).unwrap();
                let bits = grid.key_bits(lights);
                assert_eq!(tile.key_bits(), bits, "{w}x{h} tile {ts} lights {lights}");
                let what = format!("{w}x{h} tile {ts} {order:?} lights {lights}");
                let none = if bits == 64 {
                    u64::MAX
                } else {
                    (1u64 << bits) - 1
                };
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
                // The CPU hasher on the rays it accepts, in the same order.
                let valid: Vec<usize> = (0..rays.len())
                    .filter(|&i| cpu_key(&grid, lights, &rays[i]).is_some())
                    .collect();
                let host: Vec<Ray> = valid.iter().map(|&i| rays[i]).collect();
                let want = cpu_keys(grid, lights, &host, RayKind::Shadow);
                for (&i, k) in valid.iter().zip(&want) {
                    assert_eq!(keys[i], *k, "{what}: {:?}", rays[i]);
                    checked += 1;
                }
                for (i, r) in rays.iter().enumerate() {
                    if cpu_key(&grid, lights, r).is_none() {
                        assert_eq!(keys[i], none, "{what}: {r:?}");
                        refused += 1;
                    }
                }
            }
        }
    }
    // Real batches, with the hasher the registry builds from a resolved spec.
    for name in ["cornell-mirrors", "office-boxes", "glass-sphere-500"] {
        let s = builtin(name);
        let gs = GpuScene::new(&b, &s).unwrap();
        let (w, h) = (100, 37);
        let sizes = [1, 8, 16, 32].map(|ts| (ts, "rows"));
        for (ts, order) in sizes.into_iter().chain([1, 4, 16].map(|ts| (ts, "morton"))) {
            let mut spec = crsh_cpu::hash::tile::info().defaults();
            spec.params
                .insert("tile_size".into(), crsh_core::ParamValue::Int(ts as i64));
            spec.params
                .insert("order".into(), crsh_core::ParamValue::Str(order.into()));
            let frame = FrameSize::new(w, h).unwrap();
            let tile = Tile::new(&gs, frame, &spec).unwrap();
            let cpu = TileHasher::new(frame, s.lights.len(), &spec).unwrap();
            assert_eq!(tile.key_bits(), Hasher::<Cpu>::key_bits(&cpu));
            for (kind, rays) in whitted_batches(&s, w, h) {
                let keys = tile
                    .hash(&b, &b.upload(&rays).unwrap(), kind, &mut Stats::default())
                    .unwrap();
                let keys = b.download(&keys).unwrap();
                let want = cpu.hash(&Cpu, &rays, kind, &mut Stats::default()).unwrap();
                assert_eq!(keys, want, "{name} tile {ts} {order} {kind:?}");
                checked += keys.len();
            }
        }
    }
    println!("{checked} keys equal to the CPU's, {refused} refused rays with the all-ones key");
}

// ---- tile_cone ------------------------------------------------------------------------------

fn angle64(x: DVec3, v: DVec3) -> f64 {
    x.cross(v).length().atan2(x.dot(v))
}

/// What one built hierarchy looked like, for the printed summaries.
#[derive(Default, Debug)]
struct Summary {
    rays: usize,
    nodes: usize,
    full: usize,
    angle_sum: f64,
}

impl Summary {
    fn add(&mut self, o: &Summary) {
        self.rays += o.rays;
        self.nodes += o.nodes;
        self.full += o.full;
        self.angle_sum += o.angle_sum;
    }
}

/// Absolute tolerance of a half-angle, rad (plus [`ANGLE_REL`] of the angle): the CPU's
/// `atan2` against `kernels/trig.wgsl`'s (a few 1e-8 rad), the guard applied to both, and
/// the rounding of the apex and axis the angles are measured from.
const ANGLE_ABS: f64 = 1e-5;
/// Relative tolerance of a half-angle.
const ANGLE_REL: f64 = 1e-5;
/// The largest half-angle difference allowed on any node (π on neither side), rad.
const MAX_ANGLE_OFF: f64 = 2e-3;
/// Tolerance of the apex, relative to the node's scale: the largest of 1, the coordinates of
/// the node's origins and the CPU's apex (the apex of a thin cone lies far behind the origins,
/// `t = g²/(e·g)` dividing by about `sin 2φ`, so its rounding grows with that distance).
const APEX_REL: f64 = 1e-5;
/// Tolerance of the axis, rad.
const AXIS_ABS: f64 = 1e-5;
/// The device's reach is at least the CPU's times `1 − REACH_LOW` and at most the CPU's times
/// `1 + REACH_HIGH` plus `REACH_ABS` times the largest coordinate of the node (or infinite on
/// both), give or take the distance between the two apexes: the device guards its f32
/// distances by `+1e-6·scale` and `·(1 + 1e-5)` plus an ulp (`kernels/reach.wgsl`, shared with
/// the sphere cones), the CPU its f64 distances by `·(1 + 1e-6)`, so `1 + 1e-5` alone is
/// exceeded by design (by up to about 1e-6 relative).
const REACH_LOW: f64 = 1e-6;
const REACH_HIGH: f64 = 2e-5;
const REACH_ABS: f64 = 2e-6;

/// How the device's tile cones compared with the CPU twin's ([`build_nodes`]) over many
/// builds: the offsets are equal (asserted); per node the largest differences, and the nodes
/// that differ beyond the tolerances or whose π flags differ (*flipped*: a branch of the
/// construction taken differently on rounding).
#[derive(Default, Debug)]
struct Agreement {
    builds: usize,
    nodes: usize,
    full_both: usize,
    flipped: usize,
    pi_flips: usize,
    /// Nodes, π on neither side, whose half-angles differ beyond the tolerances.
    angle_off: usize,
    /// The largest half-angle difference of those nodes, flipped or not, rad.
    max_angle_off: f64,
    max_apex_rel: f64,
    max_axis: f64,
    max_angle: f64,
    max_reach_over: f64,
    max_reach_under: f64,
}

impl Agreement {
    fn report(&self, what: &str) {
        println!(
            "{what}: {} builds, {} nodes compared ({} π on both), {} flipped ({} of them π on one side only); largest \
             differences: apex {:.3e} of the scale, axis {:.3e} rad, half-angle {:.3e} rad, \
             reach +{:.3e} / -{:.3e} relative",
            self.builds,
            self.nodes,
            self.full_both,
            self.flipped,
            self.pi_flips,
            self.max_apex_rel,
            self.max_axis,
            self.max_angle,
            self.max_reach_over,
            self.max_reach_under
        );
        println!(
            "{what}: {} nodes with half-angles apart beyond the tolerances, by up to {:.3e} rad",
            self.angle_off, self.max_angle_off
        );
        // The apex and axis of a thin or wide cone are ill-conditioned (many cones hold the
        // same rays almost as tightly), so flipped nodes are counted, not bounded; what the
        // traversal sees is bounded: the half-angles, and the branch to π. Measured on
        // lavapipe: 0.26 % of the soups' nodes and 0.85 % of the Whitted batches' flipped.
        // On an NVIDIA H200 (2026-12-04), which fuses `a·b + c` and rounds divisions to
        // 2.5 ULP, 4.4 % and 5.2 % flipped; the half-angles of 1.8 % and 1.7 % differed
        // beyond the tolerances, by up to 4.2e-4 rad, and 0.16 % and 0.08 % went to π on one
        // side only. Containment is checked on every node either way ([`check_hierarchy`]).
        assert!(
            self.pi_flips <= (self.nodes / 200).max(2),
            "{what}: {} of {} nodes π on one side only",
            self.pi_flips,
            self.nodes
        );
        assert!(
            self.angle_off <= (self.nodes / 20).max(2),
            "{what}: {} of {} nodes with other half-angles",
            self.angle_off,
            self.nodes
        );
        assert!(
            self.max_angle_off <= MAX_ANGLE_OFF,
            "{what}: half-angles {:.3e} rad apart",
            self.max_angle_off
        );
    }
}

/// Builds the tile cones of `rays` in `order` on the device with `tile_size` for `frame`,
/// checks the spec's properties on the downloaded output ([`check_hierarchy`]) and compares it
/// with the CPU twin's ([`compare_with_cpu`]).
#[allow(clippy::too_many_arguments)]
fn check_build(
    b: &Wgpu,
    what: &str,
    rays: &[Ray],
    order: &[u32],
    frame: FrameSize,
    tile_size: u32,
    agree: &mut Agreement,
) -> Summary {
    let params = TileConeParams::new(tile_size, 0.05).unwrap();
    let builder = TileConeBuilder::with_params(frame, params).unwrap();
    let h: RayHierarchy<Wgpu> = builder
        .build(
            b,
            &b.upload(rays).unwrap(),
            b.upload(order).unwrap(),
            &mut Stats::default(),
        )
        .unwrap_or_else(|e| panic!("{what}: {e}"));
    let (sum, nodes, reach, offsets) = check_hierarchy(b, what, rays, order, frame, tile_size, &h);
    compare_with_cpu(
        what, rays, order, frame, &params, &offsets, &nodes, &reach, agree,
    );
    sum
}

/// The device's output against the CPU twin's on the same rays and order: equal offsets, the
/// reach within the guards (asserted), and per node the apex, axis and half-angle within the
/// tolerances above (or both π); the other nodes are counted as flipped (and printed).
///
/// Why nodes flip: the construction decides at boundaries. After step (a) the new ray lies
/// exactly on the cone (`cos φ = x·r`), after step (b) the origin exactly on the near
/// generator, so the next coherent ray's `x·r < cos φ` or `x·c < cos φ·|c|` compares nearly
/// equal numbers, and one ulp (a multiply-add the driver contracts, a division or `sqrt`
/// rounded differently) takes the other branch; the apex then slides along the axis by a
/// different amount (1e-5 to 1e-3 of the scale on the mirrors' reflection tiles, with the same
/// axis and angle to 1e-6), or one side ends at π. Both results contain every ray (checked).
#[allow(clippy::too_many_arguments)]
fn compare_with_cpu(
    what: &str,
    rays: &[Ray],
    order: &[u32],
    frame: FrameSize,
    params: &TileConeParams,
    offsets: &[u32],
    nodes: &[SphereCone],
    reach: &[f32],
    agree: &mut Agreement,
) {
    let cpu = build_nodes(rays, order, frame, params).unwrap();
    assert_eq!(
        offsets, cpu.offsets,
        "{what}: offsets differ from the CPU's"
    );
    agree.builds += 1;
    for (k, (g, c)) in nodes.iter().zip(&cpu.nodes).enumerate() {
        agree.nodes += 1;
        let pi = std::f32::consts::PI;
        let (g_full, c_full) = (g.cone.half_angle >= pi, c.cone.half_angle >= pi);
        let leaves = &order[offsets[k] as usize..offsets[k + 1] as usize];
        let scale = leaves
            .iter()
            .map(|&i| rays[i as usize].origin.abs().max_element() as f64)
            .fold(1f64, f64::max)
            .max(c.sphere.center.abs().max_element() as f64);
        let apex = (g.sphere.center.as_dvec3() - c.sphere.center.as_dvec3()).length() / scale;
        let axis = angle64(g.cone.axis.as_dvec3(), c.cone.axis.as_dvec3());
        let (ga, ca) = (g.cone.half_angle as f64, c.cone.half_angle as f64);
        let angle = (ga - ca).abs();
        // The reach: the device's f32 guard (`kernels/reach.wgsl`: `+1e-6·scale`, `·(1 + 1e-5)`,
        // one ulp) against the CPU's f64 bound (`·(1 + 1e-6)`), from apexes `apex_d` apart.
        let (gr, cr) = (reach[k] as f64, cpu.reach[k] as f64);
        let apex_d = apex * scale;
        let reach_scale = leaves
            .iter()
            .map(|&i| {
                let r = &rays[i as usize];
                let tip = if r.t_max.is_finite() {
                    r.origin + r.dir * r.t_max
                } else {
                    r.origin
                };
                r.origin.abs().max_element().max(tip.abs().max_element()) as f64
            })
            .fold(scale, f64::max);
        if cr.is_infinite() || gr.is_infinite() {
            assert_eq!(gr, cr, "{what}: node {k} reach");
        } else {
            assert!(
                gr >= cr * (1.0 - REACH_LOW) - apex_d
                    && gr <= cr * (1.0 + REACH_HIGH) + REACH_ABS * reach_scale + apex_d,
                "{what}: node {k}: device reach {gr}, CPU {cr} (apexes {apex_d} apart)"
            );
            if cr > 0.0 && !(g_full || c_full) {
                agree.max_reach_over = agree.max_reach_over.max(gr / cr - 1.0);
                agree.max_reach_under = agree.max_reach_under.max(1.0 - gr / cr);
            }
        }
        let ok = if g_full || c_full {
            // A π node stores the first origin or the incremental apex; only the flags count.
            g_full == c_full
        } else {
            apex <= APEX_REL && axis <= AXIS_ABS && angle <= ANGLE_ABS + ANGLE_REL * ca
        };
        if !(g_full || c_full) {
            agree.max_angle_off = agree.max_angle_off.max(angle);
            agree.angle_off += (angle > ANGLE_ABS + ANGLE_REL * ca) as usize;
        }
        if !ok {
            agree.flipped += 1;
            agree.pi_flips += (g_full != c_full) as usize;
            println!(
                "{what}: node {k} ({} rays) flipped: device {g:?} reach {gr}, CPU {c:?} reach \
                 {cr} (apex {apex:.3e} of {scale}, axis {axis:.3e}, angle {angle:.3e})",
                leaves.len()
            );
            continue;
        }
        if g_full {
            agree.full_both += 1;
            continue;
        }
        agree.max_apex_rel = agree.max_apex_rel.max(apex);
        agree.max_axis = agree.max_axis.max(axis);
        agree.max_angle = agree.max_angle.max(angle);
    }
}

/// Checks every property of the spec on the downloaded output: one level, offsets from 0 to n
/// strictly increasing with one group per run and different groups in adjacent runs, nodes of
/// radius 0 with a (nearly) unit axis and a half-angle below π/2 or exactly π, and the CPU
/// twin's containment check in f64 ([`check_containment`]: every ray's direction and origin
/// within the half-angle of the axis seen from the apex, every segment within the reach).
/// Returns the summary and the downloaded nodes, reach and offsets.
fn check_hierarchy(
    b: &Wgpu,
    what: &str,
    rays: &[Ray],
    order: &[u32],
    frame: FrameSize,
    tile_size: u32,
    h: &RayHierarchy<Wgpu>,
) -> (Summary, Vec<SphereCone>, Vec<f32>, Vec<u32>) {
    let n = rays.len();
    assert_eq!(b.download(&h.order).unwrap(), order, "{what}: order");
    assert_eq!(h.levels.len(), 1, "{what}: levels");
    assert_eq!(h.reach.len(), 1, "{what}: reach levels");
    assert_eq!(h.subdivision, tile_size * tile_size, "{what}: subdivision");
    let nodes: Vec<SphereCone> = b.download(&h.levels[0]).unwrap();
    let reach: Vec<f32> = b.download(&h.reach[0]).unwrap();
    let offsets: Vec<u32> = b
        .download(h.leaf_offsets.as_ref().expect("leaf offsets"))
        .unwrap();
    assert_eq!(*offsets.last().unwrap() as usize, n, "{what}: last offset");
    assert!(
        offsets.windows(2).all(|w| w[0] < w[1]),
        "{what}: offsets not strictly increasing"
    );
    let full = check_containment(rays, order, &offsets, &nodes, &reach)
        .unwrap_or_else(|e| panic!("{what}: {e}"));
    let grid = TileGrid::new(frame, tile_size).unwrap();
    let group = |pos: u32| grid.group(&rays[order[pos as usize] as usize]).unwrap();
    let mut sum = Summary {
        rays: n,
        nodes: nodes.len(),
        full,
        ..Summary::default()
    };
    for (k, node) in nodes.iter().enumerate() {
        let (first, end) = (offsets[k], offsets[k + 1]);
        let g0 = group(first);
        assert!(
            (first..end).all(|p| group(p) == g0),
            "{what}: node {k} mixes groups"
        );
        if k > 0 {
            assert_ne!(
                group(first - 1),
                g0,
                "{what}: nodes {} and {k} not maximal",
                k - 1
            );
        }
        let ha = node.cone.half_angle;
        let pi = ha == std::f32::consts::PI;
        assert!(
            pi || (ha as f64) < std::f64::consts::FRAC_PI_2,
            "{what}: node {k} half-angle {ha}"
        );
        let x = node.cone.axis.as_dvec3();
        assert!((x.length() - 1.0).abs() < 1e-5, "{what}: node {k} axis {x}");
        assert!(
            node.sphere.center.is_finite(),
            "{what}: node {k} apex {node:?}"
        );
        if !pi {
            sum.angle_sum += ha as f64;
        }
    }
    (sum, nodes, reach, offsets)
}

/// The order that groups equal groups, in generation order within a group (a stable sort of
/// the CPU's groups, as the `tile` hash and the radix sort make it).
fn tile_order(rays: &[Ray], frame: FrameSize, tile_size: u32) -> Vec<u32> {
    let grid = TileGrid::new(frame, tile_size).unwrap();
    let mut order: Vec<u32> = (0..rays.len() as u32).collect();
    order.sort_by_key(|&i| grid.group(&rays[i as usize]).unwrap());
    order
}

/// Tile cones of real Whitted batches (shadow, reflection, refraction rays at two depths of the
/// built-in scenes, on a frame divisible by no tile size and another), tile sizes 1, 8, 16, 32,
/// in tile order and in generation order: every property of the spec, and the CPU twin's
/// offsets and nodes.
#[test]
fn tile_cones_contain_every_ray_of_whitted_batches() {
    let Some(b) =
        crsh_wgpu::testing::shared_backend("tile_cones_contain_every_ray_of_whitted_batches")
    else {
        return;
    };
    let mut agree = Agreement::default();
    for name in ["cornell-mirrors", "office-boxes", "glass-sphere-500"] {
        let s = builtin(name);
        for (w, h) in [(100, 37), (48, 36)] {
            let frame = FrameSize::new(w, h).unwrap();
            let batches = whitted_batches(&s, w, h);
            // (glass-sphere-500 has no mirror: shadow and refraction rays only.)
            assert!(batches.len() >= 2, "{name}: {} batches", batches.len());
            for ts in [1, 8, 16, 32] {
                let mut sum = Summary::default();
                for (kind, rays) in &batches {
                    let what = format!("{name} {w}x{h} tile {ts} {kind:?}");
                    let order = tile_order(rays, frame, ts);
                    sum.add(&check_build(&b, &what, rays, &order, frame, ts, &mut agree));
                    if ts == 16 {
                        let generation: Vec<u32> = (0..rays.len() as u32).collect();
                        let what = format!("{what} (generation order)");
                        check_build(&b, &what, rays, &generation, frame, ts, &mut agree);
                    }
                }
                println!(
                    "{name} {w}x{h} tile {ts}: {} rays, {} nodes, {} at π, mean half-angle of \
                     the others {:.4} rad",
                    sum.rays,
                    sum.nodes,
                    sum.full,
                    sum.angle_sum / (sum.nodes - sum.full).max(1) as f64
                );
            }
        }
    }
    agree.report("Whitted batches against the CPU twin");
}

/// Random ray soups of every awkward kind, each once as one node (every ray in pixel 0) and
/// once spread over a 100×37 frame with tile sizes 1, 8, 16, 32 (tile order and generation
/// order): every property of the spec.
#[test]
fn tile_cones_contain_random_soups() {
    let Some(b) = crsh_wgpu::testing::shared_backend("tile_cones_contain_random_soups") else {
        return;
    };
    let mut g = Lcg(11);
    let ray = |o: Vec3, d: Vec3| ray_at(0, RayKind::Reflection, u32::MAX, o, d);
    let mut soups: Vec<(&str, Vec<Ray>)> = Vec::new();
    let d = g.dir();
    soups.push((
        "parallel rays, different origins",
        (0..60).map(|_| ray(g.vec() * 3.0, d)).collect(),
    ));
    let p = g.vec();
    soups.push((
        "parallel rays, origins on the axis line",
        (0..40)
            .map(|i| ray(p + d * (i as f32 * 0.37 - 5.0), d))
            .collect(),
    ));
    soups.push((
        "opposite rays from one point",
        vec![ray(p, d), ray(p, -d), ray(p, d), ray(p, -d)],
    ));
    soups.push((
        "opposite rays, different origins",
        (0..30)
            .map(|i| ray(g.vec(), if i % 2 == 0 { d } else { -d }))
            .collect(),
    ));
    soups.push(("a single ray", vec![ray(p, d)]));
    soups.push((
        "a second ray behind the first on its line",
        vec![ray(p, d), ray(p - d * 2.0, d)],
    ));
    soups.push((
        "huge coordinates",
        (0..50)
            .map(|_| {
                let c = Vec3::new(1e6, -1e6, 1e6) + g.vec() * 10.0;
                ray(c, (d + g.vec() * 0.01).normalize())
            })
            .collect(),
    ));
    soups.push((
        "huge and spread coordinates",
        (0..50)
            .map(|_| ray(g.vec() * 1e6, (d + g.vec() * 0.2).normalize()))
            .collect(),
    ));
    soups.push((
        "grazing directions",
        (0..50)
            .map(|i| {
                let z = 1e-5 * (i as f32 - 25.0);
                ray(
                    g.vec(),
                    Vec3::new(1.0, (i % 7) as f32 * 1e-6, z).normalize(),
                )
            })
            .collect(),
    ));
    soups.push((
        "one origin, directions everywhere",
        (0..80).map(|_| ray(p, g.dir())).collect(),
    ));
    soups.push((
        "shadow segments from one light",
        (0..80)
            .map(|_| {
                let to = p + (d + g.vec() * 0.1) * 4.0;
                let mut r = ray_at(0, RayKind::Shadow, 0, p, (to - p).normalize());
                r.t_max = (to - p).length();
                r
            })
            .collect(),
    ));
    soups.push((
        "coherent reflections off a patch",
        (0..120)
            .map(|_| {
                let mut r = ray(
                    Vec3::new(g.unit(), g.unit(), 0.0) * 0.2,
                    (Vec3::new(0.3, 0.2, 1.0) + g.vec() * 0.02).normalize(),
                );
                r.t_min = 1e-4;
                r
            })
            .collect(),
    ));
    soups.push((
        "non-unit directions",
        (0..40)
            .map(|i| ray(g.vec(), (d + g.vec() * 0.1) * 10f32.powi(i % 7 - 3)))
            .collect(),
    ));
    soups.push((
        "anything",
        (0..300)
            .map(|i| {
                let mut r = ray(g.vec() * 20.0, g.dir() * (0.5 + g.unit().abs()));
                if i % 3 == 0 {
                    r.t_max = 5.0 * g.unit().abs();
                }
                r
            })
            .collect(),
    ));
    let frame = FrameSize::new(100, 37).unwrap();
    let mut total = Summary::default();
    let mut agree = Agreement::default();
    for (name, soup) in &soups {
        // One node: every ray in pixel 0.
        let order: Vec<u32> = (0..soup.len() as u32).collect();
        let what = format!("{name} (one node)");
        let sum = check_build(&b, &what, soup, &order, frame, 16, &mut agree);
        assert_eq!(sum.nodes, 1, "{name}");
        println!(
            "{name}: one node of {} rays, half-angle {}",
            soup.len(),
            if sum.full == 1 {
                "π".to_string()
            } else {
                format!("{:.3e}", sum.angle_sum)
            }
        );
        total.add(&sum);
        // Spread: random pixels (shadow rays over three lights), then tiles.
        let spread: Vec<Ray> = soup
            .iter()
            .map(|r| {
                let mut r = *r;
                r.pixel = g.below(100 * 37) as u32;
                if r.kind == RayKind::Shadow as u32 {
                    r.light = g.below(3) as u32;
                }
                r
            })
            .collect();
        for ts in [1, 8, 16, 32] {
            let order = tile_order(&spread, frame, ts);
            let what = format!("{name} (spread, tile {ts})");
            total.add(&check_build(
                &b, &what, &spread, &order, frame, ts, &mut agree,
            ));
            let generation: Vec<u32> = (0..spread.len() as u32).collect();
            let what = format!("{name} (spread, tile {ts}, generation order)");
            total.add(&check_build(
                &b,
                &what,
                &spread,
                &generation,
                frame,
                ts,
                &mut agree,
            ));
        }
    }
    println!("{total:?}");
    agree.report("random soups against the CPU twin");
    // Parallel rays with different origins get a narrow cone, not π: the apex moved back far
    // enough. (Parallel rays whose origins lie on one line along the direction get π on both
    // twins: at φ = 0 an origin ahead on the axis fails the inside test `x·c < cos φ·|c|` by
    // rounding, `perp_towards_axis` falls back to a fixed perpendicular (`|w| ≤ 1e-6·|c|`), and
    // the translation's `e·g` is then positive, so the node is flagged full; correct, only
    // wide.)
    for (name, soup) in &soups[..1] {
        let order: Vec<u32> = (0..soup.len() as u32).collect();
        let sum = check_build(&b, name, soup, &order, frame, 16, &mut agree);
        assert_eq!(sum.full, 0, "{name}: π");
        assert!(sum.angle_sum < 0.01, "{name}: {}", sum.angle_sum);
    }
}

/// One translation step of the spec (paper §4, fig. 3) in f32: the apex that makes the cone
/// `(a, x, φ)` hold the origin `o`, moving by `+e·t` (`paper = false`) or by the printed
/// `−e·t` (`paper = true`).
fn translate(a: Vec3, x: Vec3, cos_phi: f32, sin_phi: f32, o: Vec3, paper: bool) -> Vec3 {
    let c = o - a;
    let w = x * x.dot(c) - c;
    let q = w / w.length();
    let e = x * cos_phi + q * sin_phi;
    let n = x * cos_phi - q * sin_phi;
    let g = c - n * n.dot(c);
    let t = g.dot(g) / e.dot(g);
    if paper {
        a - e * t
    } else {
        a + e * t
    }
}

/// Erratum 1's evidence: translating a cone to hold an origin beside it by the paper's printed
/// `a − e·t` leaves the origin far outside (and the apex ahead of the cone), while `a + e·t`
/// holds it on the near generator; the device's two-ray node uses `+` (its apex is that step's,
/// and both rays are inside).
#[test]
fn the_paper_apex_update_fails_containment() {
    let (a, x) = (Vec3::ZERO, Vec3::Z);
    let phi = 0.1f32;
    let o = Vec3::new(1.0, 0.0, 0.0);
    let inside = |apex: Vec3, p: Vec3| angle64(x.as_dvec3(), (p - apex).as_dvec3());
    let fixed = translate(a, x, phi.cos(), phi.sin(), o, false);
    let paper = translate(a, x, phi.cos(), phi.sin(), o, true);
    // `+e·t`: the origin on the near generator, the old apex inside too.
    assert!((inside(fixed, o) - phi as f64).abs() < 1e-5, "{fixed}");
    assert!(inside(fixed, a) <= phi as f64 + 1e-6, "{fixed}");
    // `−e·t`: the origin (and the old apex) far outside.
    assert!(inside(paper, o) > 1.0, "{paper}: {}", inside(paper, o));
    assert!(inside(paper, a) > 1.0);

    let Some(b) = crsh_wgpu::testing::shared_backend("the_paper_apex_update_fails_containment")
    else {
        return;
    };
    // Two rays in one tile: the second tilted by 0.2 rad (step (a) opens the cone to 0.1 rad
    // about the bisector) and starting beside the first (step (b) translates it).
    let d1 = Vec3::new(0.0, 0.2f32.sin(), 0.2f32.cos());
    let rays = [
        ray_at(0, RayKind::Reflection, u32::MAX, a, x),
        ray_at(1, RayKind::Reflection, u32::MAX, o, d1),
    ];
    let frame = FrameSize::new(4, 4).unwrap();
    let order = [0u32, 1];
    let mut agree = Agreement::default();
    check_build(&b, "two rays", &rays, &order, frame, 4, &mut agree);
    agree.report("two rays");
    assert_eq!(agree.flipped, 0);
    let h = TileConeBuilder::with_params(frame, TileConeParams::new(4, 0.05).unwrap())
        .unwrap()
        .build(
            &b,
            &b.upload(&rays).unwrap(),
            b.upload(&order).unwrap(),
            &mut Stats::default(),
        )
        .unwrap();
    let node = b.download(&h.levels[0]).unwrap()[0];
    // The host step in f32 with the device's axis and opening (step (a)'s result).
    let axis = (x + d1).normalize();
    let (cos_phi, sin_phi) = (axis.dot(d1), (1.0 - axis.dot(d1).powi(2)).max(0.0).sqrt());
    let want = translate(a, axis, cos_phi, sin_phi, o, false);
    let literal = translate(a, axis, cos_phi, sin_phi, o, true);
    // (t = g²/(e·g) divides by about sin 2φ: the f32 steps agree to a few 1e-6 relative.)
    assert!(
        (node.sphere.center - want).length() < 1e-4 * want.length(),
        "device apex {} vs a + e·t {want}",
        node.sphere.center
    );
    assert!((node.cone.axis - axis).length() < 1e-6);
    let lit_angle = angle64(node.cone.axis.as_dvec3(), (o - literal).as_dvec3());
    assert!(
        lit_angle > 3.0 * node.cone.half_angle as f64,
        "the literal apex {literal} holds the origin ({lit_angle} rad)"
    );
}

/// Bad input is a clear error, never a panic: an order of the wrong length or with an entry
/// out of range, a pixel outside the frame, an invalid ray; an empty batch gives an empty
/// level with offsets `[0]`.
#[test]
fn tile_cone_rejects_bad_input() {
    let Some(b) = crsh_wgpu::testing::shared_backend("tile_cone_rejects_bad_input") else {
        return;
    };
    let frame = FrameSize::new(10, 10).unwrap();
    let builder =
        TileConeBuilder::with_params(frame, TileConeParams::new(4, 0.05).unwrap()).unwrap();
    let good: Vec<Ray> = (0..20)
        .map(|i| ray_at(i * 5, RayKind::Reflection, u32::MAX, Vec3::ZERO, Vec3::X))
        .collect();
    let run = |rays: &[Ray], order: &[u32]| {
        builder.build(
            &b,
            &b.upload(rays).unwrap(),
            b.upload(order).unwrap(),
            &mut Stats::default(),
        )
    };
    let order: Vec<u32> = (0..20).collect();
    assert!(run(&good, &order).is_ok());
    let expect_err = |r: crsh_core::Result<RayHierarchy<Wgpu>>, what: &str, word: &str| match r {
        Err(crsh_core::CoreError::InvalidInput(m)) => {
            assert!(m.contains(word), "{what}: {m}")
        }
        Err(e) => panic!("{what}: {e}"),
        Ok(_) => panic!("{what}: accepted"),
    };
    expect_err(run(&good, &order[..19]), "short order", "leaves");
    let mut o = order.clone();
    o[7] = 20;
    expect_err(run(&good, &o), "order out of range", "order entry");
    let mut r = good.clone();
    r[3].pixel = 100;
    expect_err(run(&r, &order), "pixel outside", "outside the 10x10 frame");
    let mut r = good.clone();
    r[5].dir = Vec3::ZERO;
    expect_err(run(&r, &order), "zero direction", "not valid");
    let mut r = good.clone();
    r[5].origin.x = f32::NAN;
    expect_err(run(&r, &order), "NaN origin", "not valid");
    let h = run(&[], &[]).unwrap();
    assert_eq!(h.levels.len(), 1);
    assert!(h.levels[0].is_empty());
    assert_eq!(
        b.download(h.leaf_offsets.as_ref().unwrap()).unwrap(),
        vec![0]
    );
}

/// An end-to-end frame on the wgpu backend of raster primaries, whitted, hash `tile`, sort
/// `radix`, hierarchy `tile_cone`, traverse `crsh` (no mesh culling) and intersect `brute`:
/// every ray's hit agrees with the CPU's brute force (exactly 1.0), and the image is the GPU
/// brute-force pipeline's, bit for bit; fewer ray-triangle tests than brute force.
#[test]
fn tile_cone_pipeline_agrees_with_brute_force() {
    let Some(b) = crsh_wgpu::testing::shared_backend("tile_cone_pipeline_agrees_with_brute_force")
    else {
        return;
    };
    let registry = Registry::<Wgpu>::builtin();
    let (w, h) = (40, 30);
    for name in ["cornell-mirrors", "office-boxes"] {
        let s = builtin(name);
        let g = GpuScene::new(&b, &s).unwrap();
        let ctx = StageContext::new(&b, &g, FrameSize::new(w, h).unwrap());
        let reference = HostIntersector::new(crsh_wgpu::testing::cpu_intersector(
            &StageSpec::new("brute"),
            &s,
        ));
        let opts = FrameOptions::new().with_max_depth(3);
        let brute_cfg = registry.preset("brute").unwrap();
        let brute = registry
            .build(&ctx, &brute_cfg)
            .unwrap()
            .render(&b, &opts, None, &mut |_| {})
            .unwrap();
        let brute_image = b.download(&brute.image).unwrap();
        for ts in [16, 8] {
            // The `tile_cone` preset (tile, radix, tile_cone, crsh without mesh culling, brute),
            // with the tile size of both stages set.
            let mut cfg = registry.preset("tile_cone").expect("tile_cone preset");
            for set in [
                format!("hash.tile_size={ts}"),
                format!("hierarchy.tile_size={ts}"),
            ] {
                cfg.set(&set).unwrap();
            }
            registry.resolve(&mut cfg).unwrap();
            let what = format!("{name} tile {ts}");
            let f = registry
                .build(&ctx, &cfg)
                .unwrap_or_else(|e| panic!("{what}: {e}"))
                .render(&b, &opts, Some(&reference), &mut |_| {})
                .unwrap_or_else(|e| panic!("{what}: {e}"));
            let st = &f.stats;
            assert_eq!(st.stages["hash"], "tile");
            assert_eq!(st.stages["hierarchy"], "tile_cone");
            let acc = st.accuracy.clone().expect("reference given");
            assert!(acc.rays > 0, "{what}: nothing compared");
            assert_eq!(acc.hit_agreement(), 1.0, "{what}: {acc:?}");
            let image = b.download(&f.image).unwrap();
            assert!(
                image == brute_image,
                "{what}: image differs from brute force's"
            );
            println!(
                "{what}: {} traced rays, ray-triangle tests {} (brute force {}), bounds {}",
                st.traced_rays, st.tests.ray_triangle, st.tests.brute_force, st.tests.bounds
            );
            assert!(st.tests.ray_triangle < st.tests.brute_force, "{what}");
        }
    }
}
