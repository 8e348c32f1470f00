// `tile_cone` on the device: seed 004 §4's incremental enclosing cones of screen tiles, the
// twin of crsh_cpu::hierarchy::tile_cone::node_cone, whose f32 operations it follows line by
// line and in the same order (see its module docs for the errata and choices).
// Prepended: common.wgsl, glam.wgsl, kernels/reach.wgsl, the constants generated from the CPU
// twin's (PI, FRAC_PI_2, EXTEND_EPS, PERP_EPS, PERP_SWITCH, GUARD_SCALE, GUARD_ADD,
// RAY_KIND_SHADOW) and hash/tile_group.wgsl; trig.wgsl is appended.

struct Params {
    // Rays (positions of the order) and nodes (after the scan).
    n: u32,
    nodes: u32,
    // The tile grid (crsh_cpu::hash::tile::TileGrid).
    width: u32,
    height: u32,
    tile_size: u32,
    tiles_x: u32,
    tiles: u32,
    _a: u32,
    // sin and cos of min_half_angle_deg (crsh_cpu's TileConeParams::sin_cos_min).
    sin_min: f32,
    cos_min: f32,
    _b: f32,
    _c: f32,
}

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> rays: array<Ray>;
@group(0) @binding(2) var<storage, read> order: array<u32>;
// Run-start flags, scanned in place into node indices between run_flags and run_offsets.
@group(0) @binding(3) var<storage, read_write> starts: array<u32>;
// Leaf offsets: nodes + 1 entries.
@group(0) @binding(4) var<storage, read_write> offsets: array<u32>;
@group(0) @binding(5) var<storage, read_write> out_nodes: array<SphereCone>;
@group(0) @binding(6) var<storage, read_write> out_reach: array<f32>;
// [first bad position as 0xffffffff - i (0: none), node count (copied by the scan), what was
// bad (1: order entry out of range, 2: pixel outside the frame, 4: invalid ray), unused]
@group(0) @binding(7) var<storage, read_write> counters: array<atomic<u32>>;

// The group (lo, hi, valid) of the ray at position i; reports a bad position.
fn group_at(i: u32) -> vec3<u32> {
    let ri = order[i];
    if (ri >= p.n) {
        atomicMax(&counters[0], 0xffffffffu - i);
        atomicOr(&counters[2], 1u);
        return vec3<u32>(0u, 0u, 0u);
    }
    let r = rays[ri];
    let g = tile_group(r.pixel, r.light, r.kind, p.width, p.height, p.tile_size, p.tiles_x,
                       p.tiles, 0u);
    if (g.z == 0u) {
        atomicMax(&counters[0], 0xffffffffu - i);
        atomicOr(&counters[2], 2u);
    }
    let o = ray_origin(r);
    let d = ray_dir(r);
    if (!g_vec_finite(o) || !g_vec_finite(d) || g_is_zero(d) || r.t_min != r.t_min
        || r.t_max != r.t_max) {
        atomicMax(&counters[0], 0xffffffffu - i);
        atomicOr(&counters[2], 4u);
    }
    return g;
}

// Whether position i starts a run (a node): the first position, or a group unlike the one
// before. Reads the previous position's ray without reporting it (its own invocation does).
fn starts_run(i: u32) -> bool {
    if (i == 0u) {
        return true;
    }
    let prev = order[i - 1u];
    let cur = order[i];
    if (prev >= p.n || cur >= p.n) {
        return true;
    }
    let a = rays[prev];
    let b = rays[cur];
    let ga = tile_group(a.pixel, a.light, a.kind, p.width, p.height, p.tile_size, p.tiles_x,
                        p.tiles, 0u);
    let gb = tile_group(b.pixel, b.light, b.kind, p.width, p.height, p.tile_size, p.tiles_x,
                        p.tiles, 0u);
    return any(ga != gb);
}

// Pass 1, one invocation per position: the run-start flag (and the input checks).
@compute @workgroup_size(WG)
fn run_flags(@builtin(global_invocation_id) gid: vec3<u32>,
             @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg);
    if (i >= p.n) {
        return;
    }
    _ = group_at(i);
    starts[i] = select(0u, 1u, starts_run(i));
}

// Pass 2, one invocation per position, after the exclusive scan of the flags: a run start
// writes its node's first position; position 0 writes the last offset (the ray count).
@compute @workgroup_size(WG)
fn run_offsets(@builtin(global_invocation_id) gid: vec3<u32>,
               @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg);
    if (i >= p.n) {
        return;
    }
    if (starts_run(i)) {
        offsets[starts[i]] = i;
    }
    if (i == 0u) {
        offsets[p.nodes] = p.n;
    }
}

// The CPU twin's normalize: v divided by its length, component by component (not a
// multiplication by the reciprocal).
fn normalize_div(v: vec3<f32>) -> vec3<f32> {
    let l = g_length(v);
    return vec3<f32>(v.x / l, v.y / l, v.z / l);
}

// The CPU twin's any_perpendicular(x) (erratum 4).
fn any_perpendicular(x: vec3<f32>) -> vec3<f32> {
    if (abs(x.x) < PERP_SWITCH) {
        return normalize_div(g_cross(x, vec3<f32>(1.0, 0.0, 0.0)));
    }
    return normalize_div(g_cross(x, vec3<f32>(0.0, 1.0, 0.0)));
}

// The CPU twin's perp_towards_axis(x, v, xv): the unit vector from v towards its projection on
// the axis x (paper §4's q), or any perpendicular of x when |w| <= PERP_EPS·|v| (v on the axis
// line to within f32 rounding).
fn perp_towards_axis(x: vec3<f32>, v: vec3<f32>, xv: f32) -> vec3<f32> {
    let w = x * xv - v;
    let l = g_length(w);
    if (l > PERP_EPS * g_length(v)) {
        return vec3<f32>(w.x / l, w.y / l, w.z / l);
    }
    return any_perpendicular(x);
}

// angle(x, v) = atan2(|x × v|, x · v).
fn angle_of(x: vec3<f32>, v: vec3<f32>) -> f32 {
    return atan2_accurate(g_length(g_cross(x, v)), g_dot(x, v));
}

fn max_abs3(v: vec3<f32>) -> f32 {
    return max(abs(v.x), max(abs(v.y), abs(v.z)));
}

// Pass 3, one invocation per node: the incremental construction over the node's rays in order
// (paper §4 steps (a) and (b), with the errata), then the final pass that measures the
// half-angle against the stored apex and axis, and the reach.
@compute @workgroup_size(WG)
fn cones(@builtin(global_invocation_id) gid: vec3<u32>,
         @builtin(num_workgroups) nwg: vec3<u32>) {
    let k = linear_id(gid, nwg);
    if (k >= p.nodes) {
        return;
    }
    let first = offsets[k];
    let end = offsets[k + 1u];
    let r0 = rays[order[first]];
    let a0 = ray_origin(r0);
    var a = a0;
    var x = normalize_div(ray_dir(r0));
    var cos_phi = 1.0;
    var sin_phi = 0.0;
    var full = false;
    for (var i = first + 1u; i < end; i++) {
        let ray = rays[order[i]];
        let r = normalize_div(ray_dir(ray));
        // (a) Extend the solid angle to hold the direction r (paper §4, fig. 2).
        let xr = g_dot(x, r);
        if (xr < cos_phi) {
            if (xr <= -cos_phi) {
                // φ + angle(x, r) ≥ π: e + r would bisect the wrong arc (erratum 2).
                full = true;
                break;
            }
            let q = perp_towards_axis(x, r, xr);
            let e = x * cos_phi + q * sin_phi;
            let s = e + r;
            let ls = g_length(s);
            if (ls <= EXTEND_EPS) {
                full = true;
                break;
            }
            x = vec3<f32>(s.x / ls, s.y / ls, s.z / ls);
            cos_phi = g_dot(x, r);
            if (cos_phi <= 0.0) {
                full = true;
                break;
            }
            sin_phi = sqrt(max(1.0 - cos_phi * cos_phi, 0.0));
        }
        // (b) Translate to hold the origin (paper §4, fig. 3), the apex moving by +e·t.
        let o = ray_origin(ray);
        let c = o - a;
        let xc = g_dot(x, c);
        let lc = g_length(c);
        if (xc < cos_phi * lc) {
            if (sin_phi < p.sin_min) {
                cos_phi = p.cos_min;
                sin_phi = p.sin_min;
            }
            if (-xc >= cos_phi * lc) {
                // The origin lies in the backward cone: it becomes the apex.
                a = o;
                continue;
            }
            // crsh_cpu's translate_apex(a, x, cos φ, sin φ, o, Corrected).
            let q = perp_towards_axis(x, c, g_dot(x, c));
            let e = x * cos_phi + q * sin_phi;
            let nn = x * cos_phi - q * sin_phi;
            let g = c - nn * g_dot(nn, c);
            let eg = g_dot(e, g);
            if (!(eg < 0.0)) {
                full = true;
                break;
            }
            let t = g_dot(g, g) / eg;
            a = a + e * t;
        }
    }
    if (!g_vec_finite(a) || !g_vec_finite(x)) {
        // Safety net (the CPU twin's module docs, item 5): a full node at the first origin.
        full = true;
        a = a0;
        if (!g_vec_finite(x)) {
            x = vec3<f32>(0.0, 0.0, 1.0);
        }
    }
    // Final pass: the stored half-angle is measured against the stored apex and axis.
    var phi = 0.0;
    var far = 0.0;
    var scale = max(1.0, max_abs3(a));
    for (var i = first; i < end; i++) {
        let ray = rays[order[i]];
        let o = ray_origin(ray);
        let d = ray_dir(ray);
        phi = max(phi, angle_of(x, d));
        let c = o - a;
        if (any(c != vec3<f32>(0.0))) {
            phi = max(phi, angle_of(x, c));
        }
        far = max(far, g_length(o - a));
        scale = max(scale, max_abs3(o));
        if (ray.t_max < inf()) {
            let tip = o + d * ray.t_max;
            far = max(far, g_length(tip - a));
            scale = max(scale, max_abs3(tip));
        } else {
            far = inf();
        }
    }
    phi = phi * GUARD_SCALE + GUARD_ADD;
    // A NaN angle (a degenerate direction) goes to π too.
    if (full || phi >= FRAC_PI_2 || phi != phi) {
        phi = PI;
    }
    out_nodes[k] = SphereCone(a, 0.0, x, phi);
    out_reach[k] = reach_guard(far, scale);
}
