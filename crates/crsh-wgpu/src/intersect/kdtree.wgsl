// `kdtree` on the device: one ray per invocation through RTTest's kd-tree (seed 003 listing
// 2.2 with its errata fixed), the twin of crsh_cpu::kdtree::trace_single (walk_leaves_until, clip,
// front_back, crossing, descend, test_leaf, KdLeaf::holds_final), the same operations in the
// same order. Prepended: common.wgsl, mt.wgsl, and the constants T_SLACK, CELL_MARGIN (f32)
// and STACK (u32) generated from the Rust ones (kdtree.rs).
//
// Three things keep the arithmetic the CPU's, bit for bit:
// - no NaN is ever formed: where the CPU's widening `x ∓ |x|·T_SLACK` of an infinite `x` is
//   NaN or infinite, f32::max/min keep the other operand, and `widen_*` below return it
//   directly; a zero direction component's inverse is the signed infinity the CPU divides to;
// - every product that feeds an addition goes through `rounded`, so that a driver cannot
//   contract the two into a fused multiply-add (Rust never does);
// - f32::max/min are written as comparisons (WGSL's max/min leave NaN and zero signs open).

struct Params {
    // Rays in this dispatch, 1 for any-hit queries, index of the chunk's first ray.
    n: u32,
    any_hit: u32,
    first: u32,
    // Nodes in the tree (0: no hittable triangle, nothing is traversed).
    n_nodes: u32,
    // The root cell (KdTree::bounds), w unused.
    lo: vec4<f32>,
    hi: vec4<f32>,
    // Always 0: the operand of `rounded`'s integer identity.
    zero: u32,
    _a: u32,
    _b: u32,
    _c: u32,
}

// crsh_cpu::kdtree::KdNode (12 bytes).
struct KdNode {
    split: f32,
    // 0, 1, 2 (x, y, z) or LEAF.
    axis: u32,
    // Inner node: left child (right = index + 1). Leaf: index into `leaves`.
    index: u32,
}

// crsh_cpu::kdtree::KdLeaf (32 bytes).
struct KdLeaf {
    min_x: f32, min_y: f32, min_z: f32,
    start: u32,
    max_x: f32, max_y: f32, max_z: f32,
    count: u32,
}

// crsh_cpu::kdtree::Entry.
struct Entry {
    node: u32,
    near: f32,
    far: f32,
}

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> rays: array<Ray>;
@group(0) @binding(2) var<storage, read> nodes: array<KdNode>;
@group(0) @binding(3) var<storage, read> leaves: array<KdLeaf>;
@group(0) @binding(4) var<storage, read> leaf_tris: array<u32>;
@group(0) @binding(5) var<storage, read> tris: array<MtTri>;
@group(0) @binding(6) var<storage, read_write> hits: array<Hit>;
// [inner nodes lo, hi, leaves lo, hi, triangle tests lo, hi, invalid ray report, flags: 1 stack
// overflow, 2 a loop cut short by the adapter]
@group(0) @binding(7) var<storage, read_write> counters: array<atomic<u32>>;

const LEAF: u32 = 3u;

var<workgroup> wg_inner: atomic<u32>;
var<workgroup> wg_leaves: atomic<u32>;
var<workgroup> wg_tests: atomic<u32>;

// `x` as already rounded: an integer identity the compiler cannot see through (p.zero is 0
// only at run time), so a product passed through it is never fused with what it is added to.
fn rounded(x: f32) -> f32 {
    return bitcast<f32>(bitcast<u32>(x) ^ p.zero);
}

// Rust's `a.max(x - x.abs() * T_SLACK)` for `a` not NaN, an infinite `x` left unwidened
// (crsh_cpu::kdtree::descend): +∞ wins, −∞ never does.
fn widen_max(a: f32, x: f32) -> f32 {
    if (!f32_finite(x)) {
        return select(a, x, x > 0.0);
    }
    let w = x - rounded(abs(x) * T_SLACK);
    return select(a, w, w > a);
}

// Rust's `a.min(x + x.abs() * T_SLACK)` for `a` not NaN: an infinite `x` leaves `a`.
fn widen_min(a: f32, x: f32) -> f32 {
    if (!f32_finite(x)) {
        return a;
    }
    let w = x + rounded(abs(x) * T_SLACK);
    return select(a, w, w < a);
}

// `1.0 / d` as the CPU computes it, a zero giving the infinity of its sign.
fn inverse(d: f32) -> f32 {
    if (d == 0.0) {
        return select(inf(), -inf(), (bitcast<u32>(d) & 0x80000000u) != 0u);
    }
    return 1.0 / d;
}

// crsh_cpu::kdtree::clip against the root cell: `(near, far, 1)` or `(_, _, 0)` when the ray
// misses it. A zero direction component skips its axis when the origin is inside the slab
// and misses otherwise, as on the CPU.
fn clip(o: vec3<f32>, d: vec3<f32>, t_min: f32, t_max: f32) -> vec3<f32> {
    var near = select(t_min, 0.0, 0.0 > t_min);
    var far = t_max;
    for (var a = 0u; a < 3u; a++) {
        if (d[a] == 0.0) {
            // Parallel to the slab: inside it for every t, or never.
            if (o[a] < p.lo[a] || o[a] > p.hi[a]) {
                return vec3<f32>(0.0, 0.0, 0.0);
            }
            continue;
        }
        let inv = 1.0 / d[a];
        let t0 = (p.lo[a] - o[a]) * inv;
        let t1 = (p.hi[a] - o[a]) * inv;
        var lo = t1;
        var hi = t0;
        if (t0 <= t1) {
            lo = t0;
            hi = t1;
        }
        near = widen_max(near, lo);
        far = widen_min(far, hi);
    }
    return vec3<f32>(near, far, select(0.0, 1.0, near <= far));
}

// crsh_cpu::kdtree::KdLeaf::holds_final for the point `o + d·t`.
fn holds_final(leaf: KdLeaf, o: vec3<f32>, d: vec3<f32>, t: f32) -> bool {
    let lo = vec3<f32>(leaf.min_x, leaf.min_y, leaf.min_z);
    let hi = vec3<f32>(leaf.max_x, leaf.max_y, leaf.max_z);
    for (var a = 0u; a < 3u; a++) {
        let x = o[a] + rounded(d[a] * t);
        let big = max(max(abs(lo[a]), abs(hi[a])), abs(x));
        let m = rounded(CELL_MARGIN * big);
        if (!(x > lo[a] + m && x < hi[a] - m)) {
            return false;
        }
    }
    return true;
}

// crsh_cpu::kdtree::trace_single with Möller-Trumbore, one ray per invocation, merging into
// the stored hit; counts inner nodes, leaves and triangle tests as KdCounts does.
@compute @workgroup_size(WG)
fn traverse(@builtin(global_invocation_id) gid: vec3<u32>,
            @builtin(local_invocation_index) lid: u32,
            @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg);
    if (lid == 0u) {
        atomicStore(&wg_inner, 0u);
        atomicStore(&wg_leaves, 0u);
        atomicStore(&wg_tests, 0u);
    }
    workgroupBarrier();
    var inner = 0u;
    var n_leaves = 0u;
    var tests = 0u;
    if (i < p.n) {
        let r = rays[i];
        var best = hits[i];
        if (!ray_valid(r)) {
            atomicMax(&counters[6], 0xffffffffu - (p.first + i));
        } else if ((p.any_hit == 0u || best.tri == NO_HIT) && r.t_min < r.t_max
                   && p.n_nodes > 0u) {
            let o = ray_origin(r);
            let d = ray_dir(r);
            let d_len = ray_dir_len(d);
            let c = clip(o, d, r.t_min, r.t_max);
            if (c.z > 0.5) {
                let inv = vec3<f32>(inverse(d.x), inverse(d.y), inverse(d.z));
                var stack: array<Entry, STACK>;
                stack[0] = Entry(0u, c.x, c.y);
                var sp = 1u;
                var done = false;
                while (sp > 0u && !done) {
                    sp -= 1u;
                    var node = stack[sp].node;
                    var near = stack[sp].near;
                    var far = stack[sp].far;
                    // crsh_cpu::kdtree::walk_leaves_until: a closest-hit ray skips the
                    // subtrees that start beyond its best hit.
                    if (p.any_hit == 0u && near > best.t) {
                        continue;
                    }
                    loop {
                        let n = nodes[node];
                        if (n.axis == LEAF) {
                            n_leaves += 1u;
                            let leaf = leaves[n.index];
                            for (var k = leaf.start; k < leaf.start + leaf.count; k++) {
                                let id = leaf_tris[k];
                                tests += 1u;
                                let h = mt_hit(tris[id], o, d, d_len, r.t_min, r.t_max);
                                if (h.x < inf() && closer_than(h.x, id, best)) {
                                    best = Hit(h.x, id, h.y, h.z);
                                    if (p.any_hit != 0u) {
                                        break;
                                    }
                                }
                            }
                            if (p.any_hit != 0u) {
                                done = best.tri != NO_HIT;
                            } else {
                                done = best.tri != NO_HIT && holds_final(leaf, o, d, best.t);
                            }
                            break;
                        }
                        inner += 1u;
                        let dist = n.split - o[n.axis];
                        var front = n.index;
                        var back = n.index + 1u;
                        if (dist < 0.0) {
                            front = n.index + 1u;
                            back = n.index;
                        }
                        if (sp == STACK) {
                            // Unreachable for trees no deeper than STACK (checked on upload):
                            // the entries lie at distinct depths up to this inner node's.
                            atomicOr(&counters[7], 1u);
                            done = true;
                            break;
                        }
                        if (dist == 0.0) {
                            // On the plane: the ray may go either way; both sides whole.
                            stack[sp] = Entry(back, near, far);
                            sp += 1u;
                            node = front;
                            continue;
                        }
                        // crossing (behind the origin or never: +inf), then descend.
                        let x = dist * inv[n.axis];
                        let cross = select(inf(), x, x >= 0.0);
                        let front_far = widen_min(far, cross);
                        let back_near = widen_max(near, cross);
                        let has_front = near <= front_far;
                        let has_back = back_near <= far;
                        if (has_front && has_back) {
                            stack[sp] = Entry(back, back_near, far);
                            sp += 1u;
                            node = front;
                            far = front_far;
                        } else if (has_front) {
                            node = front;
                            far = front_far;
                        } else if (has_back) {
                            node = back;
                            near = back_near;
                        } else {
                            break;
                        }
                    }
                }
            }
            hits[i] = best;
            // llvmpipe (the software adapter without a GPU) ends every loop of an invocation
            // once its loops have run 65535 iterations in all, silently: a loop that must run
            // twice and runs once says that a traversal loop above was cut short.
            var probe = 0u;
            for (var j = 0u; j < 2u + p.zero; j++) {
                probe += 1u;
            }
            if (probe != 2u) {
                atomicOr(&counters[7], 2u);
            }
        }
    }
    atomicAdd(&wg_inner, inner);
    atomicAdd(&wg_leaves, n_leaves);
    atomicAdd(&wg_tests, tests);
    workgroupBarrier();
    if (lid == 0u) {
        add_u64(0u, atomicLoad(&wg_inner));
        add_u64(2u, atomicLoad(&wg_leaves));
        add_u64(4u, atomicLoad(&wg_tests));
    }
}
