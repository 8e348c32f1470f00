// Accurate f32 trigonometry from +, −, ×, ÷ and sqrt only. WGSL's sin, cos, atan2 and acos need
// not be accurate (Vulkan allows an absolute error of 2⁻¹¹ for sin / cos and 4096 ULP for
// atan2; lavapipe's acos was off by 2e-5 rad), which the conservative bounds of the hierarchy
// and the traversal cannot absorb. Prepended where needed; `PI` must be defined by the includer.

// atan(x) for x >= 0 by Cephes' atanf (range reduction at tan(π/8), tan(3π/8), then a
// degree-9 odd polynomial): within a few 1e-8 rad.
fn atan_pos(x0: f32) -> f32 {
    var x = x0;
    var y0 = 0.0;
    if (x > 2.414213562373095) {
        y0 = 0.5 * PI;
        x = -1.0 / x;
    } else if (x > 0.4142135623730950) {
        y0 = 0.25 * PI;
        x = (x - 1.0) / (x + 1.0);
    }
    let z = x * x;
    let y = (((8.05374449538e-2 * z - 1.38776856032e-1) * z + 1.99777106478e-1) * z
        - 3.33329491539e-1) * z * x + x;
    return y0 + y;
}

// atan2(y, x) in [-π, π] from atan_pos, with IEEE's signed zeros: atan2(±0, +0) = ±0 and
// atan2(±0, −0) = ±π.
fn atan2_accurate(y: f32, x: f32) -> f32 {
    let ax = abs(x);
    let ay = abs(y);
    var a: f32;
    if (ay == 0.0 && ax == 0.0) {
        a = 0.0;
    } else if (ay <= ax) {
        a = atan_pos(ay / ax);
    } else {
        a = 0.5 * PI - atan_pos(ax / ay);
    }
    if (x < 0.0 || (x == 0.0 && (bitcast<u32>(x) & 0x80000000u) != 0u)) {
        a = PI - a;
    }
    if (y < 0.0 || (y == 0.0 && (bitcast<u32>(y) & 0x80000000u) != 0u)) {
        a = -a;
    }
    return a;
}

// sin(x) for x in [-π/2, π/2]: the Taylor series to x¹³ (error below 1e-9).
fn sin_half(x: f32) -> f32 {
    let z = x * x;
    return x * (1.0 + z * (-1.0 / 6.0 + z * (1.0 / 120.0 + z * (-1.0 / 5040.0
        + z * (1.0 / 362880.0 + z * (-1.0 / 39916800.0 + z * (1.0 / 6227020800.0)))))));
}

// sin and cos of an angle in [0, π], within about 1e-7.
fn sin_accurate(x: f32) -> f32 {
    return sin_half(select(x, PI - x, x > 0.5 * PI));
}

fn cos_accurate(x: f32) -> f32 {
    return sin_half(0.5 * PI - x);
}
