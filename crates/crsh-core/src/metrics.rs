//! Image metrics and output conversion shared by every backend and the CLI.

/// Converts a linear HDR RGBA image to 8-bit RGBA: each channel clamped to `[0, 1]`, then
/// encoded with the sRGB transfer function (alpha forced to 255).
pub fn to_rgba8(image: &[[f32; 4]]) -> Vec<u8> {
    let mut out = Vec::with_capacity(image.len() * 4);
    for px in image {
        for c in &px[..3] {
            out.push(encode_srgb(*c));
        }
        out.push(255);
    }
    out
}

/// sRGB-encodes one linear channel value (NaN → 0) to 8 bits.
pub fn encode_srgb(linear: f32) -> u8 {
    let x = if linear.is_nan() {
        0.0
    } else {
        linear.clamp(0.0, 1.0)
    };
    let s = if x <= 0.003_130_8 {
        12.92 * x
    } else {
        1.055 * x.powf(1.0 / 2.4) - 0.055
    };
    (s * 255.0 + 0.5).floor().clamp(0.0, 255.0) as u8
}

/// Peak signal-to-noise ratio in dB between two 8-bit RGBA images of equal size, over the RGB
/// channels; `f64::INFINITY` when they are identical.
///
/// # Panics
/// If the images differ in length.
pub fn psnr_rgba8(a: &[u8], b: &[u8]) -> f64 {
    assert_eq!(a.len(), b.len(), "images differ in size");
    let mut se = 0.0f64;
    let mut n = 0u64;
    for (pa, pb) in a.chunks_exact(4).zip(b.chunks_exact(4)) {
        for c in 0..3 {
            let d = pa[c] as f64 - pb[c] as f64;
            se += d * d;
            n += 1;
        }
    }
    if se == 0.0 || n == 0 {
        return f64::INFINITY;
    }
    let mse = se / n as f64;
    10.0 * (255.0f64 * 255.0 / mse).log10()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn srgb_endpoints() {
        assert_eq!(encode_srgb(0.0), 0);
        assert_eq!(encode_srgb(1.0), 255);
        assert_eq!(encode_srgb(7.0), 255);
        assert_eq!(encode_srgb(f32::NAN), 0);
        assert_eq!(encode_srgb(0.5), 188);
    }

    #[test]
    fn psnr_known_values() {
        let a = vec![100u8, 100, 100, 255];
        assert!(psnr_rgba8(&a, &a).is_infinite());
        let b = vec![110u8, 100, 100, 255];
        // MSE = 100 / 3.
        let expect = 10.0 * (255.0f64 * 255.0 / (100.0 / 3.0)).log10();
        assert!((psnr_rgba8(&a, &b) - expect).abs() < 1e-9);
    }
}
