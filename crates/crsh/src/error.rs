//! The library's error type.

use std::path::PathBuf;

use crsh_core::CoreError;

/// Result with [`Error`].
pub type Result<T, E = Error> = std::result::Result<T, E>;

/// What can go wrong while configuring a pipeline, loading a scene, rendering or writing
/// output.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A pipeline description, a stage's parameters or a frame size were refused, or a stage
    /// failed while rendering ([`Error::is_usage`] tells which).
    #[error(transparent)]
    Core(#[from] CoreError),
    /// The scene could not be loaded.
    #[error(transparent)]
    Scene(#[from] crsh_scene::SceneError),
    /// The wgpu device failed (no adapter, a limit, a lost device).
    #[error("wgpu: {0}")]
    Gpu(#[from] crsh_wgpu::GpuError),
    /// An output file could not be written.
    #[error("writing {path}: {reason}")]
    Write {
        /// The file.
        path: PathBuf,
        /// What went wrong.
        reason: String,
    },
}

impl Error {
    /// Whether the error is the caller's description rather than a failure of the work: an
    /// unknown variant or parameter, a value out of range, stages that do not fit together, a
    /// variant the backend lacks. A command line reports these as usage errors.
    pub fn is_usage(&self) -> bool {
        matches!(
            self,
            Error::Core(
                CoreError::InvalidParam { .. }
                    | CoreError::UnknownVariant { .. }
                    | CoreError::Unsupported { .. }
                    | CoreError::Incompatible { .. }
            )
        )
    }
}
