//! Image output: linear HDR frames to 8-bit sRGB PNG, and [`write_atomic`], through which
//! every file crsh writes goes.

use std::io::{self, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

use image::codecs::png::PngEncoder;
use image::{ExtendedColorType, ImageEncoder};

use crate::error::{Error, Result};

pub use crsh_core::metrics::to_rgba8;

/// Writes the file at `path` with `write`, so that a failed write never leaves a truncated
/// file where a good one was: the bytes go to a temporary file beside the target (flushed and
/// synced, every error checked), which then replaces the target by a rename; on any error the
/// temporary file is removed and the target is untouched.
///
/// A symbolic link is followed (the file it points to is replaced). A target that exists and
/// is neither a regular file nor a directory (a device such as `/dev/null` or `/dev/full`, a
/// pipe) has no file to replace and no directory to hold a temporary file: it is written
/// directly, and a failure (e.g. `ENOSPC` on `/dev/full`) is still an error.
///
/// # Errors
/// The I/O error of creating, writing, flushing, syncing or renaming the file, or `write`'s
/// own; a directory at `path` is an error.
pub fn write_atomic<F>(path: &Path, write: F) -> io::Result<()>
where
    F: FnOnce(&mut dyn Write) -> io::Result<()>,
{
    let target = resolve_link(path);
    match std::fs::metadata(&target) {
        Ok(m) if m.is_dir() => {
            return Err(io::Error::new(
                io::ErrorKind::IsADirectory,
                "is a directory",
            ))
        }
        Ok(m) if !m.is_file() => {
            let file = std::fs::OpenOptions::new().write(true).open(&target)?;
            let mut w = io::BufWriter::new(file);
            write(&mut w)?;
            return w.flush();
        }
        _ => {}
    }
    let name = target
        .file_name()
        .ok_or_else(|| io::Error::new(io::ErrorKind::InvalidInput, "not a file name"))?;
    let dir = match target.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    static COUNTER: AtomicU64 = AtomicU64::new(0);
    // Short enough that a long target name still gives a valid temporary name.
    let stem: String = name.to_string_lossy().chars().take(64).collect();
    let tmp = dir.join(format!(
        ".{stem}.{}-{}.crsh-tmp",
        std::process::id(),
        COUNTER.fetch_add(1, Ordering::Relaxed)
    ));
    let file = std::fs::OpenOptions::new()
        .write(true)
        .create_new(true)
        .open(&tmp)?;
    let written = (|| {
        let mut w = io::BufWriter::new(file);
        write(&mut w)?;
        let file = w.into_inner().map_err(io::IntoInnerError::into_error)?;
        if let Ok(old) = std::fs::metadata(&target) {
            file.set_permissions(old.permissions())?;
        }
        file.sync_all()
    })();
    let done = written.and_then(|()| std::fs::rename(&tmp, &target));
    if done.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    done
}

/// `path`, or the file a symbolic link at `path` points to.
fn resolve_link(path: &Path) -> PathBuf {
    match std::fs::symlink_metadata(path) {
        Ok(m) if m.file_type().is_symlink() => {
            std::fs::canonicalize(path).unwrap_or_else(|_| path.to_path_buf())
        }
        _ => path.to_path_buf(),
    }
}

/// Writes an 8-bit RGBA image (`width × height`, row-major, top row first) to `path` as PNG,
/// through [`write_atomic`].
///
/// # Errors
/// [`Error::Write`] when `rgba` is not `width × height × 4` bytes or the file cannot be
/// written.
pub fn write_png(path: &Path, width: u32, height: u32, rgba: &[u8]) -> Result<()> {
    let write = |reason: String| Error::Write {
        path: path.to_path_buf(),
        reason,
    };
    if rgba.len() != width as usize * height as usize * 4 {
        return Err(write(format!(
            "an image of {} bytes is not {width}x{height} RGBA",
            rgba.len()
        )));
    }
    write_atomic(path, |w| {
        PngEncoder::new(w)
            .write_image(rgba, width, height, ExtendedColorType::Rgba8)
            .map_err(|e| match e {
                image::ImageError::IoError(e) => e,
                e => io::Error::other(e),
            })
    })
    .map_err(|e| write(e.to_string()))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn dir(name: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("crsh-output-{}-{name}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).unwrap();
        d
    }

    fn names(d: &Path) -> Vec<String> {
        let mut v: Vec<String> = std::fs::read_dir(d)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        v.sort();
        v
    }

    #[test]
    fn png_roundtrip() {
        let dir = dir("png");
        let p = dir.join("a.png");
        let px = [
            255u8, 0, 0, 255, 0, 255, 0, 255, 0, 0, 255, 255, 10, 20, 30, 255,
        ];
        write_png(&p, 2, 2, &px).unwrap();
        let img = image::open(&p).unwrap().to_rgba8();
        assert_eq!(img.dimensions(), (2, 2));
        assert_eq!(img.into_raw(), px.to_vec());
        assert!(matches!(write_png(&p, 3, 2, &px), Err(Error::Write { .. })));
        assert!(write_png(&dir.join("no/such/dir/a.png"), 2, 2, &px).is_err());
        assert_eq!(names(&dir), ["a.png"]);
    }

    #[test]
    fn a_failed_write_keeps_the_old_file_and_leaves_nothing() {
        let d = dir("atomic");
        let p = d.join("f.txt");
        write_atomic(&p, |w| w.write_all(b"good")).unwrap();
        let err = write_atomic(&p, |w| {
            w.write_all(b"half")?;
            Err(io::Error::other("disk on fire"))
        })
        .unwrap_err();
        assert_eq!(err.to_string(), "disk on fire");
        assert_eq!(std::fs::read(&p).unwrap(), b"good");
        assert_eq!(names(&d), ["f.txt"]);
        // A directory in the way is an error, and stays a directory.
        std::fs::create_dir(d.join("sub")).unwrap();
        let e = write_atomic(&d.join("sub"), |w| w.write_all(b"x")).unwrap_err();
        assert_eq!(e.kind(), io::ErrorKind::IsADirectory);
        assert!(d.join("sub").is_dir());
        // A missing directory: nothing is created.
        assert!(write_atomic(&d.join("no/f.txt"), |w| w.write_all(b"x")).is_err());
        assert_eq!(names(&d), ["f.txt", "sub"]);
    }

    #[cfg(unix)]
    #[test]
    fn devices_are_written_directly_and_their_errors_reported() {
        let null = Path::new("/dev/null");
        if null.exists() {
            write_atomic(null, |w| w.write_all(b"nothing")).unwrap();
        }
        let full = Path::new("/dev/full");
        if full.exists() {
            let e = write_atomic(full, |w| w.write_all(&[0u8; 100_000])).unwrap_err();
            assert_eq!(e.raw_os_error(), Some(28), "{e}"); // ENOSPC
        }
    }

    #[cfg(unix)]
    #[test]
    fn a_link_is_followed() {
        let d = dir("link");
        let real = d.join("real.txt");
        std::fs::write(&real, "old").unwrap();
        std::os::unix::fs::symlink(&real, d.join("link.txt")).unwrap();
        write_atomic(&d.join("link.txt"), |w| w.write_all(b"new")).unwrap();
        assert_eq!(std::fs::read(&real).unwrap(), b"new");
        assert!(std::fs::symlink_metadata(d.join("link.txt"))
            .unwrap()
            .file_type()
            .is_symlink());
    }
}
