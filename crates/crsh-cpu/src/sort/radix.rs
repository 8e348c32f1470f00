//! `radix`: sorts every (key, ray index) pair directly with a least-significant-digit radix
//! sort, the baseline for `compress` (seed 000 §3.2.5 sorts chunks with the same radix sort,
//! the thesis's reference \[13\]).
//!
//! # Algorithm and stability
//!
//! [`stable_radix_order`] sorts records of a key and its index in [`PAIR_DIGIT`]-bit digits of
//! the key only, least significant first (`⌈key_bits / 8⌉` passes: a 32-bit key costs 4). Each
//! pass histograms fixed blocks of [`PAIR_BLOCK`] records in parallel, scans the counts in
//! (digit, block) order and scatters every block in parallel, so each pass is stable and the
//! result is the stable order by key, the same for any thread count. A pass whose digit is
//! the same for every key moves nothing and is skipped. Keys of at most 32 bits travel packed
//! with their index in one `u64` (8 bytes a record), wider keys in 16-byte records.
//!
//! From 65,536 records on, the first pass is by the key's highest 8 bits instead, and each of
//! its 256 buckets then sorts its lower bits on its own, in the cache, buckets in parallel
//! (`radix_sort_by`): the same stable order with one pass over the whole array instead of
//! four. (The top digit was first aligned to 8-bit digits: a 17-bit key, 2 lights' worth of
//! screen tiles on the dining room, then split into two buckets by one bit and paid a second
//! whole-array pass.) Criterion `sorting/radix/thesis_interleave` and `thesis_concat` (Sponza 256², 77,670
//! keys; 2 threads) ran 13 % and 15 % faster than the four whole-array passes; in the reverse
//! order, the four passes ran 10 % and 15 % slower. On whole 1024² frames (1.24M keys) the
//! sort's time was not distinguishable on a busy machine, nor was the uniform grid's pair sort
//! (`crsh grid-build`, 500K triangles, 3.2M pairs of 22-bit keys: 100-102 against 105-114 ms
//! on one thread, 71 against 68 ms on two).
//!
//! # Errors
//! [`CoreError::InvalidInput`] when `key_bits > 64`, a key has bits set above `key_bits`, or
//! there are more than `u32::MAX` keys.

use std::sync::Arc;
use std::time::Instant;

use crsh_core::{
    CoreError, Registry, Result, Sorter, StageKind, StageSpec, StageVariantInfo, Stats,
};
use crsh_scene::Scene;
use rayon::prelude::*;

use crate::backend::Cpu;

/// A key of up to 64 bits and its value (the records of keys wider than 32 bits; narrower keys
/// travel in one `u64`, key in the high half).
#[derive(Clone, Copy, Debug)]
struct Wide {
    key: u64,
    value: u32,
}

/// Sorts `a` stably by keys of `key_bits` bits, `digit(record, shift)` being the
/// [`PAIR_DIGIT`]-bit digit of a record's key from bit `shift` on (`< 2^PAIR_DIGIT`).
///
/// Arrays of at least [`HYBRID_MIN`] records first move stably by their most significant digit
/// into 256 buckets ([`scatter_pass`], blocks in parallel), then sort each bucket's lower digits
/// on its own, buckets in parallel: a bucket of a few thousand records stays in the cache for
/// its remaining passes, where every whole-array pass streams the array through memory again.
/// Smaller arrays, and buckets still larger than [`HYBRID_MIN`], take the same route again
/// ([`lsd_sort_by`] below it). A stable partition by the top digit and stable sorts within the
/// buckets are the stable order by the whole key, so the result is [`lsd_sort_by`]'s, the same
/// for any thread count.
fn radix_sort_by<R: Copy + Send + Sync>(
    a: Vec<R>,
    key_bits: u32,
    digit: &(impl Fn(&R, u32) -> usize + Sync),
) -> Vec<R> {
    if a.len() < HYBRID_MIN || key_bits <= PAIR_DIGIT {
        return lsd_sort_by(a, key_bits, digit);
    }
    // The top digit: the highest `PAIR_DIGIT` bits of the key, so that the partition always
    // makes up to 256 buckets. A digit-aligned top digit of a 17-bit key would be a single bit
    // (two buckets, each still too large for the cache: one more whole-array pass). Digits
    // below overlap it; within a bucket the overlapping bits are the same for every key.
    let top = key_bits - PAIR_DIGIT;
    let mut b = a.clone();
    let Some(totals) = scatter_pass(&a, &mut b, top, digit) else {
        // One top digit for every key: the lower bits decide alone.
        return radix_sort_by(a, top, digit);
    };
    drop(a);
    let mut rest: &mut [R] = &mut b;
    let mut buckets = Vec::with_capacity(totals.len());
    for &t in &totals {
        let (head, tail) = rest.split_at_mut(t);
        buckets.push(head);
        rest = tail;
    }
    buckets.into_par_iter().for_each(|bucket| {
        if bucket.len() >= HYBRID_MIN {
            let sorted = radix_sort_by(bucket.to_vec(), top, digit);
            bucket.copy_from_slice(&sorted);
        } else {
            sort_in_cache(bucket, top, digit);
        }
    });
    b
}

/// The widest key remainder [`sort_in_cache`] sorts in one pass (2048 counters, 8 KiB, beside
/// a bucket of a few thousand records in the cache).
const WIDE_DIGIT_MAX: u32 = 11;

/// Records from which [`radix_sort_by`] partitions by the top digit first (below, every pass
/// streams the whole array, which stays in the cache anyway).
const HYBRID_MIN: usize = 1 << 16;

/// Sorts `v` stably by the low `bits` bits of its keys, one thread, least significant digit
/// first, skipping digits that are the same for every record: for a bucket that fits the cache.
/// Up to [`WIDE_DIGIT_MAX`] bits take a single pass over one digit of all of them.
fn sort_in_cache<R: Copy>(v: &mut [R], bits: u32, digit: &impl Fn(&R, u32) -> usize) {
    if v.len() < 2 || bits == 0 {
        return;
    }
    if bits > PAIR_DIGIT && bits <= WIDE_DIGIT_MAX {
        // One pass over a digit of all `bits` bits instead of two over 8-bit digits (a 17-bit
        // key's buckets keep 9 bits): the same stable order, half the passes.
        let mask = (1 << bits) - 1;
        let src = v.to_vec();
        counting_pass(&src, v, 1 << bits, |r| {
            (digit(r, 0) | digit(r, PAIR_DIGIT) << PAIR_DIGIT) & mask
        });
        return;
    }
    // Passes alternate between `v` and `scratch`; `in_v` says where the records are.
    let mut scratch = v.to_vec();
    let mut in_v = true;
    let mut shift = 0;
    while shift < bits {
        let (src, dst): (&[R], &mut [R]) = if in_v {
            (&*v, &mut scratch[..])
        } else {
            (&scratch[..], &mut *v)
        };
        if counting_pass(src, dst, 1 << PAIR_DIGIT, |r| digit(r, shift)) {
            in_v = !in_v;
        }
        shift += PAIR_DIGIT;
    }
    if !in_v {
        v.copy_from_slice(&scratch);
    }
}

/// One stable counting-sort pass of `src` into `dst` (same length) by `key` (below `radix`),
/// one thread; `false` (and `dst` untouched) when every record has the same key.
fn counting_pass<R: Copy>(
    src: &[R],
    dst: &mut [R],
    radix: usize,
    key: impl Fn(&R) -> usize,
) -> bool {
    let mut at = vec![0u32; radix];
    for r in src {
        at[key(r)] += 1;
    }
    if at.iter().any(|&c| c as usize == src.len()) {
        return false;
    }
    let mut run = 0;
    for c in at.iter_mut() {
        (*c, run) = (run, run + *c);
    }
    for r in src {
        let d = key(r);
        dst[at[d] as usize] = *r;
        at[d] += 1;
    }
    true
}

/// One stable pass of the digit at `shift` from `a` into `b` (same length): a histogram per
/// block of [`PAIR_BLOCK`] records, an exclusive scan of the counts in (digit, block) order and
/// a scatter, blocks in parallel. Returns the records per digit, or `None` (and `b` untouched)
/// when every record has the same digit.
fn scatter_pass<R: Copy + Send + Sync>(
    a: &[R],
    b: &mut [R],
    shift: u32,
    digit: &(impl Fn(&R, u32) -> usize + Sync),
) -> Option<Vec<usize>> {
    let n = a.len();
    let radix = 1usize << PAIR_DIGIT;
    let blocks = n.div_ceil(PAIR_BLOCK);
    // Per block, per digit counts.
    let hist: Vec<Vec<u32>> = a
        .par_chunks(PAIR_BLOCK)
        .map(|chunk| {
            let mut h = vec![0u32; radix];
            for r in chunk {
                h[digit(r, shift)] += 1;
            }
            h
        })
        .collect();
    let totals: Vec<usize> = (0..radix)
        .map(|d| hist.iter().map(|h| h[d] as usize).sum())
        .collect();
    if totals.contains(&n) {
        return None;
    }
    // Exclusive scan in (digit, block) order: where each block's run of each digit starts.
    let mut offsets = vec![vec![0u32; radix]; blocks];
    let mut run = 0u32;
    for d in 0..radix {
        for (block, h) in hist.iter().enumerate() {
            offsets[block][d] = run;
            run += h[d];
        }
    }
    // Scatter: every block writes disjoint slots.
    let out = SharedSlice::new(b);
    a.par_chunks(PAIR_BLOCK)
        .zip(offsets.into_par_iter())
        .for_each(|(records, mut off)| {
            for &r in records {
                let d = digit(&r, shift);
                let at = off[d] as usize;
                off[d] += 1;
                // SAFETY: the scan gives every (block, digit) a disjoint slot range of
                // exactly its count, so no two writes share a slot.
                unsafe { out.write(at, r) };
            }
        });
    Some(totals)
}

/// Sorts `a` stably by keys of `key_bits` bits with one [`scatter_pass`] per digit, least
/// significant first (see the module docs). A pass whose digit is the same for every record is
/// skipped.
fn lsd_sort_by<R: Copy + Send + Sync>(
    mut a: Vec<R>,
    key_bits: u32,
    digit: &(impl Fn(&R, u32) -> usize + Sync),
) -> Vec<R> {
    if a.len() < 2 || key_bits == 0 {
        return a;
    }
    // Scratch of the same length (every slot is written before it is read).
    let mut b = a.clone();
    let mut shift = 0;
    while shift < key_bits {
        if scatter_pass(&a, &mut b, shift, digit).is_some() {
            std::mem::swap(&mut a, &mut b);
        }
        shift += PAIR_DIGIT;
    }
    a
}

/// The digit of a narrow record: a key of at most 32 bits in the high half of a `u64`, its value
/// in the low half.
#[inline]
fn narrow_digit(r: &u64, shift: u32) -> usize {
    ((*r >> (32 + shift)) as usize) & ((1 << PAIR_DIGIT) - 1)
}

/// Checks `keys` against `key_bits` (see the module's errors).
pub fn check_keys(keys: &[u64], key_bits: u32) -> Result<()> {
    if key_bits > 64 {
        return Err(CoreError::InvalidInput(format!(
            "key_bits {key_bits} is more than 64"
        )));
    }
    if keys.len() > u32::MAX as usize {
        return Err(CoreError::InvalidInput(format!(
            "{} keys do not fit 32-bit indices",
            keys.len()
        )));
    }
    if key_bits < 64 {
        let mask = !((1u64 << key_bits) - 1);
        if let Some(k) = crate::position_first(keys, |&k| k & mask != 0).map(|i| keys[i]) {
            return Err(CoreError::InvalidInput(format!(
                "key {k:#x} has bits set above key_bits = {key_bits}"
            )));
        }
    }
    Ok(())
}

/// The stable order of `keys` by their low `key_bits` bits: `order[i]` is the index of the
/// key at sorted position `i`, equal keys in input order. See the module docs.
///
/// # Errors
/// As the module docs say.
pub fn stable_radix_order(keys: &[u64], key_bits: u32) -> Result<Vec<u32>> {
    check_keys(keys, key_bits)?;
    Ok(if key_bits <= 32 {
        let records: Vec<u64> = keys
            .par_iter()
            .enumerate()
            .map(|(i, &k)| k << 32 | i as u64)
            .collect();
        radix_sort_by(records, key_bits, &narrow_digit)
            .par_iter()
            .map(|&r| r as u32)
            .collect()
    } else {
        let records: Vec<Wide> = keys
            .par_iter()
            .enumerate()
            .map(|(i, &key)| Wide {
                key,
                value: i as u32,
            })
            .collect();
        radix_sort_by(records, key_bits, &|r: &Wide, shift| {
            ((r.key >> shift) as usize) & ((1 << PAIR_DIGIT) - 1)
        })
        .par_iter()
        .map(|r| r.value)
        .collect()
    })
}

/// Records per block of the radix passes ([`stable_radix_order`], [`stable_sort_pairs_u32`]): each block histograms and scatters its keys
/// on its own, so blocks run in parallel and the order is the same for any thread count.
pub const PAIR_BLOCK: usize = 1 << 16;

/// Digit width of the radix passes: 8 bits, so a digit's 256 write streams stay
/// within the caches and the TLB (11-bit digits, two passes for a 4M-cell grid instead of
/// three, measured 1.3-1.4× slower on 3.2M pairs: 2048 streams over a 25 MB array miss the TLB
/// on most writes).
pub const PAIR_DIGIT: u32 = 8;

/// `(keys, values)` sorted by the low `key_bits` bits of `keys`, stably (equal keys keep
/// their input order): a least-significant-digit radix sort of `u32` key-value pairs packed in
/// one `u64` each, in [`PAIR_DIGIT`]-bit digits, each pass a parallel block histogram, an
/// exclusive scan of the digit counts in (digit, block) order and a parallel scatter (the
/// passes of [`stable_radix_order`]); the twin of the wgpu backend's block radix sort. What a
/// uniform grid's build sorts (seed 002 §3.2.4): the values ride along with their keys.
///
/// # Errors
/// [`CoreError::InvalidInput`] when the lengths differ, `key_bits > 32`, a key has bits above
/// `key_bits`, or there are more than `u32::MAX` pairs.
pub fn stable_sort_pairs_u32(
    keys: &[u32],
    values: &[u32],
    key_bits: u32,
) -> Result<(Vec<u32>, Vec<u32>)> {
    if keys.len() != values.len() {
        return Err(CoreError::InvalidInput(format!(
            "{} keys but {} values",
            keys.len(),
            values.len()
        )));
    }
    if key_bits > 32 || keys.len() > u32::MAX as usize {
        return Err(CoreError::InvalidInput(format!(
            "{} pairs with key_bits {key_bits}: at most 32 bits and u32::MAX pairs",
            keys.len()
        )));
    }
    if key_bits < 32 {
        if let Some(k) = crate::position_first(keys, |&k| k >> key_bits != 0).map(|i| keys[i]) {
            return Err(CoreError::InvalidInput(format!(
                "key {k:#x} has bits set above key_bits = {key_bits}"
            )));
        }
    }
    // One record per pair, key in the high half: one write stream per digit bucket.
    let records: Vec<u64> = keys
        .par_iter()
        .zip(values.par_iter())
        .map(|(&k, &v)| (k as u64) << 32 | v as u64)
        .collect();
    Ok(radix_sort_by(records, key_bits, &narrow_digit)
        .par_iter()
        .map(|&r| ((r >> 32) as u32, r as u32))
        .unzip())
}

/// A slice written at disjoint indices from several threads (the radix scatter).
struct SharedSlice<T> {
    ptr: *mut T,
    len: usize,
}

// SAFETY: writes go to disjoint indices (the caller's contract in `write`).
unsafe impl<T: Send> Sync for SharedSlice<T> {}
unsafe impl<T: Send> Send for SharedSlice<T> {}

impl<T> SharedSlice<T> {
    fn new(v: &mut [T]) -> SharedSlice<T> {
        SharedSlice {
            ptr: v.as_mut_ptr(),
            len: v.len(),
        }
    }

    /// # Safety
    /// No two calls may write the same `i` concurrently; `i < len` is checked.
    unsafe fn write(&self, i: usize, value: T) {
        assert!(i < self.len, "scatter index {i} out of {}", self.len);
        // SAFETY: in bounds (checked), and disjoint by the caller's contract.
        unsafe { self.ptr.add(i).write(value) }
    }
}

/// The `radix` sorter (no parameters).
#[derive(Clone, Copy, Debug, Default)]
pub struct RadixSorter;

/// The catalogue entry of the `radix` sorter.
pub fn info() -> StageVariantInfo {
    StageVariantInfo::new(
        StageKind::Sort,
        "radix",
        "stable radix sort of every (key, ray) pair, no compression (baseline for \
         seed 000 §3.2.4-3.2.6)",
    )
}

/// Registers `radix` ([`info`], [`RadixSorter::new`]).
pub fn register(registry: &mut Registry<Cpu>) -> Result<()> {
    registry.add_sorter(info(), |ctx, spec| {
        Ok(Box::new(RadixSorter::new(ctx.scene, spec)?))
    })?;
    Ok(())
}

impl RadixSorter {
    /// The sorter; `scene` and `spec` have nothing it needs.
    pub fn new(scene: &Arc<Scene>, spec: &StageSpec) -> Result<RadixSorter, CoreError> {
        let _ = (scene, spec);
        Ok(RadixSorter)
    }
}

impl Sorter<Cpu> for RadixSorter {
    fn name(&self) -> &str {
        "radix"
    }

    /// Records the sort as the `sorting` timing.
    fn sort(
        &self,
        _backend: &Cpu,
        keys: &Vec<u64>,
        key_bits: u32,
        stats: &mut Stats,
    ) -> Result<Vec<u32>> {
        let t = Instant::now();
        let order = stable_radix_order(keys, key_bits)?;
        stats.add_time("sorting", t.elapsed());
        Ok(order)
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    #[test]
    fn pair_sort_is_stable_and_equals_the_key_order() {
        let mut rng = Rng(0x9e37_79b9_7f4a_7c15);
        for (n, bits) in [
            (0usize, 5u32),
            (1, 5),
            (1000, 3),
            (300_000, 22),
            (200_000, 32),
        ] {
            let keys: Vec<u32> = (0..n)
                .map(|_| (rng.next() as u32) & (((1u64 << bits) - 1) as u32))
                .collect();
            let values: Vec<u32> = (0..n as u32).collect();
            let (k, v) = stable_sort_pairs_u32(&keys, &values, bits).unwrap();
            let wide: Vec<u64> = keys.iter().map(|&k| k as u64).collect();
            let order = stable_radix_order(&wide, bits).unwrap();
            assert_eq!(v, order, "n {n} bits {bits}");
            assert!(k.windows(2).all(|w| w[0] <= w[1]));
            let one = crate::with_threads(1, || stable_sort_pairs_u32(&keys, &values, bits))
                .unwrap()
                .unwrap();
            assert_eq!((k, v), one);
        }
        assert!(stable_sort_pairs_u32(&[8], &[0], 3).is_err());
        assert!(stable_sort_pairs_u32(&[1, 2], &[0], 3).is_err());
        assert!(stable_sort_pairs_u32(&[1], &[0], 33).is_err());
    }

    /// A small deterministic generator (xorshift64*).
    pub(crate) struct Rng(pub(crate) u64);

    impl Rng {
        pub(crate) fn next(&mut self) -> u64 {
            self.0 ^= self.0 >> 12;
            self.0 ^= self.0 << 25;
            self.0 ^= self.0 >> 27;
            self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
        }
    }

    /// `n` keys below `2^bits` from `distinct` values, in runs of 1-12 equal keys.
    pub(crate) fn runs_with_duplicates(n: usize, bits: u32, distinct: u64, seed: u64) -> Vec<u64> {
        let mut rng = Rng(seed | 1);
        let values: Vec<u64> = (0..distinct)
            .map(|_| {
                let v = rng.next();
                if bits == 64 {
                    v
                } else {
                    v & ((1u64 << bits) - 1)
                }
            })
            .collect();
        let mut keys = Vec::with_capacity(n);
        while keys.len() < n {
            let v = values[(rng.next() % distinct) as usize];
            let run = 1 + (rng.next() % 12) as usize;
            for _ in 0..run.min(n - keys.len()) {
                keys.push(v);
            }
        }
        keys
    }

    /// The oracle: the stable std sort of the indices by key.
    pub(crate) fn oracle(keys: &[u64]) -> Vec<u32> {
        let mut idx: Vec<u32> = (0..keys.len() as u32).collect();
        idx.sort_by_key(|&i| keys[i as usize]);
        idx
    }

    #[test]
    fn matches_the_stable_oracle_for_every_key_width() {
        for (bits, distinct) in [(1, 2), (8, 20), (13, 300), (32, 1000), (50, 5000), (64, 64)] {
            let keys = runs_with_duplicates(20_000, bits, distinct, bits as u64 * 7919);
            let order = stable_radix_order(&keys, bits).unwrap();
            assert_eq!(order, oracle(&keys), "{bits} bits");
        }
    }

    /// Digits that are the same for every key are skipped: keys whose low, middle or high
    /// bytes are constant (one light, a constant field) still sort stably, narrow and wide.
    #[test]
    fn constant_digits_are_skipped_without_changing_the_order() {
        let mut rng = Rng(0x5eed);
        for (bits, mask, fixed) in [
            (32u32, 0xffff_ff00u64, 0x5u64),
            (32, 0x00ff_ff00, 0x7700_0000),
            (24, 0x0000_00ff, 0x00ab_cd00),
            (64, 0xff00_0000_ffff_0000, 0x0012_3400_0000_0042),
            (48, 0x0000_0000_0000_ff0f, 0x0000_1200_0000_0000),
        ] {
            let keys: Vec<u64> = (0..50_000)
                .map(|_| (((rng.next() % 97) * 0x0101_0101_0101_0101) & mask) | fixed)
                .collect();
            assert_eq!(stable_radix_order(&keys, bits).unwrap(), oracle(&keys));
        }
        let same = vec![0x1234u64; 1000];
        assert_eq!(
            stable_radix_order(&same, 16).unwrap(),
            (0..1000).collect::<Vec<u32>>()
        );
    }

    /// Arrays past [`HYBRID_MIN`] take the top-digit partition: uniform keys (small buckets
    /// sorted in the cache), keys crowded into one top bucket larger than `HYBRID_MIN` (sorted
    /// by the same route again), a constant top digit (skipped), narrow and wide keys, with 1
    /// and 3 threads: the stable order every time.
    #[test]
    fn partition_by_the_top_digit_keeps_the_stable_order() {
        let n = 3 * HYBRID_MIN + 123;
        let mut rng = Rng(0xface);
        let uniform = runs_with_duplicates(n, 32, 200_000, 7);
        let crowded: Vec<u64> = (0..n)
            .map(|i| {
                let top = if i % 10 == 0 { rng.next() % 256 } else { 0x42 };
                top << 24 | (rng.next() % 5000)
            })
            .collect();
        let constant_top: Vec<u64> = (0..n).map(|_| 0x7f << 40 | (rng.next() % 70_000)).collect();
        let wide = runs_with_duplicates(n, 64, 100_000, 11);
        // Widths off the 8-bit digits, whose top digit overlaps the digits below it: 17 bits
        // (two lights' screen tiles), one light's keys crowded so that its bucket is past
        // HYBRID_MIN; 13, 19 and 41 bits uniform.
        let odd17: Vec<u64> = (0..n)
            .map(|i| {
                let light = u64::from(i % 7 == 0);
                light << 16 | (rng.next() % if i % 3 == 0 { 1 << 16 } else { 40 })
            })
            .collect();
        let odd13 = runs_with_duplicates(n, 13, 5_000, 5);
        // 19 bits: buckets keep 11 bits, sorted in one pass of an 11-bit digit.
        let odd19 = runs_with_duplicates(n, 19, 50_000, 17);
        let odd41 = runs_with_duplicates(n, 41, 100_000, 13);
        for (what, keys, bits) in [
            ("uniform", &uniform, 32),
            ("crowded", &crowded, 32),
            ("constant top", &constant_top, 48),
            ("wide", &wide, 64),
            ("17 bits", &odd17, 17),
            ("13 bits", &odd13, 13),
            ("19 bits", &odd19, 19),
            ("41 bits", &odd41, 41),
        ] {
            let want = oracle(keys);
            for threads in [1, 3] {
                let got = crate::with_threads(threads, || stable_radix_order(keys, bits))
                    .unwrap()
                    .unwrap();
                assert!(got == want, "{what}, {threads} threads");
            }
        }
        let values: Vec<u32> = (0..n as u32).collect();
        let keys32: Vec<u32> = crowded.iter().map(|&k| k as u32).collect();
        let (k, v) = stable_sort_pairs_u32(&keys32, &values, 32).unwrap();
        assert!(v == oracle(&crowded) && k.windows(2).all(|w| w[0] <= w[1]));
    }

    #[test]
    fn empty_single_and_zero_bit_inputs() {
        let mut stats = Stats::default();
        assert!(RadixSorter
            .sort(&Cpu, &vec![], 32, &mut stats)
            .unwrap()
            .is_empty());
        assert_eq!(
            RadixSorter.sort(&Cpu, &vec![7], 32, &mut stats).unwrap(),
            vec![0]
        );
        assert_eq!(stable_radix_order(&[0, 0, 0], 0).unwrap(), vec![0, 1, 2]);
        assert!(stats.timings_ms.contains_key("sorting"));
    }

    #[test]
    fn rejects_keys_wider_than_key_bits() {
        assert!(stable_radix_order(&[1, 1 << 20], 16).is_err());
        assert!(stable_radix_order(&[1], 65).is_err());
        assert!(stable_radix_order(&[u64::MAX], 64).is_ok());
    }

    #[test]
    fn same_order_for_one_and_three_threads() {
        let keys = runs_with_duplicates(100_000, 32, 2000, 42);
        let one = crate::with_threads(1, || stable_radix_order(&keys, 32))
            .unwrap()
            .unwrap();
        let three = crate::with_threads(3, || stable_radix_order(&keys, 32))
            .unwrap()
            .unwrap();
        assert_eq!(one, three);
        assert_eq!(one, oracle(&keys));
    }
}
