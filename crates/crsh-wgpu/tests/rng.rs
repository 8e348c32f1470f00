//! The device's counter-based random numbers (`rng.wgsl`) against `crsh_core::rng`: the same
//! `pcg4d` words and `unit()` floats bit for bit for many keys (every field varied, edge
//! values included), and cosine-weighted directions within a few 1e-7 for many normals
//! (axes, both signs of a zero z, tilted shading normals that the front mirror folds back).
//!
//! Without an adapter every test prints `SKIP:` and passes, unless `CRSH_REQUIRE_GPU=1`.

use crsh_core::glam::Vec3;
use crsh_core::rng::{pcg4d, RngKey};
use crsh_wgpu::kernels::rng::{rng_on_device, rng_on_host, RngQuery};

/// Largest component difference allowed between the CPU's and the device's directions: the
/// device's `sqrt`, division and sine / cosine polynomials differ from the CPU's correctly
/// rounded results by a few ULPs.
const DIR_TOL: f32 = 2e-6;

/// A deterministic unit vector for `i` (a splitmix-style hash mapped to the sphere).
fn unit_vector(i: u32) -> Vec3 {
    let w = pcg4d([i, 0x5eed, 17, 3]);
    let z = (w[0] >> 8) as f32 / 16_777_216.0 * 2.0 - 1.0;
    let phi = (w[1] >> 8) as f32 / 16_777_216.0 * std::f32::consts::TAU;
    let r = (1.0 - z * z).max(0.0).sqrt();
    Vec3::new(r * phi.cos(), r * phi.sin(), z).normalize()
}

fn queries() -> Vec<RngQuery> {
    let mut out = Vec::new();
    let special = [
        Vec3::X,
        -Vec3::X,
        Vec3::Y,
        -Vec3::Y,
        Vec3::Z,
        -Vec3::Z,
        Vec3::new(0.6, 0.8, 0.0),
        Vec3::new(0.6, 0.8, -0.0),
        Vec3::new(0.0, 0.0, -1.0),
        Vec3::new(1e-4, 0.0, -1.0).normalize(),
    ];
    let mut i = 0u32;
    for seed in [0, 1, 0xdead_beef, u32::MAX] {
        for bounce in [0, 1, 5, u32::MAX] {
            for sample in [0, 1, 3, 4095] {
                for pixel in (0..1024).chain([u32::MAX - 1, u32::MAX]) {
                    let key = RngKey {
                        pixel,
                        sample,
                        bounce,
                        seed,
                    };
                    let n_geo = if i.is_multiple_of(7) {
                        special[(i / 7) as usize % special.len()]
                    } else {
                        unit_vector(i)
                    };
                    // Every third query tilts the shading normal away from the face, some
                    // past 90°, so that the front mirror and its fallback run.
                    let n = if i.is_multiple_of(3) {
                        (n_geo + unit_vector(i ^ 0x9e37_79b9) * 1.5).normalize_or(n_geo)
                    } else {
                        n_geo
                    };
                    out.push(RngQuery::new(key, n, n_geo));
                    i += 1;
                }
            }
        }
    }
    out
}

#[test]
fn device_random_numbers_are_the_cpus() {
    let Some(ctx) = crsh_wgpu::testing::shared_context("device_random_numbers_are_the_cpus") else {
        return;
    };
    let q = queries();
    let got = rng_on_device(&ctx, &q).unwrap();
    let want = rng_on_host(&q);
    assert_eq!(got.len(), want.len());
    let (mut worst_cos, mut worst_front, mut folded) = (0.0f32, 0.0f32, 0usize);
    for (i, (g, w)) in got.iter().zip(&want).enumerate() {
        assert_eq!(g.words, w.words, "query {i} {:?}: pcg4d words", q[i].key);
        let bits = |u: [f32; 4]| u.map(f32::to_bits);
        assert_eq!(
            bits(g.uniforms),
            bits(w.uniforms),
            "query {i} {:?}: unit()",
            q[i].key
        );
        let dc = (g.cosine() - w.cosine()).abs().max_element();
        let df = (g.front() - w.front()).abs().max_element();
        assert!(
            dc <= DIR_TOL && df <= DIR_TOL,
            "query {i} {:?}: directions gpu {:?} / {:?}, cpu {:?} / {:?}",
            q[i],
            g.cosine(),
            g.front(),
            w.cosine(),
            w.front()
        );
        worst_cos = worst_cos.max(dc);
        worst_front = worst_front.max(df);
        if w.cosine() != w.front() {
            folded += 1;
        }
        let n_geo = Vec3::from_slice(&q[i].geo_normal[..3]);
        assert!(g.front().dot(n_geo) > 0.0, "query {i}: behind the face");
    }
    println!(
        "{} keys: words and uniforms identical; direction differences up to {worst_cos:e} \
         (cosine) and {worst_front:e} (front, {folded} mirrored)",
        q.len()
    );
    assert!(folded > 100, "only {folded} directions were mirrored");
}

#[test]
fn device_pcg4d_golden_values() {
    let Some(ctx) = crsh_wgpu::testing::shared_context("device_pcg4d_golden_values") else {
        return;
    };
    let key = |k: [u32; 4]| {
        RngQuery::new(
            RngKey {
                pixel: k[0],
                sample: k[1],
                bounce: k[2],
                seed: k[3],
            },
            Vec3::Z,
            Vec3::Z,
        )
    };
    let got = rng_on_device(&ctx, &[key([0; 4]), key([1, 2, 3, 4])]).unwrap();
    // crsh_core::rng's golden values.
    assert_eq!(
        got[0].words,
        [251_852_841, 760_645_481, 850_445_371, 3_542_436_074]
    );
    assert_eq!(
        got[1].words,
        [908_250_390, 4_044_648_920, 3_775_961_919, 45_698_095]
    );
    assert!(rng_on_device(&ctx, &[]).unwrap().is_empty());
}
