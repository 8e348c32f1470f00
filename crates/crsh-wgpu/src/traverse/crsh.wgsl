// `crsh` traversal on the device: the twin of crsh_cpu::traverse::crsh (see crsh.rs).
// Prepended: common.wgsl.

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

struct Params {
    // prepare: nodes of the level; top / mesh_cull: top nodes; descend: input pairs.
    n: u32,
    // Meshes, triangles of the batch and its first triangle.
    n_meshes: u32,
    batch: u32,
    t0: u32,
    // Children per node and nodes in the child level.
    sub: u32,
    n_children: u32,
    mesh_culling: u32,
    // Whether the level has reach bounds.
    has_reach: u32,
}

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> level_nodes: array<SphereCone>;
@group(0) @binding(2) var<storage, read> level_reach: array<f32>;
@group(0) @binding(3) var<storage, read_write> bounds: array<Bound>;
// The bounds of the child level (descend) — a separate binding from `bounds`.
@group(0) @binding(4) var<storage, read> child_bounds: array<Bound>;
@group(0) @binding(5) var<storage, read> tri_spheres: array<vec4<f32>>;
@group(0) @binding(6) var<storage, read> tri_info: array<TriangleInfo>;
@group(0) @binding(7) var<storage, read> meshes: array<Mesh>;
@group(0) @binding(8) var<storage, read_write> keep: array<u32>;
@group(0) @binding(9) var<storage, read> pairs_in: array<Candidate>;
// Survivor flags, scanned in place into output positions between the test and emit passes.
@group(0) @binding(10) var<storage, read_write> flags: array<u32>;
@group(0) @binding(11) var<storage, read_write> pairs_out: array<Candidate>;
// [tests lo, hi, mesh pairs kept, bad node report]
@group(0) @binding(12) var<storage, read_write> counters: array<atomic<u32>>;

var<workgroup> wg_tests: atomic<u32>;

fn add_u64(at: u32, n: u32) {
    if (n == 0u) { return; }
    let old = atomicAdd(&counters[at], n);
    if (old + n < old) {
        atomicAdd(&counters[at + 1u], 1u);
    }
}

fn f_finite(x: f32) -> bool {
    return (bitcast<u32>(x) & 0x7f800000u) != 0x7f800000u;
}

fn max_abs3(v: vec3<f32>) -> f32 {
    return max(abs(v.x), max(abs(v.y), abs(v.z)));
}

// crsh_cpu's NodeBound::new (with_reach when the level has bounds).
@compute @workgroup_size(WG)
fn prepare(@builtin(global_invocation_id) gid: vec3<u32>,
           @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg);
    if (i >= p.n) {
        return;
    }
    let node = level_nodes[i];
    var b: Bound;
    b.center = node.center;
    b.radius = node.radius;
    b.scale = max(1.0, max_abs3(node.center));
    b.reach = inf();
    if (p.has_reach != 0u) {
        let r = level_reach[i];
        if (f_finite(r) && r >= 0.0) {
            b.reach = r;
        }
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
    if (bad) {
        atomicMax(&counters[3], 0xffffffffu - i);
    }
    bounds[i] = b;
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
    if (d2 <= rho2) {
        return true;
    }
    if (b.cos_a < 0.0 && rho2 >= d2 * b.sin_a * b.sin_a * (1.0 - F32_SLACK)) {
        return true;
    }
    // a·v ≥ cos α·√(D² − ρ²) − sin α·ρ, accepting the worst rounding of both sides: the
    // radicand is off by at most e = 8ε(D² + ρ²), so its root by min(√e, e / (2√(D² − ρ²)));
    // the products and sums by a few ε of their magnitudes.
    let dist = sqrt(d2);
    let s2 = max(d2 - rho2, 0.0);
    let s = sqrt(s2);
    let e = 8.0 * EPS * (d2 + rho2);
    var root_err = sqrt(e);
    if (s > 0.0) {
        root_err = min(root_err, e / (2.0 * s));
    }
    let slack = abs(b.cos_a) * root_err + 16.0 * EPS * (dist + rho) + 4e-7 * (s + rho);
    return dot(b.axis, v) >= b.cos_a * s - b.sin_a * rho - slack;
}

// Mesh culling: keep[node * meshes + m] for every top node and mesh.
@compute @workgroup_size(WG)
fn mesh_cull(@builtin(global_invocation_id) gid: vec3<u32>,
             @builtin(num_workgroups) nwg: vec3<u32>) {
    let j = linear_id(gid, nwg);
    if (j >= p.n * p.n_meshes) {
        return;
    }
    let node = j / p.n_meshes;
    let m = j % p.n_meshes;
    let k = may_hit(bounds[node], meshes[m].sphere);
    keep[j] = select(0u, 1u, k);
    if (k) {
        atomicAdd(&counters[2], 1u);
    }
}

// Top level, pair j = (node j / batch, triangle t0 + j % batch): flag, and count the tests of
// kept meshes.
fn top_pair(j: u32) -> vec3<u32> {
    let node = j / p.batch;
    let tri = p.t0 + j % p.batch;
    var tested = 1u;
    if (p.mesh_culling != 0u && keep[node * p.n_meshes + tri_info[tri].mesh] == 0u) {
        tested = 0u;
    }
    var hit = 0u;
    if (tested != 0u && may_hit(bounds[node], tri_spheres[tri])) {
        hit = 1u;
    }
    return vec3<u32>(node, tri, hit | (tested << 1u));
}

@compute @workgroup_size(WG)
fn top_test(@builtin(global_invocation_id) gid: vec3<u32>,
            @builtin(local_invocation_index) lid: u32,
            @builtin(num_workgroups) nwg: vec3<u32>) {
    let j = linear_id(gid, nwg);
    if (lid == 0u) {
        atomicStore(&wg_tests, 0u);
    }
    workgroupBarrier();
    if (j < p.n * p.batch) {
        let r = top_pair(j);
        flags[j] = r.z & 1u;
        atomicAdd(&wg_tests, r.z >> 1u);
    }
    workgroupBarrier();
    if (lid == 0u) {
        add_u64(0u, atomicLoad(&wg_tests));
    }
}

@compute @workgroup_size(WG)
fn top_emit(@builtin(global_invocation_id) gid: vec3<u32>,
            @builtin(num_workgroups) nwg: vec3<u32>) {
    let j = linear_id(gid, nwg);
    if (j >= p.n * p.batch) {
        return;
    }
    let r = top_pair(j);
    if ((r.z & 1u) != 0u) {
        pairs_out[flags[j]] = Candidate(r.x, r.y);
    }
}

// The run of pairs_in with node `node`: [first, end).
fn run_of(node: u32) -> vec2<u32> {
    var lo = 0u;
    var hi = p.n;
    while (lo < hi) {
        let mid = lo + (hi - lo) / 2u;
        if (pairs_in[mid].node < node) { lo = mid + 1u; } else { hi = mid; }
    }
    var lo2 = lo;
    var hi2 = p.n;
    while (lo2 < hi2) {
        let mid = lo2 + (hi2 - lo2) / 2u;
        if (pairs_in[mid].node <= node) { lo2 = mid + 1u; } else { hi2 = mid; }
    }
    return vec2<u32>(lo, lo2);
}

// Descent, item (pair k, child slot j): its place in the output order, which is by child and
// then triangle (for a run [s, e) of one node: s·sub + j·(e − s) + (k − s)), the child, and
// whether the child exists and may hit the triangle (bit 0) / exists (bit 1).
fn descend_item(idx: u32) -> vec4<u32> {
    let k = idx / p.sub;
    let j = idx % p.sub;
    let c = pairs_in[k];
    let run = run_of(c.node);
    let flat = run.x * p.sub + j * (run.y - run.x) + (k - run.x);
    let child = c.node * p.sub + j;
    var bits = 0u;
    if (child < p.n_children) {
        bits = 2u;
        if (may_hit(child_bounds[child], tri_spheres[c.tri])) {
            bits = 3u;
        }
    }
    return vec4<u32>(flat, child, c.tri, bits);
}

@compute @workgroup_size(WG)
fn descend_test(@builtin(global_invocation_id) gid: vec3<u32>,
                @builtin(local_invocation_index) lid: u32,
                @builtin(num_workgroups) nwg: vec3<u32>) {
    let idx = linear_id(gid, nwg);
    if (lid == 0u) {
        atomicStore(&wg_tests, 0u);
    }
    workgroupBarrier();
    if (idx < p.n * p.sub) {
        let r = descend_item(idx);
        flags[r.x] = r.w & 1u;
        atomicAdd(&wg_tests, r.w >> 1u);
    }
    workgroupBarrier();
    if (lid == 0u) {
        add_u64(0u, atomicLoad(&wg_tests));
    }
}

@compute @workgroup_size(WG)
fn descend_emit(@builtin(global_invocation_id) gid: vec3<u32>,
                @builtin(num_workgroups) nwg: vec3<u32>) {
    let idx = linear_id(gid, nwg);
    if (idx >= p.n * p.sub) {
        return;
    }
    let r = descend_item(idx);
    if ((r.w & 1u) != 0u) {
        pairs_out[flags[r.x]] = Candidate(r.y, r.z);
    }
}
