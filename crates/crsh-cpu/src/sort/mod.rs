//! Ray sorters (seed 000 §3.2.4-3.2.6): compress, radix sort, decompress.
