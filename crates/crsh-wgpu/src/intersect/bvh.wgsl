// `bvh` on the device: obvhs's CWBVH (Ylitie et al. 2017) traversed one ray per invocation,
// the twin of crsh_cpu::intersect::bvh (see bvh.rs). Prepended: common.wgsl, mt.wgsl.

struct Params {
    n: u32,
    n_nodes: u32,
    any_hit: u32,
    first: u32,
}

// obvhs::cwbvh::node::CwBvhNode (80 bytes): p, e[3] | imask << 24, child_base_idx,
// primitive_base_idx, then child_meta, child_min_x, child_max_x, child_min_y, child_max_y,
// child_min_z, child_max_z as 8 bytes each.
struct BvhNode {
    px: f32,
    py: f32,
    pz: f32,
    e_imask: u32,
    child_base: u32,
    prim_base: u32,
    q: array<u32, 14>,
}

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> rays: array<Ray>;
@group(0) @binding(2) var<storage, read> nodes: array<BvhNode>;
@group(0) @binding(3) var<storage, read> leaf_tris: array<MtTri>;
@group(0) @binding(4) var<storage, read> leaf_ids: array<u32>;
@group(0) @binding(5) var<storage, read_write> hits: array<Hit>;
// [bounds lo, hi, triangle tests lo, hi, invalid ray report, stack overflow, inner-node visits
// lo, hi, leaf visits lo, hi]
@group(0) @binding(6) var<storage, read_write> counters: array<atomic<u32>>;

const SLAB_SLACK: f32 = 1e-6;
const T_SLACK: f32 = 1e-5;
const MIN_DIR: f32 = 1e-25;
const STACK: u32 = 64u;

var<workgroup> wg_bounds: atomic<u32>;
var<workgroup> wg_prims: atomic<u32>;
var<workgroup> wg_inner: atomic<u32>;
var<workgroup> wg_leaves: atomic<u32>;

// Byte `i` of the 8-byte field starting at word `w` of q.
fn qbyte(n: BvhNode, w: u32, i: u32) -> u32 {
    return (n.q[w + i / 4u] >> (8u * (i % 4u))) & 0xffu;
}

fn cull_distance(t: f32) -> f32 {
    return t + abs(t) * T_SLACK;
}

fn clamp_dir(d: f32) -> f32 {
    if (abs(d) < MIN_DIR) {
        return select(MIN_DIR, -MIN_DIR, (bitcast<u32>(d) & 0x80000000u) != 0u);
    }
    return d;
}

// crsh_cpu::intersect::bvh::child_hits: the children whose widened boxes the ray overlaps
// within [t_lo, t_hi], as the traversal's hit mask.
fn child_hits(n: BvhNode, o: vec3<f32>, inv: vec3<f32>, neg: vec3<bool>, oct_inv4: u32,
              t_lo: f32, t_hi: f32) -> u32 {
    let e = vec3<f32>(bitcast<f32>((n.e_imask & 0xffu) << 23u),
                      bitcast<f32>(((n.e_imask >> 8u) & 0xffu) << 23u),
                      bitcast<f32>(((n.e_imask >> 16u) & 0xffu) << 23u));
    let a = e * inv;
    let orig = (vec3<f32>(n.px, n.py, n.pz) - o) * inv;
    let slack = (abs(a) * 255.0 + abs(orig)) * SLAB_SLACK;
    let lo = orig - slack;
    let hi = orig + slack;
    let oct = oct_inv4 & 0xffu;
    var mask = 0u;
    for (var c = 0u; c < 8u; c++) {
        let minx = f32(qbyte(n, 2u, c));
        let maxx = f32(qbyte(n, 4u, c));
        let miny = f32(qbyte(n, 6u, c));
        let maxy = f32(qbyte(n, 8u, c));
        let minz = f32(qbyte(n, 10u, c));
        let maxz = f32(qbyte(n, 12u, c));
        let nx = select(minx, maxx, neg.x);
        let fx = select(maxx, minx, neg.x);
        let ny = select(miny, maxy, neg.y);
        let fy = select(maxy, miny, neg.y);
        let nz = select(minz, maxz, neg.z);
        let fz = select(maxz, minz, neg.z);
        let t0 = max(max(max(nx * a.x + lo.x, ny * a.y + lo.y), nz * a.z + lo.z), t_lo);
        let t1 = min(min(min(fx * a.x + hi.x, fy * a.y + hi.y), fz * a.z + hi.z), t_hi);
        if (t0 <= t1) {
            let m = qbyte(n, 0u, c);
            let inner = ((m & (m << 1u)) & 0x10u) != 0u;
            let bit_index = (m ^ select(0u, oct, inner)) & 0x1fu;
            let child_bits = (m >> 5u) & 0x7u;
            mask |= child_bits << bit_index;
        }
    }
    return mask;
}

fn meta_count(n: BvhNode) -> u32 {
    var k = 0u;
    for (var c = 0u; c < 8u; c++) {
        k += select(0u, 1u, qbyte(n, 0u, c) != 0u);
    }
    return k;
}

// crsh_cpu::intersect::bvh::leaf_top_bits: for each leaf child (non-empty meta, imask bit
// clear) holding primitives first .. first + count, bit first + count - 1: the primitive of
// that leaf the traversal tests first (highest bit first), where the leaf visit is counted.
fn leaf_top_bits(n: BvhNode) -> u32 {
    let imask = n.e_imask >> 24u;
    var tops = 0u;
    for (var c = 0u; c < 8u; c++) {
        let m = qbyte(n, 0u, c);
        if (m != 0u && ((imask >> c) & 1u) == 0u) {
            tops |= 1u << ((m & 0x1fu) + countOneBits(m >> 5u) - 1u);
        }
    }
    return tops;
}

@compute @workgroup_size(WG)
fn traverse(@builtin(global_invocation_id) gid: vec3<u32>,
            @builtin(local_invocation_index) lid: u32,
            @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg);
    if (lid == 0u) {
        atomicStore(&wg_bounds, 0u);
        atomicStore(&wg_prims, 0u);
        atomicStore(&wg_inner, 0u);
        atomicStore(&wg_leaves, 0u);
    }
    workgroupBarrier();
    var bounds = 0u;
    var prims = 0u;
    var inner = 0u;
    var leaves = 0u;
    if (i < p.n) {
        let r = rays[i];
        var best = hits[i];
        if (!ray_valid(r)) {
            atomicMax(&counters[4], 0xffffffffu - (p.first + i));
        } else if (p.n_nodes > 0u && (p.any_hit == 0u || best.tri == NO_HIT)
                   && r.t_min < r.t_max) {
            // (An empty interval, an origin offset past the ray's end, is not traversed.)
            let o = ray_origin(r);
            let d = ray_dir(r);
            let d_len = ray_dir_len(d);
            let dc = vec3<f32>(clamp_dir(d.x), clamp_dir(d.y), clamp_dir(d.z));
            let inv = vec3<f32>(1.0) / dc;
            let neg = vec3<bool>(dc.x < 0.0, dc.y < 0.0, dc.z < 0.0);
            var oct_inv4 = 0u;
            if (!(d.x < 0.0)) { oct_inv4 |= 0x04040404u; }
            if (!(d.y < 0.0)) { oct_inv4 |= 0x02020202u; }
            if (!(d.z < 0.0)) { oct_inv4 |= 0x01010101u; }
            let t_lo = r.t_min - abs(r.t_min) * T_SLACK;
            var t_hi = cull_distance(min(r.t_max, best.t));
            var cur = vec2<u32>(0u, 0x80000000u);
            var prim = vec2<u32>(0u, 0u);
            var stack: array<vec2<u32>, STACK>;
            var sp = 0u;
            var done = false;
            var leaf_tops = 0u;
            loop {
                while (prim.y != 0u) {
                    let lpi = firstLeadingBit(prim.y);
                    prim.y &= ~(1u << lpi);
                    let slot = prim.x + lpi;
                    prims += 1u;
                    leaves += (leaf_tops >> lpi) & 1u;
                    let h = mt_hit(leaf_tris[slot], o, d, d_len, r.t_min, r.t_max);
                    if (h.x < inf()) {
                        let id = leaf_ids[slot];
                        if (p.any_hit != 0u) {
                            best = Hit(h.x, id, h.y, h.z);
                            done = true;
                            break;
                        }
                        if (closer_than(h.x, id, best)) {
                            best = Hit(h.x, id, h.y, h.z);
                            t_hi = cull_distance(min(r.t_max, best.t));
                        }
                    }
                }
                if (done) {
                    break;
                }
                prim = vec2<u32>(0u, 0u);
                if ((cur.y & 0xff000000u) != 0u) {
                    let hits_imask = cur.y;
                    let off = firstLeadingBit(hits_imask);
                    let base = cur.x;
                    cur.y &= ~(1u << off);
                    if ((cur.y & 0xff000000u) != 0u) {
                        if (sp == STACK) {
                            atomicOr(&counters[5], 1u);
                            break;
                        }
                        stack[sp] = cur;
                        sp += 1u;
                    }
                    let slot_index = (off - 24u) ^ (oct_inv4 & 0xffu);
                    let rel = countOneBits(hits_imask & ~(0xffffffffu << slot_index));
                    let node = nodes[base + rel];
                    inner += 1u;
                    bounds += meta_count(node);
                    leaf_tops = leaf_top_bits(node);
                    let hitmask = child_hits(node, o, inv, neg, oct_inv4, t_lo, t_hi);
                    cur = vec2<u32>(node.child_base, (hitmask & 0xff000000u) | (node.e_imask >> 24u));
                    prim = vec2<u32>(node.prim_base, hitmask & 0x00ffffffu);
                } else {
                    cur = vec2<u32>(0u, 0u);
                }
                if (prim.y == 0u && (cur.y & 0xff000000u) == 0u) {
                    if (sp == 0u) {
                        break;
                    }
                    sp -= 1u;
                    cur = stack[sp];
                }
            }
            hits[i] = best;
        }
    }
    atomicAdd(&wg_bounds, bounds);
    atomicAdd(&wg_prims, prims);
    atomicAdd(&wg_inner, inner);
    atomicAdd(&wg_leaves, leaves);
    workgroupBarrier();
    if (lid == 0u) {
        add_u64(0u, atomicLoad(&wg_bounds));
        add_u64(2u, atomicLoad(&wg_prims));
        add_u64(6u, atomicLoad(&wg_inner));
        add_u64(8u, atomicLoad(&wg_leaves));
    }
}
