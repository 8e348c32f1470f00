//! Timed rebuilds of the uniform grid ([`crate::intersect::grid`]): seed 002 §5.1 and its
//! table 1 ("time in milliseconds to rebuild the entire grid structure") on the random
//! triangle soups of [`crsh_scene::random`], with the time of every pass.
//!
//! [`timed_build`] runs exactly the steps of [`GridData::build`] — the binning set and eq. 1
//! ([`PassTimes::setup_ms`]), then the five passes of §3.1 — with a clock around each, and
//! returns the same grid. [`measure`] repeats it inside a rayon pool of a given size (1: the
//! serial build, the same code; 0: one thread per core) after warm-up builds and keeps the
//! median of each column. `crsh grid-build` prints the table next to the paper's figures
//! ([`PAPER_TRIANGLES`], [`PAPER_CPU_MS`], [`PAPER_GPU_MS`]); the `grid_build` criterion bench
//! times [`GridData::build`] on the same scenes.
//!
//! ```
//! use crsh_cpu::grid_timing::{measure, timed_build};
//! use crsh_cpu::intersect::grid::{GridData, DEFAULT_DENSITY};
//! use crsh_cpu::triangle::TestKind;
//!
//! let scene = crsh_scene::random::triangle_soup(2000, 1).unwrap();
//! let (grid, times) = timed_build(&scene, DEFAULT_DENSITY, TestKind::MollerTrumbore).unwrap();
//! assert_eq!(grid, GridData::build(&scene, DEFAULT_DENSITY, TestKind::MollerTrumbore).unwrap());
//! assert!(times.total_ms() >= times.sort_ms);
//! let m = measure(&scene, DEFAULT_DENSITY, 1, 1, 3).unwrap();
//! assert_eq!((m.triangles, m.threads, m.repeats), (2000, 1, 3));
//! assert_eq!(m.pairs, grid.cell_tris.len());
//! ```

use std::time::Instant;

use crsh_core::{CoreError, Result};
use crsh_scene::Scene;
use serde::{Deserialize, Serialize};

use crate::intersect::grid::{
    count_pass, hittable, ranges_pass, scan_pass, sort_pass, triangle_boxes, write_pairs_pass,
    BoxCells, GridData, GridGeometry,
};
use crate::registry::with_threads;
use crate::triangle::TestKind;

/// Triangle counts of seed 002's table 1.
pub const PAPER_TRIANGLES: [usize; 8] = [
    5_000, 10_000, 50_000, 100_000, 200_000, 300_000, 400_000, 500_000,
];

/// Seed 002 table 1, row "CPU": rebuild time in ms of the authors' CPU implementation (an
/// Intel Core 2 of 2008-2009) for [`PAPER_TRIANGLES`].
pub const PAPER_CPU_MS: [f64; 8] = [0.8, 1.5, 10.2, 33.8, 94.1, 167.4, 253.0, 353.6];

/// Seed 002 table 1, row "Ours": rebuild time in ms of the authors' GPU implementation (GLSL +
/// CUDA on a GeForce 8800 Ultra) for [`PAPER_TRIANGLES`].
pub const PAPER_GPU_MS: [f64; 8] = [1.7, 2.2, 6.9, 14.5, 32.9, 55.2, 63.8, 87.4];

/// The paper's figures for `triangles`, if table 1 has that column: `(CPU ms, GPU ms)`.
pub fn paper_ms(triangles: usize) -> Option<(f64, f64)> {
    PAPER_TRIANGLES
        .iter()
        .position(|&n| n == triangles)
        .map(|i| (PAPER_CPU_MS[i], PAPER_GPU_MS[i]))
}

/// Wall time of each step of one grid rebuild, in milliseconds.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct PassTimes {
    /// Before the passes: which triangles are binned (non-degenerate for the test) and the
    /// grid geometry (eq. 1 resolution, cell planes).
    pub setup_ms: f64,
    /// Pass 1 (§3.2.1): each triangle's AABB widened by the margin, turned into its block of
    /// cells, and the number of cells it overlaps.
    pub count_ms: f64,
    /// Pass 2 (§3.2.2): exclusive scan of the counts.
    pub scan_ms: f64,
    /// Pass 3 (§3.2.3): one (cell, triangle) pair per output slot.
    pub write_pairs_ms: f64,
    /// Pass 4 (§3.2.4): stable radix sort of the pairs by cell.
    pub sort_ms: f64,
    /// Pass 5 (§3.2.5): `(start, count)` per cell from the runs of the sorted pairs.
    pub ranges_ms: f64,
}

impl PassTimes {
    /// Names of the columns, in build order (as in [`PassTimes::values`]).
    pub const NAMES: [&'static str; 6] =
        ["setup", "count", "scan", "write_pairs", "sort", "ranges"];

    /// The columns in build order.
    pub fn values(&self) -> [f64; 6] {
        [
            self.setup_ms,
            self.count_ms,
            self.scan_ms,
            self.write_pairs_ms,
            self.sort_ms,
            self.ranges_ms,
        ]
    }

    fn from_values(v: [f64; 6]) -> PassTimes {
        PassTimes {
            setup_ms: v[0],
            count_ms: v[1],
            scan_ms: v[2],
            write_pairs_ms: v[3],
            sort_ms: v[4],
            ranges_ms: v[5],
        }
    }

    /// The whole rebuild: the sum of every column (table 1's "entire grid structure").
    pub fn total_ms(&self) -> f64 {
        self.values().iter().sum()
    }
}

/// [`GridData::build`] with a clock around each step; the same grid.
///
/// # Errors
/// Those of [`GridData::build`] (a grid too large for 32-bit indices), and a `k` that is not
/// finite and positive.
pub fn timed_build(scene: &Scene, k: f64, test: TestKind) -> Result<(GridData, PassTimes)> {
    if !(k.is_finite() && k > 0.0) {
        return Err(CoreError::InvalidParam {
            key: "grid.grid_density".into(),
            reason: format!("{k} is not a positive number"),
        });
    }
    let ms = |t: Instant| t.elapsed().as_secs_f64() * 1e3;
    let t = Instant::now();
    let keep = hittable(scene, test);
    let binned = keep.iter().filter(|&&h| h).count();
    let geometry = GridGeometry::new(&scene.bounds, binned, k);
    let setup_ms = ms(t);

    let t = Instant::now();
    let boxes = triangle_boxes(&geometry, scene, &keep);
    let cells = BoxCells {
        geometry: &geometry,
        boxes: &boxes,
    };
    let counts = count_pass(&cells);
    let count_ms = ms(t);

    let t = Instant::now();
    let scan = scan_pass(&counts)?;
    let scan_ms = ms(t);

    let t = Instant::now();
    let (pair_cells, pair_prims) = write_pairs_pass(&scan, &cells);
    let write_pairs_ms = ms(t);

    let t = Instant::now();
    let (sorted_cells, sorted_prims) = sort_pass(&pair_cells, &pair_prims, geometry.key_bits())?;
    let sort_ms = ms(t);

    let t = Instant::now();
    let ranges = ranges_pass(&sorted_cells, geometry.cell_count());
    let ranges_ms = ms(t);

    let data = GridData {
        geometry,
        cell_ranges: ranges,
        cell_tris: sorted_prims,
    };
    let times = PassTimes {
        setup_ms,
        count_ms,
        scan_ms,
        write_pairs_ms,
        sort_ms,
        ranges_ms,
    };
    Ok((data, times))
}

/// Largest number of repeats [`measure`] accepts.
pub const MAX_REPEATS: usize = 1000;

/// Median build times of one scene on one pool size.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct BuildMeasurement {
    /// Triangles in the scene.
    pub triangles: usize,
    /// Cells of the grid (eq. 1).
    pub cells: usize,
    /// Cells per axis.
    pub dims: [u32; 3],
    /// (cell, triangle) pairs: the length of the grid's triangle lists.
    pub pairs: usize,
    /// Worker threads of the pool the builds ran in.
    pub threads: usize,
    /// Timed builds (after the warm-up ones).
    pub repeats: usize,
    /// Median of each column over the repeats.
    pub median: PassTimes,
    /// Median of the whole rebuild's time over the repeats (not the sum of the column
    /// medians).
    pub median_total_ms: f64,
    /// Fastest whole rebuild.
    pub min_total_ms: f64,
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n == 0 {
        0.0
    } else if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

/// Builds the grid of `scene` at density `k` (Möller-Trumbore binning, the `grid` default)
/// `warmup` times untimed and `repeats` times timed, all inside a rayon pool of `threads`
/// workers (1: serial; 0: one per core), and returns the medians.
///
/// # Errors
/// `repeats` outside `1..=MAX_REPEATS`, a pool that cannot start, and those of
/// [`timed_build`].
pub fn measure(
    scene: &Scene,
    k: f64,
    threads: usize,
    warmup: usize,
    repeats: usize,
) -> Result<BuildMeasurement> {
    if !(1..=MAX_REPEATS).contains(&repeats) || warmup > MAX_REPEATS {
        return Err(CoreError::InvalidInput(format!(
            "grid build timing: repeats must be in 1..={MAX_REPEATS} and warm-up at most \
             {MAX_REPEATS} (got {repeats} and {warmup})"
        )));
    }
    with_threads(threads, || -> Result<BuildMeasurement> {
        let test = TestKind::MollerTrumbore;
        for _ in 0..warmup {
            timed_build(scene, k, test)?;
        }
        let mut runs = Vec::with_capacity(repeats);
        let mut last = None;
        for _ in 0..repeats {
            let (grid, times) = timed_build(scene, k, test)?;
            runs.push(times);
            last = Some(grid);
        }
        let grid = last.ok_or_else(|| CoreError::InvalidInput("no timed build".into()))?;
        let column = |i: usize| median(runs.iter().map(|r| r.values()[i]).collect());
        let totals: Vec<f64> = runs.iter().map(PassTimes::total_ms).collect();
        Ok(BuildMeasurement {
            triangles: scene.triangle_count(),
            cells: grid.geometry.cell_count(),
            dims: grid.geometry.dims,
            pairs: grid.cell_tris.len(),
            threads: rayon::current_num_threads(),
            repeats,
            median: PassTimes::from_values([0, 1, 2, 3, 4, 5].map(column)),
            median_total_ms: median(totals.clone()),
            min_total_ms: totals.iter().copied().fold(f64::INFINITY, f64::min),
        })
    })?
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::intersect::grid::DEFAULT_DENSITY;

    #[test]
    fn timed_build_is_the_build_and_threads_do_not_change_it() {
        let scene = crsh_scene::random::triangle_soup(5000, 11).unwrap();
        let want = GridData::build(&scene, DEFAULT_DENSITY, TestKind::MollerTrumbore).unwrap();
        let serial = with_threads(1, || {
            timed_build(&scene, DEFAULT_DENSITY, TestKind::MollerTrumbore)
        })
        .unwrap()
        .unwrap();
        let parallel = with_threads(3, || {
            timed_build(&scene, DEFAULT_DENSITY, TestKind::MollerTrumbore)
        })
        .unwrap()
        .unwrap();
        assert_eq!(serial.0, want);
        assert_eq!(parallel.0, want);
        // Every binned triangle is in at least one cell; small triangles in few.
        assert!(want.cell_tris.len() >= 5000 && want.cell_tris.len() < 5000 * 27);
        for t in [serial.1, parallel.1] {
            assert!(t.values().iter().all(|v| v.is_finite() && *v >= 0.0));
            assert_eq!(t.total_ms(), t.values().iter().sum::<f64>());
        }
    }

    #[test]
    fn measurement_describes_the_grid() {
        let scene = crsh_scene::random::triangle_soup(3000, 5).unwrap();
        let m = measure(&scene, DEFAULT_DENSITY, 2, 0, 3).unwrap();
        let grid = GridData::build(&scene, DEFAULT_DENSITY, TestKind::MollerTrumbore).unwrap();
        assert_eq!(m.triangles, 3000);
        assert_eq!(m.threads, 2);
        assert_eq!(m.cells, grid.cell_ranges.len());
        assert_eq!(m.dims, grid.geometry.dims);
        assert_eq!(m.pairs, grid.cell_tris.len());
        assert!(m.min_total_ms <= m.median_total_ms);
        assert!(measure(&scene, DEFAULT_DENSITY, 1, 0, 0).is_err());
        assert!(measure(&scene, DEFAULT_DENSITY, 1, 0, MAX_REPEATS + 1).is_err());
        assert!(measure(&scene, f64::NAN, 1, 0, 1).is_err());
    }

    #[test]
    fn paper_figures() {
        assert_eq!(paper_ms(500_000), Some((353.6, 87.4)));
        assert_eq!(paper_ms(5_000), Some((0.8, 1.7)));
        assert_eq!(paper_ms(7), None);
        assert_eq!(median(vec![3.0, 1.0, 2.0]), 2.0);
        assert_eq!(median(vec![4.0, 1.0, 2.0, 3.0]), 2.5);
    }
}
