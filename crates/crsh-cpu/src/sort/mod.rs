//! Ray sorters (seed 000 §3.2.4-3.2.6): compress, radix sort, decompress.
//!
//! Both variants return the stable permutation that orders the rays by key (`order[i]` is the
//! index of the ray at position `i`; equal keys keep their input order), so they return the
//! same order for the same keys:
//! - [`compress`]: the thesis's compression-sorting-decompression (after Garanzha & Loop 2010):
//!   runs of equal keys become chunks, only the chunks are radix sorted.
//! - [`radix`]: every (key, index) pair radix sorted directly; also home of the stable radix
//!   sort both use ([`radix::stable_radix_order`]).

pub mod compress;
pub mod radix;

/// Sorting real ray batches of a built-in scene, both hashers × both sorters.
#[cfg(test)]
mod scene_batches {
    use std::sync::Arc;

    use crsh_core::{
        Hasher, PrimaryVisibility, RayGen, RayKind, Sorter, StageSpec, StageVariantInfo, Stats,
    };

    use crate::hash::{morton_octa::MortonOcta, thesis::ThesisHasher};
    use crate::primary::raster::Raster;
    use crate::raygen::whitted::Whitted;
    use crate::sort::compress::{compress, CompressSorter};
    use crate::sort::radix::RadixSorter;
    use crate::Cpu;

    fn defaults(info: &StageVariantInfo) -> StageSpec {
        info.defaults()
    }

    fn default_spec(name: &str) -> StageSpec {
        crsh_core::Registry::<Cpu>::builtin()
            .variants()
            .iter()
            .find(|i| i.name == name)
            .expect("variant in the registry")
            .defaults()
    }

    /// Both sorters give the stable order on real shadow and reflection batches of
    /// `cornell-mirrors`; prints the chunk counts of each hasher (run with `--nocapture`).
    #[test]
    fn real_batches_sort_stably_with_both_hashers() {
        let scene = Arc::new(crsh_scene::builtin::build("cornell-mirrors").unwrap());
        let raster = Raster::new(&scene, &default_spec("raster")).unwrap();
        let whitted = Whitted::new(&scene, &default_spec("whitted")).unwrap();
        let mut stats = Stats::default();
        let gbuf = raster.gbuffer(&Cpu, 160, 120, &mut stats).unwrap();
        let thesis = ThesisHasher::new(&scene, &defaults(&crate::hash::thesis::info())).unwrap();
        let morton = MortonOcta::new(&scene, &defaults(&crate::hash::morton_octa::info())).unwrap();
        // Coarser budgets: thesis 3·4 + 8 bounce bits and 16 shadow bits; morton 3·5 + 10.
        let thesis_coarse = ThesisHasher::from_parts(&scene, 4, 8, 16).unwrap();
        let morton_coarse = MortonOcta::with_bounds(scene.bounds, 5, 10);
        let hashers: [(&str, &dyn Hasher<Cpu>); 4] = [
            ("default", &thesis),
            ("default", &morton),
            ("coarse", &thesis_coarse),
            ("coarse", &morton_coarse),
        ];
        for kind in [RayKind::Shadow, RayKind::Reflection] {
            let rays = whitted.generate(&Cpu, &gbuf, kind, &mut stats).unwrap();
            assert!(!rays.is_empty(), "{kind:?} rays");
            for (budget, h) in hashers {
                let keys = h.hash(&Cpu, &rays, kind, &mut stats).unwrap();
                let bits = h.key_bits();
                let c = CompressSorter.sort(&Cpu, &keys, bits, &mut stats).unwrap();
                let r = RadixSorter.sort(&Cpu, &keys, bits, &mut stats).unwrap();
                let mut want: Vec<u32> = (0..keys.len() as u32).collect();
                want.sort_by_key(|&i| keys[i as usize]);
                assert_eq!(c, want);
                assert_eq!(r, want);
                let chunks = compress(&keys);
                let mut sorted = keys.clone();
                sorted.sort_unstable();
                sorted.dedup();
                println!(
                    "{:?} {} ({budget}, {} bits): {} rays, {} chunks, {} distinct keys",
                    kind,
                    h.name(),
                    bits,
                    rays.len(),
                    chunks.len(),
                    sorted.len()
                );
                assert!(chunks.len() <= rays.len() && chunks.len() >= sorted.len());
            }
        }
    }
}
