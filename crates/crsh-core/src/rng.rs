//! Counter-based random numbers and the sampling that AO and diffuse rays share.
//!
//! A ray's random numbers are a pure function of its key (pixel, sample, bounce, seed): no
//! generator state is carried between rays, so an image is the same whatever the thread count,
//! the batch order or the backend. The hash is Jarzynski and Olano's `pcg4d` ("Hash Functions
//! for GPU Rendering", JCGT 9(3), 2020): four 32-bit words in, four out, integer multiplies,
//! adds, xors and shifts only, so the WGSL twin (`crsh-wgpu`'s `rng.wgsl`) computes the very
//! same bits. Floats take the top 24 bits ([`unit()`]), exact in `f32` on both backends.
//!
//! [`cosine_direction`] maps two uniforms to a cosine-weighted direction about a normal
//! (Malley's method: a uniform disc sample lifted to the hemisphere), in the orthonormal basis
//! of Duff et al., "Building an Orthonormal Basis, Revisited" (JCGT 6(1), 2017).

use glam::Vec3;

/// The random-number key of one ray.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct RngKey {
    /// Pixel index (`y * width + x`).
    pub pixel: u32,
    /// Sample index within the pixel (which of its AO rays or diffuse paths).
    pub sample: u32,
    /// Bounce: the depth of the surface the ray leaves (0 at the primary hit).
    pub bounce: u32,
    /// A user seed (param `seed` of the generators).
    pub seed: u32,
}

impl RngKey {
    /// Four random words for this key ([`pcg4d`]).
    pub fn words(&self) -> [u32; 4] {
        pcg4d([self.pixel, self.sample, self.bounce, self.seed])
    }

    /// Two uniforms in `[0, 1)` for this key (the first two words).
    pub fn uniforms2(&self) -> [f32; 2] {
        let w = self.words();
        [unit(w[0]), unit(w[1])]
    }
}

/// Jarzynski and Olano's `pcg4d` hash (JCGT 2020, listing "pcg4d"): an LCG step on each word,
/// two rounds of cross-word multiply-adds with a xor-shift between them.
pub fn pcg4d(v: [u32; 4]) -> [u32; 4] {
    let mut v = v.map(|x| x.wrapping_mul(1_664_525).wrapping_add(1_013_904_223));
    let mix = |v: &mut [u32; 4]| {
        v[0] = v[0].wrapping_add(v[1].wrapping_mul(v[3]));
        v[1] = v[1].wrapping_add(v[2].wrapping_mul(v[0]));
        v[2] = v[2].wrapping_add(v[0].wrapping_mul(v[1]));
        v[3] = v[3].wrapping_add(v[1].wrapping_mul(v[2]));
    };
    mix(&mut v);
    let mut v = v.map(|x| x ^ (x >> 16));
    mix(&mut v);
    v
}

/// A uniform `f32` in `[0, 1)` from the top 24 bits of `w` (exact in `f32`).
pub fn unit(w: u32) -> f32 {
    (w >> 8) as f32 * (1.0 / 16_777_216.0)
}

/// An orthonormal basis `(t, b)` completing the unit vector `n` (Duff et al. 2017, listing 3):
/// branch-free but for the sign, continuous except where `n.z` changes sign.
pub fn basis(n: Vec3) -> (Vec3, Vec3) {
    let sign = 1.0f32.copysign(n.z);
    let a = -1.0 / (sign + n.z);
    let b = n.x * n.y * a;
    (
        Vec3::new(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x),
        Vec3::new(b, sign + n.y * n.y * a, -n.y),
    )
}

/// The cosine-weighted direction about the unit normal `n` for uniforms `u = [u1, u2]`:
/// `r = √u1`, `φ = 2π u2`, `d = r cos φ · t + r sin φ · b + √(1 − u1) · n` (pdf `cos θ / π`).
/// Unit length up to rounding.
pub fn cosine_direction(n: Vec3, u: [f32; 2]) -> Vec3 {
    let r = u[0].sqrt();
    let phi = std::f32::consts::TAU * u[1];
    let (t, b) = basis(n);
    let z = (1.0 - u[0]).max(0.0).sqrt();
    (t * (r * phi.cos()) + b * (r * phi.sin()) + n * z).normalize_or_zero()
}

/// A direction about the shading normal `n` kept on the front side of the geometric normal
/// `n_geo` (both unit, on the same side): [`cosine_direction`] about `n`, mirrored about the
/// geometric plane when it points at or below it (a shading normal tilted away from the face
/// would otherwise send rays into the surface they leave). Falls back to `n_geo` for a
/// direction exactly in the plane.
pub fn front_cosine_direction(n: Vec3, n_geo: Vec3, u: [f32; 2]) -> Vec3 {
    let d = cosine_direction(n, u);
    let s = d.dot(n_geo);
    if s > 0.0 {
        d
    } else {
        let m = (d - 2.0 * s * n_geo).normalize_or_zero();
        if m.dot(n_geo) > 0.0 {
            m
        } else {
            n_geo
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const GOLDEN_ZERO: [u32; 4] = [251_852_841, 760_645_481, 850_445_371, 3_542_436_074];
    const GOLDEN_1234: [u32; 4] = [908_250_390, 4_044_648_920, 3_775_961_919, 45_698_095];

    #[test]
    fn pcg4d_is_a_fixed_function_of_the_key() {
        // Golden values: images and the WGSL twin depend on these exact bits.
        assert_eq!(pcg4d([0; 4]), GOLDEN_ZERO);
        assert_eq!(pcg4d([1, 2, 3, 4]), GOLDEN_1234);
        // Neighbouring keys decorrelate: every output word differs.
        let a = pcg4d([7, 0, 0, 0]);
        let b = pcg4d([8, 0, 0, 0]);
        assert!(a.iter().zip(&b).all(|(x, y)| x != y));
    }

    #[test]
    fn uniforms_are_uniform() {
        let mut hist = [0u32; 16];
        for p in 0..4096 {
            for s in 0..4 {
                let u = RngKey {
                    pixel: p,
                    sample: s,
                    bounce: 1,
                    seed: 0,
                }
                .uniforms2();
                assert!((0.0..1.0).contains(&u[0]) && (0.0..1.0).contains(&u[1]));
                hist[(u[0] * 16.0) as usize] += 1;
            }
        }
        // 16384 draws, 1024 expected per bin; 5 sigma is ±160.
        for h in hist {
            assert!((864..=1184).contains(&h), "{hist:?}");
        }
    }

    #[test]
    fn cosine_directions_are_unit_front_facing_and_cosine_distributed() {
        let n = Vec3::new(0.3, -0.5, 0.81).normalize();
        let (t, b) = basis(n);
        assert!(t.dot(n).abs() < 1e-6 && b.dot(n).abs() < 1e-6 && t.dot(b).abs() < 1e-6);
        let mut mean_cos = 0.0f64;
        let count = 20_000;
        for p in 0..count {
            let u = RngKey {
                pixel: p,
                sample: 0,
                bounce: 0,
                seed: 3,
            }
            .uniforms2();
            let d = cosine_direction(n, u);
            assert!((d.length() - 1.0).abs() < 1e-5);
            assert!(d.dot(n) >= 0.0);
            mean_cos += d.dot(n) as f64;
        }
        // E[cos θ] under the cosine pdf is 2/3.
        mean_cos /= count as f64;
        assert!((mean_cos - 2.0 / 3.0).abs() < 0.01, "{mean_cos}");
    }

    #[test]
    fn tilted_shading_normals_stay_in_front_of_the_face() {
        let n_geo = Vec3::Z;
        let n = Vec3::new(0.9, 0.0, 0.2).normalize();
        for p in 0..2000 {
            let u = RngKey {
                pixel: p,
                sample: 1,
                bounce: 2,
                seed: 0,
            }
            .uniforms2();
            assert!(front_cosine_direction(n, n_geo, u).dot(n_geo) > 0.0);
        }
    }
}
