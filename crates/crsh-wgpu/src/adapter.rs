//! Adapter discovery and the device context that buffers and kernels share.
//!
//! Adapter choice follows wgpu's environment conventions so that a user can steer it without
//! code changes:
//!
//! * `WGPU_BACKEND` (`vulkan`, `gl`, `metal`, `dx12`, comma-separated) restricts the backends
//!   searched (wgpu's [`wgpu::Backends::from_env`], applied through
//!   [`wgpu::InstanceDescriptor::new_without_display_handle_from_env`], which also honours
//!   `WGPU_DEBUG` / `WGPU_VALIDATION`);
//! * `WGPU_ADAPTER_NAME` picks the first adapter whose name contains the given text
//!   (case-insensitive); unlike wgpu's helper, a name that matches nothing is an error, not a
//!   panic;
//! * `WGPU_POWER_PREF` (`low`, `high`, `none`) otherwise steers `request_adapter`; the default
//!   here is `high` (a discrete GPU wins over an integrated one or lavapipe);
//! * `CRSH_WGPU_LIMITS` (`adapter`, the default, or `webgpu`) picks the limits the device is
//!   opened with ([`DeviceLimits`]): `webgpu` runs every kernel as a WebGPU implementation
//!   that grants only the defaults would (8 storage buffers per stage, 128 MiB bindings).
//!
//! On OpenGL (`WGPU_BACKEND=gl`, Mesa's llvmpipe where no Vulkan driver is installed) wgpu
//! drives one GL context, and a call waits at most 6 s for it while another thread's
//! submission or wait holds it: use a [`GpuContext`] there from one thread at a time (the
//! renderer does; [`crate::testing`] serialises the tests that share one).

use std::any::{Any, TypeId};
use std::collections::HashMap;
use std::fmt;
use std::sync::{Arc, Mutex};

use serde::{Deserialize, Serialize};

use crate::error::{GpuError, GpuResult};

/// What a wgpu adapter says about itself, in a serialisable form (for `crsh devices`, stats
/// files and benchmark reports).
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct AdapterInfo {
    /// Adapter name, e.g. `llvmpipe (LLVM 15.0.6, 256 bits)` for lavapipe.
    pub name: String,
    /// Backend in lower case: `vulkan`, `gl`, `metal`, `dx12`, `webgpu`, `noop`.
    pub backend: String,
    /// Device type: `discrete-gpu`, `integrated-gpu`, `virtual-gpu`, `cpu` (software, such
    /// as lavapipe) or `other`.
    pub device_type: String,
    /// Driver name (may be empty on some backends).
    pub driver: String,
    /// Driver version and build information (may be empty).
    pub driver_info: String,
    /// PCI vendor id (0 when unknown).
    pub vendor: u32,
    /// PCI device id (0 when unknown).
    pub device: u32,
}

impl AdapterInfo {
    /// True for software adapters (lavapipe, llvmpipe, WARP): timings on them say nothing about
    /// GPU performance.
    pub fn is_software(&self) -> bool {
        self.device_type == "cpu"
    }
}

impl From<&wgpu::AdapterInfo> for AdapterInfo {
    fn from(info: &wgpu::AdapterInfo) -> Self {
        let device_type = match info.device_type {
            wgpu::DeviceType::DiscreteGpu => "discrete-gpu",
            wgpu::DeviceType::IntegratedGpu => "integrated-gpu",
            wgpu::DeviceType::VirtualGpu => "virtual-gpu",
            wgpu::DeviceType::Cpu => "cpu",
            wgpu::DeviceType::Other => "other",
        };
        AdapterInfo {
            name: info.name.clone(),
            backend: info.backend.to_str().to_string(),
            device_type: device_type.to_string(),
            driver: info.driver.clone(),
            driver_info: info.driver_info.clone(),
            vendor: info.vendor,
            device: info.device,
        }
    }
}

/// The backends searched: `WGPU_BACKEND` when set, otherwise all compiled-in backends.
pub fn backends_from_env() -> wgpu::Backends {
    wgpu::Backends::from_env().unwrap_or_else(wgpu::Backends::all)
}

fn new_instance() -> wgpu::Instance {
    wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle_from_env())
}

/// Every adapter visible to wgpu on this machine (restricted to `WGPU_BACKEND` when set).
///
/// An empty list means no GPU driver and no software Vulkan/GL implementation is installed.
pub fn enumerate_adapters() -> Vec<AdapterInfo> {
    let instance = new_instance();
    pollster::block_on(instance.enumerate_adapters(backends_from_env()))
        .iter()
        .map(|a| AdapterInfo::from(&a.get_info()))
        .collect()
}

/// The limits a device is opened with.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum DeviceLimits {
    /// The adapter's own: the most this machine allows (a discrete GPU grants storage
    /// bindings of several GiB and 1024-invocation workgroups; lavapipe 128 MiB bindings).
    #[default]
    Adapter,
    /// WebGPU's defaults (`wgpu::Limits::default()`, lowered where the adapter has less):
    /// what every WebGPU implementation grants, so that a kernel that runs here runs
    /// anywhere.
    WebGpu,
}

impl DeviceLimits {
    /// The environment variable that picks the limits of [`GpuContext::new`].
    pub const ENV: &'static str = "CRSH_WGPU_LIMITS";

    /// `CRSH_WGPU_LIMITS` (`adapter` or `webgpu`; unset or empty: `adapter`).
    pub fn from_env() -> GpuResult<DeviceLimits> {
        match std::env::var(Self::ENV) {
            Err(_) => Ok(DeviceLimits::Adapter),
            Ok(v) => match v.trim().to_ascii_lowercase().as_str() {
                "" | "adapter" => Ok(DeviceLimits::Adapter),
                "webgpu" | "default" => Ok(DeviceLimits::WebGpu),
                _ => Err(GpuError::BadEnv {
                    var: Self::ENV,
                    value: v,
                    expected: "`adapter` or `webgpu`",
                }),
            },
        }
    }

    /// The name in lower case (`adapter`, `webgpu`).
    pub fn name(self) -> &'static str {
        match self {
            DeviceLimits::Adapter => "adapter",
            DeviceLimits::WebGpu => "webgpu",
        }
    }

    /// The limits to request from an adapter whose own are `adapter`.
    pub fn request(self, adapter: &wgpu::Limits) -> wgpu::Limits {
        match self {
            DeviceLimits::Adapter => adapter.clone(),
            DeviceLimits::WebGpu => wgpu::Limits::default().or_worse_values_from(adapter),
        }
    }
}

/// Optional features requested when the adapter has them, never required.
///
/// `TIMESTAMP_QUERY` (and its in-encoder variant) lets later stages report GPU-side timings.
pub const OPTIONAL_FEATURES: wgpu::Features =
    wgpu::Features::TIMESTAMP_QUERY.union(wgpu::Features::TIMESTAMP_QUERY_INSIDE_ENCODERS);

/// Passes the profiler can time at once, over all threads (each takes two timestamp queries).
pub const MAX_TIMED_PASSES: u32 = 2048;

/// Bytes between two resolved query pairs (wgpu's `QUERY_RESOLVE_BUFFER_ALIGNMENT`).
const RESOLVE_STRIDE: u64 = 256;

/// One thread's open stages and timed passes.
#[derive(Default)]
struct ThreadTimers {
    /// Open stages, innermost last.
    stack: Vec<String>,
    /// The query pair and stage of each pass timed since this thread's last read.
    passes: Vec<(u32, String)>,
}

#[derive(Default)]
struct ProfilerState {
    /// Per thread: stages are opened and closed by the thread that runs them, so concurrent
    /// frames on one shared device (tests, a multi-threaded host) keep their timings apart.
    threads: HashMap<std::thread::ThreadId, ThreadTimers>,
    /// Query pairs not in use.
    free: Vec<u32>,
}

/// GPU timestamp queries around passes, attributed to the stage the beginning thread had open.
struct Profiler {
    queries: Option<wgpu::QuerySet>,
    resolve: wgpu::Buffer,
    state: Mutex<ProfilerState>,
}

impl Profiler {
    fn new(device: &wgpu::Device) -> Self {
        let timed = device.features().contains(wgpu::Features::TIMESTAMP_QUERY);
        let queries = timed.then(|| {
            device.create_query_set(&wgpu::QuerySetDescriptor {
                label: Some("crsh stage timestamps"),
                ty: wgpu::QueryType::Timestamp,
                count: 2 * MAX_TIMED_PASSES,
            })
        });
        let resolve = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("crsh timestamp resolve"),
            size: if timed {
                u64::from(MAX_TIMED_PASSES) * RESOLVE_STRIDE
            } else {
                8
            },
            usage: wgpu::BufferUsages::QUERY_RESOLVE | wgpu::BufferUsages::COPY_SRC,
            mapped_at_creation: false,
        });
        Profiler {
            queries,
            resolve,
            state: Mutex::new(ProfilerState {
                threads: HashMap::new(),
                free: (0..MAX_TIMED_PASSES).rev().collect(),
            }),
        }
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, ProfilerState> {
        // The state is plain maps and lists; a panic cannot leave them half-updated.
        self.state.lock().unwrap_or_else(|p| p.into_inner())
    }
}

/// Compiled kernels by type: the type's name and the kernel.
type KernelMap = HashMap<TypeId, (&'static str, Arc<dyn Any + Send + Sync>)>;
type KernelCache = Mutex<KernelMap>;

/// An open device: instance, adapter, device and queue, plus the limits and features that
/// were granted and a cache of compiled kernels.
///
/// Create one per process and share it (`Arc<GpuContext>`); wgpu objects are thread-safe.
pub struct GpuContext {
    instance: wgpu::Instance,
    adapter: wgpu::Adapter,
    device: wgpu::Device,
    queue: wgpu::Queue,
    info: AdapterInfo,
    limits: DeviceLimits,
    kernels: KernelCache,
    profiler: Profiler,
}

impl fmt::Debug for GpuContext {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("GpuContext")
            .field("info", &self.info)
            .field("features", &self.device.features())
            .finish_non_exhaustive()
    }
}

impl GpuContext {
    /// Opens the adapter chosen by the environment (see the module docs) with the limits
    /// `CRSH_WGPU_LIMITS` picks (the adapter's own by default, [`DeviceLimits`]) and
    /// [`OPTIONAL_FEATURES`] where available.
    ///
    /// Fails with [`GpuError::NoAdapter`] when no adapter exists.
    pub fn new() -> GpuResult<Self> {
        Self::with_limits(DeviceLimits::from_env()?)
    }

    /// [`GpuContext::new`] with the limits `limits` whatever the environment says.
    pub fn with_limits(limits: DeviceLimits) -> GpuResult<Self> {
        let instance = new_instance();
        let backends = backends_from_env();
        let adapter = match std::env::var("WGPU_ADAPTER_NAME") {
            Ok(wanted) if !wanted.trim().is_empty() => {
                let adapters = pollster::block_on(instance.enumerate_adapters(backends));
                let needle = wanted.to_lowercase();
                let names: Vec<String> = adapters.iter().map(|a| a.get_info().name).collect();
                match adapters
                    .into_iter()
                    .find(|a| a.get_info().name.to_lowercase().contains(&needle))
                {
                    Some(a) => a,
                    None if names.is_empty() => {
                        return Err(GpuError::NoAdapter {
                            backends: format!("{backends:?}"),
                            reason: "enumerate_adapters returned none".into(),
                        })
                    }
                    None => {
                        return Err(GpuError::AdapterNameNotFound {
                            wanted,
                            found: names.join(", "),
                        })
                    }
                }
            }
            _ => {
                let options = wgpu::RequestAdapterOptions {
                    power_preference: wgpu::PowerPreference::from_env()
                        .unwrap_or(wgpu::PowerPreference::HighPerformance),
                    ..Default::default()
                };
                pollster::block_on(instance.request_adapter(&options)).map_err(|e| {
                    GpuError::NoAdapter {
                        backends: format!("{backends:?}"),
                        reason: e.to_string(),
                    }
                })?
            }
        };
        Self::from_adapter_with_limits(instance, adapter, limits)
    }

    /// Opens a device with the adapter's own limits on a given adapter (for callers that pick
    /// adapters themselves).
    pub fn from_adapter(instance: wgpu::Instance, adapter: wgpu::Adapter) -> GpuResult<Self> {
        Self::from_adapter_with_limits(instance, adapter, DeviceLimits::Adapter)
    }

    /// Opens a device with `limits` on a given adapter.
    pub fn from_adapter_with_limits(
        instance: wgpu::Instance,
        adapter: wgpu::Adapter,
        limits: DeviceLimits,
    ) -> GpuResult<Self> {
        let wgpu_info = adapter.get_info();
        let info = AdapterInfo::from(&wgpu_info);
        let desc = wgpu::DeviceDescriptor {
            label: Some("crsh"),
            required_features: adapter.features() & OPTIONAL_FEATURES,
            required_limits: limits.request(&adapter.limits()),
            ..Default::default()
        };
        let (device, queue) = pollster::block_on(adapter.request_device(&desc)).map_err(|e| {
            GpuError::RequestDevice {
                adapter: info.name.clone(),
                reason: e.to_string(),
            }
        })?;
        let profiler = Profiler::new(&device);
        Ok(GpuContext {
            instance,
            adapter,
            device,
            queue,
            info,
            limits,
            kernels: Mutex::new(HashMap::new()),
            profiler,
        })
    }

    /// The wgpu instance the adapter came from.
    pub fn instance(&self) -> &wgpu::Instance {
        &self.instance
    }

    /// The adapter.
    pub fn adapter(&self) -> &wgpu::Adapter {
        &self.adapter
    }

    /// The logical device.
    pub fn device(&self) -> &wgpu::Device {
        &self.device
    }

    /// The device's queue.
    pub fn queue(&self) -> &wgpu::Queue {
        &self.queue
    }

    /// What the adapter says about itself.
    pub fn info(&self) -> &AdapterInfo {
        &self.info
    }

    /// The limits granted to the device ([`GpuContext::device_limits`] says which).
    pub fn limits(&self) -> wgpu::Limits {
        self.device.limits()
    }

    /// Which limits the device was opened with.
    pub fn device_limits(&self) -> DeviceLimits {
        self.limits
    }

    /// The type names of the kernels compiled on this device so far, sorted (what a test
    /// checks its coverage of the backend's kernels with).
    pub fn compiled_kernels(&self) -> Vec<&'static str> {
        let mut names: Vec<&'static str> = self.lock_kernels().values().map(|(n, _)| *n).collect();
        names.sort_unstable();
        names
    }

    /// The features granted to the device (a subset of [`OPTIONAL_FEATURES`]).
    pub fn features(&self) -> wgpu::Features {
        self.device.features()
    }

    /// Largest storage buffer binding in bytes (`max_storage_buffer_binding_size`): the largest
    /// buffer a kernel can read or write as one array.
    pub fn max_storage_binding_bytes(&self) -> u64 {
        self.device.limits().max_storage_buffer_binding_size
    }

    /// Largest buffer in bytes (`max_buffer_size`).
    pub fn max_buffer_bytes(&self) -> u64 {
        self.device.limits().max_buffer_size
    }

    /// Largest workgroup count per dispatch dimension.
    pub fn max_workgroups_per_dimension(&self) -> u32 {
        self.device.limits().max_compute_workgroups_per_dimension
    }

    /// Whether GPU timestamp queries are available (`TIMESTAMP_QUERY` was granted).
    pub fn has_timestamp_query(&self) -> bool {
        self.device
            .features()
            .contains(wgpu::Features::TIMESTAMP_QUERY)
    }

    /// Nanoseconds per timestamp tick (meaningful when [`Self::has_timestamp_query`]).
    pub fn timestamp_period_ns(&self) -> f32 {
        self.queue.get_timestamp_period()
    }

    /// Blocks until all submitted work has finished.
    pub fn wait(&self) -> GpuResult<()> {
        self.device
            .poll(wgpu::PollType::wait_indefinitely())
            .map(|_| ())
            .map_err(|e| GpuError::Poll(e.to_string()))
    }

    /// Fails with [`GpuError::TooLarge`] when `bytes` cannot be bound as one storage buffer.
    pub fn check_storage_binding(&self, what: &str, bytes: u64) -> GpuResult<()> {
        let limit = self.max_storage_binding_bytes();
        if bytes > limit {
            return Err(GpuError::TooLarge {
                what: what.to_string(),
                bytes,
                limit_name: "max_storage_buffer_binding_size",
                limit,
            });
        }
        Ok(())
    }

    /// Runs `f` (device calls: creating resources, submitting work) and turns any validation
    /// or out-of-memory error the device reports for it into [`GpuError::Device`] instead of
    /// wgpu's default uncaptured-error panic.
    pub fn capture<R>(&self, op: &str, f: impl FnOnce() -> R) -> GpuResult<R> {
        let oom = self.device.push_error_scope(wgpu::ErrorFilter::OutOfMemory);
        let validation = self.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let r = f();
        let validation = pollster::block_on(validation.pop());
        let oom = pollster::block_on(oom.pop());
        match validation.or(oom) {
            Some(e) => Err(GpuError::Device {
                op: op.to_string(),
                reason: e.to_string(),
            }),
            None => Ok(r),
        }
    }

    /// The kernel of type `K` compiled for this device, built with `init` on first use and
    /// shared afterwards (pipelines are expensive to compile, especially on lavapipe).
    pub fn kernel<K: Any + Send + Sync>(
        &self,
        init: impl FnOnce(&GpuContext) -> GpuResult<K>,
    ) -> GpuResult<Arc<K>> {
        let id = TypeId::of::<K>();
        if let Some((_, k)) = self.lock_kernels().get(&id) {
            if let Ok(k) = Arc::clone(k).downcast::<K>() {
                return Ok(k);
            }
        }
        // Compile outside the lock; if two threads race, the first insert wins.
        let built: Arc<dyn Any + Send + Sync> = Arc::new(init(self)?);
        let stored = Arc::clone(
            &self
                .lock_kernels()
                .entry(id)
                .or_insert((std::any::type_name::<K>(), built))
                .1,
        );
        stored.downcast::<K>().map_err(|_| GpuError::Device {
            op: "kernel cache".into(),
            reason: "type mismatch in kernel cache".into(),
        })
    }

    /// Opens stage `key` for the timestamp profiler on the calling thread: compute and render
    /// passes this thread begins with [`GpuContext::compute_pass`] /
    /// [`GpuContext::render_timestamps`] until the matching [`GpuContext::end_stage`] are timed
    /// and attributed to its innermost open stage.
    pub fn begin_stage(&self, key: &str) {
        let mut state = self.profiler.lock();
        let t = state
            .threads
            .entry(std::thread::current().id())
            .or_default();
        t.stack.push(key.to_string());
    }

    /// Closes the calling thread's innermost stage and reads back every timestamp pair this
    /// thread wrote since its last read: milliseconds per stage key. Call it after waiting for
    /// the device, and submit a stage's encoders before opening a nested stage (a pass still in
    /// an unsubmitted encoder has no timestamps yet). Without timestamp queries it returns
    /// nothing.
    pub fn end_stage(&self) -> GpuResult<Vec<(String, f64)>> {
        let id = std::thread::current().id();
        let mut state = self.profiler.lock();
        let Some(t) = state.threads.get_mut(&id) else {
            return Ok(Vec::new());
        };
        t.stack.pop();
        let passes = std::mem::take(&mut t.passes);
        if t.stack.is_empty() {
            state.threads.remove(&id);
        }
        drop(state);
        if passes.is_empty() {
            return Ok(Vec::new());
        }
        let read = self.read_timestamps(&passes);
        let mut state = self.profiler.lock();
        state.free.extend(passes.iter().map(|(pair, _)| *pair));
        read
    }

    fn read_timestamps(&self, passes: &[(u32, String)]) -> GpuResult<Vec<(String, f64)>> {
        let Some(queries) = &self.profiler.queries else {
            return Ok(Vec::new());
        };
        let bytes = passes.len() as u64 * 16;
        let staging = crate::backend::create_raw_buffer(
            self,
            "crsh timestamps readback",
            bytes,
            wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            false,
        )?;
        let mut encoder = self
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("crsh timestamps"),
            });
        for (i, (pair, _)) in passes.iter().enumerate() {
            let at = u64::from(*pair) * RESOLVE_STRIDE;
            encoder.resolve_query_set(queries, 2 * pair..2 * pair + 2, &self.profiler.resolve, at);
            encoder.copy_buffer_to_buffer(&self.profiler.resolve, at, &staging, i as u64 * 16, 16);
        }
        self.capture("resolve timestamps", || {
            self.queue.submit([encoder.finish()]);
        })?;
        let raw = crate::backend::map_read_bytes(self, &staging, bytes)?;
        let ticks: Vec<u64> = bytemuck::pod_collect_to_vec(&raw);
        let period_ms = f64::from(self.timestamp_period_ns()) * 1e-6;
        Ok(passes
            .iter()
            .zip(ticks.chunks_exact(2))
            .map(|((_, label), t)| (label.clone(), t[1].saturating_sub(t[0]) as f64 * period_ms))
            .collect())
    }

    /// Timestamp writes for the next pass of the calling thread's innermost open stage: `None`
    /// when it has no open stage, the adapter has no timestamp queries, or all
    /// [`MAX_TIMED_PASSES`] query pairs are in use (the pass then runs untimed).
    fn next_timestamps(&self) -> Option<(&wgpu::QuerySet, u32)> {
        let queries = self.profiler.queries.as_ref()?;
        let mut state = self.profiler.lock();
        let id = std::thread::current().id();
        let stage = state.threads.get(&id)?.stack.last()?.clone();
        let pair = state.free.pop()?;
        state
            .threads
            .get_mut(&id)
            .expect("present above")
            .passes
            .push((pair, stage));
        Some((queries, 2 * pair))
    }

    /// Begins a compute pass on `encoder`, timed for the innermost open stage (see
    /// [`GpuContext::begin_stage`]). Every kernel of the backend begins its passes here.
    pub fn compute_pass<'e>(
        &self,
        encoder: &'e mut wgpu::CommandEncoder,
        label: &str,
    ) -> wgpu::ComputePass<'e> {
        let timestamp_writes =
            self.next_timestamps()
                .map(|(query_set, first)| wgpu::ComputePassTimestampWrites {
                    query_set,
                    beginning_of_pass_write_index: Some(first),
                    end_of_pass_write_index: Some(first + 1),
                });
        encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some(label),
            timestamp_writes,
        })
    }

    /// Timestamp writes for a render pass, timed for the innermost open stage like
    /// [`GpuContext::compute_pass`].
    pub fn render_timestamps(&self) -> Option<wgpu::RenderPassTimestampWrites<'_>> {
        self.next_timestamps()
            .map(|(query_set, first)| wgpu::RenderPassTimestampWrites {
                query_set,
                beginning_of_pass_write_index: Some(first),
                end_of_pass_write_index: Some(first + 1),
            })
    }

    fn lock_kernels(&self) -> std::sync::MutexGuard<'_, KernelMap> {
        // A panic while holding the lock cannot leave the map inconsistent (insert is atomic).
        self.kernels.lock().unwrap_or_else(|p| p.into_inner())
    }
}
