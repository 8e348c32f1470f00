//! Output files: early checks of the paths (so a long render does not fail at the end, and
//! no output is written over an input or another output of the same run), text files and
//! stdout. Every file is written through [`crsh::output::write_atomic`] (PNG writing is the
//! library's, `crsh::output::write_png`).

use std::io::Write;
use std::path::{Path, PathBuf};

use crate::error::{CliError, CliResult};

/// Checks that `path` can be written later: its directory exists and it is not a directory.
/// `what` names the option in errors (`--out`, `--stats`).
pub fn check_writable(path: &Path, what: &str) -> CliResult<()> {
    if path.as_os_str().is_empty() {
        return Err(CliError::usage(format!("{what}: empty file name")));
    }
    if path.is_dir() {
        return Err(CliError::usage(format!(
            "{what} {}: is a directory",
            path.display()
        )));
    }
    match path.parent() {
        Some(dir) if !dir.as_os_str().is_empty() && !dir.is_dir() => Err(CliError::usage(format!(
            "{what} {}: directory {} does not exist",
            path.display(),
            dir.display()
        ))),
        _ => Ok(()),
    }
}

/// Checks `--out`: writable, and named `.png` (the only format written) or with no extension.
pub fn check_png_path(path: &Path) -> CliResult<()> {
    check_writable(path, "--out")?;
    match path.extension().and_then(|e| e.to_str()) {
        None => Ok(()),
        Some(e) if e.eq_ignore_ascii_case("png") => Ok(()),
        Some(e) => Err(CliError::usage(format!(
            "--out {}: crsh writes PNG only; name the file `.png` (got `.{e}`)",
            path.display()
        ))),
    }
}

/// Checks a JSON output (`--stats`, `--json`): writable, and named `.json` or with no
/// extension (so that `--stats scene.obj` cannot write over a scene).
pub fn check_json_path(path: &Path, what: &str) -> CliResult<()> {
    check_extension(path, what, "json", "JSON")
}

/// Checks a Markdown output (`crsh tables --out`): writable, named `.md` or with no extension.
pub fn check_md_path(path: &Path, what: &str) -> CliResult<()> {
    check_extension(path, what, "md", "Markdown")
}

fn check_extension(path: &Path, what: &str, ext: &str, format: &str) -> CliResult<()> {
    check_writable(path, what)?;
    match path.extension().and_then(|e| e.to_str()) {
        None => Ok(()),
        Some(e) if e.eq_ignore_ascii_case(ext) => Ok(()),
        Some(e) => Err(CliError::usage(format!(
            "{what} {}: crsh writes {format} there; name the file `.{ext}` (got `.{e}`)",
            path.display()
        ))),
    }
}

/// The files one run reads and writes, to refuse (as a usage error, before any work) a run
/// that would write over one of its inputs or write one file twice. Paths are compared
/// canonically (links and `..` resolved; a file that does not exist yet by its directory's
/// canonical path and its name).
#[derive(Debug, Default)]
pub struct RunFiles {
    inputs: Vec<(PathBuf, String)>,
    outputs: Vec<(PathBuf, String)>,
    output_dirs: Vec<(PathBuf, String)>,
}

/// `path` made absolute and canonical as far as it exists.
pub fn canonical(path: &Path) -> PathBuf {
    if let Ok(p) = std::fs::canonicalize(path) {
        return p;
    }
    let absolute = std::path::absolute(path).unwrap_or_else(|_| path.to_path_buf());
    match (absolute.parent(), absolute.file_name()) {
        (Some(dir), Some(name)) => canonical(dir).join(name),
        _ => absolute,
    }
}

impl RunFiles {
    /// No files yet.
    pub fn new() -> RunFiles {
        RunFiles::default()
    }

    /// An input file; `what` says what it is (`the plan`, `pipeline file`, ...).
    pub fn input(&mut self, path: &Path, what: impl Into<String>) {
        self.inputs.push((canonical(path), what.into()));
    }

    /// The files loading scene `spec` reads ([`crsh_scene::input_files`]).
    pub fn scene(&mut self, spec: &str) {
        for f in crsh_scene::input_files(spec) {
            self.input(&f, format!("read by scene `{spec}`"));
        }
    }

    /// The file pipeline `spec` names, when it is a file rather than a preset.
    pub fn pipeline(&mut self, registries: &crsh::Registries, spec: &str) {
        if registries.preset(spec).is_none() {
            self.input(Path::new(spec), "a pipeline file of this run");
        }
    }

    /// A file the run writes; `what` names the option (`--out`, `--stats`, `--out DIR's
    /// results.csv`).
    pub fn output(&mut self, path: &Path, what: impl Into<String>) {
        let what = format!("{} {}", what.into(), path.display());
        self.outputs.push((canonical(path), what));
    }

    /// A directory the run writes files into (and may remove stale ones from): no input may
    /// lie inside it.
    pub fn output_dir(&mut self, path: &Path, what: impl Into<String>) {
        let what = format!("{} {}", what.into(), path.display());
        self.output_dirs.push((canonical(path), what));
    }

    /// Refuses the run when an output is an input, two outputs are the same file, or an input
    /// lies in an output directory. Errors name both sides.
    pub fn check(&self) -> CliResult<()> {
        let mut inputs = std::collections::HashMap::new();
        for (p, is) in &self.inputs {
            inputs.entry(p).or_insert(is);
        }
        let mut outputs = std::collections::HashMap::new();
        for (out, what) in &self.outputs {
            if let Some(is) = inputs.get(out) {
                return Err(CliError::usage(format!(
                    "{what}: that file is an input of this run ({is}); refusing to write over it"
                )));
            }
            // A device (`/dev/null`) can take any number of outputs.
            let device = std::fs::metadata(out).is_ok_and(|m| !m.is_file() && !m.is_dir());
            if device {
                continue;
            }
            if let Some(other) = outputs.insert(out, what) {
                return Err(CliError::usage(format!(
                    "{what}: that file is also {other}; give each output its own file"
                )));
            }
        }
        for (dir, what) in &self.output_dirs {
            if let Some((p, is)) = self.inputs.iter().find(|(p, _)| p.starts_with(dir)) {
                return Err(CliError::usage(format!(
                    "{what}: holds {}, an input of this run ({is}); crsh writes and removes \
                     files there, so give another directory",
                    p.display()
                )));
            }
        }
        Ok(())
    }
}

/// Prints `text` on stdout. A closed pipe (`crsh pipelines | head`) is not an error; other
/// write failures are (`println!` would panic on both).
pub fn print_stdout(text: &str) -> CliResult<()> {
    let mut out = std::io::stdout().lock();
    match out.write_all(text.as_bytes()).and_then(|()| out.flush()) {
        Err(e) if e.kind() != std::io::ErrorKind::BrokenPipe => {
            Err(CliError::runtime(format!("writing to stdout: {e}")))
        }
        _ => Ok(()),
    }
}

/// Writes `text` to `path` ([`crsh::output::write_atomic`]: checked, flushed, and a failure
/// leaves the old file as it was).
pub fn write_text(path: &Path, text: &str) -> CliResult<()> {
    write_bytes(path, text.as_bytes())
}

/// Writes `bytes` to `path`, as [`write_text`].
pub fn write_bytes(path: &Path, bytes: &[u8]) -> CliResult<()> {
    crsh::output::write_atomic(path, |w| w.write_all(bytes))
        .map_err(|e| CliError::runtime(format!("writing {}: {e}", path.display())))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tmp(name: &str) -> std::path::PathBuf {
        let d = std::env::temp_dir().join(format!("crsh-cli-output-{}", std::process::id()));
        std::fs::create_dir_all(&d).unwrap();
        d.join(name)
    }

    #[test]
    fn path_checks() {
        assert!(check_png_path(Path::new("x.png")).is_ok());
        assert!(check_png_path(Path::new("x.PNG")).is_ok());
        assert!(check_png_path(Path::new("x")).is_ok());
        assert!(check_png_path(Path::new("x.jpg")).is_err());
        assert!(check_png_path(Path::new("/definitely/not/here/x.png")).is_err());
        assert!(check_writable(&std::env::temp_dir(), "--stats").is_err());
        assert!(check_writable(&tmp("s.json"), "--stats").is_ok());
        assert!(check_json_path(Path::new("s.json"), "--stats").is_ok());
        assert!(check_json_path(Path::new("s"), "--stats").is_ok());
        assert!(check_json_path(Path::new("s.obj"), "--stats").is_err());
        assert!(check_md_path(Path::new("t.md"), "--out").is_ok());
        assert!(check_md_path(Path::new("t.toml"), "--out").is_err());
    }

    #[test]
    fn outputs_over_inputs_or_each_other_are_refused() {
        let a = tmp("a.obj");
        std::fs::write(&a, "v 0 0 0\n").unwrap();
        let dir = a.parent().unwrap().to_path_buf();
        let mut f = RunFiles::new();
        f.input(&a, "the scene");
        f.output(&dir.join("new.png"), "--out");
        f.output(&dir.join("new.json"), "--stats");
        assert!(f.check().is_ok());
        // The same file by another spelling.
        f.output(&dir.join(".").join("a.obj"), "--stats");
        let e = f.check().unwrap_err().to_string();
        assert!(e.contains("is an input of this run (the scene)"), "{e}");
        let mut f = RunFiles::new();
        f.output(&dir.join("x"), "--out");
        f.output(&dir.join("x"), "--stats");
        let e = f.check().unwrap_err().to_string();
        assert!(
            e.starts_with("--stats ") && e.contains("is also --out"),
            "{e}"
        );
        let mut f = RunFiles::new();
        f.input(&a, "the plan");
        f.output_dir(&dir, "--out");
        let e = f.check().unwrap_err().to_string();
        assert!(e.contains("an input of this run (the plan)"), "{e}");
    }
}
