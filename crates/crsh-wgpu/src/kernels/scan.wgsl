// Exclusive prefix sum of u32 with wrapping (mod 2^32) addition; see scan.rs for the driver.
//
// One workgroup scans one block of BLOCK = WG * ITEMS consecutive elements in place:
//   1. coalesced load of the block into workgroup memory (zero past `n`);
//   2. each invocation scans its ITEMS consecutive elements sequentially;
//   3. a work-efficient Blelloch scan (up-sweep / down-sweep) of the WG per-invocation totals
//      in workgroup memory; the block total is stored to `sums[block]`;
//   4. coalesced store of prefix + local exclusive sums.
// `add_offsets` then adds the (scanned) block sums back to every element of its block.
// No subgroup operations are used, so the result is the same on every adapter.

const WG: u32 = 256u;
const ITEMS: u32 = 8u;
const BLOCK: u32 = 2048u; // WG * ITEMS

struct Params {
    // Elements in `data`.
    n: u32,
    // Blocks in `data` (= ceil(n / BLOCK)); also the length of `sums`.
    blocks: u32,
    // Workgroups per row of the (possibly 2D) dispatch.
    groups_x: u32,
    _pad: u32,
}

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read_write> data: array<u32>;
@group(0) @binding(2) var<storage, read_write> sums: array<u32>;

var<workgroup> tile: array<u32, BLOCK>;
var<workgroup> partial: array<u32, WG>;

@compute @workgroup_size(256)
fn scan_blocks(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
) {
    let block = wg.y * params.groups_x + wg.x;
    let base = block * BLOCK;

    for (var j = 0u; j < ITEMS; j += 1u) {
        let i = base + j * WG + lid;
        var v = 0u;
        if (block < params.blocks && i < params.n) {
            v = data[i];
        }
        tile[j * WG + lid] = v;
    }
    workgroupBarrier();

    let first = lid * ITEMS;
    var local: array<u32, ITEMS>;
    var run = 0u;
    for (var j = 0u; j < ITEMS; j += 1u) {
        local[j] = run;
        run += tile[first + j];
    }
    partial[lid] = run;
    workgroupBarrier();

    // Up-sweep: partial[k * 2^(d+1) - 1] accumulates its subtree.
    var stride = 1u;
    for (var lanes = WG >> 1u; lanes > 0u; lanes >>= 1u) {
        if (lid < lanes) {
            let a = stride * (2u * lid + 1u) - 1u;
            let b = stride * (2u * lid + 2u) - 1u;
            partial[b] += partial[a];
        }
        stride <<= 1u;
        workgroupBarrier();
    }

    if (lid == 0u) {
        if (block < params.blocks) {
            sums[block] = partial[WG - 1u];
        }
        partial[WG - 1u] = 0u;
    }
    workgroupBarrier();

    // Down-sweep: turn the reduction tree into exclusive prefixes.
    for (var lanes = 1u; lanes < WG; lanes <<= 1u) {
        stride >>= 1u;
        if (lid < lanes) {
            let a = stride * (2u * lid + 1u) - 1u;
            let b = stride * (2u * lid + 2u) - 1u;
            let t = partial[a];
            partial[a] = partial[b];
            partial[b] += t;
        }
        workgroupBarrier();
    }

    let prefix = partial[lid];
    for (var j = 0u; j < ITEMS; j += 1u) {
        tile[first + j] = prefix + local[j];
    }
    workgroupBarrier();

    for (var j = 0u; j < ITEMS; j += 1u) {
        let i = base + j * WG + lid;
        if (block < params.blocks && i < params.n) {
            data[i] = tile[j * WG + lid];
        }
    }
}

@compute @workgroup_size(256)
fn add_offsets(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
) {
    let block = wg.y * params.groups_x + wg.x;
    // Block 0's offset is 0 by construction.
    if (block == 0u || block >= params.blocks) {
        return;
    }
    let offset = sums[block];
    let base = block * BLOCK;
    for (var j = 0u; j < ITEMS; j += 1u) {
        let i = base + j * WG + lid;
        if (i < params.n) {
            data[i] += offset;
        }
    }
}
