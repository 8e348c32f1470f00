// `sphere_cone` on the device: the twin of crsh_cpu::hierarchy::sphere_cone in f32 (see
// sphere_cone.rs for what differs). Prepended: common.wgsl, kernels/reach.wgsl (round_up and
// the reach guard); trig.wgsl is appended.

const PI: f32 = 3.14159265358979;
const MAX_SUB: u32 = 64u;
// Stored-node margins, a little wider than the CPU's 1e-6: the construction is f32, with angles
// from trig.wgsl's atan2 (a few 1e-8 rad) and f32 cross / dot products (about 1e-7 rad).
const CONE_REL: f32 = 2e-6;
const CONE_ABS: f32 = 1e-6;
const SPHERE_REL: f32 = 2e-6;
// Times max(1, |centre|∞, |point|∞): the rounding of distances between f32 points.
const SPHERE_ABS: f32 = 1e-6;

struct Params {
    // Nodes in this level, children per node, and nodes (or leaves) below.
    nodes: u32,
    sub: u32,
    below: u32,
    // 1: spheres bound the segment starts o + clamp(t_min, 0, t_max)·d (`origins = start`,
    // crsh_cpu's segment_starts), and reach runs from there.
    starts: u32,
    // 1: lowest cones by `leaf_cone = extremes` (crsh_cpu's extremes_axis), else eq. 3.8-3.11.
    leaf_cone: u32,
    // 1: lowest sphere centres at the origins' bounding-box centre (`leaf_sphere = box`),
    // else Welzl's minimal ball.
    leaf_sphere: u32,
    pad1: u32,
    pad2: u32,
}

// crsh_cpu's WIDE_LEAF_COS: below it an `extremes` node keeps the narrower of its heuristic
// axis and eq. 3.8-3.11's.
const WIDE_LEAF_COS: f32 = 0.97;

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> rays: array<Ray>;
@group(0) @binding(2) var<storage, read> order: array<u32>;
@group(0) @binding(3) var<storage, read> children: array<SphereCone>;
@group(0) @binding(4) var<storage, read> child_reach: array<f32>;
@group(0) @binding(5) var<storage, read_write> out_nodes: array<SphereCone>;
@group(0) @binding(6) var<storage, read_write> out_reach: array<f32>;

fn unit3(v: vec3<f32>) -> vec3<f32> {
    let l = length(v);
    if (l > 0.0 && l < inf()) {
        return v / l;
    }
    return vec3<f32>(0.0, 0.0, 1.0);
}

// The angle between two non-zero vectors (atan2 form: accurate for small and large angles).
fn angle_between(a: vec3<f32>, b: vec3<f32>) -> f32 {
    return atan2_accurate(length(cross(a, b)), dot(a, b));
}

// A unit vector orthogonal to the unit `v`.
fn any_orthonormal(v: vec3<f32>) -> vec3<f32> {
    var t = vec3<f32>(1.0, 0.0, 0.0);
    if (abs(v.x) > 0.9) {
        t = vec3<f32>(0.0, 1.0, 0.0);
    }
    return normalize(cross(v, t));
}

// crsh_cpu's union_d: the smallest cone containing cones (a, fa) and (b, fb); result in
// (axis, angle) as vec4.
fn cone_union(a: vec3<f32>, fa: f32, b: vec3<f32>, fb: f32) -> vec4<f32> {
    if (fa >= PI || fb >= PI) {
        return vec4<f32>(a, PI);
    }
    let theta = angle_between(a, b);
    if (theta + fb <= fa) {
        return vec4<f32>(a, fa);
    }
    if (theta + fa <= fb) {
        return vec4<f32>(b, fb);
    }
    let phi = 0.5 * (fa + theta + fb);
    if (phi >= PI) {
        return vec4<f32>(a, PI);
    }
    let alpha = phi - fa;
    let ortho = b - a * dot(a, b);
    var u: vec3<f32>;
    if (length(ortho) > 1e-6) {
        u = normalize(ortho);
    } else {
        u = any_orthonormal(a);
    }
    return vec4<f32>(unit3(a * cos_accurate(alpha) + u * sin_accurate(alpha)), phi);
}

// Smallest ball with `a`, `b` on its boundary.
fn ball2(a: vec3<f32>, b: vec3<f32>) -> vec4<f32> {
    let c = 0.5 * (a + b);
    return vec4<f32>(c, length(a - c));
}

// Smallest ball with `a`, `b`, `c` on its boundary (their circumcircle); the two-point ball
// of the longest side for (nearly) collinear points.
fn ball3(a: vec3<f32>, b: vec3<f32>, c: vec3<f32>) -> vec4<f32> {
    let ab = b - a;
    let ac = c - a;
    let n = cross(ab, ac);
    let n2 = dot(n, n);
    if (n2 <= 1e-12 * dot(ab, ab) * dot(ac, ac)) {
        var s = ball2(a, b);
        let s2 = ball2(a, c);
        if (s2.w > s.w) { s = s2; }
        let s3 = ball2(b, c);
        if (s3.w > s.w) { s = s3; }
        return s;
    }
    let o = (cross(n, ab) * dot(ac, ac) + cross(ac, n) * dot(ab, ab)) / (2.0 * n2);
    return vec4<f32>(a + o, length(o));
}

// The ball with `a`, `b`, `c`, `d` on its boundary (their circumsphere); the best three-point
// ball for (nearly) coplanar points.
fn ball4(a: vec3<f32>, b: vec3<f32>, c: vec3<f32>, d: vec3<f32>) -> vec4<f32> {
    let u = b - a;
    let v = c - a;
    let w = d - a;
    let det = dot(u, cross(v, w));
    let scale = length(u) * length(v) * length(w);
    if (abs(det) <= 1e-6 * scale) {
        var s = ball3(a, b, c);
        let s2 = ball3(a, b, d);
        if (s2.w > s.w) { s = s2; }
        let s3 = ball3(a, c, d);
        if (s3.w > s.w) { s = s3; }
        let s4 = ball3(b, c, d);
        if (s4.w > s.w) { s = s4; }
        return s;
    }
    let o = (cross(v, w) * dot(u, u) + cross(w, u) * dot(v, v) + cross(u, v) * dot(w, w))
        / (2.0 * det);
    return vec4<f32>(a + o, length(o));
}

var<private> pts: array<vec3<f32>, MAX_SUB>;

fn outside(s: vec4<f32>, q: vec3<f32>) -> bool {
    return length(q - s.xyz) > s.w * (1.0 + 1e-6) + 1e-7 * max(1.0, max(abs(q.x), max(abs(q.y), abs(q.z))));
}

// Welzl's minimal enclosing ball of pts[0..n] (the classic nested form with up to three
// boundary points fixed); deterministic for a given point order.
fn min_ball(n: u32) -> vec4<f32> {
    var s = vec4<f32>(pts[0], 0.0);
    for (var i = 1u; i < n; i++) {
        if (!outside(s, pts[i])) { continue; }
        s = vec4<f32>(pts[i], 0.0);
        for (var j = 0u; j < i; j++) {
            if (!outside(s, pts[j])) { continue; }
            s = ball2(pts[i], pts[j]);
            for (var k = 0u; k < j; k++) {
                if (!outside(s, pts[k])) { continue; }
                s = ball3(pts[i], pts[j], pts[k]);
                for (var l = 0u; l < k; l++) {
                    if (!outside(s, pts[l])) { continue; }
                    s = ball4(pts[i], pts[j], pts[k], pts[l]);
                }
            }
        }
    }
    return s;
}

fn max_abs3(v: vec3<f32>) -> f32 {
    return max(abs(v.x), max(abs(v.y), abs(v.z)));
}

// The point a leaf ray's sphere bounds and the length its reach adds (segment_starts).
fn leaf_start(r: Ray) -> vec4<f32> {
    let o = ray_origin(r);
    if (p.starts == 0u) {
        return vec4<f32>(o, r.t_max);
    }
    var t = 0.0;
    if (abs(r.t_min) <= 3.40282347e38) {
        t = clamp(r.t_min, 0.0, max(r.t_max, 0.0));
    }
    return vec4<f32>(o + ray_dir(r) * t, r.t_max - t);
}

// The unit direction of leaf k of the node starting at `first`.
fn leaf_dir(first: u32, k: u32) -> vec3<f32> {
    return unit3(ray_dir(rays[order[first + k]]));
}

// The smallest dot product of `axis` with the node's n directions (cosine of the widest).
fn min_dot(first: u32, n: u32, axis: vec3<f32>) -> f32 {
    var m = 3.0;
    for (var k = 0u; k < n; k++) {
        m = min(m, dot(axis, leaf_dir(first, k)));
    }
    return m;
}

// The node's direction farthest from `origin_dir` (the first on a tie).
fn farthest(first: u32, n: u32, origin_dir: vec3<f32>) -> vec3<f32> {
    var m = 3.0;
    var best = origin_dir;
    for (var k = 0u; k < n; k++) {
        let d = leaf_dir(first, k);
        let c = dot(origin_dir, d);
        if (c < m) {
            m = c;
            best = d;
        }
    }
    return best;
}

// crsh_cpu's extremes_axis: the better (nearer widest ray) of the mean direction and the
// bisector of two extreme rays, with that widest cosine in w; w = 2 when the directions nearly
// cancel (eq. 3.8-3.11 alone then).
fn extremes_axis(first: u32, n: u32) -> vec4<f32> {
    var sum = vec3<f32>(0.0);
    for (var k = 0u; k < n; k++) {
        sum += leaf_dir(first, k);
    }
    if (length(sum) <= 1e-3 * f32(n)) {
        return vec4<f32>(0.0, 0.0, 1.0, 2.0);
    }
    let mean = normalize(sum);
    var best = vec4<f32>(mean, min_dot(first, n, mean));
    let a = farthest(first, n, leaf_dir(first, 0u));
    let pair = a + farthest(first, n, a);
    if (length(pair) > 1e-6) {
        let axis = normalize(pair);
        let c = min_dot(first, n, axis);
        if (c > best.w) {
            best = vec4<f32>(axis, c);
        }
    }
    return best;
}

// Lowest level: node i over leaves i·sub .. min((i+1)·sub, below).
@compute @workgroup_size(WG)
fn leaves(@builtin(global_invocation_id) gid: vec3<u32>,
          @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg);
    if (i >= p.nodes) {
        return;
    }
    let first = i * p.sub;
    let n = min(p.below - first, p.sub);
    // Cone: eq. 3.8-3.11 one ray at a time (crsh_cpu's leaf_node, which does it on (cos, sin)
    // pairs; here in angle form).
    var axis = unit3(ray_dir(rays[order[first]]));
    var phi = 0.0;
    var cos_phi = 1.0;
    var same = true;
    let o0 = leaf_start(rays[order[first]]).xyz;
    for (var k = 0u; k < n; k++) {
        let r = rays[order[first + k]];
        pts[k] = leaf_start(r).xyz;
        same = same && all(pts[k] == o0);
        let d = unit3(ray_dir(r));
        if (k > 0u && dot(axis, d) < cos_phi) {
            let c = cone_union(axis, phi, d, 0.0);
            axis = c.xyz;
            phi = c.w;
            cos_phi = cos_accurate(phi);
        }
    }
    if (p.leaf_cone == 1u) {
        let h = extremes_axis(first, n);
        // A wide node keeps eq. 3.8-3.11's axis when that one is narrower (and not the
        // whole sphere).
        if (h.w <= 1.0 && (h.w >= WIDE_LEAF_COS || !(phi < PI && min_dot(first, n, unit3(axis)) > h.w))) {
            axis = h.xyz;
            phi = 0.0;
        }
    }
    // Stored cone: re-measured against the stored axis, widened.
    let stored_axis = unit3(axis);
    var measured = PI;
    if (phi < PI) {
        measured = 0.0;
        for (var k = 0u; k < n; k++) {
            let d = unit3(ray_dir(rays[order[first + k]]));
            measured = max(measured, angle_between(stored_axis, d));
        }
    }
    let half = min(round_up(measured * (1.0 + CONE_REL) + CONE_ABS, 0.0), PI);
    // Sphere: minimal ball, re-measured, widened.
    var ball = vec4<f32>(o0, 0.0);
    if (!same) {
        if (p.leaf_sphere == 1u) {
            // crsh_cpu's Aabb::from_points(..).center(): the same f32 operations.
            var lo = pts[0];
            var hi = pts[0];
            for (var k = 1u; k < n; k++) {
                lo = min(lo, pts[k]);
                hi = max(hi, pts[k]);
            }
            ball = vec4<f32>((lo + hi) * 0.5, 0.0);
        } else {
            ball = min_ball(n);
        }
    }
    let c = ball.xyz;
    var far = 0.0;
    var scale = max(1.0, max_abs3(c));
    var reach = 0.0;
    for (var k = 0u; k < n; k++) {
        far = max(far, length(pts[k] - c));
        scale = max(scale, max_abs3(pts[k]));
        let r = rays[order[first + k]];
        reach = max(reach, length(pts[k] - c) + leaf_start(r).w * length(ray_dir(r)));
    }
    var radius = 0.0;
    if (!same || any(c != o0)) {
        radius = round_up(far * (1.0 + SPHERE_REL) + SPHERE_ABS * scale, 0.0);
    }
    out_nodes[i] = SphereCone(c, radius, stored_axis, half);
    out_reach[i] = reach_guard(reach, scale);
}

// Upper levels: node i over children i·sub .. min((i+1)·sub, below).
@compute @workgroup_size(WG)
fn inner(@builtin(global_invocation_id) gid: vec3<u32>,
         @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg);
    if (i >= p.nodes) {
        return;
    }
    let first = i * p.sub;
    let n = min(p.below - first, p.sub);
    var node0 = children[first];
    var axis = unit3(node0.axis);
    var phi = clamp(node0.half_angle, 0.0, PI);
    var ball = vec4<f32>(node0.center, node0.radius);
    for (var k = 1u; k < n; k++) {
        let ch = children[first + k];
        let cu = cone_union(axis, phi, unit3(ch.axis), clamp(ch.half_angle, 0.0, PI));
        axis = cu.xyz;
        phi = cu.w;
        // crsh_cpu's sphere_union_d.
        let d = distance(ball.xyz, ch.center);
        if (d + ch.radius <= ball.w) {
            continue;
        }
        if (d + ball.w <= ch.radius) {
            ball = vec4<f32>(ch.center, ch.radius);
            continue;
        }
        let r = 0.5 * (d + ball.w + ch.radius);
        ball = vec4<f32>(ball.xyz + (ch.center - ball.xyz) * ((r - ball.w) / d), r);
    }
    let stored_axis = unit3(axis);
    var measured = PI;
    if (phi < PI) {
        measured = 0.0;
        for (var k = 0u; k < n; k++) {
            let ch = children[first + k];
            measured = max(measured, angle_between(stored_axis, unit3(ch.axis)) + ch.half_angle);
        }
    }
    let half = min(round_up(measured * (1.0 + CONE_REL) + CONE_ABS, 0.0), PI);
    let c = ball.xyz;
    var far = 0.0;
    var scale = max(1.0, max_abs3(c));
    var reach = 0.0;
    for (var k = 0u; k < n; k++) {
        let ch = children[first + k];
        far = max(far, distance(c, ch.center) + ch.radius);
        scale = max(scale, max_abs3(ch.center));
        reach = max(reach, distance(c, ch.center) + child_reach[first + k]);
    }
    let radius = round_up(far * (1.0 + SPHERE_REL) + SPHERE_ABS * scale, 0.0);
    out_nodes[i] = SphereCone(c, radius, stored_axis, half);
    out_reach[i] = reach_guard(reach, scale);
}
