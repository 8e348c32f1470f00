//! Grouping a ray batch for the coherent traversals (seed 003 §2.3.1-2.3.2, §4.1): rays that
//! share an origin (camera rays from the eye, shadow rays from a point light whose origin is
//! the light) are grouped by screen tile, and a group's rays into 2×2 packets by pixel quad.
//! Also the per-group state every coherent traversal shares: the rays, their best hits, which
//! of them are finished, and the packet-leaf test (with packet/leaf culling, §4.1.4).
//!
//! # Grouping (deterministic)
//!
//! Only [`RayKind::Primary`] and [`RayKind::Shadow`] rays are grouped. The key is the kind,
//! the light index, the origin's exact bit pattern and the screen tile of the ray's pixel
//! (`tile × tile` pixels, `pixel = y·width + x`). Groups are ordered by tile (row-major), then
//! kind, light and origin bits; a group's rays by pixel quad (row-major), then pixel, then batch
//! index; consecutive rays of one quad form packets of at most four. Rays of other kinds and
//! rays alone in their group are *singles*, traced one by one. Nothing depends on the thread
//! count.
//!
//! Each packet belongs to one quadrant of its tile (from its quad's top-left pixel), the
//! frustum it joins in multiple frustum traversal (§4.1.5).

use crsh_core::glam::Vec3;
use crsh_core::{Hit, HitMode, Ray, RayKind};

use super::coherent::PacketCounts;
use super::{clip, Interval, KdCounts, KdTree};
use crate::triangle::TriangleTest;

/// A packet: up to four consecutive rays of a group (a pixel quad's rays).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PacketRef {
    /// First ray, as an index into the group's rays.
    pub start: u32,
    /// Number of rays (1..=4).
    pub len: u32,
    /// Quadrant of the tile the packet lies in: bit 0 right half, bit 1 bottom half.
    pub quadrant: u32,
}

/// One group: rays sharing kind, light, origin and screen tile.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Group {
    /// Batch indices of the rays, packet by packet.
    pub rays: Vec<u32>,
    /// The packets, in order; their ray runs tile `rays`.
    pub packets: Vec<PacketRef>,
}

/// A batch split into groups and singles.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Grouping {
    /// Groups of at least two rays.
    pub groups: Vec<Group>,
    /// Batch indices of the rays traced one by one, ascending.
    pub singles: Vec<u32>,
}

/// Whether rays of `kind` may share an origin with others (camera and shadow rays).
pub fn groupable(kind: u32) -> bool {
    kind == RayKind::Primary as u32 || kind == RayKind::Shadow as u32
}

/// Splits `rays` into groups and singles (module doc). `width` is the image width (`0` is
/// taken as 1); `tile` the tile side in pixels, rounded up to an even number (at least 2) so
/// that tiles hold whole pixel quads.
pub fn group_rays(rays: &[Ray], width: u32, tile: u32) -> Grouping {
    let width = width.max(1);
    let tile = tile.max(2).next_multiple_of(2);
    // (tile y, tile x, kind, light, origin bits, quad y, quad x, pixel, index)
    type Key = ([u32; 8], u32, u32);
    let mut keyed: Vec<Key> = Vec::new();
    let mut singles = Vec::new();
    for (i, r) in rays.iter().enumerate() {
        if !groupable(r.kind) {
            singles.push(i as u32);
            continue;
        }
        let (x, y) = (r.pixel % width, r.pixel / width);
        let o = r.origin.to_array().map(f32::to_bits);
        keyed.push((
            [y / tile, x / tile, r.kind, r.light, o[0], o[1], o[2], y / 2],
            x / 2,
            i as u32,
        ));
    }
    // Sort by the key, then quad x, pixel and batch index.
    keyed.sort_unstable_by_key(|&(k, qx, i)| (k, qx, rays[i as usize].pixel, i));
    let mut groups = Vec::new();
    let mut s = 0;
    while s < keyed.len() {
        let same = |a: &Key, b: &Key| a.0[..7] == b.0[..7];
        let mut e = s + 1;
        while e < keyed.len() && same(&keyed[s], &keyed[e]) {
            e += 1;
        }
        if e - s == 1 {
            singles.push(keyed[s].2);
        } else {
            let mut g = Group {
                rays: Vec::with_capacity(e - s),
                packets: Vec::new(),
            };
            let mut q = s;
            while q < e {
                // One quad's rays, in packets of at most four.
                let mut qe = q + 1;
                while qe < e && keyed[qe].0[7] == keyed[q].0[7] && keyed[qe].1 == keyed[q].1 {
                    qe += 1;
                }
                let (qy, qx) = (keyed[q].0[7], keyed[q].1);
                let half = tile / 2;
                let quadrant =
                    u32::from((qx * 2) % tile >= half) | u32::from((qy * 2) % tile >= half) << 1;
                for chunk in keyed[q..qe].chunks(4) {
                    g.packets.push(PacketRef {
                        start: g.rays.len() as u32,
                        len: chunk.len() as u32,
                        quadrant,
                    });
                    g.rays.extend(chunk.iter().map(|k| k.2));
                }
                q = qe;
            }
            groups.push(g);
        }
        s = e;
    }
    singles.sort_unstable();
    Grouping { groups, singles }
}

/// The traversal state of one group: its rays (in packet order), their per-ray test data,
/// best hits and finished flags, and the counters.
pub struct GroupState<'t, T: TriangleTest> {
    /// The tree.
    pub tree: &'t KdTree,
    /// The prepared triangles.
    pub tris: &'t [T::Tri],
    /// Closest or any hit.
    pub mode: HitMode,
    /// The shared origin.
    pub origin: Vec3,
    /// The rays.
    pub rays: Vec<Ray>,
    /// Their per-ray test data.
    pub pre: Vec<T::Ray>,
    /// Their best hits so far.
    pub best: Vec<Hit>,
    /// Finished: any hit found, closest hit final ([`super::KdLeaf::holds_final`]), or
    /// nothing to trace (empty interval, misses the tree).
    pub done: Vec<bool>,
    /// Each ray's interval in the root cell ([`clip`]); `None` for rays finished from the
    /// start.
    pub root: Vec<Option<Interval>>,
    /// The packets.
    pub packets: Vec<PacketRef>,
    /// Unfinished rays per tile quadrant.
    pub remaining: [u32; 4],
    /// Per tile quadrant, the largest best-hit `t` of its unfinished rays (`+∞` while one of
    /// them has no hit): a subtree whose interval starts beyond it holds nothing those rays
    /// still need ([`GroupState::update_limits`]).
    pub limits: [f32; 4],
    /// Node and ray-triangle counts.
    pub kd: KdCounts,
    /// The paper's packet metrics.
    pub pc: PacketCounts,
}

impl<'t, T: TriangleTest> GroupState<'t, T> {
    /// The state of `group` of `rays`, starting from the hits in `hits` (indexed like `rays`).
    pub fn new(
        tree: &'t KdTree,
        tris: &'t [T::Tri],
        mode: HitMode,
        rays: &[Ray],
        hits: &[Hit],
        group: &Group,
    ) -> Self {
        let rs: Vec<Ray> = group.rays.iter().map(|&i| rays[i as usize]).collect();
        let best: Vec<Hit> = group.rays.iter().map(|&i| hits[i as usize]).collect();
        let root: Vec<Option<Interval>> = rs
            .iter()
            .zip(&best)
            .map(|(r, b)| {
                let skip = crate::intersect::nothing_to_trace(r, mode, b) || tree.nodes.is_empty();
                if skip {
                    None
                } else {
                    clip(&tree.bounds, r.origin, r.dir, r.t_min, r.t_max)
                }
            })
            .collect();
        let done: Vec<bool> = root.iter().map(Option::is_none).collect();
        let mut remaining = [0; 4];
        for p in &group.packets {
            for l in p.start..p.start + p.len {
                remaining[p.quadrant as usize] += u32::from(!done[l as usize]);
            }
        }
        GroupState {
            tree,
            tris,
            mode,
            origin: rs[0].origin,
            pre: rs.iter().map(T::ray_of).collect(),
            rays: rs,
            best,
            done,
            root,
            packets: group.packets.clone(),
            remaining,
            limits: [f32::INFINITY; 4],
            kd: KdCounts::default(),
            pc: PacketCounts {
                packets: group.packets.len() as u64,
                groups: 1,
                ..PacketCounts::default()
            },
        }
    }

    /// Whether every ray is finished.
    #[inline]
    pub fn all_done(&self) -> bool {
        self.remaining == [0; 4]
    }

    /// Recomputes [`GroupState::limits`] (after a leaf's tests). A closest-hit ray with a hit on
    /// a split plane is final in no cell; the limits let the traversals skip the cells past
    /// such hits (the group's intervals are widened, so no cell that could hold a closer hit
    /// is skipped).
    pub fn update_limits(&mut self) {
        let mut limits = [f32::NEG_INFINITY; 4];
        for pk in &self.packets {
            let q = pk.quadrant as usize;
            for i in pk.start as usize..(pk.start + pk.len) as usize {
                if !self.done[i] {
                    limits[q] = limits[q].max(self.best[i].t);
                }
            }
        }
        self.limits = limits;
    }

    /// The largest of [`GroupState::limits`]: the proxy of the whole tile needs nothing past
    /// it.
    #[inline]
    pub fn limit(&self) -> f32 {
        self.limits.iter().fold(f32::NEG_INFINITY, |a, &b| a.max(b))
    }

    /// Bit mask (over the tile quadrants) of the quadrants with unfinished rays.
    #[inline]
    pub fn alive_quadrants(&self) -> u32 {
        (0..4)
            .filter(|&q| self.remaining[q] > 0)
            .fold(0, |m, q| m | 1 << q)
    }

    /// The best-hit `t` of packet `p`'s lanes (`+∞` for lanes past its rays).
    #[inline]
    pub fn packet_best_t(&self, p: usize) -> super::simd::F4 {
        let pk = self.packets[p];
        let mut t = [f32::INFINITY; 4];
        for (l, t) in t.iter_mut().enumerate().take(pk.len as usize) {
            *t = self.best[pk.start as usize + l].t;
        }
        super::simd::F4::new(t)
    }

    /// Bit mask of packet `p`'s unfinished rays (bit `l`: ray `start + l`).
    #[inline]
    pub fn live(&self, p: usize) -> u32 {
        let pk = self.packets[p];
        (0..pk.len)
            .filter(|&l| !self.done[(pk.start + l) as usize])
            .fold(0, |m, l| m | 1 << l)
    }

    fn finish(&mut self, i: usize, quadrant: u32) {
        if !self.done[i] {
            self.done[i] = true;
            self.remaining[quadrant as usize] -= 1;
        }
    }

    /// Tests the unfinished rays of packet `p` selected by `lanes` against the triangles of
    /// leaf `leaf`, one packet-triangle test per triangle ([`TriangleTest::test_packet`], bit
    /// for bit the scalar test), merging hits as brute force does ([`Hit::closer_than`]).
    /// With `cull`, the packet is skipped (and its avoided tests counted) when none of those
    /// rays' intervals meets the leaf's cell (packet/leaf culling, §4.1.4; the widened slab
    /// test of [`clip`], so a ray through the cell is never culled). Being per ray, this
    /// culling keeps a packet at a leaf exactly when (up to rounding margins) one of its
    /// unfinished rays passes through the cell: the leaves where 2×2 packet traversal tests
    /// it, so a culled tile traversal has the packets' `I` for closest-hit rays (the paper's
    /// culled frusta have 2-6× its packets' `I`, table 4.1: its culling is coarser, or keeps
    /// testing packets whose rays have hit). Afterwards an any-hit
    /// ray with a hit, or a closest-hit ray whose best hit the leaf
    /// [`holds_final`](super::KdLeaf::holds_final), is finished.
    pub fn test_packet(&mut self, leaf: usize, p: usize, lanes: u32, cull: bool) {
        let pk = self.packets[p];
        let start = pk.start as usize;
        let lf = &self.tree.leaves[leaf];
        if lf.count == 0 {
            return;
        }
        let mut live = self.live(p) & lanes;
        if live == 0 {
            return;
        }
        if cull {
            let cell = lf.cell();
            let meets = lanes_of(live).any(|l| {
                let r = &self.rays[start + l];
                // A closest-hit ray needs the cell only up to its best hit (widened like the
                // traversal's intervals): a hit on a split plane is final in no cell.
                let b = self.best[start + l];
                let end = if self.mode != HitMode::Any && b.is_hit() {
                    r.t_max.min(b.t + b.t.abs() * super::T_SLACK)
                } else {
                    r.t_max
                };
                clip(&cell, r.origin, r.dir, r.t_min, end).is_some()
            });
            if !meets {
                self.pc.culled_tests += u64::from(lf.count);
                return;
            }
        }
        let fill = |live: u32, rays: &[Ray]| {
            let mut packet = T::empty_packet();
            for l in lanes_of(live) {
                T::set_lane(&mut packet, l, &rays[start + l]);
            }
            packet
        };
        let mut packet = fill(live, &self.rays);
        for &id in &self.tree.leaf_tris[lf.range()] {
            self.pc.packet_tests += 1;
            self.kd.tests += u64::from(live.count_ones());
            let (mask, h) = T::test_packet(&packet, &self.tris[id as usize]);
            let mut refill = false;
            for l in lanes_of(mask & live) {
                let hit = Hit {
                    t: h.t[l],
                    tri: id,
                    u: h.u[l],
                    v: h.v[l],
                };
                if hit.closer_than(&self.best[start + l]) {
                    self.best[start + l] = hit;
                    if self.mode == HitMode::Any {
                        self.finish(start + l, pk.quadrant);
                        live &= !(1 << l);
                        refill = true;
                    }
                }
            }
            if refill {
                if live == 0 {
                    break;
                }
                packet = fill(live, &self.rays);
            }
        }
        if self.mode != HitMode::Any {
            for l in lanes_of(live) {
                let (r, b) = (&self.rays[start + l], self.best[start + l]);
                if b.is_hit() && lf.holds_final(r.at(b.t)) {
                    self.finish(start + l, pk.quadrant);
                }
            }
        }
    }

    /// The group's results: `(batch index, hit)` per ray.
    pub fn results(&self, group: &Group) -> Vec<(u32, Hit)> {
        group
            .rays
            .iter()
            .copied()
            .zip(self.best.iter().copied())
            .collect()
    }
}

/// The set bits of `mask` as lane indices, ascending.
#[inline]
pub fn lanes_of(mut mask: u32) -> impl Iterator<Item = usize> {
    std::iter::from_fn(move || {
        (mask != 0).then(|| {
            let l = mask.trailing_zeros() as usize;
            mask &= mask - 1;
            l
        })
    })
}
