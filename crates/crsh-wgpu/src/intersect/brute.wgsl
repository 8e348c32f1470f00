// `brute` on the device: the twin of crsh_cpu::intersect::brute (see brute.rs).
// Prepended: common.wgsl, mt.wgsl.

struct Params {
    // Rays in this dispatch (a chunk of the batch for scene queries; leaves for candidates).
    n: u32,
    n_tris: u32,
    // 1 for any-hit queries.
    any_hit: u32,
    // Candidate queries: pairs in the batch, and the hierarchy's subdivision.
    n_pairs: u32,
    subdivision: u32,
    // Scene queries: index of the chunk's first ray in the batch.
    first: u32,
    // Candidate queries: 1 when the hierarchy has leaf offsets (`offsets` is bound; node k
    // holds leaves offsets[k] .. offsets[k + 1]), 0 for fixed groups (node = leaf / subdivision).
    has_offsets: u32,
    // Candidate queries: nodes of levels[0], and leaves (the order's length).
    n_nodes: u32,
    n_leaves: u32,
    // Candidate queries: 1 when `lanes` holds a mask per pair (bit k: the node's k-th ray).
    has_lanes: u32,
    // The window of this dispatch: scene queries test triangles [start, min(start + span,
    // n_tris)); candidate queries the pairs of each node from its start-th on, at most span
    // (no invocation loops more than a span: lavapipe ends every loop of an invocation after
    // 65535 iterations in all, see brute.rs).
    start: u32,
    span: u32,
}

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> rays: array<Ray>;
@group(0) @binding(2) var<storage, read> tris: array<MtTri>;
@group(0) @binding(3) var<storage, read_write> hits: array<Hit>;
// [tests lo, tests hi, found lo, found hi, check flags, first invalid ray, more pairs, 0]
@group(0) @binding(4) var<storage, read_write> counters: array<atomic<u32>>;
// Candidate queries: the hierarchy's order (leaf -> ray) and the sorted pairs.
@group(0) @binding(5) var<storage, read> order: array<u32>;
@group(0) @binding(6) var<storage, read> pairs: array<Candidate>;
// Candidate queries with has_offsets: the hierarchy's leaf offsets (n_nodes + 1 entries).
@group(0) @binding(7) var<storage, read> offsets: array<u32>;
// Candidate queries with has_lanes: each pair's lane mask (crsh_core::CandidateBatch::lanes).
@group(0) @binding(8) var<storage, read> lanes: array<u32>;

const LANES: u32 = 8u;

var<workgroup> tile: array<MtTri, WG>;
var<workgroup> wg_tests: atomic<u32>;
var<workgroup> wg_found: atomic<u32>;
var<workgroup> live: atomic<u32>;
var<workgroup> live_copy: u32;

// Every ray of the chunk against every triangle, in increasing id order, triangles staged in
// workgroup memory WG at a time. Closest: Hit::closer_than over all; any-hit: a ray whose hit
// is already a hit is skipped, otherwise the first (lowest-id) hit stops it, and the tests
// counted are those of the CPU's 8-wide blocks: min(8·(block of the hit + 1), triangles).
@compute @workgroup_size(WG)
fn scene_query(@builtin(global_invocation_id) gid: vec3<u32>,
               @builtin(local_invocation_index) lid: u32,
               @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg);
    var best = Hit(inf(), NO_HIT, 0.0, 0.0);
    var searching = false;
    var o = vec3<f32>(0.0);
    var d = vec3<f32>(0.0);
    var d_len = 0.0;
    var t_min = 0.0;
    var t_max = 0.0;
    if (i < p.n) {
        let r = rays[i];
        best = hits[i];
        searching = p.any_hit == 0u || best.tri == NO_HIT;
        if (!ray_valid(r)) {
            // Reported by the host (the smallest bad index wins); the ray is not tested.
            atomicMax(&counters[5], 0xffffffffu - (p.first + i));
            searching = false;
        }
        o = ray_origin(r);
        d = ray_dir(r);
        d_len = ray_dir_len(d);
        t_min = r.t_min;
        t_max = r.t_max;
    }
    let was_active = searching;
    var tests = 0u;
    if (lid == 0u) {
        atomicStore(&wg_tests, 0u);
    }
    workgroupBarrier();
    let end = min(p.start + p.span, p.n_tris);
    for (var base = p.start; base < end; base += WG) {
        if (p.any_hit != 0u) {
            if (lid == 0u) {
                atomicStore(&live, 0u);
            }
            workgroupBarrier();
            if (searching) {
                atomicStore(&live, 1u);
            }
            workgroupBarrier();
            if (lid == 0u) {
                live_copy = atomicLoad(&live);
            }
            if (workgroupUniformLoad(&live_copy) == 0u) {
                break;
            }
        }
        workgroupBarrier();
        if (base + lid < end) {
            tile[lid] = tris[base + lid];
        }
        workgroupBarrier();
        if (searching) {
            let m = min(WG, end - base);
            for (var k = 0u; k < m; k++) {
                let h = mt_hit(tile[k], o, d, d_len, t_min, t_max);
                if (h.x < inf()) {
                    let tri = base + k;
                    if (p.any_hit != 0u) {
                        best = Hit(h.x, tri, h.y, h.z);
                        searching = false;
                        tests = min((tri / LANES + 1u) * LANES, p.n_tris) - p.start;
                        break;
                    } else if (closer_than(h.x, tri, best)) {
                        best = Hit(h.x, tri, h.y, h.z);
                    }
                }
            }
        }
    }
    if (i < p.n) {
        if (was_active && (p.any_hit == 0u || searching)) {
            tests = end - p.start;
        }
        hits[i] = best;
    }
    atomicAdd(&wg_tests, tests);
    workgroupBarrier();
    if (lid == 0u) {
        add_u64(0u, atomicLoad(&wg_tests));
    }
}

// The first pair index whose node is >= `node` (pairs sorted by node, then triangle).
fn first_pair(node: u32) -> u32 {
    var lo = 0u;
    var hi = p.n_pairs;
    while (lo < hi) {
        let mid = lo + (hi - lo) / 2u;
        if (pairs[mid].node < node) {
            lo = mid + 1u;
        } else {
            hi = mid;
        }
    }
    return lo;
}

// The levels[0] node holding `leaf` under leaf offsets: the first k with offsets[k + 1] > leaf
// (offsets non-decreasing from 0 to n_leaves, checked by check_pairs; empty nodes are skipped).
fn node_of_leaf(leaf: u32) -> u32 {
    var lo = 0u;
    var hi = p.n_nodes;
    while (lo < hi) {
        let mid = lo + (hi - lo) / 2u;
        if (offsets[mid + 1u] <= leaf) {
            lo = mid + 1u;
        } else {
            hi = mid;
        }
    }
    return lo;
}

// The first leaf of levels[0] node `node` and its leaf count.
fn node_leaves(node: u32) -> vec2<u32> {
    if (p.has_offsets != 0u) {
        return vec2<u32>(offsets[node], offsets[node + 1u] - offsets[node]);
    }
    let s = node * p.subdivision;
    return vec2<u32>(s, min(s + p.subdivision, p.n_leaves) - s);
}

// Whether pair k is for the node's ray in lane `lane` (every ray without lane masks; a mask
// other than all lanes is only on nodes of at most 32 rays, check_pairs refuses others).
fn for_lane(k: u32, lane: u32) -> bool {
    if (p.has_lanes == 0u || lanes[k] == 0xffffffffu) {
        return true;
    }
    return lane < 32u && ((lanes[k] >> lane) & 1u) != 0u;
}

// One invocation per hierarchy leaf: its ray against the triangles paired with its node, in
// increasing id order (pairs strictly increasing), merged into its current hit like the CPU's
// candidate mode (any-hit: a hit ray is skipped, the first hit stops it). With lane masks only
// the pairs naming the leaf's lane are tested. Counts every test and every test that found an
// intersection (the level-0 row of the tables).
@compute @workgroup_size(WG)
fn candidates(@builtin(global_invocation_id) gid: vec3<u32>,
              @builtin(local_invocation_index) lid: u32,
              @builtin(num_workgroups) nwg: vec3<u32>) {
    let leaf = linear_id(gid, nwg);
    if (lid == 0u) {
        atomicStore(&wg_tests, 0u);
        atomicStore(&wg_found, 0u);
    }
    workgroupBarrier();
    var tests = 0u;
    var found = 0u;
    if (leaf < p.n) {
        var node: u32;
        if (p.has_offsets != 0u) {
            node = node_of_leaf(leaf);
        } else {
            node = leaf / p.subdivision;
        }
        let ri = order[leaf];
        let r = rays[ri];
        var best = hits[ri];
        let o = ray_origin(r);
        let d = ray_dir(r);
        let d_len = ray_dir_len(d);
        if (!ray_valid(r)) {
            atomicMax(&counters[5], 0xffffffffu - ri);
        } else if (p.any_hit == 0u || best.tri == NO_HIT) {
            let lane = leaf - node_leaves(node).x;
            let first = first_pair(node) + p.start;
            let limit = min(p.n_pairs, first + p.span);
            var k = first;
            for (; k < limit && pairs[k].node == node; k++) {
                if (!for_lane(k, lane)) {
                    continue;
                }
                let tri = pairs[k].tri;
                tests += 1u;
                let h = mt_hit(tris[tri], o, d, d_len, r.t_min, r.t_max);
                if (h.x < inf()) {
                    found += 1u;
                    if (p.any_hit != 0u) {
                        best = Hit(h.x, tri, h.y, h.z);
                        break;
                    } else if (closer_than(h.x, tri, best)) {
                        best = Hit(h.x, tri, h.y, h.z);
                    }
                }
            }
            if (k == limit && k < p.n_pairs && pairs[k].node == node
                && (p.any_hit == 0u || best.tri == NO_HIT)) {
                // The node has pairs beyond this window: the host dispatches the next.
                atomicOr(&counters[6], 1u);
            }
            hits[ri] = best;
        }
    }
    atomicAdd(&wg_tests, tests);
    atomicAdd(&wg_found, found);
    workgroupBarrier();
    if (lid == 0u) {
        add_u64(0u, atomicLoad(&wg_tests));
        add_u64(2u, atomicLoad(&wg_found));
    }
}

// Bits of counters[4]: 1 when the pairs are not strictly increasing (the host sorts them), 2
// when a pair references a node or triangle out of range, 4 when the leaf offsets are not
// 0, non-decreasing, ..., n_leaves, 8 when a pair's lane mask is partial on a node of more
// than 32 rays (all reported by the host). One invocation per pair and, with offsets, per
// offset entry.
@compute @workgroup_size(WG)
fn check_pairs(@builtin(global_invocation_id) gid: vec3<u32>,
               @builtin(num_workgroups) nwg: vec3<u32>) {
    let k = linear_id(gid, nwg);
    if (p.has_offsets != 0u && k <= p.n_nodes) {
        let o = offsets[k];
        if ((k == 0u && o != 0u) || (k == p.n_nodes && o != p.n_leaves) || o > p.n_leaves
            || (k > 0u && offsets[k - 1u] > o)) {
            atomicOr(&counters[4], 4u);
        }
    }
    if (k >= p.n_pairs) {
        return;
    }
    let c = pairs[k];
    if (c.node >= p.n_nodes || c.tri >= p.n_tris) {
        atomicOr(&counters[4], 2u);
    } else if (p.has_lanes != 0u && lanes[k] != 0xffffffffu && node_leaves(c.node).y > 32u) {
        atomicOr(&counters[4], 8u);
    }
    if (k + 1u < p.n_pairs) {
        let nx = pairs[k + 1u];
        if (nx.node < c.node || (nx.node == c.node && nx.tri <= c.tri)) {
            atomicOr(&counters[4], 1u);
        }
    }
}
