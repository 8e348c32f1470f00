//! crsh-wgpu (in progress)
