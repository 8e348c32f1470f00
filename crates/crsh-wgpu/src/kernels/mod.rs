//! Compute kernels. Each kernel module holds the WGSL (included with `include_str!`), the
//! host-side driver, and a CPU twin with identical semantics that the tests compare against.

pub mod scan;
