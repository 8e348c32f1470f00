//! Criterion benches of the uniform grid's rebuild (seed 002 §5.1, table 1: "time to rebuild
//! the entire grid structure").
//!
//! The scenes: `crsh_scene::random::triangle_soup` (random triangles in `[-50, 50]³`, enclosing
//! sphere radius uniform in `[0.2, 1.0]`, seed `crsh_scene::random::DEFAULT_SEED`) with 5K,
//! 50K and 500K triangles; the grid at the default density (eq. 1). Each benchmark times
//! `GridData::build` (binning set, eq. 1 and the five passes) and reports throughput in
//! triangles.
//!
//! Groups:
//! - `grid_build_serial`: inside a 1-thread rayon pool (the same code, serial);
//! - `grid_build_parallel`: inside a pool of one thread per core.
//!
//! Run with `cargo bench -p crsh-cpu --bench grid_build` (add `-- --quick` for a short run, or
//! a group name to filter). `crsh grid-build` prints the full table with the per-pass split
//! next to the paper's figures.

use std::time::Duration;

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use crsh_cpu::intersect::grid::{GridData, DEFAULT_DENSITY};
use crsh_cpu::triangle::TestKind;
use crsh_scene::random::{triangle_soup, DEFAULT_SEED};

/// Triangle counts benched (the first, a middle and the last column of table 1).
const SIZES: [usize; 3] = [5_000, 50_000, 500_000];

fn benches(c: &mut Criterion) {
    let scenes: Vec<_> = SIZES
        .iter()
        .map(|&n| (n, triangle_soup(n, DEFAULT_SEED).expect("a valid soup")))
        .collect();
    for (group, threads) in [("grid_build_serial", 1), ("grid_build_parallel", 0)] {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .expect("a rayon pool");
        let mut g = c.benchmark_group(group);
        for (n, scene) in &scenes {
            g.throughput(Throughput::Elements(*n as u64));
            if *n >= 100_000 {
                g.sample_size(10);
            }
            g.bench_function(format!("{n}"), |b| {
                pool.install(|| {
                    b.iter(|| {
                        GridData::build(scene, DEFAULT_DENSITY, TestKind::MollerTrumbore)
                            .expect("a grid")
                    })
                })
            });
        }
        g.finish();
    }
}

/// Short runs: the machine this was written on has 2 shared cores.
fn config() -> Criterion {
    Criterion::default()
        .sample_size(20)
        .warm_up_time(Duration::from_millis(500))
        .measurement_time(Duration::from_secs(3))
}

criterion_group! {
    name = grid_build_group;
    config = config();
    targets = benches
}
criterion_main!(grid_build_group);
