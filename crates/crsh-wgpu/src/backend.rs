//! The wgpu [`Backend`]: stage buffers are device buffers.

use std::marker::PhantomData;
use std::mem::size_of;
use std::sync::mpsc::RecvTimeoutError;
use std::sync::Arc;
use std::time::Duration;

use bytemuck::Pod;
use crsh_core::{Backend, Result};

use crate::adapter::GpuContext;
use crate::error::{GpuError, GpuResult};

/// Smallest allocation in bytes. wgpu forbids zero-sized bindings, so an empty
/// [`GpuBuffer`] still owns this many (zeroed) bytes while its [`GpuBuffer::len`] is 0.
pub const MIN_BUFFER_BYTES: u64 = 16;

/// Usages of every stage buffer: bindable as storage, copyable both ways.
pub const STAGE_BUFFER_USAGE: wgpu::BufferUsages = wgpu::BufferUsages::STORAGE
    .union(wgpu::BufferUsages::COPY_SRC)
    .union(wgpu::BufferUsages::COPY_DST);

/// Re-polls (2 ms apart, plus the poll itself) before a map callback counts as lost.
const MAX_MAP_POLLS: u32 = 10_000;

/// Staging chunk used by [`GpuBuffer::filled`] to replicate a non-zero value on the device.
const FILL_CHUNK_BYTES: usize = 1 << 16;

/// A typed device buffer of `len` elements of `T` (usage [`STAGE_BUFFER_USAGE`]).
///
/// The allocation is padded up to a multiple of 4 bytes and to at least
/// [`MIN_BUFFER_BYTES`]; the padding is zero. Kernels that bind the buffer must take the
/// element count from [`GpuBuffer::len`], not from `arrayLength`.
#[derive(Debug)]
pub struct GpuBuffer<T> {
    buffer: wgpu::Buffer,
    len: usize,
    _elem: PhantomData<fn() -> T>,
}

/// `bytes` rounded up to the copy alignment (4) and to at least [`MIN_BUFFER_BYTES`].
pub fn padded_size(bytes: u64) -> u64 {
    bytes
        .div_ceil(wgpu::COPY_BUFFER_ALIGNMENT)
        .saturating_mul(wgpu::COPY_BUFFER_ALIGNMENT)
        .max(MIN_BUFFER_BYTES)
}

/// Creates a raw buffer of `bytes` (padded with [`padded_size`]) after checking the device's
/// `max_buffer_size`; device errors come back as [`GpuError::Device`].
pub fn create_raw_buffer(
    ctx: &GpuContext,
    label: &str,
    bytes: u64,
    usage: wgpu::BufferUsages,
    mapped_at_creation: bool,
) -> GpuResult<wgpu::Buffer> {
    let size = padded_size(bytes);
    let limit = ctx.max_buffer_bytes();
    if size > limit {
        return Err(GpuError::TooLarge {
            what: format!("buffer `{label}`"),
            bytes: size,
            limit_name: "max_buffer_size",
            limit,
        });
    }
    ctx.capture("create_buffer", || {
        ctx.device().create_buffer(&wgpu::BufferDescriptor {
            label: Some(label),
            size,
            usage,
            mapped_at_creation,
        })
    })
}

/// Copies the first `bytes` of `src` to the host through a staging buffer and waits for it.
pub fn read_buffer_bytes(ctx: &GpuContext, src: &wgpu::Buffer, bytes: u64) -> GpuResult<Vec<u8>> {
    if bytes == 0 {
        return Ok(Vec::new());
    }
    let copy = padded_size(bytes).min(src.size());
    let staging = create_raw_buffer(
        ctx,
        "crsh readback",
        copy,
        wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
        false,
    )?;
    let mut encoder = ctx
        .device()
        .create_command_encoder(&wgpu::CommandEncoderDescriptor {
            label: Some("crsh readback"),
        });
    encoder.copy_buffer_to_buffer(src, 0, &staging, 0, copy);
    ctx.capture("readback copy", || {
        ctx.queue().submit([encoder.finish()]);
    })?;
    map_read_bytes(ctx, &staging, bytes)
}

/// Maps a `MAP_READ` buffer whose copy has been submitted, waits, and returns its first
/// `bytes` bytes (then unmaps it).
pub fn map_read_bytes(ctx: &GpuContext, staging: &wgpu::Buffer, bytes: u64) -> GpuResult<Vec<u8>> {
    if bytes == 0 {
        return Ok(Vec::new());
    }
    let copy = padded_size(bytes).min(staging.size());
    if bytes > copy {
        return Err(GpuError::Map(format!(
            "asked for {bytes} bytes of a {copy}-byte buffer"
        )));
    }
    let (tx, rx) = std::sync::mpsc::channel();
    staging.map_async(wgpu::MapMode::Read, 0..copy, move |r| {
        // The receiver outlives the poll below; a failed send only means it gave up.
        let _ = tx.send(r);
    });
    ctx.wait()?;
    // Another thread's poll may have collected this callback and not yet invoked it when our
    // wait returns, so wait for the callback itself (re-polling); a callback dropped without
    // being called disconnects the channel.
    let mut polls = 0u32;
    let mapped = loop {
        match rx.recv_timeout(Duration::from_millis(2)) {
            Ok(r) => break r,
            Err(RecvTimeoutError::Timeout) if polls < MAX_MAP_POLLS => {
                polls += 1;
                ctx.wait()?;
            }
            Err(RecvTimeoutError::Timeout) => {
                return Err(GpuError::Map(format!(
                    "map callback not delivered after {MAX_MAP_POLLS} polls"
                )))
            }
            Err(RecvTimeoutError::Disconnected) => {
                return Err(GpuError::Map(
                    "map callback dropped without a result".into(),
                ))
            }
        }
    };
    mapped.map_err(|e| GpuError::Map(e.to_string()))?;
    let out = {
        let view = staging
            .get_mapped_range(0..copy)
            .map_err(|e| GpuError::Map(e.to_string()))?;
        view[..bytes as usize].to_vec()
    };
    staging.unmap();
    Ok(out)
}

fn byte_len_of<T>(len: usize, what: &str) -> GpuResult<u64> {
    (len as u64)
        .checked_mul(size_of::<T>() as u64)
        .ok_or_else(|| GpuError::TooLarge {
            what: what.to_string(),
            bytes: u64::MAX,
            limit_name: "max_buffer_size",
            limit: u64::MAX,
        })
}

impl<T: Pod> GpuBuffer<T> {
    /// A buffer of `len` zeroed elements (wgpu zero-initialises new buffers).
    pub fn zeroed(ctx: &GpuContext, label: &str, len: usize) -> GpuResult<Self> {
        let bytes = byte_len_of::<T>(len, label)?;
        let buffer = create_raw_buffer(ctx, label, bytes, STAGE_BUFFER_USAGE, false)?;
        Ok(GpuBuffer {
            buffer,
            len,
            _elem: PhantomData,
        })
    }

    /// A buffer holding a copy of `data` (written through a buffer mapped at creation).
    pub fn from_slice(ctx: &GpuContext, label: &str, data: &[T]) -> GpuResult<Self> {
        let bytes: &[u8] = bytemuck::cast_slice(data);
        if bytes.is_empty() {
            return Self::zeroed(ctx, label, data.len());
        }
        let buffer = create_raw_buffer(ctx, label, bytes.len() as u64, STAGE_BUFFER_USAGE, true)?;
        {
            let mut view = buffer
                .get_mapped_range_mut(..)
                .map_err(|e| GpuError::Map(e.to_string()))?;
            view.slice(..bytes.len()).copy_from_slice(bytes);
        }
        buffer.unmap();
        Ok(GpuBuffer {
            buffer,
            len: data.len(),
            _elem: PhantomData,
        })
    }

    /// A buffer of `len` copies of `value`. Zero values cost no transfer; other values are
    /// uploaded once as a chunk of at most 64 KiB and replicated with device copies when the
    /// element size is a multiple of 4 bytes.
    pub fn filled(ctx: &GpuContext, label: &str, len: usize, value: T) -> GpuResult<Self> {
        let elem = size_of::<T>();
        if len == 0 || elem == 0 || bytemuck::bytes_of(&value).iter().all(|&b| b == 0) {
            return Self::zeroed(ctx, label, len);
        }
        let chunk_len = (FILL_CHUNK_BYTES / elem).max(1).min(len);
        let chunk = Self::from_slice(ctx, "crsh fill chunk", &vec![value; chunk_len])?;
        if chunk_len == len {
            return Ok(GpuBuffer { len, ..chunk });
        }
        if !(elem as u64).is_multiple_of(wgpu::COPY_BUFFER_ALIGNMENT) {
            return Self::from_slice(ctx, label, &vec![value; len]);
        }
        let out = Self::zeroed(ctx, label, len)?;
        let chunk_bytes = chunk.byte_len();
        let total = out.byte_len();
        let mut encoder = ctx
            .device()
            .create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some(label) });
        let mut offset = 0;
        while offset < total {
            let n = chunk_bytes.min(total - offset);
            encoder.copy_buffer_to_buffer(&chunk.buffer, 0, &out.buffer, offset, n);
            offset += n;
        }
        ctx.capture("fill", || {
            ctx.queue().submit([encoder.finish()]);
        })?;
        Ok(out)
    }

    /// The buffers' contents one after the other. Element sizes that are multiples of 4 bytes
    /// (every crsh record) are copied on the device; other sizes go through the host because
    /// wgpu copies need 4-byte aligned offsets.
    pub fn concat(ctx: &GpuContext, label: &str, parts: Vec<Self>) -> GpuResult<Self> {
        let mut nonempty: Vec<Self> = parts.into_iter().filter(|p| p.len > 0).collect();
        let len = nonempty
            .iter()
            .try_fold(0usize, |acc, p| acc.checked_add(p.len))
            .ok_or_else(|| GpuError::TooLarge {
                what: label.to_string(),
                bytes: u64::MAX,
                limit_name: "max_buffer_size",
                limit: u64::MAX,
            })?;
        if nonempty.len() <= 1 {
            return match nonempty.pop() {
                Some(only) => Ok(only),
                None => Self::zeroed(ctx, label, 0),
            };
        }
        if !(size_of::<T>() as u64).is_multiple_of(wgpu::COPY_BUFFER_ALIGNMENT) {
            let mut host = Vec::with_capacity(len);
            for p in &nonempty {
                host.extend(p.to_vec(ctx)?);
            }
            return Self::from_slice(ctx, label, &host);
        }
        let out = Self::zeroed(ctx, label, len)?;
        let mut encoder = ctx
            .device()
            .create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some(label) });
        let mut offset = 0;
        for p in &nonempty {
            encoder.copy_buffer_to_buffer(&p.buffer, 0, &out.buffer, offset, p.byte_len());
            offset += p.byte_len();
        }
        ctx.capture("concat", || {
            ctx.queue().submit([encoder.finish()]);
        })?;
        Ok(out)
    }

    /// A host copy of the contents (copy to a staging buffer, map, wait).
    pub fn to_vec(&self, ctx: &GpuContext) -> GpuResult<Vec<T>> {
        if self.len == 0 || size_of::<T>() == 0 {
            return Ok(vec![T::zeroed(); self.len]);
        }
        let bytes = read_buffer_bytes(ctx, &self.buffer, self.byte_len())?;
        Ok(bytemuck::pod_collect_to_vec(&bytes))
    }

    /// A host copy of elements `range` (element sizes that are multiples of 4 bytes, as every
    /// crsh record is; others are read whole and cut).
    pub fn to_vec_range(
        &self,
        ctx: &GpuContext,
        range: std::ops::Range<usize>,
    ) -> GpuResult<Vec<T>> {
        let range =
            range.start.min(self.len)..range.end.min(self.len).max(range.start.min(self.len));
        let elem = size_of::<T>();
        if range.is_empty() || elem == 0 {
            return Ok(vec![T::zeroed(); range.len()]);
        }
        if !elem.is_multiple_of(4) {
            return Ok(self.to_vec(ctx)?[range].to_vec());
        }
        let offset = (range.start * elem) as u64;
        let bytes = (range.len() * elem) as u64;
        let staging = create_raw_buffer(
            ctx,
            "crsh readback",
            bytes,
            wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            false,
        )?;
        let mut encoder = ctx
            .device()
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("crsh readback range"),
            });
        encoder.copy_buffer_to_buffer(&self.buffer, offset, &staging, 0, bytes);
        ctx.capture("readback copy", || {
            ctx.queue().submit([encoder.finish()]);
        })?;
        let raw = map_read_bytes(ctx, &staging, bytes)?;
        Ok(bytemuck::pod_collect_to_vec(&raw))
    }

    /// Number of elements.
    pub fn len(&self) -> usize {
        self.len
    }

    /// True when the buffer holds no elements (it still owns [`MIN_BUFFER_BYTES`]).
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Bytes of payload: `len * size_of::<T>()` (the allocation may be larger).
    pub fn byte_len(&self) -> u64 {
        self.len as u64 * size_of::<T>() as u64
    }

    /// The underlying wgpu buffer (for binding it in kernels).
    pub fn buffer(&self) -> &wgpu::Buffer {
        &self.buffer
    }

    /// The whole allocation as a binding resource (always non-empty).
    pub fn binding(&self) -> wgpu::BindingResource<'_> {
        self.buffer.as_entire_binding()
    }
}

/// The wgpu backend: stage buffers are [`GpuBuffer`]s on one shared [`GpuContext`].
///
/// Cloning is cheap and shares the device.
#[derive(Clone, Debug)]
pub struct Wgpu {
    ctx: Arc<GpuContext>,
}

impl Wgpu {
    /// Opens the default adapter ([`GpuContext::new`]).
    pub fn new() -> GpuResult<Self> {
        Ok(Wgpu {
            ctx: Arc::new(GpuContext::new()?),
        })
    }

    /// A backend on an existing context (to share one device between backends and kernels).
    pub fn from_context(ctx: Arc<GpuContext>) -> Self {
        Wgpu { ctx }
    }

    /// The device context.
    pub fn context(&self) -> &Arc<GpuContext> {
        &self.ctx
    }
}

impl Backend for Wgpu {
    type Buffer<T: Pod + Send + Sync> = GpuBuffer<T>;
    type Scene = crate::scene::GpuScene;

    fn name(&self) -> &'static str {
        "wgpu"
    }

    fn upload<T: Pod + Send + Sync>(&self, data: &[T]) -> Result<GpuBuffer<T>> {
        Ok(GpuBuffer::from_slice(&self.ctx, "crsh stage buffer", data)?)
    }

    fn download<T: Pod + Send + Sync>(&self, buf: &GpuBuffer<T>) -> Result<Vec<T>> {
        Ok(buf.to_vec(&self.ctx)?)
    }

    fn len<T: Pod + Send + Sync>(&self, buf: &GpuBuffer<T>) -> usize {
        buf.len()
    }

    fn filled<T: Pod + Send + Sync>(&self, len: usize, value: T) -> Result<GpuBuffer<T>> {
        Ok(GpuBuffer::filled(
            &self.ctx,
            "crsh stage buffer",
            len,
            value,
        )?)
    }

    fn concat<T: Pod + Send + Sync>(&self, parts: Vec<GpuBuffer<T>>) -> Result<GpuBuffer<T>> {
        Ok(GpuBuffer::concat(&self.ctx, "crsh stage buffer", parts)?)
    }

    fn sync(&self) -> Result<()> {
        Ok(self.ctx.wait()?)
    }

    fn begin_stage(&self, key: &str) {
        self.ctx.begin_stage(key);
    }

    fn end_stage(&self) -> Result<Vec<(String, f64)>> {
        Ok(self.ctx.end_stage()?)
    }
}
