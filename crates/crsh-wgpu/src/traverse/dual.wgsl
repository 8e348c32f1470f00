// `dual` traversal on the device: the twin of crsh_cpu::traverse::dual (see dual.rs).
// Prepended: common.wgsl. Appended: mt.wgsl (ray_valid, add_u64 on `counters`),
// node_bound.wgsl, trig.wgsl.

// An object node (crsh_cpu::traverse::dual::FlatNode), 48 bytes: an internal node's children
// are `a` and `b` (indices in the same array); a leaf has b == OBJ_LEAF and its triangle in a.
struct ObjNode {
    sphere: vec4<f32>,
    lo: vec3<f32>,
    a: u32,
    hi: vec3<f32>,
    b: u32,
}

const OBJ_LEAF: u32 = 0xffffffffu;

// A box of ray segments (lo > hi: empty; ±inf: every point), 32 bytes.
struct RBox {
    lo: vec3<f32>,
    _a: u32,
    hi: vec3<f32>,
    _b: u32,
}

// A (ray node, object node) pair waiting for its test, 16 bytes. info: the ray level in bits
// 0..16 (SINGLE: the single rays `mask` of lowest node `node`), the object depth above.
struct Pair {
    node: u32,
    obj: u32,
    mask: u32,
    info: u32,
}

// A ray node's prepared bound and the box of its rays' segments, 80 bytes.
struct NodeRec {
    bound: Bound,
    rbox: RBox,
}

const SINGLE: u32 = 0xffffu;
const ALL: u32 = 0xffffffffu;

// Outcome codes of a tested pair.
const DROP: u32 = 0u;
const CANDIDATE: u32 = 1u;
const TO_SINGLE: u32 = 2u;
const SPLIT_RAYS: u32 = 3u;
const SPLIT_OBJECT: u32 = 4u;

struct Params {
    // Items of the dispatch (nodes of a level, pairs, candidates).
    n: u32,
    // The level's first index in the all-levels arrays (prepare, boxes).
    first: u32,
    // Whether the level has reach bounds (prepare).
    has_reach: u32,
    sub: u32,
    // Rays (leaves), (padding), ray levels, whether the hierarchy has leaf offsets.
    n_rays: u32,
    _pad: u32,
    n_levels: u32,
    has_offsets: u32,
    // Object-depth rows, box test, single rays, the object root.
    n_depths: u32,
    box_test: u32,
    single_rays: u32,
    root: u32,
    // The box of every triangle (the segment boxes are clipped to it).
    scene_lo: vec3<f32>,
    // The bits of a candidate key's triangle field.
    tri_bits: u32,
    scene_hi: vec3<f32>,
    // The child level's first index (upper boxes).
    child_first: u32,
    // Each level's first index in `nodes`, then the total (MAX_LEVELS + 1 entries): in the
    // parameters rather than a buffer, so that the test pass binds at most 8 storage buffers
    // (WebGPU's default limit).
    level_first: array<vec4<u32>, 16>,
}

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> level_nodes: array<SphereCone>;
@group(0) @binding(2) var<storage, read> level_reach: array<f32>;
// Every level's prepared bounds and segment boxes, lowest level first (level_first(l) ..
// level_first(l + 1)).
@group(0) @binding(3) var<storage, read_write> nodes: array<NodeRec>;
@group(0) @binding(4) var<storage, read> rays: array<Ray>;
@group(0) @binding(5) var<storage, read> order: array<u32>;
@group(0) @binding(6) var<storage, read> offsets: array<u32>;
@group(0) @binding(7) var<storage, read> objs: array<ObjNode>;
@group(0) @binding(8) var<storage, read> pairs_in: array<Pair>;
// Per input pair: (code, live mask).
@group(0) @binding(9) var<storage, read_write> outcome: array<vec2<u32>>;
// A round's children counts (0 .. n) then candidate counts (n .. 2n), scanned in place in one
// pass into output positions between the test and emit passes; the merge's run heads.
@group(0) @binding(10) var<storage, read_write> counts: array<u32>;
@group(0) @binding(11) var<storage, read_write> pairs_out: array<Pair>;
// Candidates as the rounds find them: Pair(node, triangle, lanes, 0).
@group(0) @binding(12) var<storage, read_write> raw: array<Pair>;
// The merged candidates of a batch (sorted, one per pair) and their lane masks.
@group(0) @binding(13) var<storage, read_write> cands: array<Candidate>;
@group(0) @binding(14) var<storage, read_write> lanes: array<u32>;
// Candidate keys (node << tri_bits | tri as vec2<u32>) and their stable sorted order.
@group(0) @binding(15) var<storage, read_write> keys: array<vec2<u32>>;
@group(0) @binding(16) var<storage, read> sorted: array<u32>;
// [0]: bad node report; from 4: per ray level (tests lo, hi, passes lo, hi), then per object
// depth the same.
@group(0) @binding(17) var<storage, read_write> counters: array<atomic<u32>>;

// The first index of ray level `l` in `nodes`.
fn level_first(l: u32) -> u32 {
    return p.level_first[l / 4u][l % 4u];
}

fn empty_box() -> RBox {
    return RBox(vec3<f32>(inf()), 0u, vec3<f32>(-inf()), 0u);
}

fn union_box(a: RBox, b: RBox) -> RBox {
    return RBox(min(a.lo, b.lo), 0u, max(a.hi, b.hi), 0u);
}

// The first leaf of lowest node n and its leaf count.
fn node_leaves(n: u32) -> vec2<u32> {
    if (p.has_offsets != 0u) {
        return vec2<u32>(offsets[n], offsets[n + 1u] - offsets[n]);
    }
    let s = n * p.sub;
    return vec2<u32>(s, min(s + p.sub, p.n_rays) - s);
}

// crsh_cpu's dual::clip in f32: [t0, t1] of a valid ray's interval within box [lo, hi], with
// the slab distances widened by a relative 1e-6, so it contains the CPU's exact f64 one:
// (lo − o)·(1/d) is off by at most 7u relative (u = 2⁻²⁴: the subtraction and the product u
// each, WGSL's reciprocal 2.5 ulp), 4.2e-7, and clip's own widening is 1e-9. The CPU's
// single-ray test (dual::meets_box) is this test with a correctly rounded reciprocal (3u).
// t0 > t1 when empty.
fn clip(o: vec3<f32>, d: vec3<f32>, t_min: f32, t_max: f32, lo: vec3<f32>, hi: vec3<f32>) -> vec2<f32> {
    var t0 = t_min;
    var t1 = t_max;
    for (var axis = 0u; axis < 3u; axis++) {
        if (d[axis] == 0.0) {
            if (o[axis] < lo[axis] || o[axis] > hi[axis]) {
                return vec2<f32>(1.0, 0.0);
            }
            continue;
        }
        let inv = 1.0 / d[axis];
        let a = (lo[axis] - o[axis]) * inv;
        let c = (hi[axis] - o[axis]) * inv;
        let near = min(a, c);
        let far = max(a, c);
        t0 = max(t0, near - 1e-6 * abs(near));
        t1 = min(t1, far + 1e-6 * abs(far));
    }
    if (t0 <= t1) {
        return vec2<f32>(t0, t1);
    }
    return vec2<f32>(1.0, 0.0);
}

// crsh_cpu's dual::segment_box, the same f32 formula: the end points of the ray's interval
// (clipped to the scene's box when unbounded), padded by 4ε·(|o| + |d|·|t|) + 2e-9·max(1, |p|∞):
// the point o + d·t is off by at most 2u·(|o| + |d·t|) (u = ε/2, with or without a fused
// multiply-add) and the pad's subtraction by u·(|lo| + pad), so the box holds the exact
// segment. The CPU's clip has a correctly rounded reciprocal and this one WGSL's 2.5 ulp, so
// the boxes can differ in their last bits; both hold the exact segment.
fn segment_box(r: Ray) -> RBox {
    if (!ray_valid(r)) {
        return RBox(vec3<f32>(-inf()), 0u, vec3<f32>(inf()), 0u);
    }
    let o = ray_origin(r);
    let d = ray_dir(r);
    var t = vec2<f32>(r.t_min, r.t_max);
    if (f32_finite(r.t_min) && f32_finite(r.t_max)) {
        if (r.t_min > r.t_max) {
            return empty_box();
        }
    } else {
        t = clip(o, d, r.t_min, r.t_max, p.scene_lo, p.scene_hi);
        if (t.x > t.y) {
            return empty_box();
        }
    }
    let p0 = o + d * t.x;
    let p1 = o + d * t.y;
    let lo = min(p0, p1);
    let hi = max(p0, p1);
    let mag = abs(o) + abs(d) * max(abs(t.x), abs(t.y));
    let scale = max(1.0, max(max_abs3(lo), max_abs3(hi)));
    let pad = 4.0 * EPS * mag + vec3<f32>(2e-9 * scale);
    return RBox(lo - pad, 0u, hi + pad, 0u);
}

// NodeBound::new for level nodes first .. first + n.
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
        atomicMax(&counters[0], 0xffffffffu - (p.first + i));
    }
    nodes[p.first + i].bound = b;
}

// A lowest node's box: the union of its rays' segment boxes.
@compute @workgroup_size(WG)
fn lowest_boxes(@builtin(global_invocation_id) gid: vec3<u32>,
                @builtin(num_workgroups) nwg: vec3<u32>) {
    let n = linear_id(gid, nwg);
    if (n >= p.n) {
        return;
    }
    let leaves = node_leaves(n);
    var b = empty_box();
    for (var k = 0u; k < leaves.y; k++) {
        b = union_box(b, segment_box(rays[order[leaves.x + k]]));
    }
    nodes[n].rbox = b;
}

// A higher node's box: the union of its children's.
@compute @workgroup_size(WG)
fn upper_boxes(@builtin(global_invocation_id) gid: vec3<u32>,
               @builtin(num_workgroups) nwg: vec3<u32>) {
    let n = linear_id(gid, nwg);
    if (n >= p.n) {
        return;
    }
    let below = p.first - p.child_first;
    let c0 = min(n * p.sub, below);
    let c1 = min(c0 + p.sub, below);
    var b = empty_box();
    for (var c = c0; c < c1; c++) {
        b = union_box(b, nodes[p.child_first + c].rbox);
    }
    nodes[p.first + n].rbox = b;
}

fn overlaps(a: RBox, lo: vec3<f32>, hi: vec3<f32>) -> bool {
    return all(a.lo <= hi) && all(lo <= a.hi);
}

fn count_row(row: u32, tests: u32, passes: u32) {
    add_u64(4u + 4u * row, tests);
    add_u64(6u + 4u * row, passes);
}

// The first pairs of a chunk of top nodes: (top node first + i, root).
@compute @workgroup_size(WG)
fn seed(@builtin(global_invocation_id) gid: vec3<u32>,
        @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg);
    if (i >= p.n) {
        return;
    }
    pairs_out[i] = Pair(p.first + i, p.root, 0u, p.n_levels - 1u);
}

// crsh_cpu's dual Task::run for one pair: the test and what follows from it. Returns (code,
// live mask); a candidate's mask is its lanes, a single-ray pair's the rays that passed.
// (Counted by emit_pairs, which runs once per tested frontier: a frontier too big for the
// budget is tested again in halves.)
fn test_pair(q: Pair) -> vec2<u32> {
    let level = q.info & 0xffffu;
    let depth = q.info >> 16u;
    let o = objs[q.obj];
    let leaf = o.b == OBJ_LEAF;
    if (level == SINGLE) {
        // The node's live rays, one by one, against the object node's box.
        let first = node_leaves(q.node).x;
        var live = 0u;
        var left = q.mask;
        while (left != 0u) {
            let i = firstTrailingBit(left);
            left = left & (left - 1u);
            let r = rays[order[first + i]];
            let t = clip(ray_origin(r), ray_dir(r), r.t_min, r.t_max, o.lo, o.hi);
            if (t.x <= t.y) {
                live = live | (1u << i);
            }
        }
        if (live == 0u) {
            return vec2<u32>(DROP, 0u);
        }
        if (leaf) {
            return vec2<u32>(CANDIDATE, live);
        }
        return vec2<u32>(SPLIT_OBJECT, live);
    }
    let rec = nodes[level_first(level) + q.node];
    let rb = rec.rbox;
    let nb = rec.bound;
    var ok = true;
    if (p.box_test != 0u && !overlaps(rb, o.lo, o.hi)) {
        ok = false;
    }
    if (ok && !may_hit(nb, o.sphere)) {
        ok = false;
    }
    if (!ok) {
        return vec2<u32>(DROP, 0u);
    }
    if (level == 0u) {
        if (leaf) {
            return vec2<u32>(CANDIDATE, ALL);
        }
        let n_rays = node_leaves(q.node).y;
        // A node with a ray that is not valid has the whole space as its box and stays whole.
        if (p.single_rays != 0u && n_rays <= 32u && f32_finite(rb.lo.x) && f32_finite(rb.lo.y)
            && f32_finite(rb.lo.z) && spreads_wider_than(nb, o.sphere)) {
            var mask = ALL;
            if (n_rays < 32u) {
                mask = (1u << n_rays) - 1u;
            }
            return vec2<u32>(TO_SINGLE, mask);
        }
        return vec2<u32>(SPLIT_OBJECT, 0u);
    }
    if (leaf || spreads_wider_than(nb, o.sphere)) {
        return vec2<u32>(SPLIT_RAYS, 0u);
    }
    return vec2<u32>(SPLIT_OBJECT, 0u);
}

// The children of ray node `node` at `level` (> 0): [c0, c1) in the level below.
fn ray_children(level: u32, node: u32) -> vec2<u32> {
    let below = level_first(level) - level_first(level - 1u);
    let c0 = min(node * p.sub, below);
    return vec2<u32>(c0, min(c0 + p.sub, below));
}

fn children_of(q: Pair, code: u32) -> u32 {
    if (code == TO_SINGLE) {
        return 1u;
    }
    if (code == SPLIT_RAYS) {
        let c = ray_children(q.info & 0xffffu, q.node);
        return c.y - c.x;
    }
    if (code == SPLIT_OBJECT) {
        return 2u;
    }
    return 0u;
}

@compute @workgroup_size(WG)
fn test_pairs(@builtin(global_invocation_id) gid: vec3<u32>,
              @builtin(num_workgroups) nwg: vec3<u32>) {
    let k = linear_id(gid, nwg);
    if (k >= p.n) {
        return;
    }
    let q = pairs_in[k];
    let r = test_pair(q);
    outcome[k] = r;
    counts[k] = children_of(q, r.x);
    counts[p.n + k] = select(0u, 1u, r.x == CANDIDATE);
}

@compute @workgroup_size(WG)
fn emit_pairs(@builtin(global_invocation_id) gid: vec3<u32>,
              @builtin(num_workgroups) nwg: vec3<u32>) {
    let k = linear_id(gid, nwg);
    if (k >= p.n) {
        return;
    }
    let q = pairs_in[k];
    let r = outcome[k];
    let at = counts[k];
    let level = q.info & 0xffffu;
    let depth = q.info >> 16u;
    // The test's counts, in its ray level's row (a single-ray pair: each ray tested, in the
    // lowest level's) and its object depth's.
    if (level == SINGLE) {
        let tested = countOneBits(q.mask);
        let passed = countOneBits(r.y);
        count_row(0u, tested, passed);
        count_row(p.n_levels + depth, tested, passed);
    } else {
        let passed = select(1u, 0u, r.x == DROP);
        count_row(level, 1u, passed);
        count_row(p.n_levels + depth, 1u, passed);
    }
    switch (r.x) {
        case 1u: {
            raw[counts[p.n + k] - counts[p.n]] = Pair(q.node, objs[q.obj].a, r.y, 0u);
        }
        case 2u: {
            pairs_out[at] = Pair(q.node, q.obj, r.y, SINGLE | (depth << 16u));
        }
        case 3u: {
            let c = ray_children(level, q.node);
            for (var j = c.x; j < c.y; j++) {
                pairs_out[at + j - c.x] = Pair(j, q.obj, 0u, (level - 1u) | (depth << 16u));
            }
        }
        case 4u: {
            let o = objs[q.obj];
            pairs_out[at] = Pair(q.node, o.a, r.y, level | ((depth + 1u) << 16u));
            pairs_out[at + 1u] = Pair(q.node, o.b, r.y, level | ((depth + 1u) << 16u));
        }
        default: {}
    }
}

// Candidate keys for the sort: node << tri_bits | triangle (a raw candidate's `obj`).
@compute @workgroup_size(WG)
fn cand_keys(@builtin(global_invocation_id) gid: vec3<u32>,
             @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg);
    if (i >= p.n) {
        return;
    }
    let c = raw[i];
    var key = vec2<u32>(c.obj, 0u);
    if (p.tri_bits >= 32u) {
        key.y = c.node << (p.tri_bits - 32u);
    } else {
        key.x = c.obj | (c.node << p.tri_bits);
        key.y = c.node >> (32u - p.tri_bits);
    }
    keys[i] = key;
}

fn is_head(i: u32) -> bool {
    return i == 0u || any(keys[sorted[i]] != keys[sorted[i - 1u]]);
}

// Run heads of the sorted candidates (one per distinct pair), scanned into positions.
@compute @workgroup_size(WG)
fn merge_heads(@builtin(global_invocation_id) gid: vec3<u32>,
               @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg);
    if (i >= p.n) {
        return;
    }
    counts[i] = select(0u, 1u, is_head(i));
}

// A run's head writes its pair once, for the union of the run's lane masks.
@compute @workgroup_size(WG)
fn merge_emit(@builtin(global_invocation_id) gid: vec3<u32>,
              @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg);
    if (i >= p.n || !is_head(i)) {
        return;
    }
    let c = raw[sorted[i]];
    var mask = c.mask;
    var j = i + 1u;
    while (j < p.n && !is_head(j)) {
        mask = mask | raw[sorted[j]].mask;
        j++;
    }
    cands[counts[i]] = Candidate(c.node, c.obj);
    lanes[counts[i]] = mask;
}
