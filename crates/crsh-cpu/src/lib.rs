//! # crsh-cpu
//!
//! The CPU backend of crsh ([`Cpu`]): every stage variant as a rayon implementation of the
//! `crsh-core` stage traits, registered in the backend's [`crsh_core::Registry`]
//! ([`Registry::<Cpu>::builtin`](crsh_core::Registry::builtin), see [`registry`]) with the
//! presets `brute`, `bvh`, `grid`, `kdtree`, `crsh`, `rah` and `tile_cone`.
//!
//! ```
//! use std::sync::Arc;
//! use crsh_core::{FrameOptions, FrameSize, Registry, StageContext};
//! use crsh_cpu::Cpu;
//!
//! let scene = Arc::new(crsh_scene::builtin::build("cornell-mirrors").unwrap());
//! let registry = Registry::<Cpu>::builtin();
//! let mut cfg = registry.preset("crsh").unwrap();
//! cfg.set("hierarchy.subdivision=16").unwrap();
//! let ctx = StageContext::new(&Cpu, &scene, FrameSize::new(32, 32).unwrap());
//! let opts = FrameOptions::default().with_max_depth(1);
//! let frame = registry.render(&ctx, &cfg, &opts, None, &mut |_| {}).unwrap();
//! assert_eq!(frame.image.len(), 32 * 32);
//! assert_eq!(frame.stats.stages["hash"], "thesis");
//! ```
//!
//! Stage variants, one module each, each with its catalogue entry (`info`) and its
//! registration (`register`) beside the stage:
//! - [`primary::raster`]: z-buffer rasterizer writing the G-buffer (seed 000 §3.1);
//!   [`primary::raycast`]: the same G-buffer by casting camera rays.
//! - [`triangle`]: the ray-triangle tests and their epsilon policy.
//! - [`intersect::brute`]: every ray against every triangle (the exact reference);
//!   [`intersect::brute64`]: the same in f64 (the accuracy reference);
//!   [`intersect::bvh`]: the obvhs CWBVH (closest and any hit);
//!   [`intersect::bvh2`]: obvhs's binary BVH with a stack traversal written here (seed 001's
//!   visited inner nodes and leaves on a binary tree);
//!   [`intersect::grid`]: seed 002's uniform grid;
//!   [`intersect::kdtree`]: seed 003's kd-tree ([`kdtree`]: its layout and single-ray
//!   traversal, the SAH build with perfect splits [`kdtree::sah`], middle splits).
//! - [`raygen::whitted`]: shadow, reflection and refraction rays (eq. 3.1-3.7).
//! - [`shade::phong`]: barycentric normals and Phong with attenuation (eq. 3.17-3.19).
//! - [`hash`], [`sort`], [`hierarchy`], [`traverse`]: the ray-space hierarchy stages
//!   (seed 000 §3.2.3-3.2.8), and seed 004's screen tiles and tile cones ([`hash::tile`],
//!   [`hierarchy::tile_cone`]); [`trim`]: head-flag scan compaction (fig. 3.10).
//! - [`stress`]: runs the stability suite of `crsh_scene::stress` against pipelines.
//! - [`isa`]: the instruction set the hot loops run in (`setup.isa` of the stats).
//! - [`grid_timing`]: timed rebuilds of the uniform grid, pass by pass (seed 002 §5.1,
//!   table 1; `crsh grid-build`).

#![warn(missing_docs)]

pub mod backend;
pub mod grid_timing;
pub mod hash;
pub mod hierarchy;
pub mod intersect;
pub mod isa;
pub mod kdtree;
pub mod primary;
pub mod raygen;
pub mod registry;
pub mod shade;
pub mod sort;
pub mod stress;
pub mod surface;
pub mod traverse;
pub mod triangle;
pub mod trim;

pub use backend::Cpu;
pub use registry::with_threads;

/// Items per chunk of [`position_first`]'s parallel scan (and of other parallel scans).
pub(crate) const SCAN_CHUNK: usize = 1 << 14;

/// The position of the first item of `items` for which `pred` holds, scanned in parallel by
/// chunks of [`SCAN_CHUNK`] items (each chunk's first match, then the least of them). For the
/// input checks that run on every batch and almost never match: rayon's per-item
/// `position_first` pays a shared-minimum check per item (10.7 ms for Sponza's 1.24M
/// shadow-ray order on two threads), a chunk's plain loop does not (the same scan in
/// 0.23-0.32 ms). The same answer as a serial `position`, whatever the thread count.
pub(crate) fn position_first<T: Sync>(
    items: &[T],
    pred: impl Fn(&T) -> bool + Sync,
) -> Option<usize> {
    use rayon::prelude::*;
    items
        .par_chunks(SCAN_CHUNK)
        .enumerate()
        .filter_map(|(k, chunk)| chunk.iter().position(&pred).map(|i| k * SCAN_CHUNK + i))
        .min()
}

/// The position of the first entry of `order` that is not below `n` or repeats an earlier
/// one; `None` when `order` holds distinct indices below `n` (a permutation of `0..n` when it
/// has `n` entries). One bit per index, so the set stays in the cache (a `bool` per index
/// took 12 ms for Sponza's 1.24M shadow rays, the bits 1.1-1.6 ms).
pub(crate) fn first_repeat(order: &[u32], n: usize) -> Option<usize> {
    let mut seen = vec![0u64; n.div_ceil(64)];
    order.iter().position(|&i| {
        let i = i as usize;
        let bit = 1u64 << (i % 64);
        match seen.get_mut(i / 64) {
            Some(word) if i < n && *word & bit == 0 => {
                *word |= bit;
                false
            }
            _ => true,
        }
    })
}

/// Asks the processor to start loading the cache line of `x` (a hint: it changes no result;
/// nothing on targets without a prefetch instruction, or for `None`). For gathers through a
/// permutation, where each load would otherwise wait for memory in turn.
#[inline(always)]
pub(crate) fn prefetch<T>(x: Option<&T>) {
    #[cfg(target_arch = "x86_64")]
    if let Some(x) = x {
        // SAFETY: a prefetch reads nothing the program observes and never faults, and `x` is
        // a valid reference.
        unsafe {
            use std::arch::x86_64::{_mm_prefetch, _MM_HINT_T0};
            _mm_prefetch::<_MM_HINT_T0>((x as *const T).cast::<i8>());
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = x;
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn position_first_is_the_serial_first_match_at_any_thread_count() {
        let n = 3 * SCAN_CHUNK + 17;
        let items: Vec<u32> = (0..n as u32)
            .map(|i| i.wrapping_mul(2_654_435_761))
            .collect();
        // Matches in no chunk, in the first item, at both sides of chunk boundaries, in the
        // last (short) chunk and in several chunks at once (the earliest wins).
        let marks: [&[usize]; 6] = [
            &[],
            &[0],
            &[SCAN_CHUNK - 1, 2 * SCAN_CHUNK],
            &[SCAN_CHUNK, 3 * SCAN_CHUNK + 5],
            &[n - 1],
            &[2 * SCAN_CHUNK + 3, SCAN_CHUNK + 9, 3 * SCAN_CHUNK],
        ];
        for threads in [1, 3] {
            for m in marks {
                let mut v = items.clone();
                for &i in m {
                    v[i] = u32::MAX;
                }
                let serial = v.iter().position(|&x| x == u32::MAX);
                let got = with_threads(threads, || position_first(&v, |&x| x == u32::MAX)).unwrap();
                assert_eq!(got, serial, "marks {m:?}, {threads} threads");
                assert_eq!(got, m.iter().min().copied());
            }
        }
        assert_eq!(position_first::<u32>(&[], |_| true), None);
    }

    #[test]
    fn first_repeat_names_the_first_repeated_or_out_of_range_entry() {
        assert_eq!(first_repeat(&[], 0), None);
        assert_eq!(first_repeat(&[2, 0, 1], 3), None);
        // Indices past one 64-bit word, and a permutation of part of the range.
        let order: Vec<u32> = (0..200).rev().collect();
        assert_eq!(first_repeat(&order, 200), None);
        assert_eq!(first_repeat(&order[..50], 200), None);
        assert_eq!(first_repeat(&[5, 1, 5, 1], 8), Some(2));
        assert_eq!(first_repeat(&[64, 0, 128, 64], 200), Some(3));
        assert_eq!(first_repeat(&[0, 3, 1], 3), Some(1));
        // One past the end, inside the last word: the range check, not the bit, refuses it.
        assert_eq!(first_repeat(&[0, 3], 3), Some(1));
        assert_eq!(first_repeat(&[u32::MAX], 3), Some(0));
    }
}
