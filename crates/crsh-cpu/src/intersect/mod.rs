//! Intersector variants (exact ray-triangle tests, §3.2.9).

pub mod brute;
pub mod brute64;
pub mod bvh;
pub mod bvh2;
pub mod embree;
pub mod grid;
pub mod kdtree;

use crsh_core::{Hit, HitMode, Ray};

/// Whether a single-ray query of `ray` has nothing to do, given the hit `best` already
/// stored: an any-hit query whose ray is already hit, or an empty (or NaN) interval
/// `t_min ≥ t_max` (Zoet and Bikker's rays whose origin offset passed their end, which can
/// hit nothing). Every intersector that traces rays one at a time skips these alike.
#[inline]
pub(crate) fn nothing_to_trace(ray: &Ray, mode: HitMode, best: &Hit) -> bool {
    (mode == HitMode::Any && best.is_hit())
        || ray.t_min.partial_cmp(&ray.t_max) != Some(std::cmp::Ordering::Less)
}
