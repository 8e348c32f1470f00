//! Running `crsh` on bad input and checking what it did to the files around it.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Output;

use crate::common;

/// A scratch directory holding one case's input files.
pub struct Case {
    /// The directory `crsh` runs in.
    pub dir: PathBuf,
}

impl Case {
    /// A fresh, empty directory for case `name` of module `suite`.
    pub fn new(suite: &str, name: &str) -> Case {
        Case {
            dir: common::scratch(&format!("bad-input-{suite}"), name),
        }
    }

    /// Writes `text` to `name` (relative to the case directory), creating parent folders.
    pub fn file(&self, name: &str, text: impl AsRef<[u8]>) -> &Case {
        let p = self.dir.join(name);
        if let Some(parent) = p.parent() {
            std::fs::create_dir_all(parent).expect("create parent");
        }
        std::fs::write(&p, text).expect("write case file");
        self
    }

    /// The path of `name` inside the case directory.
    pub fn path(&self, name: &str) -> PathBuf {
        self.dir.join(name)
    }

    /// Runs `crsh args...`, which must fail with exit code `code` and print exactly one line
    /// on stderr starting with `error:` that contains every string in `mentions` (e.g. the
    /// file name and `:LINE:`). No file may change, vanish or appear. Returns the error line.
    pub fn expect_error(&self, args: &[&str], code: i32, mentions: &[&str]) -> String {
        let before = snapshot(&self.dir);
        let o = common::crsh(&self.dir, args);
        let err = common::text(&o.stderr);
        let ctx = || {
            format!(
                "crsh {args:?} in {}\nexit: {:?}\nstdout:\n{}\nstderr:\n{err}",
                self.dir.display(),
                o.status.code(),
                common::text(&o.stdout)
            )
        };
        assert!(!err.contains("panicked"), "panicked: {}", ctx());
        assert_eq!(o.status.code(), Some(code), "wrong exit code: {}", ctx());
        let error_lines: Vec<&str> = err.lines().filter(|l| l.contains("error:")).collect();
        assert_eq!(
            error_lines.len(),
            1,
            "want exactly one `error:` line: {}",
            ctx()
        );
        let line = error_lines[0];
        assert!(
            line.starts_with("error:"),
            "not an `error:` line: {}",
            ctx()
        );
        for m in mentions {
            assert!(line.contains(m), "the error line lacks `{m}`: {}", ctx());
        }
        let after = snapshot(&self.dir);
        assert_unchanged(&before, &after, true, &ctx());
        line.to_string()
    }

    /// Runs `crsh args...`, which must succeed without printing `error:`; files that existed
    /// before must be unchanged (new outputs may appear). Returns the output.
    pub fn expect_ok(&self, args: &[&str]) -> Output {
        let before = snapshot(&self.dir);
        let o = common::crsh(&self.dir, args);
        common::assert_ok(&o);
        let err = common::text(&o.stderr);
        assert!(
            !err.contains("error:"),
            "crsh {args:?} succeeded but printed `error:`:\n{err}"
        );
        let after = snapshot(&self.dir);
        assert_unchanged(&before, &after, false, &format!("crsh {args:?}"));
        o
    }
}

/// Every regular file under `dir` with its bytes.
pub fn snapshot(dir: &Path) -> BTreeMap<PathBuf, Vec<u8>> {
    let mut out = BTreeMap::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        let Ok(rd) = std::fs::read_dir(&d) else {
            continue;
        };
        for e in rd.flatten() {
            let p = e.path();
            let Ok(ft) = e.file_type() else { continue };
            if ft.is_dir() {
                stack.push(p);
            } else if ft.is_file() {
                out.insert(p.clone(), std::fs::read(&p).unwrap_or_default());
            }
        }
    }
    out
}

/// Asserts every file of `before` is in `after` with the same bytes, and, when
/// `no_new_files`, that `after` has no others.
pub fn assert_unchanged(
    before: &BTreeMap<PathBuf, Vec<u8>>,
    after: &BTreeMap<PathBuf, Vec<u8>>,
    no_new_files: bool,
    ctx: &str,
) {
    for (p, bytes) in before {
        match after.get(p) {
            None => panic!("{} vanished: {ctx}", p.display()),
            Some(b) => assert!(b == bytes, "{} changed: {ctx}", p.display()),
        }
    }
    if no_new_files {
        let new: Vec<_> = after.keys().filter(|p| !before.contains_key(*p)).collect();
        assert!(new.is_empty(), "a failed run left files {new:?}: {ctx}");
    }
}

impl Case {
    /// [`Case::expect_error`] with `crsh` started by `sh -c` after the shell commands
    /// `prelude` (e.g. `trap '' XFSZ; ulimit -f 1`), for failures that the system, not the
    /// input, causes.
    pub fn expect_error_after(
        &self,
        prelude: &str,
        args: &[&str],
        code: i32,
        mentions: &[&str],
    ) -> String {
        let before = snapshot(&self.dir);
        let o = std::process::Command::new("sh")
            .arg("-c")
            .arg(format!("{prelude}; exec \"$0\" \"$@\""))
            .arg(env!("CARGO_BIN_EXE_crsh"))
            .args(args)
            .current_dir(&self.dir)
            .env_remove("RAYON_NUM_THREADS")
            .output()
            .expect("run sh");
        let line = one_error_line(&o, code, mentions, &format!("{prelude}; crsh {args:?}"));
        let after = snapshot(&self.dir);
        assert_unchanged(&before, &after, true, &format!("{prelude}; crsh {args:?}"));
        line
    }

    /// [`Case::expect_ok`] with the environment variables `unset` removed.
    pub fn expect_ok_without_env(&self, args: &[&str], unset: &[&str]) -> Output {
        let before = snapshot(&self.dir);
        let o = common::crsh_with(&self.dir, args, unset);
        common::assert_ok(&o);
        let err = common::text(&o.stderr);
        assert!(
            !err.contains("error:"),
            "crsh {args:?} (without {unset:?}) succeeded but printed `error:`:\n{err}"
        );
        let after = snapshot(&self.dir);
        assert_unchanged(&before, &after, false, &format!("crsh {args:?}"));
        o
    }
}

/// Asserts that `o` failed with `code` (no panic) and printed exactly one line containing
/// `error:`, starting with it and containing every string of `mentions`; returns the line.
pub fn one_error_line(o: &Output, code: i32, mentions: &[&str], what: &str) -> String {
    let err = common::text(&o.stderr);
    let ctx = format!(
        "{what}\nexit: {:?}\nstdout:\n{}\nstderr:\n{err}",
        o.status.code(),
        common::text(&o.stdout)
    );
    assert!(!err.contains("panicked"), "panicked: {ctx}");
    assert_eq!(o.status.code(), Some(code), "wrong exit code: {ctx}");
    let lines: Vec<&str> = err.lines().filter(|l| l.contains("error:")).collect();
    assert_eq!(lines.len(), 1, "want exactly one `error:` line: {ctx}");
    assert!(
        lines[0].starts_with("error:"),
        "not an `error:` line: {ctx}"
    );
    for m in mentions {
        assert!(lines[0].contains(m), "the error line lacks `{m}`: {ctx}");
    }
    lines[0].to_string()
}
