//! Helpers shared by the workspace-level tests in `tests/`.
//!
//! ```
//! // A shared scene, or `None` after printing why the test that wanted it skips.
//! if let Some(manifest) = crsh_tests::shared_scene("cornell/cornell-box.toml") {
//!     assert!(manifest.is_file());
//! }
//! ```

#![warn(missing_docs)]

use std::path::PathBuf;

/// The shared scenes directory: `CRSH_SCENES` if set, else `../shared/scenes` next to the
/// workspace. `None` (after printing why) when it does not exist, so tests can skip.
pub fn scenes_dir() -> Option<PathBuf> {
    let dir = std::env::var_os("CRSH_SCENES")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/scenes"));
    if dir.is_dir() {
        Some(dir)
    } else {
        eprintln!(
            "SKIP: scenes directory {} not found (set CRSH_SCENES to run these checks)",
            dir.display()
        );
        None
    }
}

/// A manifest under the shared scenes directory, e.g. `cornell/cornell-mirror.toml`; `None`
/// (after printing why) when absent.
pub fn shared_scene(rel: &str) -> Option<PathBuf> {
    let p = scenes_dir()?.join(rel);
    if p.is_file() {
        Some(p)
    } else {
        eprintln!("SKIP: {} not found", p.display());
        None
    }
}

/// The files ending in `.{ext}` directly under `sub` of the shared scenes directory (e.g. every
/// `cornell/*.toml`), sorted by name; empty (after printing why) when the directory is absent.
pub fn shared_scenes_in(sub: &str, ext: &str) -> Vec<PathBuf> {
    let Some(dir) = scenes_dir().map(|d| d.join(sub)) else {
        return Vec::new();
    };
    let mut found: Vec<PathBuf> = match std::fs::read_dir(&dir) {
        Ok(entries) => entries
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.is_file() && p.extension().is_some_and(|x| x == ext))
            .collect(),
        Err(e) => {
            eprintln!("SKIP: cannot list {}: {e}", dir.display());
            return Vec::new();
        }
    };
    found.sort();
    if found.is_empty() {
        eprintln!("SKIP: no .{ext} files in {}", dir.display());
    }
    found
}
