//! `compress`: the thesis's compression-sorting-decompression (seed 000 §3.2.4-3.2.6,
//! figs 3.12-3.15, after Garanzha & Loop 2010).
//!
//! 1. **Compression** (§3.2.4, fig. 3.12, [`compress`]): head flags mark every position whose
//!    key differs from the previous one (position 0 always); their inclusive scan numbers the
//!    runs of equal keys ("chunks"), and each head `i` writes its chunk `scan[i] − 1`: chunk
//!    key, base (first ray) and size arrays.
//! 2. **Sorting** (§3.2.5, fig. 3.13): the chunks — not the rays — are radix sorted by key
//!    ([`crate::sort::radix::stable_radix_order`], stable: chunks with equal keys keep their
//!    input order).
//! 3. **Decompression** (§3.2.6, fig. 3.14, [`decompress`]): the sorted chunk sizes (the
//!    "skeleton") are exclusive-scanned into output positions, and each sorted chunk writes
//!    its rays `base .. base + size` from its position on.
//!
//! Coherent rays make long runs of equal keys, so the radix sort handles far fewer items than
//! there are rays. The result equals the stable sort of the rays by key (runs keep their input
//! order, chunks with equal keys keep theirs), so it matches the `radix` variant exactly and
//! does not depend on the thread count. Records the timings `compression`, `sorting` (the
//! chunk radix sort) and `decompression`, the rows of the thesis's table 4.25; the driver
//! adds what is left of the stage to `sorting`.
//!
//! # Errors
//! As [`crate::sort::radix`]: `key_bits > 64`, keys with bits above `key_bits`, more than
//! `u32::MAX` keys.

use std::sync::Arc;
use std::time::Instant;

use crsh_core::{
    CoreError, Registry, Result, Sorter, StageKind, StageSpec, StageVariantInfo, Stats,
};
use crsh_scene::Scene;
use rayon::prelude::*;

use crate::backend::Cpu;
use crate::sort::radix::{check_keys, stable_radix_order};

/// Elements per parallel block of the scans, scatter and decompression.
pub const BLOCK: usize = 16 * 1024;

/// Runs of equal keys (§3.2.4): chunk `c` holds the rays `base[c] .. base[c] + size[c]`, all
/// with key `keys[c]`. Chunks are in input order.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Chunks {
    /// Key of each chunk.
    pub keys: Vec<u64>,
    /// Index of each chunk's first ray.
    pub base: Vec<u32>,
    /// Rays in each chunk (≥ 1).
    pub size: Vec<u32>,
}

impl Chunks {
    /// Number of chunks.
    pub fn len(&self) -> usize {
        self.keys.len()
    }

    /// True when there are no chunks (no rays).
    pub fn is_empty(&self) -> bool {
        self.keys.is_empty()
    }
}

/// Head flags: 1 where `keys[i] != keys[i − 1]` and at `i = 0`, else 0.
pub fn head_flags(keys: &[u64]) -> Vec<u32> {
    (0..keys.len())
        .into_par_iter()
        .map(|i| u32::from(i == 0 || keys[i] != keys[i - 1]))
        .collect()
}

/// Inclusive prefix sum, in parallel blocks of [`BLOCK`] (block totals, their exclusive scan,
/// then each block's local scan from its offset). Wraps on `u32` overflow, which cannot happen
/// for flag or size arrays of at most `u32::MAX` rays.
pub fn inclusive_scan(values: &[u32]) -> Vec<u32> {
    let totals: Vec<u32> = values
        .par_chunks(BLOCK)
        .map(|b| b.iter().fold(0u32, |a, &v| a.wrapping_add(v)))
        .collect();
    let mut offsets = Vec::with_capacity(totals.len());
    let mut acc = 0u32;
    for t in &totals {
        offsets.push(acc);
        acc = acc.wrapping_add(*t);
    }
    let mut out = vec![0u32; values.len()];
    out.par_chunks_mut(BLOCK)
        .zip(values.par_chunks(BLOCK))
        .zip(offsets.par_iter())
        .for_each(|((o, v), &start)| {
            let mut acc = start;
            for (o, &v) in o.iter_mut().zip(v) {
                acc = acc.wrapping_add(v);
                *o = acc;
            }
        });
    out
}

/// Exclusive prefix sum: `out[i] = Σ values[..i]`.
pub fn exclusive_scan(values: &[u32]) -> Vec<u32> {
    let inc = inclusive_scan(values);
    inc.par_iter()
        .zip(values.par_iter())
        .map(|(&s, &v)| s.wrapping_sub(v))
        .collect()
}

/// Compression (§3.2.4): head flags, their inclusive scan, and the chunk key / base / size
/// arrays. Each block of [`BLOCK`] rays owns the contiguous range of chunks whose heads it
/// holds, so the scatter `base[scan[i] − 1] = i` runs in parallel without sharing.
pub fn compress(keys: &[u64]) -> Chunks {
    let n = keys.len();
    if n == 0 {
        return Chunks::default();
    }
    let flags = head_flags(keys);
    let scan = inclusive_scan(&flags);
    let count = scan[n - 1] as usize;
    let mut base = vec![0u32; count];
    {
        // Split `base` into the per-block ranges [first chunk of block, end).
        let mut parts = Vec::with_capacity(n.div_ceil(BLOCK));
        let mut rest: &mut [u32] = &mut base;
        for start in (0..n).step_by(BLOCK) {
            let end = (start + BLOCK).min(n);
            let first = (scan[start] - flags[start]) as usize;
            let len = scan[end - 1] as usize - first;
            let (head, tail) = rest.split_at_mut(len);
            parts.push((start, end, first, head));
            rest = tail;
        }
        parts.into_par_iter().for_each(|(start, end, first, out)| {
            for i in start..end {
                if flags[i] == 1 {
                    out[scan[i] as usize - 1 - first] = i as u32;
                }
            }
        });
    }
    let size: Vec<u32> = (0..count)
        .into_par_iter()
        .map(|c| {
            let next = if c + 1 < count { base[c + 1] } else { n as u32 };
            next - base[c]
        })
        .collect();
    let chunk_keys: Vec<u64> = base.par_iter().map(|&b| keys[b as usize]).collect();
    Chunks {
        keys: chunk_keys,
        base,
        size,
    }
}

/// Decompression (§3.2.6): `sorted` lists the chunks in output order; the skeleton (their
/// sizes) is exclusive-scanned into output positions and each block of [`BLOCK`] outputs
/// finds its first chunk by binary search and fills the ray indices from there.
///
/// # Errors
/// [`CoreError::InvalidInput`] when `sorted` names a chunk that does not exist.
pub fn decompress(chunks: &Chunks, sorted: &[u32]) -> Result<Vec<u32>> {
    if let Some(&c) = sorted.iter().find(|&&c| c as usize >= chunks.len()) {
        return Err(CoreError::InvalidInput(format!(
            "sorted chunk {c} of {} chunks",
            chunks.len()
        )));
    }
    let skeleton: Vec<u32> = sorted
        .par_iter()
        .map(|&c| chunks.size[c as usize])
        .collect();
    let pos = exclusive_scan(&skeleton);
    let n: usize = skeleton.iter().map(|&s| s as usize).sum();
    let mut order = vec![0u32; n];
    order
        .par_chunks_mut(BLOCK)
        .enumerate()
        .for_each(|(blk, out)| {
            let start = blk * BLOCK;
            // The last chunk whose position is ≤ start (sizes are ≥ 1, so it contains start).
            let mut j = pos.partition_point(|&p| p as usize <= start) - 1;
            for (k, o) in out.iter_mut().enumerate() {
                let p = start + k;
                while p >= (pos[j] + skeleton[j]) as usize {
                    j += 1;
                }
                *o = chunks.base[sorted[j] as usize] + (p - pos[j] as usize) as u32;
            }
        });
    Ok(order)
}

/// The `compress` sorter (no parameters).
#[derive(Clone, Copy, Debug, Default)]
pub struct CompressSorter;

/// The catalogue entry of the `compress` sorter.
pub fn info() -> StageVariantInfo {
    StageVariantInfo::new(
        StageKind::Sort,
        "compress",
        "compress runs of equal keys into chunks, radix sort the chunks, decompress \
         (seed 000 §3.2.4-3.2.6, figs 3.12-3.15; Garanzha & Loop 2010)",
    )
}

/// Registers `compress` ([`info`], [`CompressSorter::new`]).
pub fn register(registry: &mut Registry<Cpu>) -> Result<()> {
    registry.add_sorter(info(), |ctx, spec| {
        Ok(Box::new(CompressSorter::new(ctx.scene, spec)?))
    })?;
    Ok(())
}

impl CompressSorter {
    /// The sorter; `scene` and `spec` have nothing it needs.
    pub fn new(scene: &Arc<Scene>, spec: &StageSpec) -> Result<CompressSorter, CoreError> {
        let _ = (scene, spec);
        Ok(CompressSorter)
    }
}

impl Sorter<Cpu> for CompressSorter {
    fn name(&self) -> &str {
        "compress"
    }

    fn sort(
        &self,
        _backend: &Cpu,
        keys: &Vec<u64>,
        key_bits: u32,
        stats: &mut Stats,
    ) -> Result<Vec<u32>> {
        check_keys(keys, key_bits)?;
        let t = Instant::now();
        let chunks = compress(keys);
        stats.add_time("compression", t.elapsed());
        let t = Instant::now();
        let sorted = stable_radix_order(&chunks.keys, key_bits)?;
        stats.add_time("sorting", t.elapsed());
        let t = Instant::now();
        let order = decompress(&chunks, &sorted)?;
        stats.add_time("decompression", t.elapsed());
        Ok(order)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sort::radix::tests::{oracle, runs_with_duplicates};
    use crate::sort::radix::RadixSorter;
    use crate::with_threads;

    #[test]
    fn scans_match_serial_sums() {
        for n in [0, 1, 5, BLOCK - 1, BLOCK, BLOCK + 1, 3 * BLOCK + 17] {
            let v: Vec<u32> = (0..n as u32).map(|i| i % 7).collect();
            let inc = inclusive_scan(&v);
            let exc = exclusive_scan(&v);
            let mut acc = 0;
            for i in 0..n {
                assert_eq!(exc[i], acc);
                acc += v[i];
                assert_eq!(inc[i], acc);
            }
        }
    }

    #[test]
    fn compression_finds_runs() {
        let keys = [5, 5, 3, 3, 3, 5, 9, 9, 1];
        assert_eq!(head_flags(&keys), vec![1, 0, 1, 0, 0, 1, 1, 0, 1]);
        let c = compress(&keys);
        assert_eq!(c.keys, vec![5, 3, 5, 9, 1]);
        assert_eq!(c.base, vec![0, 2, 5, 6, 8]);
        assert_eq!(c.size, vec![2, 3, 1, 2, 1]);
        // Sorted chunks [1, 3, 5, 5, 9] = chunk ids 4, 1, 0, 2, 3.
        let sorted = stable_radix_order(&c.keys, 4).unwrap();
        assert_eq!(sorted, vec![4, 1, 0, 2, 3]);
        assert_eq!(
            decompress(&c, &sorted).unwrap(),
            vec![8, 2, 3, 4, 0, 1, 5, 6, 7]
        );
        assert!(decompress(&c, &[7]).is_err());
        assert!(compress(&[]).is_empty());
    }

    #[test]
    fn compress_and_radix_match_the_oracle_and_each_other() {
        let mut stats = Stats::default();
        for (n, bits, distinct, seed) in [
            (0, 32, 1, 1),
            (1, 32, 1, 2),
            (2, 8, 1, 3),
            (100, 4, 3, 4),
            (50_000, 32, 500, 5),
            (3 * BLOCK + 5, 50, 4000, 6),
            (20_000, 64, 300, 7),
        ] {
            let keys = runs_with_duplicates(n, bits, distinct, seed);
            let c = CompressSorter.sort(&Cpu, &keys, bits, &mut stats).unwrap();
            let r = RadixSorter.sort(&Cpu, &keys, bits, &mut stats).unwrap();
            let want = oracle(&keys);
            assert_eq!(c, want, "compress n={n} bits={bits}");
            assert_eq!(r, want, "radix n={n} bits={bits}");
            if n > 0 {
                let chunks = compress(&keys);
                assert!(
                    chunks.len() < n || n < 3,
                    "runs compress: {} of {n}",
                    chunks.len()
                );
                assert_eq!(chunks.size.iter().map(|&s| s as usize).sum::<usize>(), n);
            }
        }
        for key in ["compression", "sorting", "decompression"] {
            assert!(stats.timings_ms.contains_key(key), "{key} recorded");
        }
    }

    #[test]
    fn same_order_for_one_and_three_threads() {
        let keys = runs_with_duplicates(5 * BLOCK + 123, 32, 1500, 99);
        let run = || CompressSorter.sort(&Cpu, &keys, 32, &mut Stats::default());
        let one = with_threads(1, run).unwrap().unwrap();
        let three = with_threads(3, run).unwrap().unwrap();
        assert_eq!(one, three);
        assert_eq!(one, oracle(&keys));
    }

    #[test]
    fn rejects_bad_keys() {
        let mut stats = Stats::default();
        assert!(CompressSorter
            .sort(&Cpu, &vec![1 << 40], 32, &mut stats)
            .is_err());
        assert!(CompressSorter.sort(&Cpu, &vec![1], 70, &mut stats).is_err());
    }
}
