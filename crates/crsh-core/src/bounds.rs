//! Bounding volumes: spheres, cones, sphere-cone ray-space nodes and axis-aligned boxes.
//!
//! Construction algorithms (minimal spheres, cone unions) live with the stages that use them;
//! these are the compact records (16 or 32 bytes) that stages store and upload.

use bytemuck::{Pod, Zeroable};
use glam::Vec3;
use serde::{Deserialize, Serialize};

/// A sphere (16 bytes).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable, Serialize, Deserialize)]
pub struct Sphere {
    /// Center.
    pub center: Vec3,
    /// Radius (0 for a point).
    pub radius: f32,
}

impl Sphere {
    /// A sphere from center and radius.
    pub fn new(center: Vec3, radius: f32) -> Sphere {
        Sphere { center, radius }
    }

    /// Whether `p` lies inside, allowing a relative tolerance `rel_eps` of the radius (plus an
    /// absolute floor scaled by the magnitude of the coordinates, for float rounding).
    pub fn contains(&self, p: Vec3, rel_eps: f32) -> bool {
        let scale = self
            .center
            .abs()
            .max_element()
            .max(p.abs().max_element())
            .max(1.0);
        self.center.distance(p) <= self.radius * (1.0 + rel_eps) + scale * 1e-6
    }
}

/// A cone of directions: unit axis and half-angle in radians, in `[0, π]` (16 bytes).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable, Serialize, Deserialize)]
pub struct Cone {
    /// Unit axis.
    pub axis: Vec3,
    /// Half-angle (spread) in radians.
    pub half_angle: f32,
}

impl Cone {
    /// Whether the unit direction `d` lies within the cone (with an absolute angle tolerance).
    pub fn contains_dir(&self, d: Vec3, eps: f32) -> bool {
        let c = self.axis.dot(d.normalize()).clamp(-1.0, 1.0);
        c.acos() <= self.half_angle + eps
    }
}

/// A ray-space hierarchy node: the sphere bounds the ray origins, the cone the directions
/// (seed 000 §3.2.7, figs 3.16-3.18; 32 bytes).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable, Serialize, Deserialize)]
pub struct SphereCone {
    /// Bounds the origins.
    pub sphere: Sphere,
    /// Bounds the directions.
    pub cone: Cone,
}

/// The largest `f32` not above `x` (`x` rounded toward −∞, NaN stays NaN): how a lower bound
/// computed in `f64` is stored so that it does not move inwards.
pub fn f32_down(x: f64) -> f32 {
    let f = x as f32;
    if f64::from(f) > x {
        f.next_down()
    } else {
        f
    }
}

/// The smallest `f32` not below `x` (`x` rounded toward +∞, NaN stays NaN): how an upper bound
/// (a radius, an angle, a box's maximum) computed in `f64` is stored so that it does not
/// shrink.
pub fn f32_up(x: f64) -> f32 {
    let f = x as f32;
    if f64::from(f) < x {
        f.next_up()
    } else {
        f
    }
}

/// An axis-aligned bounding box (24 bytes). The empty box has `min > max`.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable, Serialize, Deserialize)]
pub struct Aabb {
    /// Minimum corner.
    pub min: Vec3,
    /// Maximum corner.
    pub max: Vec3,
}

impl Aabb {
    /// The empty box (identity of [`Aabb::union`]).
    pub const EMPTY: Aabb = Aabb {
        min: Vec3::splat(f32::INFINITY),
        max: Vec3::splat(f32::NEG_INFINITY),
    };

    /// The smallest box containing `points`.
    pub fn from_points(points: impl IntoIterator<Item = Vec3>) -> Aabb {
        points.into_iter().fold(Aabb::EMPTY, |b, p| b.grow(p))
    }

    /// This box grown to contain `p`.
    pub fn grow(self, p: Vec3) -> Aabb {
        Aabb {
            min: self.min.min(p),
            max: self.max.max(p),
        }
    }

    /// The smallest box containing both.
    pub fn union(self, o: Aabb) -> Aabb {
        Aabb {
            min: self.min.min(o.min),
            max: self.max.max(o.max),
        }
    }

    /// Whether no point is inside.
    pub fn is_empty(&self) -> bool {
        self.min.cmpgt(self.max).any()
    }

    /// Extent per axis (zero for the empty box).
    pub fn size(&self) -> Vec3 {
        if self.is_empty() {
            Vec3::ZERO
        } else {
            self.max - self.min
        }
    }

    /// Center.
    pub fn center(&self) -> Vec3 {
        (self.min + self.max) * 0.5
    }

    /// Length of the diagonal (zero for the empty box).
    pub fn diagonal(&self) -> f32 {
        self.size().length()
    }

    /// Whether `p` is inside or on the boundary.
    pub fn contains(&self, p: Vec3) -> bool {
        p.cmpge(self.min).all() && p.cmple(self.max).all()
    }

    /// Whether the boxes share a point (touching counts). False when either is empty, except
    /// that an empty box still "overlaps" a box that is infinite on every side it is empty on
    /// (no culling test relies on that case).
    #[inline]
    pub fn overlaps(&self, o: &Aabb) -> bool {
        self.min.cmple(o.max).all() && o.min.cmple(self.max).all()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn outward_rounding_brackets_the_value() {
        let check = |x: f64| {
            let (lo, hi) = (f32_down(x), f32_up(x));
            assert!(f64::from(lo) <= x && f64::from(hi) >= x && lo <= hi, "{x}");
            // The nearest on each side: one step further passes `x`.
            assert!(f64::from(lo.next_up()) > x || f64::from(lo) == x, "{x}");
            assert!(f64::from(hi.next_down()) < x || f64::from(hi) == x, "{x}");
            assert!(hi == lo || f32_up(f64::from(lo)) == lo, "{x}");
        };
        for x in [
            0.1f64, -0.1, 1e-40, -1e-40, 0.0, 3.0, -3.0, 1e30, 16777217.0, 1e-50, -1e-50, 1e300,
        ] {
            check(x);
        }
        // Pseudo-random magnitudes from 1e-20 to 1e20, both signs.
        let mut state = 71u64;
        for _ in 0..20_000 {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            let unit = (state >> 11) as f64 / (1u64 << 53) as f64;
            check((unit - 0.5) * 10f64.powi((state % 40) as i32 - 20));
        }
        assert_eq!(f32_down(f64::INFINITY), f32::INFINITY);
        assert_eq!(f32_up(f64::NEG_INFINITY), f32::NEG_INFINITY);
        assert_eq!(f32_down(1e300), f32::MAX);
        assert!(f32_down(1e-50) == 0.0 && f32_down(-1e-50) < 0.0 && f32_up(1e-50) > 0.0);
        assert!(f32_down(f64::NAN).is_nan() && f32_up(f64::NAN).is_nan());
    }

    #[test]
    fn overlap_counts_touching_boxes_and_not_empty_ones() {
        let a = Aabb::from_points([Vec3::ZERO, Vec3::ONE]);
        let touching = Aabb::from_points([Vec3::ONE, Vec3::splat(2.0)]);
        let apart = Aabb::from_points([Vec3::new(1.5, 0.0, 0.0), Vec3::new(2.0, 1.0, 1.0)]);
        let inside = Aabb::from_points([Vec3::splat(0.25), Vec3::splat(0.5)]);
        assert!(a.overlaps(&touching) && touching.overlaps(&a));
        assert!(a.overlaps(&inside) && inside.overlaps(&a));
        assert!(!a.overlaps(&apart) && !apart.overlaps(&a));
        assert!(!a.overlaps(&Aabb::EMPTY) && !Aabb::EMPTY.overlaps(&a));
    }

    #[test]
    fn aabb_union_and_contains() {
        let b = Aabb::from_points([Vec3::ZERO, Vec3::new(1.0, 2.0, 3.0)]);
        assert!(b.contains(Vec3::new(0.5, 1.0, 1.5)));
        assert!(!b.contains(Vec3::new(1.5, 1.0, 1.5)));
        assert!(Aabb::EMPTY.is_empty());
        assert_eq!(Aabb::EMPTY.union(b), b);
        assert_eq!(b.diagonal(), Vec3::new(1.0, 2.0, 3.0).length());
    }

    #[test]
    fn cone_contains() {
        let c = Cone {
            axis: Vec3::Z,
            half_angle: 0.5,
        };
        assert!(c.contains_dir(Vec3::new(0.0, 0.4, 1.0), 0.0));
        assert!(!c.contains_dir(Vec3::new(0.0, 1.0, 1.0), 0.0));
    }

    #[test]
    fn sizes() {
        assert_eq!(std::mem::size_of::<SphereCone>(), 32);
        assert_eq!(std::mem::size_of::<Aabb>(), 24);
    }
}
