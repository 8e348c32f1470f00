// `grid` traversal on the device: the 3D-DDA (Amanatides and Woo 1987) of
// crsh_cpu::intersect::grid (UniformGrid::trace), the same operations in the same order, one
// ray per invocation. Prepended: common.wgsl, mt.wgsl.

struct Params {
    n: u32,
    any_hit: u32,
    first: u32,
    n_tris: u32,
    dims: vec4<u32>,
    lo: vec4<f32>,
    hi: vec4<f32>,
    margin: f32,
    pad0: f32,
    pad1: f32,
    pad2: f32,
}

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> rays: array<Ray>;
@group(0) @binding(2) var<storage, read> planes: array<f32>;
@group(0) @binding(3) var<storage, read> cell_ranges: array<vec2<u32>>;
@group(0) @binding(4) var<storage, read> cell_tris: array<u32>;
@group(0) @binding(5) var<storage, read> tris: array<MtTri>;
@group(0) @binding(6) var<storage, read_write> hits: array<Hit>;
// [cells lo, hi, triangle tests lo, hi, invalid ray report]
@group(0) @binding(7) var<storage, read_write> counters: array<atomic<u32>>;

const T_SLACK: f32 = 0.0001220703125; // 1 / 8192

var<workgroup> wg_cells: atomic<u32>;
var<workgroup> wg_tests: atomic<u32>;

fn plane_base(a: u32) -> u32 {
    if (a == 0u) { return 0u; }
    if (a == 1u) { return p.dims.x + 1u; }
    return p.dims.x + p.dims.y + 2u;
}

fn axis_cell(a: u32, x: f32) -> u32 {
    let base = plane_base(a);
    var lo = 1u;
    var hi = p.dims[a];
    while (lo < hi) {
        let mid = lo + (hi - lo) / 2u;
        if (planes[base + mid] <= x) { lo = mid + 1u; } else { hi = mid; }
    }
    return lo - 1u;
}

fn widen(t: f32, abs_slack: f32) -> f32 {
    let w = abs(t) * T_SLACK;
    return t + (w + abs_slack);
}

fn fmin(a: f32, b: f32) -> f32 { return select(a, b, b < a); }
fn fmax(a: f32, b: f32) -> f32 { return select(a, b, b > a); }

@compute @workgroup_size(WG)
fn traverse(@builtin(global_invocation_id) gid: vec3<u32>,
            @builtin(local_invocation_index) lid: u32,
            @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg);
    if (lid == 0u) {
        atomicStore(&wg_cells, 0u);
        atomicStore(&wg_tests, 0u);
    }
    workgroupBarrier();
    var cells = 0u;
    var tests = 0u;
    if (i < p.n) {
        let r = rays[i];
        var best = hits[i];
        if (!ray_valid(r)) {
            atomicMax(&counters[4], 0xffffffffu - (p.first + i));
        } else if (p.n_tris > 0u && (p.any_hit == 0u || best.tri == NO_HIT)) {
            let o = ray_origin(r);
            let d = ray_dir(r);
            let d_len = ray_dir_len(d);
            var inv = vec3<f32>(0.0);
            var moving = vec3<bool>(false);
            var t_in = -inf();
            var t_out = inf();
            var outside = false;
            for (var a = 0u; a < 3u; a++) {
                let iv = 1.0 / d[a];
                if (d[a] != 0.0 && f32_finite(iv)) {
                    inv[a] = iv;
                    moving[a] = true;
                    let ta = (p.lo[a] - o[a]) * iv;
                    let tb = (p.hi[a] - o[a]) * iv;
                    t_in = fmax(t_in, fmin(ta, tb));
                    t_out = fmin(t_out, fmax(ta, tb));
                } else if (o[a] < p.lo[a] || o[a] > p.hi[a]) {
                    outside = true;
                }
            }
            let dmax = fmax(fmax(abs(d.x), abs(d.y)), abs(d.z));
            let abs_slack = p.margin / dmax;
            let t_start = fmax(t_in, r.t_min);
            let t0 = t_start - (abs(t_start) * T_SLACK + abs_slack);
            var lim = widen(fmin(fmin(t_out, r.t_max), best.t), abs_slack);
            if (!outside && t0 <= lim) {
                var cell = vec3<u32>(0u);
                for (var a = 0u; a < 3u; a++) {
                    if (!moving[a]) {
                        cell[a] = axis_cell(a, o[a]);
                    } else {
                        let base = plane_base(a);
                        var lo = 1u;
                        var hi = p.dims[a];
                        while (lo < hi) {
                            let mid = lo + (hi - lo) / 2u;
                            let t = (planes[base + mid] - o[a]) * inv[a];
                            var before = t >= t0;
                            if (d[a] > 0.0) { before = t <= t0; }
                            if (before) { lo = mid + 1u; } else { hi = mid; }
                        }
                        cell[a] = lo - 1u;
                    }
                }
                loop {
                    let id = cell.x + p.dims.x * (cell.y + p.dims.y * cell.z);
                    cells += 1u;
                    let range = cell_ranges[id];
                    var done = false;
                    for (var k = range.x; k < range.x + range.y; k++) {
                        let tri = cell_tris[k];
                        tests += 1u;
                        let h = mt_hit(tris[tri], o, d, d_len, r.t_min, r.t_max);
                        if (h.x < inf()) {
                            if (p.any_hit != 0u) {
                                best = Hit(h.x, tri, h.y, h.z);
                                done = true;
                                break;
                            }
                            if (closer_than(h.x, tri, best)) {
                                best = Hit(h.x, tri, h.y, h.z);
                            }
                        }
                    }
                    if (done) { break; }
                    var axis = 3u;
                    var t_exit = inf();
                    for (var a = 0u; a < 3u; a++) {
                        if (moving[a]) {
                            let j = select(cell[a], cell[a] + 1u, d[a] > 0.0);
                            let t = (planes[plane_base(a) + j] - o[a]) * inv[a];
                            if (t < t_exit || axis == 3u) {
                                t_exit = t;
                                axis = a;
                            }
                        }
                    }
                    lim = widen(fmin(fmin(t_out, r.t_max), best.t), abs_slack);
                    if (axis == 3u || !(t_exit < lim)) { break; }
                    if (d[axis] > 0.0) {
                        if (cell[axis] + 1u >= p.dims[axis]) { break; }
                        cell[axis] += 1u;
                    } else {
                        if (cell[axis] == 0u) { break; }
                        cell[axis] -= 1u;
                    }
                }
            }
            hits[i] = best;
        }
    }
    atomicAdd(&wg_cells, cells);
    atomicAdd(&wg_tests, tests);
    workgroupBarrier();
    if (lid == 0u) {
        add_u64(0u, atomicLoad(&wg_cells));
        add_u64(2u, atomicLoad(&wg_tests));
    }
}
