//! Primary visibility variants (stage 1 of seed 000, §3.1).

pub mod raster;
pub mod raycast;
