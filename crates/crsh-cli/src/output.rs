//! Output files: early checks of the paths (so a long render does not fail at the end), text
//! files and stdout. PNG writing is the library's (`crsh::output`).

use std::path::Path;

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

/// Prints `text` on stdout. A closed pipe (`crsh pipelines | head`) is not an error; other
/// write failures are (`println!` would panic on both).
pub fn print_stdout(text: &str) -> CliResult<()> {
    use std::io::Write;
    let mut out = std::io::stdout().lock();
    match out.write_all(text.as_bytes()).and_then(|()| out.flush()) {
        Err(e) if e.kind() != std::io::ErrorKind::BrokenPipe => {
            Err(CliError::runtime(format!("writing to stdout: {e}")))
        }
        _ => Ok(()),
    }
}

/// Writes `text` to `path`.
pub fn write_text(path: &Path, text: &str) -> CliResult<()> {
    std::fs::write(path, text)
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
    }
}
