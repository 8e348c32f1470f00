//! The GPU radix sort against the CPU twin: the permutations are identical (a stable sort is
//! unique) for random keys at several key widths, many duplicates, all-equal, sorted and
//! reversed keys, empty and single inputs, and sizes spanning many blocks; bad keys are errors.
//!
//! Without an adapter every test prints `SKIP:` and passes, unless `CRSH_REQUIRE_GPU=1`.

use crsh_core::{Backend, Sorter, StageSpec, Stats};
use crsh_cpu::sort::radix::stable_radix_order as cpu_order;
use crsh_wgpu::sort::radix::{stable_radix_order, RadixSorter, RADIX_BLOCK};
use crsh_wgpu::{GpuScene, Wgpu};

struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }
}

fn masked(v: u64, bits: u32) -> u64 {
    if bits >= 64 {
        v
    } else {
        v & ((1u64 << bits) - 1)
    }
}

fn check(b: &Wgpu, keys: &[u64], bits: u32, what: &str) {
    let want = cpu_order(keys, bits).unwrap();
    let buf = b.upload(keys).unwrap();
    let got = b
        .download(&stable_radix_order(b.context(), &buf, bits).unwrap())
        .unwrap();
    assert!(
        got == want,
        "{what}: {} keys, {bits} bits: permutations differ",
        keys.len()
    );
}

#[test]
fn radix_order_matches_the_cpu() {
    let Some(b) = crsh_wgpu::testing::shared_backend("radix_order_matches_the_cpu") else {
        return;
    };
    let mut rng = Rng(0x9e3779b97f4a7c15);
    for bits in [1u32, 4, 7, 32, 33, 64] {
        for n in [
            0usize,
            1,
            5,
            RADIX_BLOCK - 1,
            RADIX_BLOCK + 1,
            5 * RADIX_BLOCK + 77,
        ] {
            let keys: Vec<u64> = (0..n).map(|_| masked(rng.next(), bits)).collect();
            check(&b, &keys, bits, "random");
        }
    }
    // Few distinct values (long runs of equal keys: stability decides the order).
    let distinct: Vec<u64> = (0..7).map(|_| masked(rng.next(), 40)).collect();
    let keys: Vec<u64> = (0..3000)
        .map(|_| distinct[(rng.next() % 7) as usize])
        .collect();
    check(&b, &keys, 40, "duplicates");
    check(&b, &vec![12345u64; 2500], 20, "all equal");
    let sorted: Vec<u64> = (0..2500u64).map(|i| i * 3).collect();
    check(&b, &sorted, 16, "sorted");
    let reversed: Vec<u64> = sorted.iter().rev().copied().collect();
    check(&b, &reversed, 16, "reversed");
    // key_bits 0: the identity.
    check(&b, &vec![0u64; 100], 0, "zero bits");
}

#[test]
fn radix_sorter_rejects_bad_keys_and_is_a_stage() {
    let Some(b) =
        crsh_wgpu::testing::shared_backend("radix_sorter_rejects_bad_keys_and_is_a_stage")
    else {
        return;
    };
    let keys = b.upload(&[1u64, 2, 1 << 20, 3]).unwrap();
    let e = stable_radix_order(b.context(), &keys, 20).unwrap_err();
    assert!(e.to_string().contains("0x100000"), "{e}");
    assert!(stable_radix_order(b.context(), &keys, 65).is_err());
    let scene = std::sync::Arc::new(crsh_scene::builtin::build("cornell-mirrors").unwrap());
    let g = GpuScene::new(&b, &scene).unwrap();
    let sorter = RadixSorter::new(&g, &StageSpec::new("radix")).unwrap();
    let order = sorter.sort(&b, &keys, 21, &mut Stats::default()).unwrap();
    assert_eq!(b.download(&order).unwrap(), vec![0, 1, 3, 2]);
}

/// Compression, the chunk sort and decompression give the CPU's chunks and permutation, bit
/// for bit, with long runs, no runs, and one run.
#[test]
fn compress_sorter_matches_the_cpu() {
    use crsh_wgpu::sort::compress::{compress, CompressSorter};
    let Some(b) = crsh_wgpu::testing::shared_backend("compress_sorter_matches_the_cpu") else {
        return;
    };
    let scene = std::sync::Arc::new(crsh_scene::builtin::build("cornell-mirrors").unwrap());
    let g = GpuScene::new(&b, &scene).unwrap();
    let sorter = CompressSorter::new(&g, &StageSpec::new("compress")).unwrap();
    let mut rng = Rng(77);
    let mut cases: Vec<(Vec<u64>, u32)> = Vec::new();
    for (n, bits, distinct) in [
        (0usize, 32u32, 1u64),
        (1, 32, 1),
        (100, 4, 3),
        (5000, 32, 40),
        (3000, 64, 3000),
        (4 * RADIX_BLOCK + 9, 50, 200),
    ] {
        let values: Vec<u64> = (0..distinct).map(|_| masked(rng.next(), bits)).collect();
        // Runs: each value repeated a random number of times.
        let mut keys = Vec::with_capacity(n);
        while keys.len() < n {
            let v = values[(rng.next() % distinct) as usize];
            for _ in 0..(1 + rng.next() % 9) {
                if keys.len() < n {
                    keys.push(v);
                }
            }
        }
        cases.push((keys, bits));
    }
    cases.push((vec![7u64; 2000], 3));
    for (keys, bits) in &cases {
        let cpu_chunks = crsh_cpu::sort::compress::compress(keys);
        let buf = b.upload(keys).unwrap();
        let chunks = compress(b.context(), &buf).unwrap();
        assert_eq!(b.download(&chunks.keys).unwrap(), cpu_chunks.keys);
        assert_eq!(b.download(&chunks.base).unwrap(), cpu_chunks.base);
        assert_eq!(b.download(&chunks.size).unwrap(), cpu_chunks.size);
        let mut stats = Stats::default();
        let order = b
            .download(&sorter.sort(&b, &buf, *bits, &mut stats).unwrap())
            .unwrap();
        assert!(
            order == cpu_order(keys, *bits).unwrap(),
            "{} keys, {bits} bits",
            keys.len()
        );
        if !keys.is_empty() {
            assert!(stats.timings_ms.contains_key("compression"));
            assert!(stats.timings_ms.contains_key("decompression"));
        }
    }
}
