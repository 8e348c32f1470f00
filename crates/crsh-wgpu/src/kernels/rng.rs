//! Counter-based random numbers on the device (`rng.wgsl`), the twin of [`crsh_core::rng`].
//!
//! `rng.wgsl` holds `pcg4d`, `rng_unit`, `rng_uniforms2` (a ray's key → two uniforms),
//! Duff et al.'s `rng_basis`, `cosine_direction` and `front_cosine_direction`; the ray
//! generators `ao` and `diffuse` prepend it ([`crate::kernels::RNG_WGSL`]). The integer hash
//! and the uniforms are the CPU's bit for bit (WGSL's `u32` arithmetic wraps as Rust's
//! `wrapping_*` does, and 24-bit integers convert to `f32` exactly); the directions agree with
//! the CPU's up to the rounding of `sqrt`, division and the sine / cosine polynomials
//! (`trig.wgsl`), a few 1e-7.
//!
//! [`rng_on_device`] evaluates everything for a list of keys and normals, so that the tests
//! can compare it with [`crsh_core::rng`] ([`rng_on_host`]).

use bytemuck::{Pod, Zeroable};
use crsh_core::glam::Vec3;
use crsh_core::rng::{cosine_direction, front_cosine_direction, unit, RngKey};

use crate::adapter::GpuContext;
use crate::backend::GpuBuffer;
use crate::error::GpuResult;
use crate::kernel::{encoder, submit, uniform, Kernel, Slot};

const PROBE: &str = include_str!("rng_probe.wgsl");

/// One evaluation asked of [`rng_on_device`] (48 bytes, `Query` in `rng_probe.wgsl`).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct RngQuery {
    /// The key `[pixel, sample, bounce, seed]`.
    pub key: [u32; 4],
    /// The unit shading normal (`w` unused).
    pub normal: [f32; 4],
    /// The unit geometric normal, on the side of `normal` (`w` unused).
    pub geo_normal: [f32; 4],
}

impl RngQuery {
    /// The query for `key` with the normals `normal` and `geo_normal`.
    pub fn new(key: RngKey, normal: Vec3, geo_normal: Vec3) -> RngQuery {
        RngQuery {
            key: [key.pixel, key.sample, key.bounce, key.seed],
            normal: normal.extend(0.0).to_array(),
            geo_normal: geo_normal.extend(0.0).to_array(),
        }
    }

    fn rng_key(&self) -> RngKey {
        let [pixel, sample, bounce, seed] = self.key;
        RngKey {
            pixel,
            sample,
            bounce,
            seed,
        }
    }
}

/// What one [`RngQuery`] evaluates to (64 bytes, `Answer` in `rng_probe.wgsl`).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct RngAnswer {
    /// `pcg4d(key)`.
    pub words: [u32; 4],
    /// `unit` of each word.
    pub uniforms: [f32; 4],
    /// `cosine_direction(normal, uniforms[0..2])` (`w` = 0).
    pub cosine: [f32; 4],
    /// `front_cosine_direction(normal, geo_normal, uniforms[0..2])` (`w` = 0).
    pub front: [f32; 4],
}

impl RngAnswer {
    /// The cosine-weighted direction.
    pub fn cosine(&self) -> Vec3 {
        Vec3::from_slice(&self.cosine[..3])
    }

    /// The direction kept in front of the geometric normal.
    pub fn front(&self) -> Vec3 {
        Vec3::from_slice(&self.front[..3])
    }
}

#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct Params {
    n: u32,
    pad: [u32; 3],
}

struct RngProbe {
    kernel: Kernel,
}

impl RngProbe {
    fn new(ctx: &GpuContext) -> GpuResult<RngProbe> {
        let source = super::compose(&[super::GLAM_WGSL, super::TRIG_WGSL, super::RNG_WGSL, PROBE]);
        Ok(RngProbe {
            kernel: Kernel::new(
                ctx,
                "crsh rng probe",
                &source,
                &["probe"],
                &[Slot::Uniform, Slot::Read, Slot::ReadWrite],
            )?,
        })
    }
}

/// Evaluates `rng.wgsl` on the device for every query (one binding's worth at most).
pub fn rng_on_device(ctx: &GpuContext, queries: &[RngQuery]) -> GpuResult<Vec<RngAnswer>> {
    if queries.is_empty() {
        return Ok(Vec::new());
    }
    ctx.check_storage_binding(
        "rng answers",
        (queries.len() * std::mem::size_of::<RngAnswer>()) as u64,
    )?;
    let k = ctx.kernel(RngProbe::new)?;
    let input = GpuBuffer::from_slice(ctx, "crsh rng queries", queries)?;
    let output = GpuBuffer::<RngAnswer>::zeroed(ctx, "crsh rng answers", queries.len())?;
    let params = Params {
        n: queries.len() as u32,
        pad: [0; 3],
    };
    let u = uniform(ctx, "crsh rng params", &params);
    let bg = k.kernel.bind_group(
        ctx,
        &[u.as_entire_binding(), input.binding(), output.binding()],
    );
    let mut enc = encoder(ctx, "crsh rng probe");
    {
        let mut pass = ctx.compute_pass(&mut enc, "crsh rng probe");
        k.kernel
            .dispatch(ctx, &mut pass, "probe", &bg, queries.len() as u32)?;
    }
    submit(ctx, "crsh rng probe", enc)?;
    output.to_vec(ctx)
}

/// The CPU twin of [`rng_on_device`]: [`crsh_core::rng`] on every query.
pub fn rng_on_host(queries: &[RngQuery]) -> Vec<RngAnswer> {
    queries
        .iter()
        .map(|q| {
            let words = q.rng_key().words();
            let u = [unit(words[0]), unit(words[1])];
            let n = Vec3::from_slice(&q.normal[..3]);
            let n_geo = Vec3::from_slice(&q.geo_normal[..3]);
            RngAnswer {
                words,
                uniforms: words.map(unit),
                cosine: cosine_direction(n, u).extend(0.0).to_array(),
                front: front_cosine_direction(n, n_geo, u).extend(0.0).to_array(),
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn records_match_their_wgsl_sizes() {
        assert_eq!(std::mem::size_of::<RngQuery>(), 48);
        assert_eq!(std::mem::size_of::<RngAnswer>(), 64);
    }
}
