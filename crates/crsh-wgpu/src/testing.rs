//! Test support shared by this crate's tests, the workspace tests and the CLI's: one device per
//! process, or a printed skip.

use std::sync::{Arc, OnceLock};

use crate::adapter::GpuContext;
use crate::backend::Wgpu;

/// Whether `CRSH_REQUIRE_GPU=1`: a missing adapter is then a failure rather than a skip.
pub fn gpu_required() -> bool {
    std::env::var("CRSH_REQUIRE_GPU").as_deref() == Ok("1")
}

/// The process-wide device for tests, or `None` after printing `SKIP: no wgpu adapter (...)`
/// naming `test`. Panics when [`gpu_required`] and no adapter can be opened.
pub fn shared_context(test: &str) -> Option<Arc<GpuContext>> {
    static CTX: OnceLock<Result<Arc<GpuContext>, String>> = OnceLock::new();
    let ctx = CTX.get_or_init(|| GpuContext::new().map(Arc::new).map_err(|e| e.to_string()));
    match ctx {
        Ok(ctx) => Some(Arc::clone(ctx)),
        Err(e) => {
            if gpu_required() {
                panic!("CRSH_REQUIRE_GPU=1 but no usable wgpu adapter for `{test}`: {e}");
            }
            println!("SKIP: no wgpu adapter ({e}) in `{test}`");
            None
        }
    }
}

/// [`shared_context`] as a [`Wgpu`] backend.
pub fn shared_backend(test: &str) -> Option<Wgpu> {
    shared_context(test).map(Wgpu::from_context)
}
