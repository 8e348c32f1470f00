//! Intersector variants (exact ray-triangle tests, §3.2.9).

pub mod brute;
pub mod brute64;
pub mod bvh;
pub mod bvh2;
pub mod embree;
pub mod grid;
pub mod kdtree;
