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
    /// A mesh file in a format this loader does not read (only OBJ/MTL today; PLY and glTF
    /// are planned).
    #[error("{context}: mesh '{}' is a .{format} file, and crsh reads .obj meshes only", path.display())]
    UnsupportedFormat {
        /// The manifest (and instance) that names the mesh.
        context: String,
        /// The mesh file.
        path: PathBuf,
        /// Its extension, in lower case.
        format: String,
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
