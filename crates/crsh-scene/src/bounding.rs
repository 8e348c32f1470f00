//! Bounding volumes of scene geometry (being written).

use crsh_core::Sphere;
use glam::Vec3;

/// The exact minimal bounding sphere of `points` (Welzl / Gärtner).
pub fn min_sphere(points: &[Vec3]) -> Sphere {
    let _ = points;
    unimplemented!()
}
