//! What the benches share: finding the shared scenes.

use std::path::PathBuf;

/// The shared scene manifest `manifest` (`sponza/sponza.toml`) under `CRSH_SCENES`, else
/// `../shared/scenes` next to the workspace, if it is there.
pub fn shared_scene(manifest: &str) -> Option<PathBuf> {
    let dir = std::env::var_os("CRSH_SCENES")
        .map(PathBuf::from)
        .unwrap_or_else(|| {
            PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/scenes")
        });
    let path = dir.join(manifest);
    path.is_file().then_some(path)
}
