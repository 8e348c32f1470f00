//! `grid`: the uniform grid of seed 002 (Ivson, Duarte and Celes 2009), built by its five
//! data-parallel passes (§3.1, §3.2) and traversed with the 3D-DDA of Amanatides and Woo 1987
//! (§4). Whole-scene queries only, closest and any hit.
//!
//! # Resolution (eq. 1)
//!
//! [`resolution`]: `N_a = d_a · ∛(k·P / V)` rounded, at least 1 per axis, where `d` is the
//! scene box's extent, `V` its volume, `P` the number of binned (non-degenerate) triangles and
//! `k` the parameter `grid_density`. Guards, so that every input gives a bounded grid:
//!
//! - a flat or zero-extent box (`V = 0`): each extent is first clamped to at least
//!   [`FLAT_EXTENT`] of the largest one (a box that is a single point, or no triangles at all,
//!   gives one cell);
//! - non-finite bounds cannot happen (the scene rejects non-finite vertices); if they did, the
//!   grid would be one cell;
//! - the total number of cells is at most `min(MAX_CELLS, max(1, CELLS_PER_WORK·k·P))`
//!   ([`MAX_CELLS`], [`CELLS_PER_WORK`]) and each axis at most [`MAX_AXIS`]: when rounding up
//!   flat axes would exceed that, the factor `∛(kP/V)` is lowered (bisection) until it fits.
//!   Memory is therefore bounded by the work, cell ids fit `u32` and the sort key needs at
//!   most 24 bits.
//!
//! # Build (§3.1, §3.2)
//!
//! The five passes are public functions, so tests and the wgpu twin check each one:
//!
//! 1. [`count_pass`]: per triangle, the number of cells its box overlaps (§3.2.1). The box is
//!    the triangle's AABB widened by the grid's [`GridGeometry::margin`] (see *Exactness*).
//! 2. [`scan_pass`]: exclusive scan of the counts with the total appended (§3.2.2, fig. 5b),
//!    the parallel [`crate::sort::compress::exclusive_scan`].
//! 3. [`write_pairs_pass`]: one task per output slot (§3.2.3): its primitive is found by binary
//!    search in the scan, its cell is the slot's local offset into the primitive's cells,
//!    enumerated in ascending linear id (`id = x + Nx·(y + Ny·z)`, x fastest).
//! 4. [`sort_pass`]: a stable radix sort of the (cell, primitive) pairs by cell (§3.2.4),
//!    [`crate::sort::radix::stable_radix_order`] with `key_bits` = the bits of the largest
//!    cell id; within a cell, primitives stay in increasing id order.
//! 5. [`ranges_pass`]: per cell, `(start, count)` by binary search in the sorted cells
//!    (§3.2.5); empty cells are `(0, 0)` as in fig. 5e.
//!
//! Passes 2-5 take the per-primitive cells through [`PrimitiveCells`], so they also run on an
//! explicit overlap list ([`ListedCells`], e.g. fig. 5's L-shaped primitive 0) as well as on
//! triangle boxes ([`BoxCells`]). Passes 1-3 and 5 run with rayon; the build inside a 1-thread
//! pool is the serial build, and every array is the same for any thread count.
//!
//! # Traversal (§4, Amanatides and Woo 1987)
//!
//! The ray's `[t_min, t_max]` is clipped to the grid box, the cell of the entry point found,
//! and the ray steps from cell to cell along the axis whose next cell plane it crosses first
//! (ties: lowest axis). Every distance is `(plane − o) · (1/d)` with the grid's cell planes
//! ([`GridGeometry::planes`], precomputed once), and the entry cell is found by binary search
//! of those distances (never by rounding a point), so the GPU twin computes exactly the same
//! operations (no multiply-add a compiler could fuse). A direction component that is zero (or
//! whose inverse is not finite) never steps along its axis; its slab test is the origin's
//! coordinate against the box.
//!
//! Each triangle of a visited cell is tested with the configured ray-triangle test (`test`:
//! `mt`, `watertight`, `projected`, [`crate::triangle`], the same prepared triangles and code
//! as `brute`) and merged with [`Hit::closer_than`]. A closest-hit ray stops once its best hit
//! lies inside the current cell: the cell's exit distance is at or beyond
//! `min(t_max, box exit, best.t)` widened by [`T_SLACK`]·|t| plus the margin in `t` units
//! (`margin / max|d_a|`), so a triangle in the next cell whose rounded `t` might still win is
//! reached; triangles stored in several cells are therefore found wherever the ray meets them.
//! Any-hit rays stop at their first hit (cell order, then increasing triangle id), and rays
//! whose stored hit is already a hit are skipped.
//!
//! # Exactness
//!
//! Closest hits are identical to `brute` with the same `test` — triangle, `t`, `u`, `v` bit for
//! bit, ties to the lower triangle id included — and any-hit rays hit exactly when `brute`'s
//! do. Degenerate triangles (never hit by the test) are not binned. The rounding that could
//! break this is absorbed in space and in `t`:
//!
//! - the grid box and every triangle box are widened by `margin` = [`MARGIN_REL`] ·
//!   (largest |coordinate| of the scene box + its largest extent), far above the rounding of
//!   the cell planes, of the binning and of the DDA's distances for rays that start within a
//!   few scene sizes of the grid, so a triangle the ray truly meets lies in a visited cell even
//!   when the DDA steps through a cell edge or corner in the other order;
//! - the interval is widened by [`T_SLACK`] relative (plus the margin in `t`), above the
//!   rounding of the triangle test's `t`.
//!
//! Rays whose origin is much farther from the grid than its size (thousands of scene
//! diagonals) make the f32 DDA itself coarser than the margin; brute force is the reference
//! there. The tests check identity on built-in scenes, random soups and the hard cases listed
//! in them, and the stability suite (`crsh_scene::stress`) through a `grid` pipeline.
//!
//! # Counting
//!
//! `stats.add_bounds`: in the grid, a bounds test is a cell visited. `stats.add_ray_triangle`:
//! one per triangle tested; a triangle stored in several cells is tested again in each (no
//! mailbox). Rays are traced in parallel with rayon, each independently, so results and counts
//! do not depend on the thread count. [`Query::Candidates`] is not supported (the grid tests
//! the whole scene): it returns [`CoreError::Unsupported`].
//!
//! # Default density
//!
//! `grid_density` (`k`) defaults to [`DEFAULT_DENSITY`] = 5, chosen by measurement
//! (`measure_density` in the tests: release build on a busy 2-core machine, 20,000 rays of
//! the tests' mix — from outside, leaving surfaces, grazing, shadow-like segments —
//! closest hit, Möller-Trumbore; per ray: cells visited + triangle tests; times are noisy):
//!
//! ```text
//! scene (triangles)        k:   0.5    1     2     3     5     8    12    16
//! cornell-mirrors (332)   tests 52.6  30.9  25.5  29.1  22.5  21.5  20.6  19.2
//! office-boxes (2,756)    tests 328   223   150   135   112   89.5  80.2  74.8
//!                      trace ms 164   125   92    84    54-72 60-64 59    58
//! sponza (262,205)        tests 469   334   252   209   181   160   139   134
//!                      trace ms 350   265   235   200   190   124-192 164 152
//!                      build ms 201   256   422   472   620-774 941-1198 1370 1696
//!                       memory  3.3   5.0   7.9   10.7  16.1  23.9  33.8  43.9 MiB
//! ```
//!
//! Tests per ray fall steeply up to `k ≈ 5` and slowly after (−26% from 5 to 16 on Sponza),
//! while trace times beyond 5 stay within the machine's noise and the build time and memory
//! grow in proportion to `k` (×2.2 and ×2.7 from 5 to 16 on Sponza). Larger `k` pays off
//! only when many frames reuse one build; `--set intersect.grid_density=...` changes it.

use std::cmp::Ordering;
use std::sync::Arc;
use std::time::{Duration, Instant};

use crsh_core::glam::Vec3;
use crsh_core::{
    Aabb, CoreError, Hit, HitMode, Intersector, ParamInfo, Query, Ray, Registry, Result, StageKind,
    StageSpec, StageVariantInfo, Stats,
};
use crsh_scene::Scene;
use rayon::prelude::*;

use crate::backend::Cpu;
use crate::intersect::brute::{check_batch, test_kind};
use crate::triangle::{AnyTriangleSet, TestKind, TriangleSet, TriangleTest};

/// Default `grid_density` (`k` of eq. 1); see the module doc for the measurements.
pub const DEFAULT_DENSITY: f64 = 5.0;

/// Smallest accepted `grid_density`.
pub const MIN_DENSITY: f64 = 0.01;

/// Largest accepted `grid_density`.
pub const MAX_DENSITY: f64 = 64.0;

/// A flat box's extents are clamped to at least this fraction of its largest extent (eq. 1
/// needs `V > 0`).
pub const FLAT_EXTENT: f32 = 1e-3;

/// Hard cap on the number of cells (16M cells: 128 MiB of ranges; ids fit 24 key bits).
pub const MAX_CELLS: u64 = 1 << 24;

/// Cap on cells per axis.
pub const MAX_AXIS: u32 = 1 << 14;

/// At most this many cells per unit of `k·P` (what eq. 1 asks for) once rounding of flat axes
/// to one cell is accounted for.
pub const CELLS_PER_WORK: f64 = 4.0;

/// Spatial margin (triangle boxes and grid box) relative to the scene's scale: the largest
/// |coordinate| of its box plus its largest extent.
pub const MARGIN_REL: f32 = 1.0 / 65536.0;

/// Relative widening of the traversal's `t` interval (rounding of the triangle test's `t`).
pub const T_SLACK: f32 = 1.0 / 8192.0;

/// Rays per rayon task.
const CHUNK: usize = 64;

/// The catalogue entry of the `grid` intersector.
pub fn info() -> StageVariantInfo {
    StageVariantInfo::new(
        StageKind::Intersect,
        "grid",
        "uniform grid (seed 002: eq. 1 resolution, five-pass parallel build, 3D-DDA of \
         Amanatides and Woo), closest and any hit, cells visited and triangle tests counted; \
         whole-scene queries only",
    )
    .param(
        ParamInfo::float(
            "grid_density",
            DEFAULT_DENSITY,
            "k of seed 002 eq. 1: about k cells per triangle (N_a = d_a·∛(kP/V))",
        )
        .range(MIN_DENSITY, MAX_DENSITY),
    )
    .param(ParamInfo::choice(
        "test",
        "mt",
        crate::triangle::TEST_NAMES,
        "ray-triangle test: `mt` Möller-Trumbore (f32), `watertight` Woop, Benthin and Wald \
         2013 (no ray slips through shared edges), `projected` RTTest's projected \
         barycentrics (seed 003 §4.2)",
    ))
    .scene_only()
}

/// Registers `grid` ([`info`], [`UniformGrid::new`]).
pub fn register(registry: &mut Registry<Cpu>) -> Result<()> {
    registry.add_intersector(info(), |ctx, spec| {
        Ok(Box::new(UniformGrid::new(ctx.scene, spec)?))
    })?;
    Ok(())
}

/// Eq. 1 of seed 002 with the module doc's guards: cells per axis for a box of extent `extent`
/// holding `primitives` primitives at density `k`.
///
/// `N_a = round(d_a · ∛(kP/V))`, clamped to `1 ..= MAX_AXIS`, after clamping each extent to at
/// least [`FLAT_EXTENT`] of the largest; lowered until the total is at most
/// `min(MAX_CELLS, max(1, CELLS_PER_WORK·k·P))`. No primitives, a non-positive or non-finite
/// `k`, or an empty, point-like or non-finite box give `[1, 1, 1]`.
pub fn resolution(extent: Vec3, primitives: usize, k: f64) -> [u32; 3] {
    let largest = extent.max_element();
    if primitives == 0
        || !extent.is_finite()
        || largest.is_nan()
        || largest <= 0.0
        || !k.is_finite()
        || k <= 0.0
    {
        return [1, 1, 1];
    }
    let d = extent
        .max(Vec3::splat(largest * FLAT_EXTENT))
        .to_array()
        .map(f64::from);
    let work = k * primitives as f64;
    let volume = d[0] * d[1] * d[2];
    let cap = (CELLS_PER_WORK * work).max(1.0).min(MAX_CELLS as f64);
    let dims_for =
        |s: f64| -> [u32; 3] { d.map(|e| (e * s).round().clamp(1.0, MAX_AXIS as f64) as u32) };
    let total = |n: [u32; 3]| n.iter().map(|&x| x as f64).product::<f64>();
    let s = (work / volume).cbrt();
    let dims = dims_for(s);
    if total(dims) <= cap {
        return dims;
    }
    // Lower the factor (the total is monotone in it) to the largest that fits.
    let (mut lo, mut hi) = (0.0f64, s);
    for _ in 0..64 {
        let mid = 0.5 * (lo + hi);
        if total(dims_for(mid)) <= cap {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    dims_for(lo)
}

/// The grid's box, resolution and cell planes.
#[derive(Clone, Debug, PartialEq)]
pub struct GridGeometry {
    /// Cells per axis (eq. 1, [`resolution`]).
    pub dims: [u32; 3],
    /// The grid box: the scene box widened by [`GridGeometry::margin`].
    pub bounds: Aabb,
    /// Cell extent per axis.
    pub cell_size: Vec3,
    /// How far triangle boxes (and the grid box) are widened (see the module doc).
    pub margin: f32,
    /// Cell planes per axis: `planes[a][j] = min(bounds.min[a] + j·cell_size[a],
    /// bounds.max[a])` for `j < dims[a]`, `planes[a][dims[a]] = bounds.max[a]`. Cell `c`
    /// spans `[planes[a][c], planes[a][c + 1])`.
    pub planes: [Vec<f32>; 3],
}

impl GridGeometry {
    /// The geometry for a scene box `scene_bounds` holding `primitives` primitives at density
    /// `k`. An empty box gives one cell around the origin.
    pub fn new(scene_bounds: &Aabb, primitives: usize, k: f64) -> GridGeometry {
        let sb = if scene_bounds.is_empty()
            || !scene_bounds.min.is_finite()
            || !scene_bounds.max.is_finite()
        {
            Aabb {
                min: Vec3::ZERO,
                max: Vec3::ZERO,
            }
        } else {
            *scene_bounds
        };
        let extent = sb.max - sb.min;
        let scale = sb.min.abs().max(sb.max.abs()).max_element() + extent.max_element();
        let margin = if scale > 0.0 {
            scale * MARGIN_REL
        } else {
            MARGIN_REL
        };
        let dims = resolution(extent, primitives, k);
        let bounds = Aabb {
            min: sb.min - Vec3::splat(margin),
            max: sb.max + Vec3::splat(margin),
        };
        let size = bounds.max - bounds.min;
        let cell_size = Vec3::new(
            size.x / dims[0] as f32,
            size.y / dims[1] as f32,
            size.z / dims[2] as f32,
        );
        let planes = [0, 1, 2].map(|a| {
            let n = dims[a] as usize;
            let (lo, hi, cs) = (bounds.min[a], bounds.max[a], cell_size[a]);
            let mut p: Vec<f32> = (0..n).map(|j| (lo + j as f32 * cs).min(hi)).collect();
            p.push(hi);
            p
        });
        GridGeometry {
            dims,
            bounds,
            cell_size,
            margin,
            planes,
        }
    }

    /// Number of cells.
    pub fn cell_count(&self) -> usize {
        self.dims.iter().map(|&n| n as usize).product()
    }

    /// Bits of the largest cell id (the radix sort's `key_bits`).
    pub fn key_bits(&self) -> u32 {
        let last = self.cell_count().saturating_sub(1) as u64;
        64 - last.leading_zeros()
    }

    /// Linear id of cell `(x, y, z)`: `x + Nx·(y + Ny·z)` (x fastest, §3.2.3).
    pub fn cell_id(&self, c: [u32; 3]) -> u32 {
        c[0] + self.dims[0] * (c[1] + self.dims[1] * c[2])
    }

    /// The cell along axis `a` holding coordinate `x`: the number of interior planes at or
    /// below `x` (so clamped to `0 ..= dims[a] − 1`).
    pub fn axis_cell(&self, a: usize, x: f32) -> u32 {
        let p = &self.planes[a];
        let last = p.len() - 2; // the highest cell
                                // A guess by one division, corrected against the planes themselves, so the answer is
                                // exactly the plane count (the DDA's and the GPU's), whatever the rounding of the guess.
        let guess = (x - p[0]) / self.cell_size[a];
        let mut c = if guess.is_finite() && guess > 0.0 {
            (guess as usize).min(last)
        } else {
            0
        };
        while c > 0 && p[c] > x {
            c -= 1;
        }
        while c < last && p[c + 1] <= x {
            c += 1;
        }
        c as u32
    }

    /// The cells (inclusive corners) overlapped by the box of `tri` widened by the margin.
    pub fn triangle_cells(&self, tri: &[Vec3; 3]) -> CellBox {
        let lo = tri[0].min(tri[1]).min(tri[2]);
        let hi = tri[0].max(tri[1]).max(tri[2]);
        let m = self.margin;
        CellBox {
            lo: [0, 1, 2].map(|a| self.axis_cell(a, lo[a] - m)),
            hi: [0, 1, 2].map(|a| self.axis_cell(a, hi[a] + m)),
        }
    }
}

/// A block of cells, inclusive corners (`lo[a] <= hi[a]`), or empty.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct CellBox {
    /// Lowest cell per axis.
    pub lo: [u32; 3],
    /// Highest cell per axis (inclusive).
    pub hi: [u32; 3],
}

impl CellBox {
    /// No cells (a degenerate triangle's box).
    pub const EMPTY: CellBox = CellBox {
        lo: [1, 1, 1],
        hi: [0, 0, 0],
    };

    /// Number of cells (0 when empty).
    pub fn count(&self) -> u32 {
        (0..3)
            .map(|a| (self.hi[a] + 1).saturating_sub(self.lo[a]))
            .product()
    }

    /// The `n`-th cell (`n < count()`) in ascending linear id (x fastest, then y, then z),
    /// as `(x, y, z)`.
    pub fn nth(&self, n: u32) -> [u32; 3] {
        let wx = self.hi[0] + 1 - self.lo[0];
        let wy = self.hi[1] + 1 - self.lo[1];
        [
            self.lo[0] + n % wx,
            self.lo[1] + (n / wx) % wy,
            self.lo[2] + n / (wx * wy),
        ]
    }
}

/// The cells each primitive overlaps, as passes 1 and 3 read them.
pub trait PrimitiveCells: Sync {
    /// Number of primitives.
    fn primitives(&self) -> usize;
    /// Number of cells primitive `p` overlaps.
    fn count(&self, p: usize) -> u32;
    /// The `n`-th (`n < count(p)`) cell id of primitive `p`, in ascending linear id.
    fn nth_cell(&self, p: usize, n: u32) -> u32;
}

/// Primitive cells given as explicit lists (each in ascending cell id), e.g. seed 002's fig. 5.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct ListedCells(pub Vec<Vec<u32>>);

impl PrimitiveCells for ListedCells {
    fn primitives(&self) -> usize {
        self.0.len()
    }
    fn count(&self, p: usize) -> u32 {
        self.0[p].len() as u32
    }
    fn nth_cell(&self, p: usize, n: u32) -> u32 {
        self.0[p][n as usize]
    }
}

/// Primitive cells from cell boxes (the triangles' widened AABBs, §3.2.1) in a geometry.
#[derive(Clone, Copy, Debug)]
pub struct BoxCells<'a> {
    /// The grid.
    pub geometry: &'a GridGeometry,
    /// One box per primitive ([`CellBox::EMPTY`] for those not binned).
    pub boxes: &'a [CellBox],
}

impl PrimitiveCells for BoxCells<'_> {
    fn primitives(&self) -> usize {
        self.boxes.len()
    }
    fn count(&self, p: usize) -> u32 {
        self.boxes[p].count()
    }
    fn nth_cell(&self, p: usize, n: u32) -> u32 {
        self.geometry.cell_id(self.boxes[p].nth(n))
    }
}

/// Whether each triangle of `scene` can be hit by test `test` (not degenerate for it): only
/// those are binned.
pub fn hittable(scene: &Scene, test: TestKind) -> Vec<bool> {
    fn keep<T: TriangleTest>(t: [Vec3; 3]) -> bool {
        !T::is_degenerate(&T::prepare(t[0], t[1], t[2]))
    }
    let keep = match test {
        TestKind::MollerTrumbore => keep::<crate::triangle::MollerTrumbore>,
        TestKind::Watertight => keep::<crate::triangle::Watertight>,
        TestKind::Projected => keep::<crate::triangle::Projected>,
    };
    (0..scene.triangle_count())
        .into_par_iter()
        .map(|t| keep(scene.triangle(t)))
        .collect()
}

/// The cell box of every triangle of `scene` (pass 1's geometry, §3.2.1): its AABB widened by
/// the margin, or [`CellBox::EMPTY`] where `hittable` is false (never hit, never binned).
pub fn triangle_boxes(geometry: &GridGeometry, scene: &Scene, hittable: &[bool]) -> Vec<CellBox> {
    (0..scene.triangle_count())
        .into_par_iter()
        .map(|t| {
            if hittable.get(t).copied().unwrap_or(false) {
                geometry.triangle_cells(&scene.triangle(t))
            } else {
                CellBox::EMPTY
            }
        })
        .collect()
}

/// Pass 1 (§3.2.1): the number of cells each primitive overlaps (fig. 5a).
pub fn count_pass(cells: &impl PrimitiveCells) -> Vec<u32> {
    (0..cells.primitives())
        .into_par_iter()
        .map(|p| cells.count(p))
        .collect()
}

/// Pass 2 (§3.2.2): the exclusive scan of `counts` with the total appended (fig. 5b:
/// `[3, 2, 4, 1]` → `[0, 3, 5, 9, 10]`).
///
/// # Errors
/// [`CoreError::InvalidInput`] when the total does not fit `u32`.
pub fn scan_pass(counts: &[u32]) -> Result<Vec<u32>> {
    let total: u64 = counts.par_iter().map(|&c| c as u64).sum();
    if total > u32::MAX as u64 {
        return Err(CoreError::InvalidInput(format!(
            "the grid would hold {total} (cell, primitive) pairs, more than 32-bit indices \
             address (lower grid_density)"
        )));
    }
    let mut scan = crate::sort::compress::exclusive_scan(counts);
    scan.push(total as u32);
    Ok(scan)
}

/// The primitive owning output slot `slot` (`< scan.last()`): the last `p` with
/// `scan[p] <= slot` (primitives with no cells share their successor's start and are
/// skipped). The binary search of §3.2.3.
pub fn slot_primitive(scan: &[u32], slot: u32) -> usize {
    scan.partition_point(|&s| s <= slot) - 1
}

/// Output slots per task of [`write_pairs_pass`].
pub const SLOT_CHUNK: u32 = 4096;

/// Pass 3 (§3.2.3): every output slot gets its (cell, primitive) pair, sorted by primitive
/// (fig. 5c). Returns `(cells, primitives)`. The slots are split into chunks of
/// [`SLOT_CHUNK`]; a chunk finds the primitive of its first slot by the binary search of
/// §3.2.3 ([`slot_primitive`]) and walks on from there (the GPU twin searches for every slot),
/// so each slot's pair is computed from the scan alone, whatever the thread count.
pub fn write_pairs_pass(scan: &[u32], cells: &impl PrimitiveCells) -> (Vec<u32>, Vec<u32>) {
    let total = scan.last().copied().unwrap_or(0) as usize;
    let mut pair_cells = vec![0u32; total];
    let mut pair_prims = vec![0u32; total];
    pair_cells
        .par_chunks_mut(SLOT_CHUNK as usize)
        .zip(pair_prims.par_chunks_mut(SLOT_CHUNK as usize))
        .enumerate()
        .for_each(|(chunk, (out_c, out_p))| {
            let first = chunk as u32 * SLOT_CHUNK;
            let mut p = slot_primitive(scan, first);
            for (i, (c, q)) in out_c.iter_mut().zip(out_p.iter_mut()).enumerate() {
                let slot = first + i as u32;
                while scan[p + 1] <= slot {
                    p += 1;
                }
                *c = cells.nth_cell(p, slot - scan[p]);
                *q = p as u32;
            }
        });
    (pair_cells, pair_prims)
}

/// Pass 4 (§3.2.4): the pairs stably sorted by cell (fig. 5d) with the project's radix sort
/// of key-value pairs ([`crate::sort::radix::stable_sort_pairs_u32`], the block radix sort the
/// wgpu backend's sorter also runs) on `key_bits` bits. Returns `(cells, primitives)`.
///
/// # Errors
/// Those of the radix sort (a cell id above `key_bits`, mismatched lengths).
pub fn sort_pass(cells: &[u32], prims: &[u32], key_bits: u32) -> Result<(Vec<u32>, Vec<u32>)> {
    crate::sort::radix::stable_sort_pairs_u32(cells, prims, key_bits)
}

/// Pass 5 (§3.2.5): per cell, `(start, count)` in the sorted pairs; `(0, 0)` for empty cells
/// (fig. 5e). The paper binary-searches every cell id (as the GPU twin does); here the runs of
/// equal cells are found in one parallel sweep of the sorted pairs (a run starts where the
/// cell differs from its predecessor) and each run is written to its cell: the same table in
/// time linear in the pairs rather than in cells × log pairs.
pub fn ranges_pass(sorted_cells: &[u32], cell_count: usize) -> Vec<[u32; 2]> {
    let n = sorted_cells.len();
    let starts: Vec<u32> = (0..n as u32)
        .into_par_iter()
        .filter(|&i| i == 0 || sorted_cells[i as usize] != sorted_cells[i as usize - 1])
        .collect();
    let mut ranges = vec![[0u32, 0u32]; cell_count];
    for (k, &start) in starts.iter().enumerate() {
        let end = starts.get(k + 1).copied().unwrap_or(n as u32);
        if let Some(r) = ranges.get_mut(sorted_cells[start as usize] as usize) {
            *r = [start, end - start];
        }
    }
    ranges
}

/// Every pass's output of one build (for tests and the GPU twin's checks).
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct BuildPasses {
    /// Pass 1: cells per primitive.
    pub counts: Vec<u32>,
    /// Pass 2: exclusive scan with the total appended.
    pub scan: Vec<u32>,
    /// Pass 3: pair cells, by primitive.
    pub pair_cells: Vec<u32>,
    /// Pass 3: pair primitives, by primitive.
    pub pair_prims: Vec<u32>,
    /// Pass 4: pair cells, sorted by cell.
    pub sorted_cells: Vec<u32>,
    /// Pass 4: pair primitives, sorted by cell (the grid's `cell_tris`).
    pub sorted_prims: Vec<u32>,
    /// Pass 5: `(start, count)` per cell.
    pub ranges: Vec<[u32; 2]>,
}

/// Runs passes 1-5 on `cells` for a grid of `cell_count` cells whose ids need `key_bits` bits.
///
/// # Errors
/// Those of [`scan_pass`] and [`sort_pass`].
pub fn run_passes(
    cells: &impl PrimitiveCells,
    cell_count: usize,
    key_bits: u32,
) -> Result<BuildPasses> {
    let counts = count_pass(cells);
    let scan = scan_pass(&counts)?;
    let (pair_cells, pair_prims) = write_pairs_pass(&scan, cells);
    let (sorted_cells, sorted_prims) = sort_pass(&pair_cells, &pair_prims, key_bits)?;
    let ranges = ranges_pass(&sorted_cells, cell_count);
    Ok(BuildPasses {
        counts,
        scan,
        pair_cells,
        pair_prims,
        sorted_cells,
        sorted_prims,
        ranges,
    })
}

/// The built grid in a GPU-friendly layout.
#[derive(Clone, Debug, PartialEq)]
pub struct GridData {
    /// Box, resolution and planes.
    pub geometry: GridGeometry,
    /// `(start, count)` into `cell_tris` per cell (linear id).
    pub cell_ranges: Vec<[u32; 2]>,
    /// Triangle ids of every cell, cell after cell, increasing within a cell.
    pub cell_tris: Vec<u32>,
}

impl GridData {
    /// Builds the grid of `scene` at density `k` (five passes), binning only the triangles
    /// that test `test` can hit.
    ///
    /// # Errors
    /// Those of [`run_passes`] (a grid too large for 32-bit indices).
    pub fn build(scene: &Scene, k: f64, test: TestKind) -> Result<GridData> {
        GridData::build_of(scene, k, &hittable(scene, test))
    }

    /// [`GridData::build`] binning the triangles `keep` marks (all of them for a structure
    /// that serves any ray-triangle test, e.g. the `dual` traverser's `objects = grid`).
    ///
    /// # Errors
    /// As [`GridData::build`].
    pub fn build_of(scene: &Scene, k: f64, keep: &[bool]) -> Result<GridData> {
        let binned = keep.iter().filter(|&&h| h).count();
        let geometry = GridGeometry::new(&scene.bounds, binned, k);
        let boxes = triangle_boxes(&geometry, scene, keep);
        let cells = BoxCells {
            geometry: &geometry,
            boxes: &boxes,
        };
        // The passes of `run_passes`, keeping only what the grid stores.
        let counts = count_pass(&cells);
        let scan = scan_pass(&counts)?;
        let (pair_cells, pair_prims) = write_pairs_pass(&scan, &cells);
        let (sorted_cells, cell_tris) = sort_pass(&pair_cells, &pair_prims, geometry.key_bits())?;
        drop((pair_cells, pair_prims));
        let cell_ranges = ranges_pass(&sorted_cells, geometry.cell_count());
        Ok(GridData {
            geometry,
            cell_ranges,
            cell_tris,
        })
    }

    /// [`GridData::build`], also returning every pass's output.
    ///
    /// # Errors
    /// As [`GridData::build`].
    pub fn build_passes(scene: &Scene, k: f64, test: TestKind) -> Result<(GridData, BuildPasses)> {
        // Eq. 1 counts the primitives that get binned; the box is the scene's.
        let keep = hittable(scene, test);
        let binned = keep.iter().filter(|&&h| h).count();
        let geometry = GridGeometry::new(&scene.bounds, binned, k);
        let boxes = triangle_boxes(&geometry, scene, &keep);
        let cells = BoxCells {
            geometry: &geometry,
            boxes: &boxes,
        };
        let passes = run_passes(&cells, geometry.cell_count(), geometry.key_bits())?;
        let data = GridData {
            cell_ranges: passes.ranges.clone(),
            cell_tris: passes.sorted_prims.clone(),
            geometry,
        };
        Ok((data, passes))
    }

    /// Bytes of the structure: cell ranges, cell triangle lists and planes.
    pub fn memory_bytes(&self) -> usize {
        self.cell_ranges.len() * 8
            + self.cell_tris.len() * 4
            + self
                .geometry
                .planes
                .iter()
                .map(|p| p.len() * 4)
                .sum::<usize>()
    }
}

/// Per-ray values of the DDA (Amanatides and Woo 1987).
#[derive(Clone, Copy, Debug)]
struct DdaRay {
    o: [f32; 3],
    inv: [f32; 3],
    moving: [bool; 3],
    /// The margin in `t` units.
    abs_slack: f32,
}

/// `t` widened by the traversal slack (see the module doc).
#[inline(always)]
fn widen(t: f32, abs_slack: f32) -> f32 {
    let w = t.abs() * T_SLACK;
    t + (w + abs_slack)
}

/// The uniform-grid intersector (variant `grid`; parameters `grid_density`, `test`).
#[derive(Clone, Debug)]
pub struct UniformGrid {
    grid: GridData,
    tris: AnyTriangleSet,
    density: f64,
    build_time: Duration,
}

impl UniformGrid {
    /// Builds the grid of `scene` with `spec.grid_density` and `spec.test`.
    pub fn new(scene: &Arc<Scene>, spec: &StageSpec) -> Result<UniformGrid> {
        let k = spec.f64("grid_density")?;
        if !(MIN_DENSITY..=MAX_DENSITY).contains(&k) {
            return Err(CoreError::InvalidParam {
                key: "grid.grid_density".into(),
                reason: format!("{k} is outside {MIN_DENSITY}..={MAX_DENSITY}"),
            });
        }
        UniformGrid::build(scene, k, test_kind(spec, "grid")?)
    }

    /// Builds the grid of `scene` at density `k` for test `test` (the build time is measured).
    ///
    /// # Errors
    /// A `k` that is not finite and positive, or a grid too large for 32-bit indices.
    pub fn build(scene: &Scene, k: f64, test: TestKind) -> Result<UniformGrid> {
        if !(k.is_finite() && k > 0.0) {
            return Err(CoreError::InvalidParam {
                key: "grid.grid_density".into(),
                reason: format!("{k} is not a positive number"),
            });
        }
        let start = Instant::now();
        let grid = GridData::build(scene, k, test)?;
        let build_time = start.elapsed();
        Ok(UniformGrid {
            grid,
            tris: AnyTriangleSet::new(scene, test),
            density: k,
            build_time,
        })
    }

    /// The built grid.
    pub fn grid(&self) -> &GridData {
        &self.grid
    }

    /// The density `k` it was built with.
    pub fn density(&self) -> f64 {
        self.density
    }

    /// The ray-triangle test in use.
    pub fn test(&self) -> TestKind {
        self.tris.kind()
    }

    /// Wall time of the build (five passes, triangle preparation excluded).
    pub fn build_time(&self) -> Duration {
        self.build_time
    }

    /// Bytes of the grid structure ([`GridData::memory_bytes`]).
    pub fn memory_bytes(&self) -> usize {
        self.grid.memory_bytes()
    }

    /// Traces one ray with test `T` (this grid's triangles, prepared for `T`); merges into
    /// `best` and returns `(cells visited, triangle tests)`.
    fn trace<T: TriangleTest>(
        &self,
        set: &TriangleSet<T>,
        ray: &Ray,
        mode: HitMode,
        best: &mut Hit,
    ) -> (u64, u64) {
        let g = &self.grid.geometry;
        if self.grid.cell_tris.is_empty() || (mode == HitMode::Any && best.is_hit()) {
            return (0, 0);
        }
        let o = ray.origin.to_array();
        let d = ray.dir.to_array();
        let mut inv = [0.0f32; 3];
        let mut moving = [false; 3];
        let mut t_in = f32::NEG_INFINITY;
        let mut t_out = f32::INFINITY;
        for a in 0..3 {
            let i = 1.0 / d[a];
            let (lo, hi) = (g.bounds.min[a], g.bounds.max[a]);
            if d[a] != 0.0 && i.is_finite() {
                inv[a] = i;
                moving[a] = true;
                let ta = (lo - o[a]) * i;
                let tb = (hi - o[a]) * i;
                t_in = t_in.max(ta.min(tb));
                t_out = t_out.min(ta.max(tb));
            } else if o[a] < lo || o[a] > hi {
                return (0, 0);
            }
        }
        let dmax = d[0].abs().max(d[1].abs()).max(d[2].abs());
        let r = DdaRay {
            o,
            inv,
            moving,
            abs_slack: g.margin / dmax,
        };
        let t_start = t_in.max(ray.t_min);
        let t0 = t_start - (t_start.abs() * T_SLACK + r.abs_slack);
        let limit = |best: &Hit| widen(t_out.min(ray.t_max).min(best.t), r.abs_slack);
        // NaN (an infinite interval end) means no cells.
        if !matches!(
            t0.partial_cmp(&limit(best)),
            Some(Ordering::Less | Ordering::Equal)
        ) {
            return (0, 0);
        }
        let tp = |a: usize, j: u32| (g.planes[a][j as usize] - r.o[a]) * r.inv[a];
        // The entry cell: per axis, the planes crossed before t0 (binary search).
        let mut cell = [0u32; 3];
        for a in 0..3 {
            let n = g.dims[a];
            cell[a] = if !r.moving[a] {
                g.axis_cell(a, r.o[a])
            } else if d[a] > 0.0 {
                partition(1, n, |j| tp(a, j) <= t0)
            } else {
                partition(1, n, |j| tp(a, j) >= t0)
            };
        }
        let (tris, ids) = (set.triangles(), &self.grid.cell_tris);
        let (mut cells, mut tests) = (0u64, 0u64);
        let pre = T::ray_of(ray);
        loop {
            let id = g.cell_id(cell) as usize;
            cells += 1;
            let [start, count] = self.grid.cell_ranges[id];
            for &tri in &ids[start as usize..(start + count) as usize] {
                tests += 1;
                if let Some(h) = T::hit(&tris[tri as usize], &pre, ray.t_min, ray.t_max, tri) {
                    if mode == HitMode::Any {
                        *best = h;
                        return (cells, tests);
                    }
                    if h.closer_than(best) {
                        *best = h;
                    }
                }
            }
            // The cell's exit: the nearest next plane (ties: lowest axis).
            let mut axis = 3;
            let mut t_exit = f32::INFINITY;
            for a in 0..3 {
                if r.moving[a] {
                    let j = if d[a] > 0.0 { cell[a] + 1 } else { cell[a] };
                    let t = tp(a, j);
                    if t < t_exit || axis == 3 {
                        t_exit = t;
                        axis = a;
                    }
                }
            }
            if axis == 3 || t_exit.partial_cmp(&limit(best)) != Some(Ordering::Less) {
                break;
            }
            if d[axis] > 0.0 {
                if cell[axis] + 1 >= g.dims[axis] {
                    break;
                }
                cell[axis] += 1;
            } else {
                if cell[axis] == 0 {
                    break;
                }
                cell[axis] -= 1;
            }
        }
        (cells, tests)
    }
}

/// The number of `j` in `first..last` for which `pred` holds, `pred` true on a prefix
/// (binary search; the entry cell of the DDA).
#[inline]
fn partition(first: u32, last: u32, pred: impl Fn(u32) -> bool) -> u32 {
    let (mut lo, mut hi) = (first, last);
    while lo < hi {
        let mid = lo + (hi - lo) / 2;
        if pred(mid) {
            lo = mid + 1;
        } else {
            hi = mid;
        }
    }
    lo - first
}

impl Intersector<Cpu> for UniformGrid {
    fn name(&self) -> &str {
        "grid"
    }

    fn supports_candidates(&self) -> bool {
        false
    }

    fn intersect(
        &self,
        _backend: &Cpu,
        rays: &Vec<Ray>,
        query: Query<'_, Cpu>,
        mode: HitMode,
        hits: &mut Vec<Hit>,
        stats: &mut Stats,
    ) -> Result<()> {
        if mode.is_edge_width() {
            return Err(mode.unsupported("grid"));
        }
        query.whole_scene_only("grid")?;
        check_batch(rays, hits)?;
        fn all<T: TriangleTest>(
            grid: &UniformGrid,
            set: &TriangleSet<T>,
            rays: &[Ray],
            mode: HitMode,
            hits: &mut [Hit],
        ) -> (u64, u64) {
            rays.par_chunks(CHUNK)
                .zip(hits.par_chunks_mut(CHUNK))
                .map(|(rs, hs)| {
                    let mut n = (0u64, 0u64);
                    for (ray, h) in rs.iter().zip(hs.iter_mut()) {
                        let (c, t) = grid.trace::<T>(set, ray, mode, h);
                        n.0 += c;
                        n.1 += t;
                    }
                    n
                })
                .reduce(|| (0, 0), |a, b| (a.0 + b.0, a.1 + b.1))
        }
        let (cells, tests) = match &self.tris {
            AnyTriangleSet::MollerTrumbore(s) => all(self, s, rays, mode, hits),
            AnyTriangleSet::Watertight(s) => all(self, s, rays, mode, hits),
            AnyTriangleSet::Projected(s) => all(self, s, rays, mode, hits),
        };
        stats.add_bounds(cells);
        stats.add_ray_triangle(tests);
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::intersect::brute::tests::{random_rays, soup, test_ray};
    use crate::intersect::brute::BruteForce;
    use crate::intersect::bvh::tests::rejects_candidates_and_bad_rays;
    use crate::surface::tests::raw_scene;
    use crate::triangle::tests::TestRng;
    use crsh_core::{ParamValue, PipelineConfig, RayKind};

    fn run(x: &dyn Intersector<Cpu>, rays: &Vec<Ray>, mode: HitMode) -> (Vec<Hit>, Stats) {
        let mut hits = vec![Hit::MISS; rays.len()];
        let mut stats = Stats::default();
        x.intersect(&Cpu, rays, Query::Scene, mode, &mut hits, &mut stats)
            .unwrap();
        (hits, stats)
    }

    fn bits(h: &Hit) -> (u32, u32, u32, u32) {
        (h.tri, h.t.to_bits(), h.u.to_bits(), h.v.to_bits())
    }

    /// Grid and brute force with the same test: closest hits bit for bit, any-hit hit/miss
    /// (and the any hit found is a real hit of its triangle). Returns the grid's closest-hit
    /// stats and how many rays hit.
    fn check_against_brute(
        scene: &Scene,
        rays: &Vec<Ray>,
        k: f64,
        test: TestKind,
    ) -> (Stats, usize) {
        let brute = BruteForce::with_test(scene, test);
        let grid = UniformGrid::build(scene, k, test).unwrap();
        assert_eq!(grid.test(), test);
        let (want, _) = run(&brute, rays, HitMode::Closest);
        let (got, stats) = run(&grid, rays, HitMode::Closest);
        for (i, (g, w)) in got.iter().zip(&want).enumerate() {
            assert_eq!(
                bits(g),
                bits(w),
                "k {k} {test:?} ray {i}: {:?}: grid {g:?} brute {w:?}",
                rays[i]
            );
        }
        let (want_any, _) = run(&brute, rays, HitMode::Any);
        let (got_any, any_stats) = run(&grid, rays, HitMode::Any);
        for (i, (g, w)) in got_any.iter().zip(&want_any).enumerate() {
            assert_eq!(
                g.is_hit(),
                w.is_hit(),
                "k {k} {test:?} any ray {i}: {:?}",
                rays[i]
            );
            if g.is_hit() {
                assert!(g.t > rays[i].t_min && g.t < rays[i].t_max);
            }
        }
        assert!(any_stats.tests.ray_triangle <= stats.tests.ray_triangle);
        (stats, want.iter().filter(|h| h.is_hit()).count())
    }

    fn check_all_tests(scene: &Scene, rays: &Vec<Ray>, ks: &[f64]) -> usize {
        let mut hit = 0;
        for &k in ks {
            for test in TestKind::ALL {
                hit = check_against_brute(scene, rays, k, test).1;
            }
        }
        hit
    }

    /// Seed 002 fig. 5: 4 primitives, 9 cells (3×3), primitive 0 an L over cells 3, 4, 6.
    #[test]
    fn fig5_worked_example() {
        let cells = ListedCells(vec![vec![3, 4, 6], vec![0, 3], vec![3, 4, 5, 7], vec![1]]);
        let p = run_passes(&cells, 9, 4).unwrap();
        assert_eq!(p.counts, [3, 2, 4, 1], "(a)");
        assert_eq!(p.scan, [0, 3, 5, 9, 10], "(b)");
        let pairs: Vec<(u32, u32)> = p
            .pair_cells
            .iter()
            .copied()
            .zip(p.pair_prims.iter().copied())
            .collect();
        assert_eq!(
            pairs,
            [
                (3, 0),
                (4, 0),
                (6, 0),
                (0, 1),
                (3, 1),
                (3, 2),
                (4, 2),
                (5, 2),
                (7, 2),
                (1, 3)
            ],
            "(c)"
        );
        let sorted: Vec<(u32, u32)> = p
            .sorted_cells
            .iter()
            .copied()
            .zip(p.sorted_prims.iter().copied())
            .collect();
        assert_eq!(
            sorted,
            [
                (0, 1),
                (1, 3),
                (3, 0),
                (3, 1),
                (3, 2),
                (4, 0),
                (4, 2),
                (5, 2),
                (6, 0),
                (7, 2)
            ],
            "(d)"
        );
        assert_eq!(
            p.ranges,
            [
                [0, 1],
                [1, 1],
                [0, 0],
                [2, 3],
                [5, 2],
                [7, 1],
                [8, 1],
                [9, 1],
                [0, 0]
            ],
            "(e)"
        );
        // The same with 1 thread.
        let serial = crate::with_threads(1, || run_passes(&cells, 9, 4).unwrap()).unwrap();
        assert_eq!(serial, p);
        // A cell id above the key bits is refused by the sort.
        assert!(run_passes(&cells, 9, 2).is_err());
    }

    #[test]
    fn slot_search_skips_empty_primitives() {
        // Counts [0, 2, 0, 0, 1]: scan [0, 0, 2, 2, 2, 3].
        let scan = scan_pass(&[0, 2, 0, 0, 1]).unwrap();
        assert_eq!(scan, [0, 0, 2, 2, 2, 3]);
        assert_eq!(
            (0..3).map(|s| slot_primitive(&scan, s)).collect::<Vec<_>>(),
            [1, 1, 4]
        );
        assert!(scan_pass(&[u32::MAX, 1]).is_err());
        assert_eq!(scan_pass(&[]).unwrap(), [0]);
    }

    #[test]
    fn cell_boxes_enumerate_in_linear_id_order() {
        let g = GridGeometry::new(
            &Aabb {
                min: Vec3::ZERO,
                max: Vec3::new(4.0, 3.0, 2.0),
            },
            24,
            1.0,
        );
        assert_eq!(g.dims, [4, 3, 2]);
        let b = CellBox {
            lo: [1, 0, 0],
            hi: [2, 1, 1],
        };
        assert_eq!(b.count(), 8);
        let ids: Vec<u32> = (0..8).map(|n| g.cell_id(b.nth(n))).collect();
        assert_eq!(ids, [1, 2, 5, 6, 13, 14, 17, 18]);
        assert_eq!(CellBox::EMPTY.count(), 0);
        // A triangle inside cell (1, 1, 0) away from its planes: one cell; one touching the
        // plane x = 2 also gets the neighbour (the margin).
        let t = [
            Vec3::new(1.2, 1.2, 0.2),
            Vec3::new(1.8, 1.2, 0.2),
            Vec3::new(1.2, 1.8, 0.8),
        ];
        assert_eq!(g.triangle_cells(&t).count(), 1);
        let t = [
            Vec3::new(1.2, 1.2, 0.2),
            Vec3::new(2.0, 1.2, 0.2),
            Vec3::new(1.2, 1.8, 0.8),
        ];
        let c = g.triangle_cells(&t);
        assert_eq!((c.lo, c.hi), ([1, 1, 0], [2, 1, 0]));
        assert_eq!(g.key_bits(), 5);
    }

    #[test]
    fn eq1_on_known_inputs() {
        // A 2×1×1 box, 1000 primitives, k = 4: ∛(4000/2) = 12.6 → 25, 13, 13.
        assert_eq!(
            resolution(Vec3::new(2.0, 1.0, 1.0), 1000, 4.0),
            [25, 13, 13]
        );
        // A unit cube, 1000 primitives, k = 1: 10 per axis.
        assert_eq!(resolution(Vec3::ONE, 1000, 1.0), [10, 10, 10]);
        assert_eq!(resolution(Vec3::splat(7.0), 1, 1.0), [1, 1, 1]);
        // Nothing, a point, bad k: one cell.
        assert_eq!(resolution(Vec3::ONE, 0, 1.0), [1, 1, 1]);
        assert_eq!(resolution(Vec3::ZERO, 100, 1.0), [1, 1, 1]);
        assert_eq!(resolution(Vec3::ONE, 100, f64::NAN), [1, 1, 1]);
        assert_eq!(resolution(Vec3::splat(f32::INFINITY), 100, 1.0), [1, 1, 1]);
        // A flat square (z extent 0) with 10,000 primitives at k = 1: the z extent is clamped
        // to 1e-3, ∛(1e4/1e-3) = 215.4 per unit, z rounds up to 1 cell, and the total
        // (215² = 46K) exceeds 4·k·P = 40K, so the factor is lowered: a square 200×200×1.
        let flat = resolution(Vec3::new(1.0, 1.0, 0.0), 10_000, 1.0);
        assert_eq!(flat[2], 1);
        assert_eq!(flat[0], flat[1]);
        assert!(flat[0] * flat[1] <= 40_000 && flat[0] >= 190, "{flat:?}");
        // Huge k·P: capped at MAX_CELLS in total and MAX_AXIS per axis.
        let big = resolution(Vec3::new(1.0, 1.0, 1.0), 100_000_000, 64.0);
        assert!(big.iter().map(|&n| n as u64).product::<u64>() <= MAX_CELLS);
        let line = resolution(Vec3::new(1.0, 0.0, 0.0), 100_000_000, 64.0);
        assert_eq!(line[0], MAX_AXIS);
        assert!(line.iter().map(|&n| n as u64).product::<u64>() <= MAX_CELLS);
    }

    /// ~20K random triangles: the build with 1 thread equals the build with 4, every array.
    #[test]
    fn serial_build_equals_parallel_build() {
        let mut rng = TestRng(77);
        let mut positions = Vec::new();
        let mut indices = Vec::new();
        for i in 0..20_000u32 {
            let a = rng.vec3(-10.0, 10.0);
            let s = if i % 100 == 0 { 5.0 } else { 0.4 };
            positions.extend([a, a + rng.vec3(-s, s), a + rng.vec3(-s, s)]);
            indices.push([3 * i, 3 * i + 1, 3 * i + 2]);
        }
        let n = positions.len();
        let scene = raw_scene(positions, vec![Vec3::Z; n], indices);
        let serial = crate::with_threads(1, || {
            GridData::build_passes(&scene, 2.0, TestKind::MollerTrumbore)
        })
        .unwrap()
        .unwrap();
        let parallel = crate::with_threads(4, || {
            GridData::build_passes(&scene, 2.0, TestKind::MollerTrumbore)
        })
        .unwrap()
        .unwrap();
        assert_eq!(serial, parallel);
        let (grid, p) = serial;
        assert!(grid.geometry.cell_count() > 10_000);
        assert_eq!(p.counts.len(), 20_000);
        assert_eq!(*p.scan.last().unwrap() as usize, grid.cell_tris.len());
        // Every triangle lies in exactly the cells of its box, each once, sorted by cell.
        assert!(p.sorted_cells.windows(2).all(|w| w[0] <= w[1]));
        let total: u64 = grid.cell_ranges.iter().map(|r| r[1] as u64).sum();
        assert_eq!(total, grid.cell_tris.len() as u64);
        for (c, r) in grid.cell_ranges.iter().enumerate() {
            let list = &grid.cell_tris[r[0] as usize..(r[0] + r[1]) as usize];
            assert!(
                list.windows(2).all(|w| w[0] < w[1]),
                "cell {c} not increasing"
            );
        }
    }

    #[test]
    fn identical_to_brute_force_on_builtin_scenes() {
        for name in crsh_scene::builtin::NAMES {
            let scene = crsh_scene::builtin::build(name).unwrap();
            let mut rays = random_rays(&scene, 61, 1500);
            let eps = scene.bounds.diagonal() * 1e-5;
            for r in rays.iter_mut().skip(1).step_by(4) {
                r.t_min = eps;
            }
            let hits = check_all_tests(&scene, &rays, &[0.3, DEFAULT_DENSITY, 8.0]);
            assert!(hits > rays.len() / 2, "{name}: {hits} hits");
        }
    }

    #[test]
    fn identical_to_brute_force_on_random_soups() {
        for (seed, n) in [(21u64, 600usize), (22, 60), (23, 1)] {
            let scene = soup(seed, n);
            let rays = random_rays(&scene, seed + 100, 1500);
            check_all_tests(&scene, &rays, &[0.5, DEFAULT_DENSITY, 16.0]);
        }
    }

    fn ray(o: Vec3, d: Vec3, t_min: f32, t_max: f32, i: usize) -> Ray {
        test_ray(o, d, t_min, t_max, i)
    }

    /// Unit quads on cell-aligned planes, rays exactly along cell planes, through cell edges
    /// and corners, axis-parallel (zero direction components), starting on surfaces, with
    /// finite segments, from outside and ending before the grid.
    #[test]
    fn identical_to_brute_force_on_grazing_and_axis_aligned_rays() {
        let mut positions = Vec::new();
        let mut indices = Vec::new();
        for (axis, offset) in [
            (0usize, 0.0f32),
            (1, 0.0),
            (2, 0.0),
            (2, 3.0),
            (0, 3.0),
            (1, 1.5),
        ] {
            for i in 0..6 {
                for j in 0..6 {
                    let corner = |di: f32, dj: f32| {
                        let mut p = [0.0f32; 3];
                        p[axis] = offset;
                        p[(axis + 1) % 3] = (i as f32 + di) * 0.5;
                        p[(axis + 2) % 3] = (j as f32 + dj) * 0.5;
                        Vec3::from_array(p)
                    };
                    let b = positions.len() as u32;
                    positions.extend([
                        corner(0.0, 0.0),
                        corner(1.0, 0.0),
                        corner(1.0, 1.0),
                        corner(0.0, 1.0),
                    ]);
                    indices.extend([[b, b + 1, b + 2], [b, b + 2, b + 3]]);
                }
            }
        }
        let n = positions.len();
        let scene = raw_scene(positions, vec![Vec3::Z; n], indices);
        for k in [0.5, DEFAULT_DENSITY, 8.0] {
            let grid = UniformGrid::build(&scene, k, TestKind::MollerTrumbore).unwrap();
            let g = &grid.grid().geometry;
            let mut rng = TestRng(31);
            let mut rays = Vec::new();
            let axes = [Vec3::X, Vec3::Y, Vec3::Z, -Vec3::X, -Vec3::Y, -Vec3::Z];
            // A coordinate on a cell plane of axis `a`, or on the scene's quad grid.
            let plane = |rng: &mut TestRng, a: usize| {
                if rng.next_u64().is_multiple_of(2) {
                    let p = &g.planes[a];
                    p[rng.next_u64() as usize % p.len()]
                } else {
                    (rng.next_u64() % 13) as f32 * 0.25
                }
            };
            for i in 0..3000 {
                let mut o = Vec3::new(plane(&mut rng, 0), plane(&mut rng, 1), plane(&mut rng, 2));
                if i % 5 == 0 {
                    o = rng.vec3(-2.0, 5.0);
                }
                let dir = match i % 5 {
                    0 | 1 => axes[i % 6],
                    2 => (axes[i % 6] + axes[(i / 6) % 6] * 0.5).normalize_or(Vec3::X),
                    3 => rng.unit(),
                    // Through cell corners: along the diagonal of a cell.
                    _ => (g.cell_size * Vec3::new(1.0, if i % 2 == 0 { 1.0 } else { -1.0 }, 1.0))
                        .normalize(),
                };
                let t_min = match i % 3 {
                    0 => 0.0,
                    1 => 1e-5,
                    _ => -1.0,
                };
                let t_max = match i % 7 {
                    0 => 1.0,
                    1 => 0.25,
                    _ => f32::INFINITY,
                };
                rays.push(ray(o, dir, t_min, t_max, i));
            }
            let (stats, hits) = check_against_brute(&scene, &rays, k, TestKind::MollerTrumbore);
            assert!(hits > 1000 && stats.tests.bounds > 0, "{hits}");
            for test in [TestKind::Watertight, TestKind::Projected] {
                check_against_brute(&scene, &rays, k, test);
            }
        }
    }

    /// One scene per hard case: a flat scene (zero-volume bounds), a single triangle, a huge
    /// triangle spanning every cell among small ones, a teapot-sized cluster in a stadium,
    /// degenerate triangles only, and rays from far outside and ending before the grid.
    #[test]
    fn identical_to_brute_force_on_hard_scenes() {
        let mut rng = TestRng(5);
        // Flat: 500 random triangles in the plane z = 2.
        let mut flat = Vec::new();
        for _ in 0..500 {
            let a = rng.vec3(-1.0, 1.0);
            let a = Vec3::new(a.x, a.y, 2.0);
            let b = a + Vec3::new(rng.range(-0.2, 0.2), rng.range(-0.2, 0.2), 0.0);
            let c = a + Vec3::new(rng.range(-0.2, 0.2), rng.range(-0.2, 0.2), 0.0);
            flat.push([a, b, c]);
        }
        // Single triangle.
        let single = vec![[
            Vec3::new(-1.0, -1.0, 0.5),
            Vec3::new(1.0, -0.5, 0.0),
            Vec3::new(0.0, 1.0, -0.3),
        ]];
        // A huge triangle spanning every cell, with small ones around.
        let mut huge = vec![[
            Vec3::new(-1.0, -1.0, -1.0),
            Vec3::new(1.0, 1.0, -1.0),
            Vec3::new(1.0, -1.0, 1.0),
        ]];
        for _ in 0..300 {
            let a = rng.vec3(-1.0, 1.0);
            huge.push([a, a + rng.vec3(-0.05, 0.05), a + rng.vec3(-0.05, 0.05)]);
        }
        // Teapot in a stadium: 2000 tiny triangles in a 0.01 box inside a 1000-wide shell.
        let mut stadium = Vec::new();
        for _ in 0..2000 {
            let a = rng.vec3(-0.005, 0.005);
            stadium.push([a, a + rng.vec3(-0.001, 0.001), a + rng.vec3(-0.001, 0.001)]);
        }
        let s = 500.0;
        for (x, y) in [(-s, -s), (s, -s), (s, s), (-s, s)] {
            stadium.push([
                Vec3::new(x, y, -s),
                Vec3::new(-y, x, -s),
                Vec3::new(0.0, 0.0, s),
            ]);
        }
        // Degenerate only.
        let degenerate = vec![[Vec3::ZERO, Vec3::X, Vec3::X * 2.0], [Vec3::Y; 3]];
        for (name, tris) in [
            ("flat", flat),
            ("single", single),
            ("huge", huge),
            ("stadium", stadium),
            ("degenerate", degenerate),
        ] {
            let mut positions = Vec::new();
            let mut indices = Vec::new();
            for (i, t) in tris.iter().enumerate() {
                positions.extend(t);
                let b = 3 * i as u32;
                indices.push([b, b + 1, b + 2]);
            }
            let n = positions.len();
            let scene = raw_scene(positions, vec![Vec3::Z; n], indices);
            let mut rays = random_rays(&scene, 9, 1200);
            if name == "stadium" {
                // Rays aimed at the teapot from around it.
                for (i, r) in rays.iter_mut().enumerate().step_by(3) {
                    let o = rng.vec3(-0.05, 0.05);
                    let target = scene.triangle(i % 2000)[0];
                    *r = ray(o, (target - o).normalize_or(Vec3::X), 0.0, f32::INFINITY, i);
                }
            }
            // From far outside, and segments ending before the grid.
            let diag = scene.bounds.diagonal().max(1.0);
            for (i, r) in rays.iter_mut().enumerate().skip(2).step_by(7) {
                let c = scene.bounds.center();
                let o = c + rng.unit() * diag * 3.0;
                let d = (c - o).normalize();
                *r = ray(o, d, 0.0, if i % 2 == 0 { diag } else { f32::INFINITY }, i);
            }
            let hits = check_all_tests(&scene, &rays, &[DEFAULT_DENSITY, 8.0]);
            if name == "degenerate" {
                assert_eq!(hits, 0);
                let grid = UniformGrid::build(&scene, 2.0, TestKind::MollerTrumbore).unwrap();
                assert!(grid.grid().cell_tris.is_empty());
                assert_eq!(run(&grid, &rays, HitMode::Closest).1.tests.total, 0);
            } else {
                assert!(hits > 0, "{name}");
            }
            if name == "flat" {
                let g = UniformGrid::build(&scene, 2.0, TestKind::MollerTrumbore).unwrap();
                assert_eq!(g.grid().geometry.dims[2], 1, "{name}");
            }
        }
    }

    /// The stability suite: explicit rays give brute force's hits; frames traced through a
    /// `grid` pipeline give brute force's outcome, column for column.
    #[test]
    fn stress_suite_matches_brute_force() {
        let registry = Registry::<Cpu>::builtin();
        for case in crsh_scene::stress::cases() {
            let Ok(scene) = &case.scene else { continue };
            match &case.probe {
                crsh_scene::stress::Probe::Rays { kind, rays, .. } => {
                    if !rays.iter().all(Ray::is_valid) {
                        let g =
                            UniformGrid::build(scene, DEFAULT_DENSITY, TestKind::MollerTrumbore)
                                .unwrap();
                        let mut hits = vec![Hit::MISS; rays.len()];
                        let r = g.intersect(
                            &Cpu,
                            rays,
                            Query::Scene,
                            HitMode::Closest,
                            &mut hits,
                            &mut Stats::default(),
                        );
                        assert!(r.is_err(), "{}", case.name);
                        continue;
                    }
                    let mode = if *kind == RayKind::Shadow {
                        HitMode::Any
                    } else {
                        HitMode::Closest
                    };
                    for test in TestKind::ALL {
                        let brute = BruteForce::with_test(scene, test);
                        let grid = UniformGrid::build(scene, DEFAULT_DENSITY, test).unwrap();
                        let (want, _) = run(&brute, rays, mode);
                        let (got, _) = run(&grid, rays, mode);
                        for (i, (g, w)) in got.iter().zip(&want).enumerate() {
                            match mode {
                                HitMode::Closest => {
                                    assert_eq!(bits(g), bits(w), "{} {test:?} ray {i}", case.name)
                                }
                                HitMode::Any | HitMode::EdgeWidth(_) => assert_eq!(
                                    g.is_hit(),
                                    w.is_hit(),
                                    "{} {test:?} ray {i}",
                                    case.name
                                ),
                            }
                        }
                    }
                }
                crsh_scene::stress::Probe::Frame { .. } => {
                    for test in ["mt", "watertight"] {
                        let outcome = |intersect: &str| {
                            let mut cfg = PipelineConfig::whitted(intersect, intersect);
                            cfg.set(&format!("intersect.test={test}")).unwrap();
                            registry.resolve(&mut cfg).unwrap();
                            let mut o = crate::stress::run_case(&registry, &case, &cfg);
                            // The answers must agree; the work differs by design.
                            o.time_ms = 0.0;
                            o.bounds_tests = 0;
                            o.triangle_tests = 0;
                            o
                        };
                        assert_eq!(outcome("grid"), outcome("brute"), "{} {test}", case.name);
                    }
                }
            }
        }
    }

    /// A ray along x through the middle of a grid with nothing to hit visits every cell of
    /// its row; one from outside aimed away visits none.
    #[test]
    fn counts_cells_along_the_ray() {
        // Two small triangles at opposite corners make the box; nothing in the middle row.
        let scene = raw_scene(
            vec![
                Vec3::ZERO,
                Vec3::new(0.1, 0.0, 0.0),
                Vec3::new(0.0, 0.1, 0.0),
                Vec3::new(4.0, 4.0, 4.0),
                Vec3::new(3.9, 4.0, 4.0),
                Vec3::new(4.0, 3.9, 4.0),
            ],
            vec![Vec3::Z; 6],
            vec![[0, 1, 2], [3, 4, 5]],
        );
        let grid = UniformGrid::build(&scene, 32.0, TestKind::MollerTrumbore).unwrap();
        let dims = grid.grid().geometry.dims;
        assert_eq!(dims, [4, 4, 4]);
        let rays = vec![
            ray(Vec3::new(-1.0, 2.1, 1.9), Vec3::X, 0.0, f32::INFINITY, 0),
            ray(Vec3::new(-1.0, 2.1, 1.9), -Vec3::X, 0.0, f32::INFINITY, 1),
            ray(Vec3::new(-1.0, 2.1, 1.9), Vec3::X, 0.0, 2.5, 2),
        ];
        let (hits, stats) = run(&grid, &rays, HitMode::Closest);
        assert!(hits.iter().all(|h| !h.is_hit()));
        // 4 cells, none, and 3 (x up to 1.5 covers cells 0 and 1, the slack none further...
        // the segment ends in cell 1: cells 0 and 1).
        assert_eq!(stats.tests.bounds, 4 + 2);
        assert_eq!(stats.tests.ray_triangle, 0);
        // A ray along the grid's diagonal from the first corner hits the first triangle in
        // the first cell and stops there.
        let r = vec![ray(
            Vec3::new(0.02, 0.02, -1.0),
            Vec3::Z,
            0.0,
            f32::INFINITY,
            0,
        )];
        let (hits, stats) = run(&grid, &r, HitMode::Closest);
        assert_eq!(hits[0].tri, 0);
        assert_eq!((stats.tests.bounds, stats.tests.ray_triangle), (1, 1));
    }

    #[test]
    fn candidates_are_unsupported_and_bad_params_rejected() {
        let scene = Arc::new(soup(41, 20));
        let mut spec = StageSpec::new("grid");
        assert!(UniformGrid::new(&scene, &spec).is_err(), "unresolved spec");
        spec.params
            .insert("grid_density".into(), ParamValue::Float(1e9));
        spec.params
            .insert("test".into(), ParamValue::Str("mt".into()));
        assert!(matches!(
            UniformGrid::new(&scene, &spec),
            Err(CoreError::InvalidParam { .. })
        ));
        spec.params
            .insert("grid_density".into(), ParamValue::Float(f64::NAN));
        assert!(matches!(
            UniformGrid::new(&scene, &spec),
            Err(CoreError::InvalidParam { .. })
        ));
        spec.params
            .insert("grid_density".into(), ParamValue::Float(3.0));
        spec.params
            .insert("test".into(), ParamValue::Str("square".into()));
        assert!(matches!(
            UniformGrid::new(&scene, &spec),
            Err(CoreError::InvalidParam { .. })
        ));
        spec.params
            .insert("test".into(), ParamValue::Str("watertight".into()));
        let grid = UniformGrid::new(&scene, &spec).unwrap();
        assert_eq!((grid.test(), grid.density()), (TestKind::Watertight, 3.0));
        assert!(grid.memory_bytes() > 0);
        rejects_candidates_and_bad_rays(&grid, &scene);
        let rays = random_rays(&scene, 42, 8);
        let mut short = vec![Hit::MISS; 7];
        assert!(grid
            .intersect(
                &Cpu,
                &rays,
                Query::Scene,
                HitMode::Any,
                &mut short,
                &mut Stats::default()
            )
            .is_err());
        // Registered, scene-only, with the documented default.
        let registry = Registry::<Cpu>::builtin();
        let info = registry
            .variant(StageKind::Intersect, "grid")
            .expect("registered");
        assert!(info.params.iter().any(|p| p.name == "grid_density"));
    }

    /// Interval ends at infinity (or reversed) visit no cell and never panic.
    #[test]
    fn infinite_or_empty_intervals_visit_nothing() {
        let scene = soup(71, 50);
        let grid = UniformGrid::build(&scene, 2.0, TestKind::MollerTrumbore).unwrap();
        let o = Vec3::new(-3.0, 0.1, 0.2);
        let rays = vec![
            ray(o, Vec3::X, f32::INFINITY, f32::INFINITY, 0),
            ray(o, Vec3::X, 0.0, f32::NEG_INFINITY, 1),
            ray(o, Vec3::X, 5.0, 1.0, 2),
            ray(o, Vec3::X, f32::NEG_INFINITY, f32::NEG_INFINITY, 3),
        ];
        for mode in [HitMode::Closest, HitMode::Any] {
            let (hits, stats) = run(&grid, &rays, mode);
            assert!(hits.iter().all(|h| !h.is_hit()));
            assert_eq!(stats.tests.total, 0, "{mode:?}");
        }
        // The whole line (t from -inf) finds what brute force finds.
        let line = vec![ray(o, Vec3::X, f32::NEG_INFINITY, f32::INFINITY, 0)];
        let (g, _) = run(&grid, &line, HitMode::Closest);
        let (b, _) = run(&BruteForce::from_scene(&scene), &line, HitMode::Closest);
        assert_eq!(g, b);
    }

    /// The measurement behind [`DEFAULT_DENSITY`] (prints, asserts nothing; run with
    /// `cargo test --release -p crsh-cpu measure_density -- --ignored --nocapture`).
    #[test]
    #[ignore]
    fn measure_density() {
        let mut scenes: Vec<(String, Scene)> = crsh_scene::builtin::NAMES
            .iter()
            .map(|n| (n.to_string(), crsh_scene::builtin::build(n).unwrap()))
            .collect();
        let sponza = "../../../shared/scenes/sponza/sponza.toml";
        if let Ok(s) = crsh_scene::load(sponza) {
            scenes.push(("sponza".into(), s));
        }
        for (name, scene) in &scenes {
            let mut rays = random_rays(scene, 99, 20_000);
            let eps = scene.bounds.diagonal() * 1e-5;
            for r in rays.iter_mut().skip(1).step_by(4) {
                r.t_min = eps;
            }
            for k in [0.5, 1.0, 2.0, 3.0, 5.0, 8.0, 12.0, 16.0] {
                let g = UniformGrid::build(scene, k, TestKind::MollerTrumbore).unwrap();
                let _ = run(&g, &rays, HitMode::Closest);
                let start = Instant::now();
                let (_, st) = run(&g, &rays, HitMode::Closest);
                let ms = start.elapsed().as_secs_f64() * 1e3;
                let n = rays.len() as f64;
                println!(
                    "{name} tris {} k {k}: dims {:?} cells/ray {:.1} tri tests/ray {:.1} total/ray {:.1} trace {ms:.1} ms build {:.1} ms mem {} KiB",
                    scene.triangle_count(),
                    g.grid().geometry.dims,
                    st.tests.bounds as f64 / n,
                    st.tests.ray_triangle as f64 / n,
                    st.tests.total as f64 / n,
                    g.build_time().as_secs_f64() * 1e3,
                    g.memory_bytes() / 1024
                );
            }
        }
    }

    #[test]
    fn stored_hits_are_kept_or_improved() {
        let scene = soup(61, 300);
        let grid = UniformGrid::build(&scene, 2.0, TestKind::MollerTrumbore).unwrap();
        let brute = BruteForce::from_scene(&scene);
        let rays = random_rays(&scene, 62, 400);
        for mode in [HitMode::Closest, HitMode::Any] {
            let start: Vec<Hit> = (0..rays.len())
                .map(|i| {
                    if i % 3 == 0 {
                        Hit {
                            t: 0.5,
                            tri: 7,
                            u: 0.1,
                            v: 0.1,
                        }
                    } else {
                        Hit::MISS
                    }
                })
                .collect();
            let (mut a, mut b) = (start.clone(), start.clone());
            grid.intersect(
                &Cpu,
                &rays,
                Query::Scene,
                mode,
                &mut a,
                &mut Stats::default(),
            )
            .unwrap();
            brute
                .intersect(
                    &Cpu,
                    &rays,
                    Query::Scene,
                    mode,
                    &mut b,
                    &mut Stats::default(),
                )
                .unwrap();
            for (i, (g, w)) in a.iter().zip(&b).enumerate() {
                match mode {
                    HitMode::Closest => assert_eq!(bits(g), bits(w), "ray {i}"),
                    HitMode::Any | HitMode::EdgeWidth(_) => {
                        assert_eq!(g.is_hit(), w.is_hit(), "ray {i}");
                        if start[i].is_hit() {
                            assert_eq!(g, &start[i]);
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn same_result_for_any_thread_count() {
        let scene = soup(51, 400);
        let grid = UniformGrid::build(&scene, 2.0, TestKind::MollerTrumbore).unwrap();
        let rays = random_rays(&scene, 52, 700);
        for mode in [HitMode::Closest, HitMode::Any] {
            let a = crate::with_threads(1, || run(&grid, &rays, mode)).unwrap();
            let b = crate::with_threads(3, || run(&grid, &rays, mode)).unwrap();
            assert_eq!(a.0, b.0);
            assert_eq!(a.1.tests, b.1.tests);
        }
        // The grid does far fewer triangle tests than brute force.
        let (_, stats) = run(&grid, &rays, HitMode::Closest);
        assert!(stats.tests.ray_triangle * 5 < (rays.len() * scene.triangle_count()) as u64);
    }
}
