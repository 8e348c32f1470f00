//! The bad-input suite: `crsh` run as an adversarial user would, on malformed scene files,
//! manifests, plans, command lines and output paths. Every case asserts the exit code, a
//! single `error:` line naming the file (and line, where there is one), no panic, and that no
//! file that existed before the run changed or vanished (compared byte for byte), nor any new
//! file appeared when the run failed.
//!
//! - `scene_files`: OBJ, MTL and manifest text.
//! - `outputs`: output paths (`--out`, `--stats`, ablate outputs), write failures, `ablate
//!   --compare` inputs, image sizes and fields of view, and `--set` values.

#[path = "../common/mod.rs"]
mod common;

mod harness;
mod outputs;
mod scene_files;
