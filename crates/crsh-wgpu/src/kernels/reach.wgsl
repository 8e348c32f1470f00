// The rounding guard of a hierarchy node's reach (crsh_core::RayHierarchy::reach) computed in
// f32 on the device, shared by the sphere-cone and tile-cone builders: the f32 distance `far`
// grows by REACH_ABS × `scale` (the largest coordinate magnitude involved, at least 1: the
// rounding of distances between f32 points) and REACH_REL relative, then one f32 step up;
// infinite (or NaN) stays infinite. Prepended: common.wgsl.

const REACH_REL: f32 = 1e-5;
const REACH_ABS: f32 = 1e-6;

// Rounds up by the relative margin and one f32 step.
fn round_up(x: f32, rel: f32) -> f32 {
    if (!(x < inf())) {
        return inf();
    }
    let y = x * (1.0 + rel);
    return bitcast<f32>(bitcast<u32>(y) + 1u);
}

fn reach_guard(far: f32, scale: f32) -> f32 {
    return round_up(far + REACH_ABS * scale, REACH_REL);
}
