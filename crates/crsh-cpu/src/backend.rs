//! The CPU backend: buffers are host vectors, stages run with rayon.

use bytemuck::Pod;
use crsh_core::{Backend, Result};

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
