//! Errors shared by stages and the frame driver.

/// Result with [`CoreError`].
pub type Result<T, E = CoreError> = std::result::Result<T, E>;

/// What can go wrong while configuring or running a pipeline.
#[derive(Debug, thiserror::Error)]
pub enum CoreError {
    /// The pipeline description names a stage variant that does not exist.
    #[error("unknown {stage} variant `{name}` (known: {known})")]
    UnknownVariant {
        /// Stage slot (`intersect`, `raygen`, ...).
        stage: String,
        /// The name asked for.
        name: String,
        /// Comma-separated list of the variants that exist.
        known: String,
    },
    /// A `--set` key or a parameter is not valid for the chosen variant.
    #[error("invalid parameter `{key}`: {reason}")]
    InvalidParam {
        /// `stage.param` key.
        key: String,
        /// Why it was rejected.
        reason: String,
    },
    /// A stage cannot answer this kind of query (e.g. a BVH asked for candidate pairs).
    #[error("{stage} `{variant}` does not support {what}")]
    Unsupported {
        /// Stage slot.
        stage: &'static str,
        /// Variant name.
        variant: String,
        /// What was asked.
        what: String,
    },
    /// The variant exists but this build of crsh left it out: it needs a cargo feature (and a
    /// system library) that was not enabled.
    #[error(
        "{stage} `{variant}` is not in this build: build crsh with the `{feature}` cargo \
         feature (`cargo build --release -p crsh-cli --features {feature}`), which needs {needs}"
    )]
    NotBuilt {
        /// Stage slot.
        stage: &'static str,
        /// Variant name.
        variant: String,
        /// The cargo feature that builds it.
        feature: &'static str,
        /// What the feature needs installed (e.g. the Debian package).
        needs: &'static str,
    },
    /// The filled slots of a pipeline do not fit together (a hash without a sorter, a
    /// hierarchy without a traverser, a whole-scene intersector under a hierarchy, ...).
    #[error("pipeline stages `{slots}` do not fit together: {reason}")]
    Incompatible {
        /// The slots involved, comma-separated in pipeline order.
        slots: String,
        /// What is wrong and how to fix it.
        reason: String,
    },
    /// Input that is out of range or inconsistent (sizes, NaN rays, ...).
    #[error("invalid input: {0}")]
    InvalidInput(String),
    /// A backend (device, allocation, transfer) failed.
    #[error("backend error: {0}")]
    Backend(String),
}

/// The message of a caught panic (`std::panic::catch_unwind`'s payload): the `&str` or
/// `String` it was raised with, else `unknown panic`. Tools that keep going after a stage
/// panics (ablate cells, stability-suite rows) report it with this.
pub fn panic_message(payload: &(dyn std::any::Any + Send)) -> String {
    payload
        .downcast_ref::<&str>()
        .map(|s| s.to_string())
        .or_else(|| payload.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "unknown panic".to_string())
}
