//! Lowest nodes of `leaf_cone = extremes` in `f32` lanes: the common case of a narrow node.
//!
//! The exact construction ([`super::leaf_node`]) normalizes every direction in `f64` (a square
//! root and a division per ray, in a chain with the gather) and runs its five passes of dot
//! products one `f64` ray at a time: on cornell-mirror's shadow rays that was most of the
//! hierarchy stage. Here the node's rays are gathered once into structure-of-arrays `f32`
//! columns and every pass runs four rays per instruction ([`Vec4`], SSE2):
//!
//! - unit directions `d · (1/√(d·d))` in `f32`;
//! - the two heuristic axes of *Leaf cones from extreme rays* (module doc of
//!   [`super`]), the mean and the bisector of two extreme rays, the better one kept by the same
//!   rule, with the rays compared by their squared chord `|d̂ − a|²` instead of the dot product
//!   (the same order, but `f32` cosines of rays less than about 3·10⁻⁴ rad apart all round
//!   to 1). Any axis gives a correct cone, so `f32` only decides which of nearly equal axes is
//!   kept;
//! - the stored half-angle is still the exact `f64` maximum of `angle(stored axis, d)` over the
//!   node's rays, measured with `atan2` (as [`super::store_leaf_cone`] measures it), but only
//!   for the rays whose `f32` chord `|d̂ − a|` (a monotonic function of the angle) comes within
//!   [`CHORD_ERROR`] twice of the largest chord: no other ray can be the widest. The result is
//!   the maximum over every ray, bit for bit (tested); a node of 32 rays measures one or two.
//!
//! A node falls back to the exact construction, which then builds it exactly as before, when a
//! ray is not usable or its squared length leaves `[2⁻¹⁰⁰, 2¹⁰⁰]` (where the `f32` error bound
//! below is not worked out), when its directions nearly cancel, or when the chosen axis is wide
//! (cosine of the widest ray below [`super::WIDE_LEAF_COS`]): those are the nodes that also
//! run eq. 3.8-3.11. Spheres and reaches are measured in `f64` from the same gathered columns,
//! with the same formulas as the exact construction.

use crsh_core::{Ray, SphereCone};
use glam::{DVec3, Vec3, Vec4};

use super::{angle, margined_cone, margined_sphere, LeafSphere, WIDE_LEAF_COS};

/// Rays per lane group.
const W: usize = 4;

/// Squared direction lengths accepted here (outside: the exact construction).
const TAME: std::ops::RangeInclusive<f32> = 1.0 / (1u128 << 100) as f32..=(1u128 << 100) as f32;

/// A bound on `|chord_f32 − chord|`, the error of a ray's `f32` chord `|d̂ − a|` against the
/// exact chord of its direction from the stored axis `a`. The unit direction is off by at most
/// about `3u` per component (`u = 2⁻²⁴`: the squared length, its square root, the reciprocal
/// and the product), `1.8e-7` in length; the difference, its squares and their sum add under
/// `3u` relative of a chord of at most 2, and the stored axis is unit within `2u`. Together under
/// `6e-7`; the bound is three times that.
pub(super) const CHORD_ERROR: f32 = 2e-6;

/// A node's rays as `f32` columns, padded to whole lane groups with copies of the first ray;
/// kept per worker so that a node allocates nothing.
#[derive(Default)]
pub(super) struct Columns {
    ox: Vec<f32>,
    oy: Vec<f32>,
    oz: Vec<f32>,
    dx: Vec<f32>,
    dy: Vec<f32>,
    dz: Vec<f32>,
    ux: Vec<f32>,
    uy: Vec<f32>,
    uz: Vec<f32>,
    t_max: Vec<f32>,
    /// Per-ray scratch values of one pass (dot products or squared chords).
    value: Vec<f32>,
    /// The origins as vectors, filled only for Welzl's algorithm.
    origins: Vec<Vec3>,
}

/// Four consecutive entries of a column as lanes.
#[inline(always)]
fn lanes(column: &[f32], group: usize) -> Vec4 {
    Vec4::from_slice(&column[group * W..group * W + W])
}

impl Columns {
    /// The columns read from the rays (the padding repeats the first ray).
    fn ray_columns(&mut self) -> [&mut Vec<f32>; 7] {
        [
            &mut self.ox,
            &mut self.oy,
            &mut self.oz,
            &mut self.dx,
            &mut self.dy,
            &mut self.dz,
            &mut self.t_max,
        ]
    }

    /// The rays `leaves` gathered (and padded); `false` when one of them is not for this path.
    fn gather(&mut self, rays: &[Ray], leaves: &[u32]) -> bool {
        let n = leaves.len();
        let padded = n.div_ceil(W) * W;
        for column in self.ray_columns() {
            column.resize(padded, 0.0);
        }
        for column in [&mut self.ux, &mut self.uy, &mut self.uz, &mut self.value] {
            column.resize(padded, 0.0);
        }
        for (k, &i) in leaves.iter().enumerate() {
            let r = &rays[i as usize];
            // In range implies a finite, non-zero direction (NaN fails the test).
            if !(r.origin.is_finite() && TAME.contains(&r.dir.length_squared())) {
                return false;
            }
            self.ox[k] = r.origin.x;
            self.oy[k] = r.origin.y;
            self.oz[k] = r.origin.z;
            self.dx[k] = r.dir.x;
            self.dy[k] = r.dir.y;
            self.dz[k] = r.dir.z;
            self.t_max[k] = r.t_max;
        }
        for column in self.ray_columns() {
            let first = column[0];
            column[n..].fill(first);
        }
        for g in 0..padded / W {
            let (x, y, z) = (lanes(&self.dx, g), lanes(&self.dy, g), lanes(&self.dz, g));
            let inv = (x * x + y * y + z * z).sqrt().recip();
            (x * inv).write_to_slice(&mut self.ux[g * W..]);
            (y * inv).write_to_slice(&mut self.uy[g * W..]);
            (z * inv).write_to_slice(&mut self.uz[g * W..]);
        }
        true
    }

    fn groups(&self) -> usize {
        self.ux.len() / W
    }

    /// The origin of ray `k`.
    fn origin(&self, k: usize) -> Vec3 {
        Vec3::new(self.ox[k], self.oy[k], self.oz[k])
    }

    /// The minimal sphere's centre of the `n` origins (Welzl's algorithm).
    fn welzl_centre(&mut self, n: usize) -> Vec3 {
        let (x, y, z) = (&self.ox[..n], &self.oy[..n], &self.oz[..n]);
        self.origins.clear();
        self.origins
            .extend((0..n).map(|k| Vec3::new(x[k], y[k], z[k])));
        crsh_scene::bounding::min_sphere(&self.origins).center
    }

    /// The unit direction of ray `k`.
    fn unit(&self, k: usize) -> Vec3 {
        Vec3::new(self.ux[k], self.uy[k], self.uz[k])
    }

    /// The squared chord `|d̂ − a|²` of every ray (into `value`) and the largest of them. The
    /// chord `2·sin(θ/2)` orders the rays by their angle `θ` from `a` as the dot product
    /// `cos θ` does, but keeps its relative precision for small angles, where `f32` cosines
    /// all round to 1 (below about 3·10⁻⁴ rad).
    fn chords(&mut self, a: Vec3) -> f32 {
        let (ax, ay, az) = (Vec4::splat(a.x), Vec4::splat(a.y), Vec4::splat(a.z));
        let mut m = Vec4::ZERO;
        for g in 0..self.groups() {
            let (x, y, z) = (
                lanes(&self.ux, g) - ax,
                lanes(&self.uy, g) - ay,
                lanes(&self.uz, g) - az,
            );
            let q = x * x + y * y + z * z;
            q.write_to_slice(&mut self.value[g * W..]);
            m = m.max(q);
        }
        m.max_element()
    }

    /// The unit direction farthest from `from` (largest chord; the first on a tie).
    fn farthest(&mut self, from: Vec3) -> Vec3 {
        let m = self.chords(from);
        let k = self.value.iter().position(|&v| v == m).unwrap_or(0);
        self.unit(k)
    }

    /// The sum of the `n` unit directions (without the padding).
    fn unit_sum(&self, n: usize) -> Vec3 {
        let (mut sx, mut sy, mut sz) = (Vec4::ZERO, Vec4::ZERO, Vec4::ZERO);
        for g in 0..self.groups() {
            sx += lanes(&self.ux, g);
            sy += lanes(&self.uy, g);
            sz += lanes(&self.uz, g);
        }
        let padding = (self.ux.len() - n) as f32;
        Vec3::new(sx.element_sum(), sy.element_sum(), sz.element_sum()) - self.unit(0) * padding
    }

    /// The axis of `leaf_cone = extremes` (the mean or the bisector of two extreme rays,
    /// whichever has the smaller largest chord; the mean on a tie) and that squared chord;
    /// `None` when the directions nearly cancel.
    fn extremes_axis(&mut self, n: usize) -> Option<(Vec3, f32)> {
        let sum = self.unit_sum(n);
        if sum.length() <= 1e-3 * n as f32 {
            return None;
        }
        let mean = sum.normalize();
        let mean_chord = self.chords(mean);
        let a = self.farthest(self.unit(0));
        let pair = a + self.farthest(a);
        if pair.length() > 1e-6 {
            let pair = pair.normalize();
            let pair_chord = self.chords(pair);
            if pair_chord < mean_chord {
                return Some((pair, pair_chord));
            }
        }
        Some((mean, mean_chord))
    }

    /// The largest `angle(a, d)` over the `n` rays, in `f64` (see the module doc): `atan2`
    /// only for the rays whose `f32` chord can be the largest.
    pub(super) fn widest_angle(&mut self, a: Vec3, n: usize) -> f64 {
        let m = self.chords(a);
        let cut = (m.sqrt() - 2.0 * CHORD_ERROR).max(0.0);
        // Rounding of `cut²` itself: a relative 2⁻²³ below it keeps the comparison safe.
        let cut = cut * cut * (1.0 - f32::EPSILON);
        let a = a.as_dvec3();
        (0..n)
            .filter(|&k| self.value[k] >= cut)
            .fold(0.0f64, |w, k| {
                let d = DVec3::new(self.dx[k] as f64, self.dy[k] as f64, self.dz[k] as f64);
                w.max(angle(a, d))
            })
    }

    /// The `f64` length `t_max·|d|` of ray `k`'s segment (the exact construction's formula).
    fn length(&self, k: usize) -> f64 {
        let d = DVec3::new(self.dx[k] as f64, self.dy[k] as f64, self.dz[k] as f64);
        self.t_max[k] as f64 * d.length()
    }

    /// The largest `t_max·|d|` of the `n` rays, as `√max((t_max⁺)²·|d|²)` in `f64` (one
    /// square root for the node; `t_max⁺ = max(t_max, 0)`, so a negative or NaN `t_max` counts
    /// as 0 as it does in [`Self::length`]'s maximum): the same value up to `f64` rounding,
    /// far inside the reach's margin ([`super::round_up_reach`]).
    fn longest(&self, n: usize) -> f64 {
        let mut m = 0.0f64;
        for k in 0..n {
            let t = (self.t_max[k] as f64).max(0.0);
            let (x, y, z) = (self.dx[k] as f64, self.dy[k] as f64, self.dz[k] as f64);
            let v = t * t * (x * x + y * y + z * z);
            if v > m {
                m = v;
            }
        }
        m.sqrt()
    }

    /// Whether every origin equals the first.
    fn one_point(&self) -> bool {
        let (x, y, z) = (
            Vec4::splat(self.ox[0]),
            Vec4::splat(self.oy[0]),
            Vec4::splat(self.oz[0]),
        );
        (0..self.groups()).all(|g| {
            (lanes(&self.ox, g).cmpeq(x)
                & lanes(&self.oy, g).cmpeq(y)
                & lanes(&self.oz, g).cmpeq(z))
            .all()
        })
    }

    /// The centre of the origins' bounding box, `(min + max)·0.5` in `f32`.
    fn box_centre(&self) -> Vec3 {
        let (mut lo, mut hi) = ([Vec4::INFINITY; 3], [Vec4::NEG_INFINITY; 3]);
        for g in 0..self.groups() {
            for (c, column) in [&self.ox, &self.oy, &self.oz].into_iter().enumerate() {
                let v = lanes(column, g);
                lo[c] = lo[c].min(v);
                hi[c] = hi[c].max(v);
            }
        }
        let min = Vec3::new(
            lo[0].min_element(),
            lo[1].min_element(),
            lo[2].min_element(),
        );
        let max = Vec3::new(
            hi[0].max_element(),
            hi[1].max_element(),
            hi[2].max_element(),
        );
        (min + max) * 0.5
    }
}

/// The lowest node over `leaves` and its reach, as [`super::leaf_node`] builds it with
/// `leaf_cone = extremes`, from `f32` lanes; `None` for a node the exact construction must
/// build (see the module doc).
pub(super) fn narrow_leaf(
    rays: &[Ray],
    leaves: &[u32],
    centre: LeafSphere,
    columns: &mut Columns,
) -> Option<(SphereCone, f32)> {
    let n = leaves.len();
    if n == 0 || !columns.gather(rays, leaves) {
        return None;
    }
    let (axis, chord2) = columns.extremes_axis(n)?;
    // `cos θ < WIDE_LEAF_COS` as a squared chord `2 − 2·cos θ`.
    if chord2 as f64 > 2.0 * (1.0 - WIDE_LEAF_COS) {
        return None;
    }
    let stored = axis.normalize();
    let cone = margined_cone(stored, columns.widest_angle(stored, n));
    let (sphere, far) = if columns.one_point() {
        (margined_sphere(columns.origin(0), 0.0), columns.longest(n))
    } else {
        let c = match centre {
            LeafSphere::Welzl => columns.welzl_centre(n),
            LeafSphere::BoxCentre => columns.box_centre(),
        };
        let stored = c.as_dvec3();
        let (measured, far) = (0..n).fold((0.0f64, 0.0f64), |(m, f), k| {
            let d = stored.distance(columns.origin(k).as_dvec3());
            (m.max(d), f.max(d + columns.length(k)))
        });
        (margined_sphere(c, measured), far)
    };
    Some((SphereCone { sphere, cone }, super::round_up_reach(far)))
}

#[cfg(test)]
mod tests {
    use super::super::{covers, exact_leaf, LeafCone, LeafScratch};
    use super::*;
    use crate::triangle::tests::TestRng;
    use crsh_core::RayKind;

    fn ray(origin: Vec3, dir: Vec3, t_max: f32) -> Ray {
        Ray::new(RayKind::Shadow, origin, dir, 0.0, t_max)
    }

    /// `n` directions within `spread` radians (about) of `axis`, of lengths 10⁻³..10³; with
    /// `ring`, all at `spread` from it (ties up to `f32` rounding).
    fn fan(rng: &mut TestRng, axis: Vec3, spread: f32, n: usize, ring: bool) -> Vec<Vec3> {
        let (u, v) = axis.any_orthonormal_pair();
        (0..n)
            .map(|_| {
                let phi = rng.range(0.0, std::f32::consts::TAU);
                let theta = if ring { spread } else { spread * rng.f32() };
                let d = axis * theta.cos() + (u * phi.cos() + v * phi.sin()) * theta.sin();
                d * 10f32.powf(rng.range(-3.0, 3.0))
            })
            .collect()
    }

    /// The exact maximum `angle(a, d)` over every direction.
    fn exact_widest(a: Vec3, dirs: &[Vec3]) -> f64 {
        dirs.iter()
            .fold(0.0f64, |w, d| w.max(angle(a.as_dvec3(), d.as_dvec3())))
    }

    #[test]
    fn widest_angle_is_the_exact_maximum_over_every_ray() {
        let mut rng = TestRng(0x5eed_c0de);
        let mut columns = Columns::default();
        let mut measured_few = 0;
        for trial in 0..4000 {
            let n = [1, 3, 16, 32, 64][trial % 5];
            let spread = [0.0, 1e-7, 1e-6, 3e-6, 1e-5, 1e-4, 1e-2, 0.2][trial / 5 % 8];
            let ring = trial % 3 == 0;
            let axis = rng.unit();
            let dirs = fan(&mut rng, axis, spread, n, ring);
            let rays: Vec<Ray> = dirs.iter().map(|&d| ray(Vec3::ZERO, d, 1.0)).collect();
            let leaves: Vec<u32> = (0..n as u32).collect();
            assert!(columns.gather(&rays, &leaves));
            // The axis the node would store, and one a little off it.
            for a in [axis, (axis + rng.unit() * spread * 0.5).normalize()] {
                let got = columns.widest_angle(a, n);
                assert_eq!(
                    got,
                    exact_widest(a, &dirs),
                    "trial {trial}: n {n}, spread {spread}, ring {ring}"
                );
                let cut = columns.value[..n]
                    .iter()
                    .fold(0.0f32, |m, &q| m.max(q))
                    .sqrt()
                    - 2.0 * CHORD_ERROR;
                if columns.value[..n]
                    .iter()
                    .filter(|&&q| q.sqrt() >= cut)
                    .count()
                    <= 2
                {
                    measured_few += 1;
                }
            }
        }
        // Not every ray measured: most nodes wider than the error bound measure one or two.
        assert!(measured_few > 3000, "{measured_few}");
    }

    /// Coherent rays as a lowest node sees them: from one light or from a patch of origins.
    fn coherent_node(rng: &mut TestRng, n: usize, one_point: bool) -> Vec<Ray> {
        let axis = rng.unit();
        let base = rng.vec3(-50.0, 50.0);
        let spread = [1e-4, 1e-3, 0.02, 0.2][(rng.next_u64() % 4) as usize];
        fan(rng, axis, spread, n, false)
            .into_iter()
            .map(|d| {
                let o = if one_point {
                    base
                } else {
                    base + rng.vec3(-0.5, 0.5)
                };
                let t_max = if rng.f32() < 0.1 {
                    f32::INFINITY
                } else {
                    rng.range(0.0, 2.0)
                };
                ray(o, d, t_max)
            })
            .collect()
    }

    #[test]
    fn narrow_nodes_match_the_exact_construction() {
        let mut rng = TestRng(0xface_feed);
        let mut scratch = LeafScratch::default();
        let mut columns = Columns::default();
        let mut built = 0;
        for trial in 0..600 {
            let n = [1, 7, 16, 32, 64][trial % 5];
            let one_point = trial % 2 == 0;
            let centre = [LeafSphere::BoxCentre, LeafSphere::Welzl][trial / 2 % 2];
            let rays = coherent_node(&mut rng, n, one_point);
            let leaves: Vec<u32> = (0..n as u32).rev().collect();
            let exact = exact_leaf(&rays, &leaves, LeafCone::Extremes, centre, &mut scratch)
                .expect("usable rays");
            let Some((node, reach)) = narrow_leaf(&rays, &leaves, centre, &mut columns) else {
                continue;
            };
            built += 1;
            for r in &rays {
                assert!(
                    covers(&node, r.origin, r.dir),
                    "trial {trial}: {node:?} {r:?}"
                );
            }
            // The same sphere (same centre, same distances); the reach within `f64` rounding of
            // the exact one before it is rounded up.
            assert_eq!(node.sphere, exact.0.sphere, "trial {trial}");
            assert!(
                (reach - exact.1).abs() <= exact.1.abs() * 2.0 * f32::EPSILON || reach == exact.1,
                "trial {trial}: reach {reach} against {}",
                exact.1
            );
            // An axis at most a little off the exact construction's: nearly as narrow.
            let (h, e) = (node.cone.half_angle as f64, exact.0.cone.half_angle as f64);
            assert!(
                h <= e * 1.001 + 3e-7,
                "trial {trial}: half-angle {h} against {e}"
            );
        }
        assert!(built > 500, "{built}");
    }

    #[test]
    fn wide_cancelling_and_untame_nodes_take_the_exact_construction() {
        let mut rng = TestRng(7);
        let mut columns = Columns::default();
        let leaves: Vec<u32> = (0..16).collect();
        let from = |dirs: Vec<Vec3>| -> Vec<Ray> {
            dirs.into_iter().map(|d| ray(Vec3::ONE, d, 1.0)).collect()
        };
        // Widest ray about 30° from the axis: below `WIDE_LEAF_COS`.
        let wide = from(fan(&mut rng, Vec3::Z, 0.6, 16, true));
        assert!(narrow_leaf(&wide, &leaves, LeafSphere::BoxCentre, &mut columns).is_none());
        let narrow = from(fan(&mut rng, Vec3::Z, 0.1, 16, true));
        assert!(narrow_leaf(&narrow, &leaves, LeafSphere::BoxCentre, &mut columns).is_some());
        let opposite = from(
            (0..16)
                .map(|i| if i % 2 == 0 { Vec3::X } else { -Vec3::X })
                .collect(),
        );
        assert!(narrow_leaf(&opposite, &leaves, LeafSphere::BoxCentre, &mut columns).is_none());
        for bad in [
            Vec3::splat(1e-31),
            Vec3::splat(1e31),
            Vec3::new(f32::NAN, 0.0, 1.0),
        ] {
            let mut rays = narrow.clone();
            rays[5].dir = bad;
            assert!(narrow_leaf(&rays, &leaves, LeafSphere::BoxCentre, &mut columns).is_none());
        }
        let mut rays = narrow.clone();
        rays[3].origin.y = f32::INFINITY;
        assert!(narrow_leaf(&rays, &leaves, LeafSphere::BoxCentre, &mut columns).is_none());
    }
}
