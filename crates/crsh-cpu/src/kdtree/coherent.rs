//! The coherent kd-tree traversals of seed 003 (§2.3, §4.1) behind one entry point,
//! [`trace_batch`]: rays that share an origin (camera rays from the eye, shadow rays from a
//! point light) are grouped by screen tile ([`super::group`]) and traced together; rays that
//! share their origin with no other ray of their tile (reflection, refraction, area-light
//! samples) are traced one by one ([`super::trace_single`]).
//!
//! | [`Traversal`] | unit | listing |
//! |---|---|---|
//! | `single` | one ray | 2.2 (fixed), every ray on its own |
//! | `packet` | 2×2 packet, sign-coherent sub-packets | 2.4 (fixed) |
//! | `omni` | 2×2 packet, any directions | 4.1 |
//! | `frustum` | one pyramid per tile | 4.2 (+ packet/leaf culling, §4.1.4) |
//! | `mft` | four quadrant frusta per tile | §4.1.5 |
//! | `cone` | one cone per tile | 4.3-4.5 (eq. 4.8) |
//!
//! All of them return brute force's hits bit for bit (the exactness rule of [`super`]). The
//! counters are the paper's ([`PacketCounts`]): `N` = nodes entered by the traversal units
//! per 2×2 packet, `I` = packet-triangle tests per packet, and the packet-leaf tests that
//! packet/leaf culling avoided.
//!
//! Groups are traced in parallel (rayon), each on its own; hits and counts do not depend on
//! the thread count.

use rayon::prelude::*;

use crsh_core::{Hit, HitMode, PacketStats, Ray, RayKind, Stats};

use super::group::{group_rays, Group, GroupState};
use super::mft::Shape;
use super::{cone, frustum, mft, omni, packet, trace_single, Entry, KdCounts, KdTree};
use crate::triangle::TriangleTest;

/// A coherent traversal (module doc).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Traversal {
    /// Each ray alone (listing 2.2, fixed).
    Single,
    /// 2×2 packets with sign-coherent sub-packets (listing 2.4, fixed).
    Packet,
    /// Omni-directional 2×2 packets (listing 4.1).
    Omni,
    /// One frustum per tile (listing 4.2).
    Frustum,
    /// Four quadrant frusta per tile traced together (§4.1.5).
    Mft,
    /// One cone per tile (listings 4.3-4.5).
    Cone,
}

impl Traversal {
    /// Every traversal, in the order of the module doc.
    pub const ALL: [Traversal; 6] = [
        Traversal::Single,
        Traversal::Packet,
        Traversal::Omni,
        Traversal::Frustum,
        Traversal::Mft,
        Traversal::Cone,
    ];

    /// The traversal's name (`single`, `packet`, `omni`, `frustum`, `mft`, `cone`).
    pub fn name(self) -> &'static str {
        match self {
            Traversal::Single => "single",
            Traversal::Packet => "packet",
            Traversal::Omni => "omni",
            Traversal::Frustum => "frustum",
            Traversal::Mft => "mft",
            Traversal::Cone => "cone",
        }
    }

    /// The traversal named `name`.
    pub fn from_name(name: &str) -> Option<Traversal> {
        Traversal::ALL.into_iter().find(|t| t.name() == name)
    }

    /// Whether the traversal traces a whole tile as one unit (frustum, MFT, cone), so that
    /// the tile size and packet/leaf culling matter.
    pub fn uses_tiles(self) -> bool {
        matches!(self, Traversal::Frustum | Traversal::Mft | Traversal::Cone)
    }
}

/// Options of [`trace_batch`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct CoherentOptions {
    /// The traversal.
    pub traversal: Traversal,
    /// Tile side in pixels (the paper's 4, 8, 16, 32; [`CoherentOptions::validate`]): the
    /// rays a frustum, MFT group or cone bounds. Packets are 2×2 whatever the tile.
    pub tile_size: u32,
    /// Packet/leaf culling (§4.1.4) for the tile traversals: skip a packet at a leaf when
    /// all its rays miss the leaf's cell.
    pub leaf_culling: bool,
    /// Image width: [`Ray::pixel`] is `y · width + x`.
    pub width: u32,
}

impl CoherentOptions {
    /// Smallest tile side.
    pub const MIN_TILE: u32 = 2;
    /// Largest tile side.
    pub const MAX_TILE: u32 = 256;

    /// Options for `traversal` on an image `width` pixels wide, with 8×8 tiles and packet/leaf
    /// culling (the paper's best single-frustum setting, tables 4.1-4.2).
    pub fn new(traversal: Traversal, width: u32) -> CoherentOptions {
        CoherentOptions {
            traversal,
            tile_size: 8,
            leaf_culling: true,
            width,
        }
    }

    /// Checks the options: an even tile size in `MIN_TILE..=MAX_TILE`, a non-zero width.
    /// ([`trace_batch`] itself takes a zero width as 1 and rounds an odd tile size up.)
    pub fn validate(&self) -> Result<(), String> {
        if self.width == 0 {
            return Err("image width is 0".into());
        }
        if !(Self::MIN_TILE..=Self::MAX_TILE).contains(&self.tile_size) || self.tile_size & 1 == 1 {
            return Err(format!(
                "tile size {} is not an even number in {}..={}",
                self.tile_size,
                Self::MIN_TILE,
                Self::MAX_TILE
            ));
        }
        Ok(())
    }
}

/// The paper's packet metrics for one batch (tables 4.1-4.5; [`PacketStats`] in
/// [`Stats::packets`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct PacketCounts {
    /// 2×2 packets traced (for `single`, and for rays traced singly, each ray is a packet).
    pub packets: u64,
    /// Nodes (inner and leaf) entered by the traversal units: ray, packet (sub-packets of a
    /// split quad each count), frustum, MFT group or cone.
    pub nodes: u64,
    /// Packet-triangle tests (one per packet and triangle; for a single ray, its tests).
    pub packet_tests: u64,
    /// Packet-triangle tests avoided by packet/leaf culling.
    pub culled_tests: u64,
    /// Groups traced coherently.
    pub groups: u64,
    /// Rays traced singly.
    pub single_rays: u64,
}

impl PacketCounts {
    /// The sum of two counts.
    pub fn plus(self, o: PacketCounts) -> PacketCounts {
        let mut s = self.stats();
        s.add(&o.stats());
        PacketCounts::from(s)
    }

    /// The counts as [`PacketStats`].
    pub fn stats(&self) -> PacketStats {
        PacketStats {
            packets: self.packets,
            nodes: self.nodes,
            packet_tests: self.packet_tests,
            culled_tests: self.culled_tests,
            groups: self.groups,
            single_rays: self.single_rays,
        }
    }

    /// Adds these counts to `stats.packets[kind]`.
    pub fn record(&self, kind: RayKind, stats: &mut Stats) {
        stats.add_packets(kind, &self.stats());
    }

    /// `N`: nodes per packet.
    pub fn nodes_per_packet(&self) -> f64 {
        self.stats().nodes_per_packet()
    }

    /// `I`: packet-triangle tests per packet.
    pub fn tests_per_packet(&self) -> f64 {
        self.stats().tests_per_packet()
    }

    /// Culled packet-leaf tests over culled plus done ones.
    pub fn culled_fraction(&self) -> f64 {
        self.stats().culled_fraction()
    }
}

impl From<PacketStats> for PacketCounts {
    fn from(s: PacketStats) -> PacketCounts {
        PacketCounts {
            packets: s.packets,
            nodes: s.nodes,
            packet_tests: s.packet_tests,
            culled_tests: s.culled_tests,
            groups: s.groups,
            single_rays: s.single_rays,
        }
    }
}

/// Traces `rays` through `tree` (triangles `tris`, test `T`) with `opts.traversal`, merging
/// into `hits` (indexed like `rays`) as [`trace_single`] does: any hit skips rays that already
/// have a hit; closest hit keeps the closer of the old and new hit. Returns the node and
/// ray-triangle counts ([`KdCounts`]: the traversal units' inner nodes and leaves, and one
/// ray-triangle test per ray in a packet test) and the paper's packet metrics. MFT uses pyramid
/// frusta; [`trace_batch_shaped`] chooses cones.
///
/// # Panics
/// If `hits` and `rays` differ in length.
pub fn trace_batch<T: TriangleTest>(
    tree: &KdTree,
    tris: &[T::Tri],
    rays: &[Ray],
    mode: HitMode,
    hits: &mut [Hit],
    opts: &CoherentOptions,
) -> (KdCounts, PacketCounts) {
    trace_batch_shaped::<T>(tree, tris, rays, mode, hits, opts, Shape::Pyramid)
}

/// [`trace_batch`] with the shape of MFT's quadrant proxies: [`Shape::Cone`] gives table
/// 4.5's "MFT cone".
pub fn trace_batch_shaped<T: TriangleTest>(
    tree: &KdTree,
    tris: &[T::Tri],
    rays: &[Ray],
    mode: HitMode,
    hits: &mut [Hit],
    opts: &CoherentOptions,
    mft_shape: Shape,
) -> (KdCounts, PacketCounts) {
    assert_eq!(rays.len(), hits.len(), "one hit per ray");
    let (groups, singles) = if opts.traversal == Traversal::Single {
        (Vec::new(), (0..rays.len() as u32).collect())
    } else {
        let g = group_rays(rays, opts.width, opts.tile_size);
        (g.groups, g.singles)
    };
    let seen: &[Hit] = hits;
    let single_out: Vec<Traced> = singles
        .par_chunks(256)
        .map_init(Vec::new, |stack, chunk| {
            let mut out = Vec::with_capacity(chunk.len());
            let (mut kd, mut pc) = (KdCounts::default(), PacketCounts::default());
            for &i in chunk {
                let mut best = seen[i as usize];
                let n = trace_single::<T>(tree, tris, &rays[i as usize], mode, &mut best, stack);
                kd = kd.plus(n);
                pc.packets += 1;
                pc.single_rays += 1;
                pc.nodes += n.inner + n.leaves;
                pc.packet_tests += n.tests;
                out.push((i, best));
            }
            (out, kd, pc)
        })
        .collect();
    let group_out: Vec<Traced> = groups
        .par_iter()
        .map_init(Stacks::default, |stacks, g| {
            trace_group::<T>(tree, tris, rays, seen, mode, g, opts, mft_shape, stacks)
        })
        .collect();
    let (mut kd, mut pc) = (KdCounts::default(), PacketCounts::default());
    for (out, k, p) in single_out.into_iter().chain(group_out) {
        kd = kd.plus(k);
        pc = pc.plus(p);
        for (i, h) in out {
            hits[i as usize] = h;
        }
    }
    (kd, pc)
}

/// What one chunk of singles or one group returns: `(batch index, hit)` per ray, and counts.
type Traced = (Vec<(u32, Hit)>, KdCounts, PacketCounts);

/// Scratch stacks of the traversals, one set per worker.
#[derive(Default)]
struct Stacks {
    scalar: Vec<Entry>,
    packet: Vec<packet::PacketEntry>,
    mft: Vec<mft::MftEntry>,
}

#[allow(clippy::too_many_arguments)]
fn trace_group<T: TriangleTest>(
    tree: &KdTree,
    tris: &[T::Tri],
    rays: &[Ray],
    hits: &[Hit],
    mode: HitMode,
    g: &Group,
    opts: &CoherentOptions,
    mft_shape: Shape,
    stacks: &mut Stacks,
) -> Traced {
    let mut st = GroupState::<T>::new(tree, tris, mode, rays, hits, g);
    let cull = opts.leaf_culling;
    if !st.all_done() {
        match opts.traversal {
            // Single never groups; kept total for the match.
            Traversal::Single | Traversal::Packet => {
                packet::trace_group(&mut st, &mut stacks.packet)
            }
            Traversal::Omni => omni::trace_group(&mut st, &mut stacks.packet),
            Traversal::Frustum => frustum::trace_group(&mut st, cull, &mut stacks.scalar),
            Traversal::Mft => mft::trace_group(&mut st, mft_shape, cull, &mut stacks.mft),
            Traversal::Cone => cone::trace_group(&mut st, cull, &mut stacks.scalar),
        }
    }
    (st.results(g), st.kd, st.pc)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::kdtree::{middle, KdLeaf, KdNode, LEAF};
    use crate::primary::raycast::camera_ray;
    use crate::triangle::tests::TestRng;
    use crate::triangle::{MollerTrumbore, Projected, TriangleSet};
    use crsh_core::glam::{DVec3, Vec3};
    use crsh_core::Aabb;
    use crsh_scene::Scene;

    const TILES: [u32; 4] = [4, 8, 16, 32];

    struct Fixture<T: TriangleTest> {
        scene: Scene,
        set: TriangleSet<T>,
        tree: KdTree,
    }

    fn fixture<T: TriangleTest>(name: &str) -> Fixture<T> {
        let scene = crsh_scene::builtin::build(name).unwrap();
        let set = TriangleSet::<T>::new(&scene);
        let input: Vec<(u32, [Vec3; 3])> = (0..scene.triangle_count())
            .filter(|&t| !T::is_degenerate(&set.triangles()[t]))
            .map(|t| (t as u32, scene.triangle(t)))
            .collect();
        let tree = middle::build(&input, 22, 6);
        tree.validate().unwrap();
        Fixture { scene, set, tree }
    }

    fn ray(origin: Vec3, dir: Vec3, t_max: f32, kind: RayKind, pixel: u32, light: u32) -> Ray {
        Ray {
            pixel,
            light,
            depth: 0,
            source: pixel,
            ..Ray::new(kind, origin, dir, 0.0, t_max)
        }
    }

    fn camera_rays(scene: &Scene, w: u32, h: u32) -> Vec<Ray> {
        (0..w * h)
            .map(|p| {
                let (o, d) = camera_ray(&scene.camera, p % w, p / w, w, h);
                ray(o, d, f32::INFINITY, RayKind::Primary, p, u32::MAX)
            })
            .collect()
    }

    /// Brute force's closest hits.
    fn brute<T: TriangleTest>(tris: &[T::Tri], rays: &[Ray]) -> Vec<Hit> {
        rays.par_iter()
            .map(|r| {
                let rr = T::ray_of(r);
                let mut best = Hit::MISS;
                for (i, t) in tris.iter().enumerate() {
                    if let Some(h) = T::hit(t, &rr, r.t_min, r.t_max, i as u32) {
                        if h.closer_than(&best) {
                            best = h;
                        }
                    }
                }
                best
            })
            .collect()
    }

    /// Shadow rays from light 0 to the surface points of the camera hits (origin = light).
    fn shadow_rays(scene: &Scene, cam: &[Ray], hits: &[Hit]) -> Vec<Ray> {
        let l = scene.lights[0].position;
        cam.iter()
            .zip(hits)
            .filter(|(_, h)| h.is_hit())
            .map(|(r, h)| {
                let d = r.at(h.t) - l;
                let len = d.length();
                ray(l, d / len, len * (1.0 - 1e-3), RayKind::Shadow, r.pixel, 0)
            })
            .collect()
    }

    /// Traces `rays` with `opts` in both modes and checks them against brute force's `want`.
    fn check<T: TriangleTest>(
        fx: &Fixture<T>,
        rays: &[Ray],
        want: &[Hit],
        mode: HitMode,
        opts: &CoherentOptions,
        shape: Shape,
    ) -> (KdCounts, PacketCounts) {
        let mut hits = vec![Hit::MISS; rays.len()];
        let out = trace_batch_shaped::<T>(
            &fx.tree,
            fx.set.triangles(),
            rays,
            mode,
            &mut hits,
            opts,
            shape,
        );
        for (i, (g, w)) in hits.iter().zip(want).enumerate() {
            match mode {
                HitMode::Any => assert_eq!(
                    g.is_hit(),
                    w.is_hit(),
                    "{} ray {i} {opts:?} {shape:?}",
                    fx.scene.name
                ),
                _ => assert_eq!(g, w, "{} ray {i} {opts:?} {shape:?}", fx.scene.name),
            }
        }
        out
    }

    fn all_options(width: u32) -> Vec<(CoherentOptions, Shape)> {
        let mut v = Vec::new();
        for t in Traversal::ALL {
            if t.uses_tiles() {
                for tile_size in TILES {
                    for leaf_culling in [false, true] {
                        let o = CoherentOptions {
                            traversal: t,
                            tile_size,
                            leaf_culling,
                            width,
                        };
                        v.push((o, Shape::Pyramid));
                        if t == Traversal::Mft {
                            v.push((o, Shape::Cone));
                        }
                    }
                }
            } else {
                v.push((CoherentOptions::new(t, width), Shape::Pyramid));
            }
        }
        v
    }

    fn exact_on<T: TriangleTest>(name: &str, w: u32, h: u32) {
        let fx = fixture::<T>(name);
        let cam = camera_rays(&fx.scene, w, h);
        let cam_want = brute::<T>(fx.set.triangles(), &cam);
        assert!(cam_want.iter().filter(|h| h.is_hit()).count() > cam.len() / 2);
        let sh = shadow_rays(&fx.scene, &cam, &cam_want);
        let sh_want = brute::<T>(fx.set.triangles(), &sh);
        let blocked = sh_want.iter().filter(|h| h.is_hit()).count();
        assert!(
            blocked > 0 && blocked < sh.len(),
            "{name}: {blocked} of {}",
            sh.len()
        );
        for (opts, shape) in all_options(w) {
            let (_, pc) = check(&fx, &cam, &cam_want, HitMode::Closest, &opts, shape);
            if opts.traversal != Traversal::Single {
                assert_eq!(pc.single_rays, 0, "{opts:?}");
            }
            check(&fx, &sh, &sh_want, HitMode::Closest, &opts, shape);
            check(&fx, &sh, &sh_want, HitMode::Any, &opts, shape);
        }
    }

    #[test]
    fn every_traversal_equals_brute_force_on_cornell_mirrors() {
        // Odd sizes: partial tiles and partial quads at the borders.
        exact_on::<MollerTrumbore>("cornell-mirrors", 50, 37);
    }

    #[test]
    fn every_traversal_equals_brute_force_on_glass_shell() {
        exact_on::<MollerTrumbore>("glass-shell-1000", 48, 40);
    }

    #[test]
    fn every_traversal_equals_brute_force_on_office_boxes_with_the_projected_test() {
        exact_on::<Projected>("office-boxes", 44, 34);
    }

    #[test]
    fn results_do_not_depend_on_the_thread_count() {
        let fx = fixture::<MollerTrumbore>("office-boxes");
        let (w, h) = (40, 30);
        let mut rays = camera_rays(&fx.scene, w, h);
        let want = brute::<MollerTrumbore>(fx.set.triangles(), &rays);
        rays.extend(shadow_rays(&fx.scene, &rays.clone(), &want));
        let run = |threads: usize, opts: &CoherentOptions| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            pool.install(|| {
                let mut hits = vec![Hit::MISS; rays.len()];
                let c = trace_batch::<MollerTrumbore>(
                    &fx.tree,
                    fx.set.triangles(),
                    &rays,
                    HitMode::Closest,
                    &mut hits,
                    opts,
                );
                (hits, c)
            })
        };
        for t in Traversal::ALL {
            let opts = CoherentOptions::new(t, w);
            let one = run(1, &opts);
            assert_eq!(one, run(3, &opts), "{t:?}");
            // Two groups per tile (camera and shadow rays).
            if t.uses_tiles() {
                assert!(one.1 .1.groups >= 2 * 20, "{:?}", one.1);
            }
        }
    }

    #[test]
    fn rays_without_a_shared_origin_are_traced_singly_and_exactly() {
        let fx = fixture::<MollerTrumbore>("cornell-mirrors");
        let (w, h) = (24, 16);
        let mut rays = camera_rays(&fx.scene, w, h);
        let cam = brute::<MollerTrumbore>(fx.set.triangles(), &rays);
        // Mirror-like rays from each camera hit: no two share an origin.
        let mut rng = TestRng(9);
        let refl: Vec<Ray> = rays
            .iter()
            .zip(&cam)
            .filter(|(_, h)| h.is_hit())
            .map(|(r, h)| {
                let mut s = ray(
                    r.at(h.t * 0.999),
                    rng.unit(),
                    f32::INFINITY,
                    RayKind::Reflection,
                    r.pixel,
                    u32::MAX,
                );
                s.depth = 1;
                s
            })
            .collect();
        let n_refl = refl.len() as u64;
        rays.extend(refl);
        // Interleave so that the singles are scattered through the batch.
        rays.reverse();
        let want = brute::<MollerTrumbore>(fx.set.triangles(), &rays);
        for t in Traversal::ALL {
            let opts = CoherentOptions::new(t, w);
            let (kd, pc) = check(&fx, &rays, &want, HitMode::Closest, &opts, Shape::Pyramid);
            let singles = if t == Traversal::Single {
                rays.len() as u64
            } else {
                n_refl
            };
            assert_eq!(pc.single_rays, singles, "{t:?}");
            assert!(kd.tests > 0);
        }
    }

    /// Listing 2.4 reads `dir[0]` where it means the ray's own component on the node's axis,
    /// and orders children by the first ray's sign: a packet whose rays point into different
    /// octants must still be exact (it is split into sign-coherent sub-packets).
    #[test]
    fn listing_2_4_packets_with_mixed_direction_signs_are_exact() {
        let fx = fixture::<MollerTrumbore>("cornell-mirrors");
        let centre = fx.scene.bounds.center();
        let mut rng = TestRng(21);
        let w = 16;
        let mut rays = Vec::new();
        // One origin per 2×2 quad (so each quad is its own group), four random directions.
        for q in 0..64u32 {
            let o = centre + rng.vec3(-0.2, 0.2);
            let (qx, qy) = (q % 8, q / 8);
            for l in 0..4 {
                let px = (qy * 2 + l / 2) * w + qx * 2 + l % 2;
                rays.push(ray(
                    o,
                    rng.unit(),
                    f32::INFINITY,
                    RayKind::Primary,
                    px,
                    u32::MAX,
                ));
            }
        }
        let mixed = rays
            .chunks(4)
            .filter(|c| {
                c.iter()
                    .any(|r| packet::signs(r.dir) != packet::signs(c[0].dir))
            })
            .count();
        assert!(mixed > 50, "{mixed}");
        let want = brute::<MollerTrumbore>(fx.set.triangles(), &rays);
        for t in Traversal::ALL {
            let opts = CoherentOptions::new(t, w);
            let (_, pc) = check(&fx, &rays, &want, HitMode::Closest, &opts, Shape::Pyramid);
            assert_eq!(pc.packets, if t == Traversal::Single { 256 } else { 64 });
            check(&fx, &rays, &want, HitMode::Any, &opts, Shape::Pyramid);
        }
    }

    /// Two leaves split at `x = 0`, a wall in each (`x = ±0.5`), rays from `x = ±0.9` towards
    /// the other side: the first leaf visited must be the origin's. From `x = 0` (on the
    /// plane) each ray must go on where it points. Listing 4.1's child
    /// convention (front = `node.left + (dist < 0 ? 0 : 1)`) is listing 2.1's the wrong way
    /// round, and listing 4.5 picks front and back from an undefined `dist`; either mistake
    /// visits the far wall first, finds its hit final in that cell, and returns it.
    #[test]
    fn listing_4_1_child_convention_is_fixed() {
        let wall = |x: f32| {
            [
                [
                    Vec3::new(x, -0.9, -0.9),
                    Vec3::new(x, 0.9, -0.9),
                    Vec3::new(x, 0.9, 0.9),
                ],
                [
                    Vec3::new(x, -0.9, -0.9),
                    Vec3::new(x, 0.9, 0.9),
                    Vec3::new(x, -0.9, 0.9),
                ],
            ]
        };
        let soup: Vec<[Vec3; 3]> = wall(-0.5).into_iter().chain(wall(0.5)).collect();
        let set = TriangleSet::<MollerTrumbore>::from_triangles(soup.iter().copied());
        let bounds = Aabb {
            min: Vec3::new(-1.0, -1.0, -1.0),
            max: Vec3::new(1.0, 1.0, 1.0),
        };
        let tree = KdTree {
            nodes: vec![
                KdNode {
                    split: 0.0,
                    axis: 0,
                    index: 1,
                },
                KdNode {
                    split: 0.0,
                    axis: LEAF,
                    index: 0,
                },
                KdNode {
                    split: 0.0,
                    axis: LEAF,
                    index: 1,
                },
            ],
            leaves: vec![
                KdLeaf {
                    min: [-1.0; 3],
                    start: 0,
                    max: [0.0, 1.0, 1.0],
                    count: 2,
                },
                KdLeaf {
                    min: [0.0, -1.0, -1.0],
                    start: 2,
                    max: [1.0; 3],
                    count: 2,
                },
            ],
            leaf_tris: vec![0, 1, 2, 3],
            bounds,
            depth: 1,
        };
        tree.validate().unwrap();
        let fx = Fixture {
            scene: Scene {
                name: "two walls".into(),
                ..crsh_scene::builtin::build("cornell-mirrors").unwrap()
            },
            set,
            tree,
        };
        // Side 0: the origin on the split plane, rays going both ways (and one along it).
        for side in [1.0f32, -1.0, 0.0] {
            let o = Vec3::new(0.9 * side, 0.0, 0.0);
            let w = 8;
            let rays: Vec<Ray> = (0..16u32)
                .map(|p| {
                    let (x, y) = ((p % 4) as f32, (p / 4) as f32);
                    let dx = if side == 0.0 {
                        [1.0, -1.0, 0.0][(p % 3) as usize]
                    } else {
                        -side
                    };
                    let d = Vec3::new(dx, (x - 1.5) * 0.1, (y - 1.5) * 0.1).normalize();
                    let px = (p / 4) * w + p % 4;
                    ray(o, d, f32::INFINITY, RayKind::Primary, px, 0)
                })
                .collect();
            let want = brute::<MollerTrumbore>(fx.set.triangles(), &rays);
            // The near wall: triangles 2, 3 (x = 0.5) from x = +0.9, 0, 1 (x = -0.5) from
            // x = -0.9; from x = 0 the wall the ray points to (none along the plane).
            for (r, h) in rays.iter().zip(&want) {
                if r.dir.x == 0.0 {
                    assert!(!h.is_hit());
                } else {
                    assert_eq!(
                        h.tri >= 2,
                        if side == 0.0 {
                            r.dir.x > 0.0
                        } else {
                            side > 0.0
                        }
                    );
                    let gap = if side == 0.0 { 0.5 } else { 0.4 };
                    assert!((h.t * r.dir.x.abs() - gap).abs() < 1e-4, "{h:?}");
                }
            }
            for (opts, shape) in all_options(w) {
                check(&fx, &rays, &want, HitMode::Closest, &opts, shape);
            }
        }
    }

    /// Eq. 4.8 needs a unit axis (eq. 4.7 erratum): for random cones, given by an axis of
    /// arbitrary length, every crossing of a ray inside the cone with a split plane lies in the
    /// cone's crossing range (in `h`, the distance along the axis); the same formula on the
    /// unnormalised axis misses some.
    #[test]
    fn cone_crossings_enclose_the_rays_for_axes_of_any_length() {
        let mut rng = TestRng(4);
        let (mut checked, mut raw_misses) = (0, 0);
        for _ in 0..400 {
            let v = rng.unit().as_dvec3();
            let scale = [0.25, 0.7, 1.0, 3.0][(rng.next_u64() % 4) as usize];
            let tan_alpha = rng.range(0.005, 1.2) as f64;
            let proxy = cone::Cone::proxy(v * scale, tan_alpha);
            let raw = raw_eq_4_8(v * scale, tan_alpha);
            for _ in 0..20 {
                // A direction within the cone.
                let w = v.cross(rng.unit().as_dvec3()).normalize();
                let theta = tan_alpha.atan() * rng.f32() as f64;
                let d = (v * theta.cos() + w * theta.sin()).as_vec3();
                let k = (rng.next_u64() % 3) as usize;
                let dist = rng.range(-3.0, 3.0);
                if dist == 0.0 {
                    continue;
                }
                let t = dist / d[k];
                if !(t > 0.0 && t.is_finite()) {
                    continue;
                }
                let h = t as f64 * d.as_dvec3().dot(v);
                let (lo, hi) = proxy.crossings(k, dist);
                let (lo, hi) = (frustum::widen_lo(lo) as f64, frustum::widen_hi(hi) as f64);
                assert!(lo <= h && h <= hi, "{h} outside {lo}..{hi}");
                checked += 1;
                let (rlo, rhi) = raw.crossings(k, dist);
                if !(rlo as f64 <= h && h <= rhi as f64) {
                    raw_misses += 1;
                }
            }
        }
        assert!(checked > 3000, "{checked}");
        assert!(raw_misses > 100, "{raw_misses}");
    }

    /// Listings 4.4-4.5 taken literally on a possibly non-unit axis.
    fn raw_eq_4_8(v: DVec3, tan_alpha: f64) -> frustum::Proxy {
        let mut m = [[[0.0f32; 2]; 2]; 3];
        for k in 0..3 {
            let beta = tan_alpha * (1.0 - v[k] * v[k]).max(0.0).sqrt();
            let p = [1.0 / (beta + v[k]), 1.0 / (-beta + v[k])];
            // t1 = min, t2 = max of the two compensated products, for either sign of dist.
            for (s, ms) in m[k].iter_mut().enumerate() {
                let dist = if s == 0 { 1.0 } else { -1.0 };
                let c = p.map(|x| {
                    let y = dist * x;
                    if y < 0.0 {
                        f64::INFINITY
                    } else {
                        y
                    }
                });
                let (t1, t2) = (c[0].min(c[1]), c[0].max(c[1]));
                *ms = [(t1 * dist) as f32, (t2 * dist) as f32];
            }
        }
        frustum::Proxy { m }
    }

    /// Counts of the camera rays of `name` at `w × h` for `opts` (checked exact).
    fn counts(
        fx: &Fixture<MollerTrumbore>,
        cam: &[Ray],
        want: &[Hit],
        opts: CoherentOptions,
        shape: Shape,
    ) -> PacketCounts {
        check(fx, cam, want, HitMode::Closest, &opts, shape).1
    }

    #[test]
    fn metrics_hold_what_they_hold_by_construction() {
        for name in ["cornell-mirrors", "office-boxes"] {
            let fx = fixture::<MollerTrumbore>(name);
            let (w, h) = (48, 48);
            let cam = camera_rays(&fx.scene, w, h);
            let want = brute::<MollerTrumbore>(fx.set.triangles(), &cam);
            let sh = shadow_rays(&fx.scene, &cam, &want);
            let sh_want = brute::<MollerTrumbore>(fx.set.triangles(), &sh);
            let o = |traversal, tile_size, leaf_culling| CoherentOptions {
                traversal,
                tile_size,
                leaf_culling,
                width: w,
            };
            for (rays, want) in [(&cam, &want), (&sh, &sh_want)] {
                let single = counts(
                    &fx,
                    rays,
                    want,
                    o(Traversal::Single, 8, true),
                    Shape::Pyramid,
                );
                assert_eq!(single.packets, rays.len() as u64);
                let pk = counts(
                    &fx,
                    rays,
                    want,
                    o(Traversal::Packet, 8, true),
                    Shape::Pyramid,
                );
                let omni = counts(&fx, rays, want, o(Traversal::Omni, 8, true), Shape::Pyramid);
                // Packets share the nodes their rays have in common.
                assert!(pk.nodes < single.nodes, "{name}: {pk:?} {single:?}");
                // Omni never splits a quad.
                assert!(omni.nodes <= pk.nodes, "{name}: {omni:?} {pk:?}");
                assert_eq!(pk.packets, omni.packets);
                for tile in [4, 8, 16] {
                    for t in [Traversal::Frustum, Traversal::Mft, Traversal::Cone] {
                        let off = counts(&fx, rays, want, o(t, tile, false), Shape::Pyramid);
                        let on = counts(&fx, rays, want, o(t, tile, true), Shape::Pyramid);
                        // Culling only skips tests. (Nodes may differ either way: a packet
                        // tested in a cell its rays miss can find their hits sooner, and the
                        // cells past a group's hits are skipped.)
                        assert!(on.packet_tests <= off.packet_tests, "{name} {t:?} {tile}");
                        assert_eq!(off.culled_tests, 0);
                        assert_eq!(on.packets, pk.packets);
                    }
                    for cull in [false, true] {
                        let fr = counts(
                            &fx,
                            rays,
                            want,
                            o(Traversal::Frustum, tile, cull),
                            Shape::Pyramid,
                        );
                        let mft = counts(
                            &fx,
                            rays,
                            want,
                            o(Traversal::Mft, tile, cull),
                            Shape::Pyramid,
                        );
                        assert!(
                            mft.packet_tests <= fr.packet_tests,
                            "{name} {tile} {mft:?} {fr:?}"
                        );
                        assert!(mft.nodes <= fr.nodes, "{name} {tile} {mft:?} {fr:?}");
                    }
                }
            }
            // A tile's frustum visits fewer nodes per packet than 2×2 packets do (table 4.1:
            // 4.17 against 33.81 on Sponza at 512²; the gap grows with the resolution).
            let pk = counts(
                &fx,
                &cam,
                &want,
                o(Traversal::Packet, 8, true),
                Shape::Pyramid,
            );
            let fr = counts(
                &fx,
                &cam,
                &want,
                o(Traversal::Frustum, 8, true),
                Shape::Pyramid,
            );
            assert!(
                fr.nodes_per_packet() < pk.nodes_per_packet(),
                "{name}: {fr:?} {pk:?}"
            );
            // Culling removes a real share of the frustum's packet-leaf tests.
            assert!(fr.culled_fraction() > 0.2, "{name}: {fr:?}");
        }
    }

    #[test]
    fn names_round_trip_and_options_validate() {
        for t in Traversal::ALL {
            assert_eq!(Traversal::from_name(t.name()), Some(t));
        }
        assert_eq!(Traversal::from_name("beam"), None);
        let mut o = CoherentOptions::new(Traversal::Mft, 64);
        assert!(o.validate().is_ok());
        o.tile_size = 7;
        assert!(o.validate().is_err());
        o.tile_size = 512;
        assert!(o.validate().is_err());
        o.tile_size = 16;
        o.width = 0;
        assert!(o.validate().is_err());
        let mut s = Stats::default();
        let pc = PacketCounts {
            packets: 2,
            nodes: 8,
            packet_tests: 3,
            culled_tests: 1,
            groups: 1,
            single_rays: 0,
        };
        pc.record(RayKind::Shadow, &mut s);
        pc.plus(pc).record(RayKind::Shadow, &mut s);
        assert_eq!(s.packets["shadow"].nodes, 24);
        assert_eq!(pc.nodes_per_packet(), 4.0);
    }

    /// The N / I / culling table of the camera and shadow rays of a built-in scene, for the
    /// report (`cargo test -p crsh-cpu --release --lib print_packet_tables -- --ignored
    /// --nocapture`; `CRSH_SCENE`, `CRSH_SIZE` override the scene and image side).
    #[test]
    #[ignore]
    fn print_packet_tables() {
        let name = std::env::var("CRSH_SCENE").unwrap_or_else(|_| "office-boxes".into());
        let side: u32 = std::env::var("CRSH_SIZE")
            .ok()
            .and_then(|s| s.parse().ok())
            .unwrap_or(256);
        let fx = fixture::<MollerTrumbore>(&name);
        let cam = camera_rays(&fx.scene, side, side);
        let want = brute::<MollerTrumbore>(fx.set.triangles(), &cam);
        let sh = shadow_rays(&fx.scene, &cam, &want);
        let sh_want = brute::<MollerTrumbore>(fx.set.triangles(), &sh);
        println!(
            "{name} {side}x{side}: {} triangles, {} nodes, {} leaves, depth {}",
            fx.set.len(),
            fx.tree.nodes.len(),
            fx.tree.leaves.len(),
            fx.tree.depth
        );
        for (label, rays, want, mode) in [
            ("camera", &cam, &want, HitMode::Closest),
            ("shadow", &sh, &sh_want, HitMode::Any),
        ] {
            println!("{label} rays ({}):", rays.len());
            println!("traversal      tile cull        N        I  culled%");
            let mut rows = vec![(Traversal::Single, 2, false, Shape::Pyramid)];
            rows.push((Traversal::Packet, 2, false, Shape::Pyramid));
            rows.push((Traversal::Omni, 2, false, Shape::Pyramid));
            for tile in TILES {
                // Without culling only at 8×8 (table 4.2) and 16×16 (the MFT criterion):
                // larger tiles without culling test every packet at every leaf.
                for cull in [false, true] {
                    if !cull && tile != 8 && tile != 16 {
                        continue;
                    }
                    for t in [Traversal::Frustum, Traversal::Mft, Traversal::Cone] {
                        rows.push((t, tile, cull, Shape::Pyramid));
                    }
                    rows.push((Traversal::Mft, tile, cull, Shape::Cone));
                }
            }
            for (t, tile, cull, shape) in rows {
                let o = CoherentOptions {
                    traversal: t,
                    tile_size: tile.max(2),
                    leaf_culling: cull,
                    width: side,
                };
                let pc = check(&fx, rays, want, mode, &o, shape).1;
                let name = match shape {
                    Shape::Cone if t == Traversal::Mft => "mft-cone",
                    _ => t.name(),
                };
                println!(
                    "{name:<12} {tile:>6} {:>4} {:>8.3} {:>8.2} {:>7.1}",
                    if cull { "on" } else { "off" },
                    pc.nodes_per_packet(),
                    pc.tests_per_packet(),
                    100.0 * pc.culled_fraction()
                );
            }
        }
    }

    /// A ray that never crosses a plane (crossing `+∞`) gets no interval in the back child
    /// (`∞ − ∞·T_SLACK` was NaN and `max(near, NaN)` gave it the whole interval, so a single
    /// ray visited nearly the whole tree).
    #[test]
    fn descend_gives_a_never_crossed_back_child_nothing() {
        let inf = f32::INFINITY;
        assert_eq!(
            crate::kdtree::descend(0.5, 5.0, inf, inf),
            (Some((0.5, 5.0)), None)
        );
        let (f, b) = crate::kdtree::descend(0.5, 5.0, 2.0, inf);
        assert_eq!(f, Some((0.5, 5.0)));
        assert!(b.unwrap().0 < 2.0);
    }
}
