//! Shader variants (eq. 3.17-3.19).

pub mod phong;
