//! # crsh-wgpu
//!
//! The wgpu backend of crsh: the same stage sequence that runs on `crsh-cpu` runs here with
//! stage buffers in device memory.
//!
//! * [`adapter`]: adapter discovery ([`enumerate_adapters`], honouring `WGPU_BACKEND`,
//!   `WGPU_ADAPTER_NAME`, `WGPU_POWER_PREF`) and the shared device context [`GpuContext`],
//!   opened with the adapter's own limits and, where available, timestamp queries.
//! * [`backend`]: [`Wgpu`], the [`crsh_core::Backend`] whose `Buffer<T>` is a typed device
//!   buffer [`GpuBuffer<T>`]. The frame driver only uploads, downloads, fills and concatenates
//!   buffers; stages record their own compute passes on the context's device.
//! * [`kernels`]: compute kernels that stages build on, starting with the exclusive prefix sum
//!   ([`kernels::scan`]).
//! * One module per stage variant (`primary`, `raygen`, `hash`, `sort`, `hierarchy`,
//!   `traverse`, `intersect`, `shade`), each registering itself in
//!   [`Registry::<Wgpu>::builtin`](crsh_core::Registry::builtin) under its CPU twin's
//!   catalogue entry ([`registry`]).
//!
//! **Every kernel has a CPU twin** in the same module (e.g. [`exclusive_scan`] and
//! [`exclusive_scan_cpu`]) with bit-identical semantics (integer kernels use the same wrapping
//! arithmetic); the tests run both on the same inputs and require equal results, so a GPU
//! result can always be checked on the host.
//!
//! Without a GPU, Mesa's lavapipe (`apt-get install mesa-vulkan-drivers libvulkan1`) provides
//! a software Vulkan adapter: results are exact, timings are not representative.
//!
//! ```
//! use std::sync::Arc;
//! use crsh_core::{Backend, FrameOptions, FrameSize, Registry, StageContext};
//! use crsh_wgpu::{GpuScene, Wgpu};
//!
//! let Ok(device) = Wgpu::new() else {
//!     println!("no wgpu adapter on this machine");
//!     return;
//! };
//! let scene = Arc::new(crsh_scene::load("cornell-mirrors").unwrap());
//! let on_device = GpuScene::new(&device, &scene).unwrap();
//! let registry = Registry::<Wgpu>::builtin();
//! let cfg = registry.preset("bvh").unwrap();
//! let ctx = StageContext::new(&device, &on_device, FrameSize::new(16, 16).unwrap());
//! let opts = FrameOptions::default().with_max_depth(1);
//! let frame = registry.render(&ctx, &cfg, &opts, None, &mut |_| {}).unwrap();
//! assert_eq!(device.download(&frame.image).unwrap().len(), 16 * 16);
//! assert_eq!(frame.stats.stages["intersect"], "bvh");
//! ```

#![warn(missing_docs)]

pub mod adapter;
pub mod backend;
pub mod error;
pub mod hash;
pub mod hierarchy;
pub mod intersect;
pub mod kernel;
pub mod kernels;
pub mod primary;
pub mod raygen;
pub mod registry;
pub mod scene;
pub mod shade;
pub mod sort;
pub mod testing;
pub mod traverse;

pub use adapter::{enumerate_adapters, AdapterInfo, DeviceLimits, GpuContext};
pub use backend::{GpuBuffer, Wgpu};
pub use error::{GpuError, GpuResult};
pub use kernel::{Kernel, KernelBindings, Slot};
pub use kernels::scan::{exclusive_scan, exclusive_scan_cpu, exclusive_scan_in_place, ScanKernel};
pub use registry::{HostIntersector, GPU_TRIANGLE_TESTS};
pub use scene::GpuScene;
