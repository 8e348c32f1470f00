//! What the `ao` and `diffuse` generators share (seed 001 §4): one cosine-weighted ray leaving
//! a surface ([`CosineRays::ray`]) and the slot array of a batch, filled in parallel with the
//! origin offsets applied ([`fill_slots`]). The wgpu twins share `raygen/cosine.wgsl` the
//! same way.

use crsh_core::glam::Vec3;
use crsh_core::rng::{front_cosine_direction, RngKey};
use crsh_core::{CoreError, Ray, RayKind, Result, Surface};

use crate::raygen::offsets::Offsets;
use crate::raygen::whitted::{offset_segment, Leg, OffsetPolicy};
use crate::trim;

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
    let n = check_batch(surfaces, per, what)?;
    Ok(trim::fill_slot_arrays(n, CHUNK * per, |slot| {
        slot_ray(surfaces, per, offsets, &make, slot)
    }))
}

/// [`fill_slots`]' rays compacted within each run of 1,024 surfaces as they are made (one
/// vector per run, in slot order), and the count the offsets ended; concatenated
/// ([`crate::trim::concat_in_order`]) they are the trimmed slots, without the slot and flag
/// arrays ever being written.
pub fn fill_runs(
    surfaces: &[Surface],
    per: usize,
    what: &str,
    offsets: &Offsets,
    make: impl Fn(u32, u32, &Surface) -> Option<Ray> + Sync,
) -> Result<(Vec<Vec<Ray>>, u64)> {
    let n = check_batch(surfaces, per, what)?;
    Ok(trim::fill_runs(n, CHUNK * per, |slot| {
        slot_ray(surfaces, per, offsets, &make, slot)
    }))
}

/// The slot count of `per` rays per surface, or the error when it does not fit 32-bit ray
/// indices.
fn check_batch(surfaces: &[Surface], per: usize, what: &str) -> Result<usize> {
    let total = surfaces.len().checked_mul(per);
    match total {
        Some(t) if surfaces.len() <= u32::MAX as usize && t <= u32::MAX as usize => Ok(t),
        _ => Err(CoreError::InvalidInput(format!(
            "{} surfaces × {per} {what} do not fit 32-bit ray indices",
            surfaces.len()
        ))),
    }
}

/// The ray of `slot` with the offsets applied and whether they ended it (emptied its
/// interval), if its surface is a hit and `make` makes one.
#[inline]
fn slot_ray(
    surfaces: &[Surface],
    per: usize,
    offsets: &Offsets,
    make: &(impl Fn(u32, u32, &Surface) -> Option<Ray> + Sync),
    slot: usize,
) -> Option<(Ray, bool)> {
    let (source, k) = (slot / per, (slot % per) as u32);
    let s = &surfaces[source];
    if !s.is_hit() {
        return None;
    }
    let mut r = make(source as u32, k, s)?;
    let kept = offsets.apply(s.tri, &mut r);
    Some((r, !kept))
}

#[cfg(test)]
mod tests {
    use std::sync::Arc;

    use crsh_core::{ParamValue, PrimaryVisibility, StageSpec, Stats};

    use crate::primary::raster::Raster;
    use crate::raygen::{ao, diffuse};
    use crate::trim::{concat_in_order, trim};
    use crate::Cpu;

    use super::*;

    fn spec(info: crsh_core::StageVariantInfo, params: &[(&str, ParamValue)]) -> StageSpec {
        let mut s = info.defaults();
        for (k, v) in params {
            s.params.insert(k.to_string(), v.clone());
        }
        s
    }

    /// The creation path `generate` takes ([`fill_runs`], then the runs concatenated) gives
    /// [`fill_slots`] + trim's rays bit for bit and its ended counts, for AO and diffuse rays
    /// with and without origin offsets, from primary and deeper vertices, with 1 and 3 threads.
    #[test]
    fn runs_equal_slots_and_trim() {
        let same = |what: &str, runs: (Vec<Vec<Ray>>, u64), slots: (Vec<Ray>, Vec<u32>, u64)| {
            let want = trim(&slots.0, &slots.1).unwrap();
            assert_eq!(runs.1, slots.2, "{what}: ended");
            let got = concat_in_order(runs.0);
            assert_eq!(
                bytemuck::cast_slice::<Ray, u8>(&got),
                bytemuck::cast_slice::<Ray, u8>(&want),
                "{what}"
            );
            assert!(!want.is_empty(), "{what}: no rays");
        };
        for name in crsh_scene::builtin::NAMES {
            let scene = Arc::new(crsh_scene::builtin::build(name).unwrap());
            let raster = Raster::new(&scene, &StageSpec::new("raster")).unwrap();
            let primary = raster.gbuffer(&Cpu, 97, 61, &mut Stats::default()).unwrap();
            // Deeper vertices: the same records one bounce on.
            let deeper: Vec<Surface> = primary.iter().map(|s| Surface { depth: 1, ..*s }).collect();
            for offsets in [
                vec![],
                vec![
                    ("offset", ParamValue::Str("wachter".into())),
                    ("offsets", ParamValue::Str("center".into())),
                ],
            ] {
                let mut params = offsets.clone();
                params.push(("samples", ParamValue::Int(3)));
                let a = ao::Ao::new(&scene, &spec(ao::info(), &params)).unwrap();
                let d = diffuse::Diffuse::new(&scene, &spec(diffuse::info(), &params)).unwrap();
                for (batch, surfaces) in [("primary", &primary), ("deeper", &deeper)] {
                    for threads in [1, 3] {
                        let what = format!("{name} {offsets:?} {batch} {threads} threads");
                        let runs = crate::with_threads(threads, || a.runs(surfaces).unwrap());
                        same(
                            &format!("ao {what}"),
                            runs.unwrap(),
                            a.slots(surfaces).unwrap(),
                        );
                        let runs =
                            crate::with_threads(threads, || d.diffuse_runs(surfaces).unwrap());
                        same(
                            &format!("diffuse {what}"),
                            runs.unwrap(),
                            d.diffuse_slots(surfaces).unwrap(),
                        );
                    }
                }
            }
        }
    }
}
