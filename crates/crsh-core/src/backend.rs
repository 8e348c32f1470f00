//! The backend abstraction: where stage buffers live.

use bytemuck::Pod;

use crate::error::Result;

/// What the frame driver and the registry need to know of a backend's scene.
pub trait StageScene: Send + Sync + 'static {
    /// Triangles in the scene, degenerate ones included: the `M` of brute force's `N × M`
    /// tests, which the driver counts for every traced batch.
    fn triangle_count(&self) -> usize;
}

/// A place where stage buffers live and stages run: host memory for `crsh-cpu`, a wgpu device
/// for `crsh-wgpu`.
///
/// The frame driver only creates, concatenates and (for statistics and accuracy) downloads
/// buffers; everything else happens inside stages, which are implemented per backend. So a
/// stage sequence written once against `B: Backend` runs unchanged on either backend.
pub trait Backend: Send + Sync + 'static {
    /// A typed buffer of `T`: `Vec<T>` on the CPU, a device buffer on the GPU.
    type Buffer<T: Pod + Send + Sync>: Send + Sync;

    /// The scene as this backend's stages are built against: the host scene on the CPU, the
    /// scene uploaded to the device on wgpu. Stage constructors find it in their
    /// [`crate::StageContext`].
    type Scene: StageScene;

    /// Short backend name as it appears in stats (`cpu`, `wgpu`).
    fn name(&self) -> &'static str;

    /// A buffer holding a copy of `data`.
    fn upload<T: Pod + Send + Sync>(&self, data: &[T]) -> Result<Self::Buffer<T>>;

    /// A host copy of the buffer's contents.
    fn download<T: Pod + Send + Sync>(&self, buf: &Self::Buffer<T>) -> Result<Vec<T>>;

    /// Number of elements.
    fn len<T: Pod + Send + Sync>(&self, buf: &Self::Buffer<T>) -> usize;

    /// A buffer of `len` copies of `value`.
    fn filled<T: Pod + Send + Sync>(&self, len: usize, value: T) -> Result<Self::Buffer<T>> {
        self.upload(&vec![value; len])
    }

    /// The buffers' contents one after the other, in order.
    fn concat<T: Pod + Send + Sync>(&self, parts: Vec<Self::Buffer<T>>) -> Result<Self::Buffer<T>>;

    /// `buf` in the order `order`: element `i` of the result is `buf[order[i]]`. The default
    /// goes through host memory; `order` must index `buf`.
    ///
    /// # Errors
    /// [`crate::CoreError::InvalidInput`] when an index of `order` is outside `buf`.
    fn gather<T: Pod + Send + Sync>(
        &self,
        buf: &Self::Buffer<T>,
        order: &Self::Buffer<u32>,
    ) -> Result<Self::Buffer<T>> {
        let data = self.download(buf)?;
        let order = self.download(order)?;
        self.upload(&crate::order::gather(&data, &order)?)
    }

    /// The inverse of [`Backend::gather`]: element `order[i]` of the result is `buf[i]`, for
    /// `order` a permutation of `0..len(buf)`.
    ///
    /// # Errors
    /// [`crate::CoreError::InvalidInput`] when `order` is not such a permutation.
    fn scatter<T: Pod + Send + Sync>(
        &self,
        buf: &Self::Buffer<T>,
        order: &Self::Buffer<u32>,
    ) -> Result<Self::Buffer<T>> {
        let data = self.download(buf)?;
        let order = self.download(order)?;
        self.upload(&crate::order::scatter(&data, &order)?)
    }

    /// Blocks until all work submitted so far has finished (for wall-clock stage timings).
    fn sync(&self) -> Result<()> {
        Ok(())
    }

    /// Opens stage `key` (a [`crate::STAGE_TIMINGS`] name) for device-side timers: work the
    /// backend records until the matching [`Backend::end_stage`] is attributed to the innermost
    /// open stage. Stages nest (`compression` inside `sorting`). The CPU backend keeps no device
    /// timers and ignores it; [`crate::timed`] calls both.
    fn begin_stage(&self, _key: &str) {}

    /// Closes the innermost stage opened by [`Backend::begin_stage`] (after a [`Backend::sync`])
    /// and returns the device time, in milliseconds per stage key, of the work that completed
    /// since the last call: GPU timestamp queries on the wgpu backend, nothing on the CPU.
    fn end_stage(&self) -> Result<Vec<(String, f64)>> {
        Ok(Vec::new())
    }
}
