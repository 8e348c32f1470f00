//! Edge-width soft shadows (seed 003 §5, eq. 5.1, listing 5.1): the scan every intersector
//! that answers [`HitMode::EdgeWidth`](crate::HitMode::EdgeWidth) runs over the sorted
//! crossings of a shadow segment, so that all of them give bit-identical answers.
//!
//! Listing 5.1 pairs the crossings of a shadow ray leaf by leaf: the ray starts outside every
//! object and toggles its state at each crossing, a pair (entry, exit) has the edge width
//! `exit − entry`, the widest pair decides the occlusion (eq. 5.1: `clamp(width / R, 0, 1)`)
//! and a pair wider than `R` ends the traversal. Two errata are fixed here and in the
//! traversals that feed the scan:
//! - the open entry carried to the next leaf is `distances[distCount]` (the last crossing of
//!   the leaf), not `distances[distCount − 1]`;
//! - a crossing on a leaf boundary is counted once: the listing's closed leaf intervals
//!   `tNear ≤ t ≤ tFar` gather a hit on a split plane in both leaves, which shifts the pairing
//!   of every later crossing. The scan takes each crossing exactly once; the traversals make
//!   sure of it (each triangle crosses a segment at most once).
//!
//! The listing returns a fraction of the unnormalised shadow ray; crsh's rays have unit
//! directions, so widths and `R` are world distances, and `R` is the light's radius
//! (`Light::radius` in crsh-scene).
//!
//! Light leaks (§5.4, fig. 5.8-5.10): the scan assumes closed occluders. Two separate sheets
//! (curtains, banners, the two walls of a thin partition modelled apart) pair as an entry and
//! an exit a short distance apart, and the point behind them is lit where the hard ray says it
//! is in shadow. The thesis's fix without artist input is [`EdgePairing::SharedVertex`]: an
//! entry and an exit form an edge width only when their triangles share a vertex (they likely
//! meet at the silhouette edge the ray passes near); any other pair has an infinite width,
//! which occludes fully. Vertices are compared by position ([`SharedVertices`]), so meshes
//! whose vertices are split at texture or normal seams still share them.

use std::collections::HashMap;

use glam::Vec3;
use serde::{Deserialize, Serialize};

use crate::ray::{Hit, NO_HIT};

/// Which entry and exit crossings may form an edge width (seed 003 §5.4, fig. 5.10).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub enum EdgePairing {
    /// Every consecutive (entry, exit) pair (listing 5.1 as printed).
    #[default]
    Any,
    /// Only an entry and an exit whose triangles share a vertex; any other pair has an
    /// infinite width (the thesis's light-leak fix, fig. 5.10).
    SharedVertex,
}

impl EdgePairing {
    /// The param value naming this rule (`any`, `shared_vertex`).
    pub fn name(self) -> &'static str {
        match self {
            EdgePairing::Any => "any",
            EdgePairing::SharedVertex => "shared_vertex",
        }
    }

    /// The rule named `name`, if any.
    pub fn from_name(name: &str) -> Option<EdgePairing> {
        match name {
            "any" => Some(EdgePairing::Any),
            "shared_vertex" => Some(EdgePairing::SharedVertex),
            _ => None,
        }
    }

    /// Every rule's name.
    pub const NAMES: [&'static str; 2] = ["any", "shared_vertex"];
}

/// Per triangle, its three vertices as ids of distinct positions: two triangles share a vertex
/// exactly when they have an id in common ([`EdgePairing::SharedVertex`]). Positions are
/// compared bit for bit (with `-0.0` taken as `0.0`). 12 bytes per triangle.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct SharedVertices {
    ids: Vec<[u32; 3]>,
}

impl SharedVertices {
    /// Welds the vertices of triangles `indices` (into `positions`) by position. Indices out
    /// of range get ids of their own (they share nothing).
    pub fn weld(positions: &[Vec3], indices: &[[u32; 3]]) -> SharedVertices {
        let key = |p: Vec3| (p + Vec3::ZERO).to_array().map(f32::to_bits);
        let mut first: HashMap<[u32; 3], u32> = HashMap::with_capacity(positions.len());
        let canon: Vec<u32> = positions
            .iter()
            .enumerate()
            .map(|(i, &p)| *first.entry(key(p)).or_insert(i as u32))
            .collect();
        let n = positions.len() as u32;
        let ids = indices
            .iter()
            .enumerate()
            .map(|(t, tri)| {
                let mut k = 0;
                tri.map(|v| {
                    k += 1;
                    canon.get(v as usize).copied().unwrap_or_else(|| {
                        // Unique and above every real id.
                        n.saturating_add((t as u32).saturating_mul(3))
                            .saturating_add(k)
                    })
                })
            })
            .collect();
        SharedVertices { ids }
    }

    /// Triangles in the set.
    pub fn len(&self) -> usize {
        self.ids.len()
    }

    /// Whether the set has no triangle.
    pub fn is_empty(&self) -> bool {
        self.ids.is_empty()
    }

    /// Whether triangles `a` and `b` share a vertex (a triangle shares with itself; an id out
    /// of range shares nothing).
    pub fn share(&self, a: u32, b: u32) -> bool {
        match (self.ids.get(a as usize), self.ids.get(b as usize)) {
            (Some(x), Some(y)) => x.iter().any(|v| y.contains(v)),
            _ => false,
        }
    }

    /// The pairing rule `pairing` over these vertices: what [`EdgeWidthScan::new`] takes.
    pub fn rule(&self, pairing: EdgePairing) -> Option<&SharedVertices> {
        match pairing {
            EdgePairing::Any => None,
            EdgePairing::SharedVertex => Some(self),
        }
    }
}

/// What an intersector keeps to answer edge-width queries on its scene: each light's radius
/// (`R`) and the vertices triangles share ([`EdgePairing::SharedVertex`]).
#[derive(Clone, Debug, Default)]
pub struct EdgeWidthLights {
    /// The radius of each scene light, by light index ([`crate::Ray::light`]).
    pub radii: Vec<f32>,
    /// The scene's triangles' welded vertices.
    pub shared: SharedVertices,
}

impl EdgeWidthLights {
    /// The lights of radii `radii` over triangles `indices` into `positions`.
    pub fn new(radii: Vec<f32>, positions: &[Vec3], indices: &[[u32; 3]]) -> EdgeWidthLights {
        EdgeWidthLights {
            radii,
            shared: SharedVertices::weld(positions, indices),
        }
    }

    /// Checks that every ray names a light (its radius is the query's `R`).
    pub fn check(&self, rays: &[crate::Ray]) -> crate::Result<()> {
        match rays
            .iter()
            .position(|r| r.light as usize >= self.radii.len())
        {
            Some(i) => Err(crate::CoreError::InvalidInput(format!(
                "edge-width ray {i} names light {} but the scene has {} lights",
                rays[i].light,
                self.radii.len()
            ))),
            None => Ok(()),
        }
    }

    /// A scan for `ray` (checked by [`EdgeWidthLights::check`]) with pairing `pairing`.
    pub fn scan(&self, ray: &crate::Ray, pairing: EdgePairing) -> EdgeWidthScan<'_> {
        EdgeWidthScan::new(self.radii[ray.light as usize], self.shared.rule(pairing))
    }

    /// The answer for all crossings of `ray`'s segment (any order; sorted here).
    pub fn hit(&self, ray: &crate::Ray, pairing: EdgePairing, crossings: &mut [Crossing]) -> Hit {
        edge_width_hit(
            crossings,
            self.radii[ray.light as usize],
            self.shared.rule(pairing),
        )
    }
}

/// One crossing of a shadow segment by a triangle.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Crossing {
    /// Distance along the ray.
    pub t: f32,
    /// Scene triangle id.
    pub tri: u32,
}

/// Sorts crossings by `t`, ties by triangle id: the order the scan needs.
pub fn sort_crossings(crossings: &mut [Crossing]) {
    crossings.sort_unstable_by(|a, b| a.t.total_cmp(&b.t).then(a.tri.cmp(&b.tri)));
}

/// The pairing scan of listing 5.1 over crossings fed in sorted order ([`sort_crossings`]).
#[derive(Clone, Copy, Debug)]
pub struct EdgeWidthScan<'a> {
    radius: f32,
    /// The shared-vertex rule's vertices ([`EdgePairing::SharedVertex`]); `None`: any pair.
    shared: Option<&'a SharedVertices>,
    /// The entry crossing still waiting for its exit.
    open: Option<Crossing>,
    /// The widest pair so far: its entry and width.
    widest: Option<(Crossing, f32)>,
    /// The final answer once the segment is known to be fully occluded.
    done: Option<Hit>,
}

impl<'a> EdgeWidthScan<'a> {
    /// A scan for a light of radius `radius` (the `R` of eq. 5.1; `≤ 0`: any crossing
    /// occludes fully) that pairs crossings by `shared` (`None`: any consecutive pair, else
    /// only pairs of triangles sharing a vertex; see [`SharedVertices::rule`]).
    pub fn new(radius: f32, shared: Option<&'a SharedVertices>) -> Self {
        EdgeWidthScan {
            radius,
            shared,
            open: None,
            widest: None,
            done: None,
        }
    }

    /// Whether the answer is final (fully occluded): further crossings change nothing, so a
    /// traversal may stop (listing 5.1's early exit).
    pub fn is_done(&self) -> bool {
        self.done.is_some()
    }

    /// Feeds the next crossing (in sorted order); returns [`EdgeWidthScan::is_done`].
    pub fn push(&mut self, c: Crossing) -> bool {
        if self.done.is_some() {
            return true;
        }
        if self.radius.is_nan() || self.radius <= 0.0 {
            self.done = Some(Hit {
                t: c.t,
                tri: c.tri,
                u: 1.0,
                v: f32::INFINITY,
            });
            return true;
        }
        match self.open.take() {
            None => self.open = Some(c),
            Some(entry) => {
                let paired = self.shared.is_none_or(|s| s.share(entry.tri, c.tri));
                let width = if paired { c.t - entry.t } else { f32::INFINITY };
                if self.widest.is_none_or(|(_, w)| width > w) {
                    self.widest = Some((entry, width));
                }
                if width >= self.radius {
                    self.done = Some(Hit {
                        t: entry.t,
                        tri: entry.tri,
                        u: 1.0,
                        v: width,
                    });
                }
            }
        }
        self.done.is_some()
    }

    /// The answer (the [`HitMode::EdgeWidth`](crate::HitMode::EdgeWidth) encoding) once every
    /// crossing has been fed: fully occluded when the scan stopped or an entry is left open,
    /// else eq. 5.1 on the widest pair; a miss when the occlusion is 0.
    pub fn finish(&self) -> Hit {
        if let Some(h) = self.done {
            return h;
        }
        if let Some(entry) = self.open {
            return Hit {
                t: entry.t,
                tri: entry.tri,
                u: 1.0,
                v: f32::INFINITY,
            };
        }
        match self.widest {
            Some((entry, width)) => {
                let occlusion = (width / self.radius).clamp(0.0, 1.0);
                if occlusion > 0.0 {
                    Hit {
                        t: entry.t,
                        tri: entry.tri,
                        u: occlusion,
                        v: width,
                    }
                } else {
                    Hit::MISS
                }
            }
            None => Hit::MISS,
        }
    }
}

/// The edge-width answer for all crossings of a segment (any order; sorted here), pairing
/// them by `shared` as [`EdgeWidthScan::new`] does.
pub fn edge_width_hit(
    crossings: &mut [Crossing],
    radius: f32,
    shared: Option<&SharedVertices>,
) -> Hit {
    sort_crossings(crossings);
    let mut scan = EdgeWidthScan::new(radius, shared);
    for &c in crossings.iter() {
        if scan.push(c) {
            break;
        }
    }
    scan.finish()
}

/// The occlusion an edge-width hit encodes: 0 for a miss, else its `u`.
pub fn occlusion(hit: &Hit) -> f32 {
    if hit.tri == NO_HIT {
        0.0
    } else {
        hit.u
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn c(t: f32, tri: u32) -> Crossing {
        Crossing { t, tri }
    }

    #[test]
    fn no_crossing_is_a_miss() {
        assert_eq!(edge_width_hit(&mut [], 1.0, None), Hit::MISS);
        assert_eq!(occlusion(&Hit::MISS), 0.0);
    }

    #[test]
    fn one_pair_is_eq_5_1() {
        let h = edge_width_hit(&mut [c(3.25, 7), c(3.0, 4)], 1.0, None);
        assert_eq!((h.tri, h.t, h.u, h.v), (4, 3.0, 0.25, 0.25));
        // Width ≥ R: fully occluded.
        let h = edge_width_hit(&mut [c(3.0, 4), c(5.0, 7)], 1.0, None);
        assert_eq!((h.tri, h.u, h.v), (4, 1.0, 2.0));
    }

    #[test]
    fn pairs_are_first_second_third_fourth() {
        // Widths 0.1 and 0.3 (not 0.2 = 2nd-3rd, which listing 5.1's off-by-one pairs).
        let h = edge_width_hit(&mut [c(1.0, 0), c(1.1, 1), c(1.3, 2), c(1.6, 3)], 1.0, None);
        assert_eq!((h.tri, h.t), (2, 1.3));
        assert!((h.u - (1.6f32 - 1.3)).abs() < 1e-6);
    }

    #[test]
    fn unpaired_entry_occludes_fully() {
        let h = edge_width_hit(&mut [c(1.0, 0), c(1.1, 1), c(2.0, 5)], 10.0, None);
        assert_eq!((h.tri, h.t, h.u, h.v), (5, 2.0, 1.0, f32::INFINITY));
    }

    #[test]
    fn zero_radius_is_a_hard_shadow() {
        let h = edge_width_hit(&mut [c(2.0, 3), c(2.5, 1)], 0.0, None);
        assert_eq!((h.tri, h.t, h.u), (3, 2.0, 1.0));
    }

    #[test]
    fn scan_stops_at_the_first_pair_as_wide_as_r() {
        let mut scan = EdgeWidthScan::new(0.5, None);
        assert!(!scan.push(c(1.0, 0)));
        assert!(!scan.push(c(1.2, 1)));
        assert!(!scan.push(c(2.0, 2)));
        assert!(scan.push(c(2.5, 3)));
        // Later crossings (an open entry) change nothing.
        assert!(scan.push(c(3.0, 4)));
        let h = scan.finish();
        assert_eq!((h.tri, h.t, h.u, h.v), (2, 2.0, 1.0, 0.5));
    }

    #[test]
    fn shared_vertex_rule_pairs_only_triangles_meeting_at_a_vertex() {
        // Triangles 0 and 1 meet at (1,0,0) through different vertex records (a seam);
        // triangle 2 is apart.
        let p = [
            Vec3::ZERO,
            Vec3::X,
            Vec3::Y,
            Vec3::X,
            Vec3::new(2.0, 0.0, 0.0),
            Vec3::new(1.0, 1.0, 0.0),
            Vec3::new(5.0, 0.0, -0.0),
            Vec3::new(6.0, 0.0, 0.0),
            Vec3::new(5.0, 1.0, 0.0),
        ];
        let sv = SharedVertices::weld(&p, &[[0, 1, 2], [3, 4, 5], [6, 7, 8], [0, 99, 2]]);
        assert_eq!(sv.len(), 4);
        assert!(sv.share(0, 1) && sv.share(1, 0) && sv.share(2, 2));
        assert!(!sv.share(0, 2) && !sv.share(1, 2) && !sv.share(0, 7));
        assert!(
            sv.share(0, 3) && !sv.share(1, 3),
            "an index out of range shares nothing"
        );
        assert!(sv.rule(EdgePairing::Any).is_none());
        let rule = sv.rule(EdgePairing::SharedVertex);
        // Adjacent entry and exit: eq. 5.1 as without the rule.
        let h = edge_width_hit(&mut [c(3.0, 0), c(3.25, 1)], 1.0, rule);
        assert_eq!((h.tri, h.u, h.v), (0, 0.25, 0.25));
        // Two separate sheets 0.25 apart: a leak without the rule, an umbra with it.
        let leak = edge_width_hit(&mut [c(3.0, 0), c(3.25, 2)], 1.0, None);
        assert_eq!(leak.u, 0.25);
        let h = edge_width_hit(&mut [c(3.0, 0), c(3.25, 2)], 1.0, rule);
        assert_eq!((h.tri, h.u, h.v), (0, 1.0, f32::INFINITY));
        for name in EdgePairing::NAMES {
            assert_eq!(EdgePairing::from_name(name).unwrap().name(), name);
        }
    }

    #[test]
    fn ties_sort_by_triangle_and_zero_width_pairs_do_not_occlude() {
        let h = edge_width_hit(&mut [c(1.0, 9), c(1.0, 2)], 1.0, None);
        assert_eq!(h, Hit::MISS);
        let mut v = [c(1.0, 9), c(1.0, 2), c(0.5, 4)];
        sort_crossings(&mut v);
        assert_eq!(v.map(|x| x.tri), [4, 2, 9]);
    }
}
