//! Helpers the `crsh` end-to-end tests share: scratch directories and running the binary.

#![allow(dead_code)] // each test binary uses its own subset

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// A fresh scratch directory for one test of one test binary (`suite`).
pub fn scratch(suite: &str, test: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("crsh-{suite}-{}-{test}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).expect("create scratch dir");
    d
}

/// Runs `crsh args...` in `dir` with rayon's default thread count.
pub fn crsh(dir: &Path, args: &[&str]) -> Output {
    crsh_with(dir, args, &[])
}

/// Runs `crsh args...` in `dir`, also removing the environment variables `unset`.
pub fn crsh_with(dir: &Path, args: &[&str], unset: &[&str]) -> Output {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_crsh"));
    cmd.args(args)
        .current_dir(dir)
        .env_remove("RAYON_NUM_THREADS");
    for v in unset {
        cmd.env_remove(v);
    }
    cmd.output().expect("run crsh")
}

/// Lossy UTF-8 of captured output.
pub fn text(b: &[u8]) -> String {
    String::from_utf8_lossy(b).into_owned()
}

/// Panics with both streams unless `o` succeeded.
pub fn assert_ok(o: &Output) {
    assert!(
        o.status.success(),
        "crsh failed ({:?})\nstdout:\n{}\nstderr:\n{}",
        o.status.code(),
        text(&o.stdout),
        text(&o.stderr)
    );
}
