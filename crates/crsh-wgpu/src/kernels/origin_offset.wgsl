// Seed 001's origin offsets on the device: the twin of crsh_cpu::raygen::origin_offset's
// query (hemisphere_interval, offset_t_min, cut_t_max) and of
// crsh_cpu::raygen::offsets::Offsets::{apply, cut_end}, with the same operations in the same
// order (glam.wgsl's dot products included). Prepended: glam.wgsl, and the constants QUERY_REL,
// T_REL and INFINITE_RADIUS generated from the Rust ones (crate::kernels::origin_offset_wgsl).
//
// The including kernel declares (raygen/slots.wgsl does):
//   hemi: HemiParams                    the table's layout (uniform);
//   hemi_table: array<vec4<f32>>        the records (centre xyz, stored radius w; per_slot
//                                       per slot, slot-major), then one normal per slot from
//                                       hemi.normals_at on;
//   hemi_index: array<u32>              polygon: the slot of each triangle.

// crate::raygen::offsets::HemiParams.
struct HemiParams {
    // Records per slot; 0 when offsets = none (rays are left as they are).
    per_slot: u32,
    // Triangles of the scene: a larger id has no hemispheres.
    triangles: u32,
    // 1 for the polygon set (slot = hemi_index[tri]); else slot = tri.
    polygon: u32,
    // Index in hemi_table of slot 0's normal (the number of records).
    normals_at: u32,
}

// hemisphere_interval: (t0, t1) of the ray o + t·d inside the stored hemisphere `rec` with
// unit normal `n`, shrunk by the query's margin; t0 >= t1 when empty.
fn hemisphere_interval(rec: vec4<f32>, n: vec3<f32>, o: vec3<f32>, d: vec3<f32>) -> vec2<f32> {
    let empty = vec2<f32>(inf(), -inf());
    let c = rec.xyz;
    let r = rec.w;
    let dd = g_dot(d, d);
    let w = o - c;
    let valid = r > 0.0 && dd > 0.0 && g_vec_finite(w) && g_finite(dd);
    if (!valid) {
        return empty;
    }
    let infinite = r >= INFINITE_RADIUS;
    var r_term = r;
    if (infinite) {
        r_term = 0.0;
    }
    let aw = abs(w);
    let ac = abs(c);
    let scale = max(max(aw.x, aw.y), aw.z) + max(max(ac.x, ac.y), ac.z) + r_term;
    let m = QUERY_REL * scale;
    let tc = -g_dot(w, d) / dd;
    // Closest approach, relative to the centre.
    let wp = w + d * tc;
    var lo = -inf();
    var hi = inf();
    if (!infinite) {
        let rq = r - m;
        if (rq <= 0.0) {
            return empty;
        }
        let disc = (rq * rq - g_dot(wp, wp)) / dd;
        if (disc <= 0.0) {
            return empty;
        }
        let s = sqrt(disc);
        lo = -s;
        hi = s;
    }
    let hn = g_dot(n, wp);
    let dn = g_dot(n, d);
    if (dn > 0.0) {
        lo = max(lo, (m - hn) / dn);
    } else if (dn < 0.0) {
        hi = min(hi, (m - hn) / dn);
    } else if (hn <= m) {
        return empty;
    }
    if (lo >= hi) {
        return empty;
    }
    return vec2<f32>(tc + lo, tc + hi);
}

// The records of triangle `tri`: (first record, count, slot); count 0 when there are none
// (offsets = none, or `tri` out of range).
fn hemi_records(tri: u32) -> vec3<u32> {
    if (hemi.per_slot == 0u || tri >= hemi.triangles) {
        return vec3<u32>(0u, 0u, 0u);
    }
    var slot = tri;
    if (hemi.polygon != 0u) {
        slot = hemi_index[tri];
    }
    return vec3<u32>(slot * hemi.per_slot, hemi.per_slot, slot);
}

// The normal of slot `slot`.
fn hemi_normal(slot: u32) -> vec3<f32> {
    return hemi_table[hemi.normals_at + slot].xyz;
}

// offset_t_min over triangle `tri`'s hemispheres (HemisphereSet::offset_t_min).
fn offset_t_min(tri: u32, o: vec3<f32>, d: vec3<f32>, t_min: f32, t_max: f32) -> f32 {
    let valid = t_min < t_max;
    if (!valid) {
        return t_min;
    }
    let at = hemi_records(tri);
    var best = t_min;
    if (at.y == 0u) {
        return min(best, t_max);
    }
    let n = hemi_normal(at.z);
    for (var i = 0u; i < at.y; i++) {
        let iv = hemisphere_interval(hemi_table[at.x + i], n, o, d);
        if (iv.x <= t_min && t_min < iv.y) {
            var t = iv.y;
            if (g_finite(iv.y)) {
                t = iv.y - T_REL * abs(iv.y);
            }
            best = max(best, t);
        }
    }
    return min(best, t_max);
}

// cut_t_max over triangle `tri`'s hemispheres (HemisphereSet::cut_t_max).
fn cut_t_max(tri: u32, o: vec3<f32>, d: vec3<f32>, t_min: f32, t_max: f32) -> f32 {
    let valid = t_min < t_max;
    if (!valid) {
        return t_max;
    }
    let at = hemi_records(tri);
    var best = t_max;
    if (at.y == 0u) {
        return max(best, t_min);
    }
    let n = hemi_normal(at.z);
    for (var i = 0u; i < at.y; i++) {
        let iv = hemisphere_interval(hemi_table[at.x + i], n, o, d);
        if (iv.x < t_max && t_max <= iv.y) {
            var t = iv.x;
            if (g_finite(iv.x)) {
                t = iv.x + T_REL * abs(iv.x);
            }
            best = min(best, t);
        }
    }
    return max(best, t_min);
}

// Offsets::apply: the interval (t_min, t_max) of a ray leaving triangle `tri` after raising
// t_min past its hemispheres; an emptied one becomes t_min = t_max. Unchanged for none.
fn offsets_apply(tri: u32, o: vec3<f32>, d: vec3<f32>, t_min: f32, t_max: f32) -> vec2<f32> {
    if (hemi.per_slot == 0u) {
        return vec2<f32>(t_min, t_max);
    }
    let t = offset_t_min(tri, o, d, t_min, t_max);
    if (t >= t_max) {
        return vec2<f32>(t_max, t_max);
    }
    return vec2<f32>(max(t_min, t), t_max);
}

// Offsets::cut_end: the interval of a shadow ray from a light ending on triangle `tri` after
// cutting t_max back to where it enters its hemispheres; an emptied one becomes
// t_max = t_min. Unchanged for none.
fn offsets_cut_end(tri: u32, o: vec3<f32>, d: vec3<f32>, t_min: f32, t_max: f32) -> vec2<f32> {
    if (hemi.per_slot == 0u) {
        return vec2<f32>(t_min, t_max);
    }
    let t = cut_t_max(tri, o, d, t_min, t_max);
    if (t <= t_min) {
        return vec2<f32>(t_min, t_min);
    }
    return vec2<f32>(t_min, min(t_max, t));
}

// Whether a made ray counts as ended by an offset (Stats::add_offset_ended): offsets in use
// and an empty interval, as the CPU generators count them.
fn offset_ended(t_min: f32, t_max: f32) -> bool {
    return hemi.per_slot != 0u && t_min >= t_max;
}
