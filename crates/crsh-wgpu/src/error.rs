//! Errors of the wgpu backend.

use crsh_core::CoreError;

/// Result with [`GpuError`].
pub type GpuResult<T> = std::result::Result<T, GpuError>;

/// What can go wrong while finding a device or running work on it.
#[derive(Debug, thiserror::Error)]
pub enum GpuError {
    /// No adapter matched the request (no GPU and no software rasteriser such as lavapipe).
    #[error(
        "no wgpu adapter found (backends: {backends}): {reason}; without a GPU on Debian/Ubuntu, \
         `apt-get install mesa-vulkan-drivers libvulkan1` provides the lavapipe software adapter"
    )]
    NoAdapter {
        /// The backends that were searched (`WGPU_BACKEND` or all).
        backends: String,
        /// What wgpu said.
        reason: String,
    },
    /// `WGPU_ADAPTER_NAME` is set but no adapter's name contains it.
    #[error("WGPU_ADAPTER_NAME=`{wanted}` matches no adapter (found: {found})")]
    AdapterNameNotFound {
        /// The requested name fragment.
        wanted: String,
        /// Comma-separated names of the adapters that exist.
        found: String,
    },
    /// An environment variable of the backend has a value it does not take.
    #[error("{var}=`{value}` is not valid: expected {expected}")]
    BadEnv {
        /// The variable.
        var: &'static str,
        /// Its value.
        value: String,
        /// What it takes.
        expected: &'static str,
    },
    /// The adapter refused to create a device.
    #[error("request_device failed on `{adapter}`: {reason}")]
    RequestDevice {
        /// Adapter name.
        adapter: String,
        /// What wgpu said.
        reason: String,
    },
    /// A buffer would exceed one of the device's limits.
    #[error("{what}: {bytes} bytes exceeds the device limit `{limit_name}` = {limit} bytes")]
    TooLarge {
        /// What was being allocated or bound.
        what: String,
        /// Requested size in bytes.
        bytes: u64,
        /// The limit's name in `wgpu::Limits`.
        limit_name: &'static str,
        /// The limit's value.
        limit: u64,
    },
    /// A kernel needs more of a per-stage resource than the device allows.
    #[error(
        "{what} needs {needed} where the device limit `{limit_name}` is {limit}; no variant of \
         the kernel fits this device"
    )]
    Limit {
        /// The kernel (and entry point) that does not fit.
        what: String,
        /// What it needs.
        needed: u64,
        /// The limit's name in `wgpu::Limits`.
        limit_name: &'static str,
        /// The limit's value.
        limit: u64,
    },
    /// Mapping a buffer for reading failed.
    #[error("buffer map failed: {0}")]
    Map(String),
    /// Waiting for the device failed (device lost, timeout).
    #[error("device poll failed: {0}")]
    Poll(String),
    /// The device reported an error (out of memory, validation) for an operation.
    #[error("device error during {op}: {reason}")]
    Device {
        /// The operation that failed.
        op: String,
        /// What wgpu said.
        reason: String,
    },
}

impl From<GpuError> for CoreError {
    fn from(e: GpuError) -> Self {
        CoreError::Backend(e.to_string())
    }
}
