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

use crate::ray::{Hit, NO_HIT};

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
pub struct EdgeWidthScan {
    radius: f32,
    /// The entry crossing still waiting for its exit.
    open: Option<Crossing>,
    /// The widest pair so far: its entry and width.
    widest: Option<(Crossing, f32)>,
    /// The final answer once the segment is known to be fully occluded.
    done: Option<Hit>,
}

impl EdgeWidthScan {
    /// A scan for a light of radius `radius` (the `R` of eq. 5.1; `≤ 0`: any crossing
    /// occludes fully).
    pub fn new(radius: f32) -> Self {
        EdgeWidthScan {
            radius,
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
                let width = c.t - entry.t;
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

/// The edge-width answer for all crossings of a segment (any order; sorted here).
pub fn edge_width_hit(crossings: &mut [Crossing], radius: f32) -> Hit {
    sort_crossings(crossings);
    let mut scan = EdgeWidthScan::new(radius);
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
        assert_eq!(edge_width_hit(&mut [], 1.0), Hit::MISS);
        assert_eq!(occlusion(&Hit::MISS), 0.0);
    }

    #[test]
    fn one_pair_is_eq_5_1() {
        let h = edge_width_hit(&mut [c(3.25, 7), c(3.0, 4)], 1.0);
        assert_eq!((h.tri, h.t, h.u, h.v), (4, 3.0, 0.25, 0.25));
        // Width ≥ R: fully occluded.
        let h = edge_width_hit(&mut [c(3.0, 4), c(5.0, 7)], 1.0);
        assert_eq!((h.tri, h.u, h.v), (4, 1.0, 2.0));
    }

    #[test]
    fn pairs_are_first_second_third_fourth() {
        // Widths 0.1 and 0.3 (not 0.2 = 2nd-3rd, which listing 5.1's off-by-one pairs).
        let h = edge_width_hit(&mut [c(1.0, 0), c(1.1, 1), c(1.3, 2), c(1.6, 3)], 1.0);
        assert_eq!((h.tri, h.t), (2, 1.3));
        assert!((h.u - (1.6f32 - 1.3)).abs() < 1e-6);
    }

    #[test]
    fn unpaired_entry_occludes_fully() {
        let h = edge_width_hit(&mut [c(1.0, 0), c(1.1, 1), c(2.0, 5)], 10.0);
        assert_eq!((h.tri, h.t, h.u, h.v), (5, 2.0, 1.0, f32::INFINITY));
    }

    #[test]
    fn zero_radius_is_a_hard_shadow() {
        let h = edge_width_hit(&mut [c(2.0, 3), c(2.5, 1)], 0.0);
        assert_eq!((h.tri, h.t, h.u), (3, 2.0, 1.0));
    }

    #[test]
    fn scan_stops_at_the_first_pair_as_wide_as_r() {
        let mut scan = EdgeWidthScan::new(0.5);
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
    fn ties_sort_by_triangle_and_zero_width_pairs_do_not_occlude() {
        let h = edge_width_hit(&mut [c(1.0, 9), c(1.0, 2)], 1.0);
        assert_eq!(h, Hit::MISS);
        let mut v = [c(1.0, 9), c(1.0, 2), c(0.5, 4)];
        sort_crossings(&mut v);
        assert_eq!(v.map(|x| x.tri), [4, 2, 9]);
    }
}
