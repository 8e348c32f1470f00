//! The CPU backend: buffers are host vectors, stages run with rayon.

use bytemuck::Pod;
use crsh_core::{Backend, Result};
use rayon::prelude::*;

/// The CPU backend. Stage buffers are `Vec<T>`; stages parallelise with rayon and produce the
/// same output whatever the thread count.
#[derive(Clone, Copy, Debug, Default)]
pub struct Cpu;

impl Backend for Cpu {
    type Buffer<T: Pod + Send + Sync> = Vec<T>;
    type Scene = crsh_scene::Scene;

    fn name(&self) -> &'static str {
        "cpu"
    }

    fn upload<T: Pod + Send + Sync>(&self, data: &[T]) -> Result<Vec<T>> {
        Ok(data.to_vec())
    }

    fn download<T: Pod + Send + Sync>(&self, buf: &Vec<T>) -> Result<Vec<T>> {
        Ok(buf.clone())
    }

    fn gather<T: Pod + Send + Sync>(&self, buf: &Vec<T>, order: &Vec<u32>) -> Result<Vec<T>> {
        // In parallel: a sorted order reads the batch nearly at random, so the gather is
        // bound by memory latency, which more threads hide.
        crsh_core::order::check_indices(order, buf.len())?;
        Ok(order.par_iter().map(|&i| buf[i as usize]).collect())
    }

    fn scatter<T: Pod + Send + Sync>(&self, buf: &Vec<T>, order: &Vec<u32>) -> Result<Vec<T>> {
        let inverse = crsh_core::order::inverse(order, buf.len())?;
        self.gather(buf, &inverse)
    }

    fn len<T: Pod + Send + Sync>(&self, buf: &Vec<T>) -> usize {
        buf.len()
    }

    fn filled<T: Pod + Send + Sync>(&self, len: usize, value: T) -> Result<Vec<T>> {
        Ok(vec![value; len])
    }

    fn concat<T: Pod + Send + Sync>(&self, parts: Vec<Vec<T>>) -> Result<Vec<T>> {
        Ok(parts.concat())
    }
}
