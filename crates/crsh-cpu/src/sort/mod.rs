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
