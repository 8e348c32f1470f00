//! What the `ao` and `diffuse` generators share (seed 001 §4): one cosine-weighted ray leaving
//! a surface ([`CosineRays::ray`]) and the slot array of a batch, filled in parallel with the
//! origin offsets applied ([`fill_slots`]). The wgpu twins share `raygen/cosine.wgsl` the
//! same way.

use crsh_core::glam::Vec3;
use crsh_core::rng::{front_cosine_direction, RngKey};
use crsh_core::{CoreError, Ray, RayKind, Result, Surface};
use rayon::prelude::*;

use crate::raygen::offsets::Offsets;
use crate::raygen::whitted::{offset_segment, Leg, OffsetPolicy};

/// Surfaces per parallel work item.
const CHUNK: usize = 1024;

/// The per-generator settings of a cosine-weighted surface ray.
#[derive(Clone, Copy, Debug)]
pub struct CosineRays {
    /// Seed of the counter-based random numbers (param `seed`).
    pub seed: u32,
    /// Rays whose largest throughput component is below this are not made.
    pub min_throughput: f32,
    /// The self-intersection policy (param `offset`).
    pub policy: OffsetPolicy,
}

impl CosineRays {
    /// The ray of kind `kind` and sample `sample` leaving surface `s` (index `source`) with
    /// `throughput`, before the origin offset: the direction
    /// [`front_cosine_direction`] for the key (pixel, `sample`, bounce = the surface's depth,
    /// seed), the segment of [`offset_segment`], and `t_max = max(length, t_min)`
    /// (`f32::INFINITY` for an unbounded ray). `None` when the throughput is below the
    /// threshold or not finite, or no direction results.
    pub fn ray(
        &self,
        kind: RayKind,
        source: u32,
        s: &Surface,
        sample: u32,
        throughput: Vec3,
        length: f32,
    ) -> Option<Ray> {
        if !(throughput.max_element() >= self.min_throughput && throughput.is_finite()) {
            return None;
        }
        let key = RngKey {
            pixel: s.pixel,
            sample,
            bounce: s.depth,
            seed: self.seed,
        };
        let dir = front_cosine_direction(s.normal, s.geo_normal, key.uniforms2());
        if dir == Vec3::ZERO {
            return None;
        }
        let seg = offset_segment(s.position, s.geo_normal, Leg::Along(dir), &self.policy)?;
        Some(Ray {
            origin: seg.origin,
            t_min: seg.t_min,
            dir: seg.dir,
            t_max: length.max(seg.t_min),
            throughput,
            kind: kind as u32,
            pixel: s.pixel,
            light: sample,
            depth: s.depth + 1,
            source,
        })
    }
}

/// Ray creation before trimming: `per` slots per surface (surface-major), slot `k` of a hit
/// surface `s` (index `source`) holding `make(source, k, s)`, with `offsets` applied, and its
/// head flag (1 where a ray was made). Returns the slots, the flags and the number of rays the
/// offsets ended (interval emptied). `what` names the rays in the error when the batch does not
/// fit 32-bit ray indices.
pub fn fill_slots(
    surfaces: &[Surface],
    per: usize,
    what: &str,
    offsets: &Offsets,
    make: impl Fn(u32, u32, &Surface) -> Option<Ray> + Sync,
) -> Result<(Vec<Ray>, Vec<u32>, u64)> {
    let total = surfaces.len().checked_mul(per);
    if surfaces.len() > u32::MAX as usize || total.is_none_or(|t| t > u32::MAX as usize) {
        return Err(CoreError::InvalidInput(format!(
            "{} surfaces × {per} {what} do not fit 32-bit ray indices",
            surfaces.len()
        )));
    }
    let n = surfaces.len() * per;
    let mut slots = vec![<Ray as bytemuck::Zeroable>::zeroed(); n];
    let mut flags = vec![0u32; n];
    let ended = slots
        .par_chunks_mut(CHUNK * per)
        .zip(flags.par_chunks_mut(CHUNK * per))
        .enumerate()
        .map(|(c, (rays, heads))| {
            let mut ended = 0u64;
            for (j, (ray, head)) in rays.iter_mut().zip(heads.iter_mut()).enumerate() {
                let slot = c * CHUNK * per + j;
                let (source, k) = (slot / per, (slot % per) as u32);
                let s = &surfaces[source];
                if !s.is_hit() {
                    continue;
                }
                let Some(mut r) = make(source as u32, k, s) else {
                    continue;
                };
                if !offsets.apply(s.tri, &mut r) {
                    ended += 1;
                }
                *ray = r;
                *head = 1;
            }
            ended
        })
        .sum();
    Ok((slots, flags, ended))
}
