// A ray-hierarchy node prepared for the conservative node test: the twin of
// crsh_cpu::traverse::crsh::NodeBound, shared by the `crsh` and `dual` traversals (crsh.rs
// states the f32 rounding bound). Needs common.wgsl and trig.wgsl.

const PI: f32 = 3.14159265358979;
// The CPU's margins (crsh_cpu::traverse::crsh::{REL_MARGIN, ABS_MARGIN, ANGLE_MARGIN}).
const REL_MARGIN: f32 = 1e-4;
const ABS_MARGIN: f32 = 1e-5;
const ANGLE_MARGIN: f32 = 1e-4;
// f32's unit roundoff (2⁻²³), for the rounding bound of the cone test (the CPU evaluates it in
// f64).
const EPS: f32 = 1.1920929e-7;
// Relative widening of the reach test for f32 rounding.
const F32_SLACK: f32 = 1e-5;

// A node prepared for may_hit (crsh_cpu's NodeBound), 48 bytes.
struct Bound {
    center: vec3<f32>,
    radius: f32,
    axis: vec3<f32>,
    cos_a: f32,
    sin_a: f32,
    all_dirs: u32,
    reach: f32,
    scale: f32,
}

fn f_finite(x: f32) -> bool {
    return (bitcast<u32>(x) & 0x7f800000u) != 0x7f800000u;
}

fn max_abs3(v: vec3<f32>) -> f32 {
    return max(abs(v.x), max(abs(v.y), abs(v.z)));
}

// crsh_cpu's NodeBound::new (with_reach when `has_reach`): the node prepared for may_hit, and
// whether it is bad (a non-finite or negative sphere or cone, or a zero cone axis).
fn bound_of(node: SphereCone, reach: f32, has_reach: bool) -> Bound {
    var b: Bound;
    b.center = node.center;
    b.radius = node.radius;
    b.scale = max(1.0, max_abs3(node.center));
    b.reach = inf();
    if (has_reach && f_finite(reach) && reach >= 0.0) {
        b.reach = reach;
    }
    let bad_sphere = !f_finite(node.center.x) || !f_finite(node.center.y) || !f_finite(node.center.z)
        || !f_finite(node.radius) || node.radius < 0.0;
    let bad_cone = !f_finite(node.half_angle) || node.half_angle < 0.0 || !f_finite(node.axis.x)
        || !f_finite(node.axis.y) || !f_finite(node.axis.z);
    let alpha = node.half_angle + ANGLE_MARGIN;
    b.axis = vec3<f32>(1.0, 0.0, 0.0);
    b.cos_a = -1.0;
    b.sin_a = 0.0;
    b.all_dirs = 1u;
    var bad = bad_sphere || bad_cone;
    if (!bad && alpha < PI) {
        let len = length(node.axis);
        if (!(len >= 1e-12)) {
            bad = true;
        } else {
            b.axis = node.axis / len;
            b.cos_a = cos_accurate(alpha);
            b.sin_a = sin_accurate(alpha);
            b.all_dirs = 0u;
        }
    }
    // A bad node is marked by bit 1 of all_dirs (and passes every test: the traversal refuses
    // the hierarchy).
    if (bad) {
        b.all_dirs = b.all_dirs | 2u;
    }
    return b;
}

fn bound_is_bad(b: Bound) -> bool {
    return (b.all_dirs & 2u) != 0u;
}

// crsh_cpu's NodeBound::may_hit in f32, with F32_SLACK on top of the CPU's margins.
fn may_hit(b: Bound, sphere: vec4<f32>) -> bool {
    let pc = sphere.xyz;
    let v = pc - b.center;
    let d2 = dot(v, v);
    let scale = max(b.scale, max_abs3(pc));
    let rho = (sphere.w + b.radius) * (1.0 + REL_MARGIN) + ABS_MARGIN * scale;
    if (b.reach < inf()) {
        let limit = (b.reach + rho) * (1.0 + REL_MARGIN) + ABS_MARGIN * scale;
        if (d2 > limit * limit * (1.0 + F32_SLACK)) {
            return false;
        }
    }
    if (b.all_dirs != 0u) {
        return true;
    }
    let rho2 = rho * rho;
    // D ≤ ρ: the CPU's d2 ≤ ρ² in f64; both sides here within a few ε.
    if (d2 <= rho2 * (1.0 + 16.0 * EPS)) {
        return true;
    }
    if (b.cos_a < 0.0 && rho2 >= d2 * b.sin_a * b.sin_a * (1.0 - F32_SLACK)) {
        return true;
    }
    // The CPU's a·v ≥ cos α·√(D² − ρ²) − sin α·ρ is θ ≤ α + β (θ the angle between the axis
    // and v, sin β = ρ/D). Here it is the distance of the sphere's centre from the cone: with
    // x = a·v, y = |a × v|, E = y cos α − x sin α = D sin(θ − α) and F = x cos α + y sin α =
    // D cos(θ − α), pass when E ≤ 0 (inside the cone) or when E ≤ ρ and F ≥ 0 (within ρ of its
    // surface, in front of its apex). The difference of two near-equal lengths above cancels
    // for narrow cones (its rounding, a few ε·D, spans an angle of ε·D / (D·sin(α + β)), as
    // wide as the cone of a shadow node); E and F do not. Each is off by at most about
    // 16.5ε·D + 1.4·D·(ε + 3e-7): x by 3.5ε·D, y by 12ε·D (the cross product, and WGSL's sqrt
    // of 4.5 ulp), the products by ε, cos α and sin α by 3e-7 (trig.wgsl's 1e-7 and α's
    // rounding). The slack takes (32ε + 4e-7)·(|x| + y), at least that much since |x| + y ≥ D.
    let x = dot(b.axis, v);
    let y = length(cross(b.axis, v));
    let slack = (32.0 * EPS + 4e-7) * (abs(x) + y);
    let e = y * b.cos_a - x * b.sin_a;
    let f = x * b.cos_a + y * b.sin_a;
    return e <= slack || (e <= rho * (1.0 + 4.0 * EPS) + slack && f >= -slack);
}

// crsh_cpu's NodeBound::spreads_wider_than in f32: whether the node's rays spread wider at
// the sphere's centre than its radius (r + D·sin α > R), a size comparison only (dual's choice
// of the side to split, not a bound anything relies on).
fn spreads_wider_than(b: Bound, sphere: vec4<f32>) -> bool {
    let room = sphere.w - b.radius;
    if (room < 0.0) {
        return true;
    }
    let v = sphere.xyz - b.center;
    var sin2 = 1.0;
    if (b.all_dirs == 0u && b.cos_a > 0.0) {
        sin2 = b.sin_a * b.sin_a;
    }
    return dot(v, v) * sin2 > room * room;
}
