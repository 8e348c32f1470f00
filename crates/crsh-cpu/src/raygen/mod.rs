//! Secondary ray generation variants (§3.2.3).

pub mod whitted;
