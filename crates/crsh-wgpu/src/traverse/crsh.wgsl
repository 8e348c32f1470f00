// `crsh` traversal on the device: the twin of crsh_cpu::traverse::crsh (see crsh.rs).
// Prepended: common.wgsl. Appended: node_bound.wgsl, trig.wgsl.

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

// crsh_cpu's NodeBound::new (with_reach when the level has bounds).
@compute @workgroup_size(WG)
fn prepare(@builtin(global_invocation_id) gid: vec3<u32>,
           @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg);
    if (i >= p.n) {
        return;
    }
    var reach = 0.0;
    if (p.has_reach != 0u) {
        reach = level_reach[i];
    }
    let b = bound_of(level_nodes[i], reach, p.has_reach != 0u);
    if (bound_is_bad(b)) {
        atomicMax(&counters[3], 0xffffffffu - i);
    }
    bounds[i] = b;
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
