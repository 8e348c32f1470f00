//! Scene loading errors.

use std::path::PathBuf;

/// What can go wrong while loading or building a scene. Every variant names the file (and
/// line or mesh where known) so the user can find the problem.
#[derive(Debug, thiserror::Error)]
pub enum SceneError {
    /// A file could not be read.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The OS error.
        source: std::io::Error,
    },
    /// The scene is structurally invalid (bad index, NaN coordinate, empty, too large, ...).
    #[error("{context}: {message}")]
    Invalid {
        /// File and line, or mesh name, where the problem is.
        context: String,
        /// What is wrong.
        message: String,
    },
}

impl SceneError {
    /// An [`SceneError::Invalid`] with the given context.
    pub fn invalid(context: impl Into<String>, message: impl Into<String>) -> SceneError {
        SceneError::Invalid {
            context: context.into(),
            message: message.into(),
        }
    }
}
