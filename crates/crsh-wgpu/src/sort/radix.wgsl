// Stable LSD radix sort of (u64 key, u32 value) pairs, 4 bits per pass: the twin of
// crsh_cpu::sort::radix (the stable order by key, then by original index). See radix.rs.
// Prepended: common.wgsl.

const RADIX: u32 = 16u;
const THREADS: u32 = 128u;
const ITEMS: u32 = 8u;
const BLOCK: u32 = 1024u; // THREADS * ITEMS

struct Params {
    n: u32,
    blocks: u32,
    // Bit offset of this pass's digit.
    shift: u32,
    // Bits above key_bits must be zero: mask of them (lo, hi) for the check pass.
    mask_lo: u32,
    mask_hi: u32,
    groups_x: u32,
    _a: u32,
    _b: u32,
}

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> keys_in: array<vec2<u32>>;
@group(0) @binding(2) var<storage, read> vals_in: array<u32>;
@group(0) @binding(3) var<storage, read_write> keys_out: array<vec2<u32>>;
@group(0) @binding(4) var<storage, read_write> vals_out: array<u32>;
// Digit-major counts: hist[digit * blocks + block]; scanned in place between the passes.
@group(0) @binding(5) var<storage, read_write> hist: array<u32>;
// [first key index with bits above key_bits, as 0xffffffff - index]
@group(0) @binding(6) var<storage, read_write> report: array<atomic<u32>>;

var<workgroup> counts: array<u32, 2048>; // THREADS * RADIX, thread-major

fn digit(k: vec2<u32>) -> u32 {
    if (p.shift < 32u) {
        return (k.x >> p.shift) & 0xfu;
    }
    return (k.y >> (p.shift - 32u)) & 0xfu;
}

fn block_id(wid: vec3<u32>) -> u32 {
    return wid.x + wid.y * p.groups_x;
}

// Values 0..n (the identity permutation) and the key_bits check.
@compute @workgroup_size(WG)
fn init(@builtin(global_invocation_id) gid: vec3<u32>,
        @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg);
    if (i >= p.n) {
        return;
    }
    vals_out[i] = i;
    let k = keys_in[i];
    if ((k.x & p.mask_lo) != 0u || (k.y & p.mask_hi) != 0u) {
        atomicMax(&report[0], 0xffffffffu - i);
    }
}

// Per block (BLOCK consecutive elements) and digit: how many elements have that digit.
@compute @workgroup_size(THREADS)
fn histogram(@builtin(workgroup_id) wid: vec3<u32>,
             @builtin(local_invocation_index) lid: u32) {
    let block = block_id(wid);
    for (var d = 0u; d < RADIX; d++) {
        counts[lid * RADIX + d] = 0u;
    }
    if (block < p.blocks) {
        let base = block * BLOCK + lid * ITEMS;
        for (var k = 0u; k < ITEMS; k++) {
            let i = base + k;
            if (i < p.n) {
                let d = digit(keys_in[i]);
                counts[lid * RADIX + d] += 1u;
            }
        }
    }
    workgroupBarrier();
    if (lid < RADIX && block < p.blocks) {
        var total = 0u;
        for (var t = 0u; t < THREADS; t++) {
            total += counts[t * RADIX + lid];
        }
        hist[lid * p.blocks + block] = total;
    }
}

// Each element goes to: (elements of smaller digits) + (same digit in earlier blocks) — the
// scanned histogram — plus the elements of its digit before it in its block. Each thread
// owns ITEMS consecutive elements, so "before it" is the earlier threads' counts (an
// exclusive scan over threads per digit) plus its own running count: a stable scatter.
@compute @workgroup_size(THREADS)
fn scatter(@builtin(workgroup_id) wid: vec3<u32>,
           @builtin(local_invocation_index) lid: u32) {
    let block = block_id(wid);
    for (var d = 0u; d < RADIX; d++) {
        counts[lid * RADIX + d] = 0u;
    }
    let base = block * BLOCK + lid * ITEMS;
    if (block < p.blocks) {
        for (var k = 0u; k < ITEMS; k++) {
            let i = base + k;
            if (i < p.n) {
                counts[lid * RADIX + digit(keys_in[i])] += 1u;
            }
        }
    }
    workgroupBarrier();
    // Exclusive scan over threads, one digit per invocation.
    if (lid < RADIX) {
        var run = 0u;
        for (var t = 0u; t < THREADS; t++) {
            let c = counts[t * RADIX + lid];
            counts[t * RADIX + lid] = run;
            run += c;
        }
    }
    workgroupBarrier();
    if (block < p.blocks) {
        for (var k = 0u; k < ITEMS; k++) {
            let i = base + k;
            if (i < p.n) {
                let key = keys_in[i];
                let d = digit(key);
                let at = hist[d * p.blocks + block] + counts[lid * RADIX + d];
                counts[lid * RADIX + d] += 1u;
                keys_out[at] = key;
                vals_out[at] = vals_in[i];
            }
        }
    }
}
