//! Image output: linear HDR frames to 8-bit sRGB PNG.

use std::path::Path;

use image::{ExtendedColorType, ImageFormat};

use crate::error::{Error, Result};

pub use crsh_core::metrics::to_rgba8;

/// Writes an 8-bit RGBA image (`width × height`, row-major, top row first) to `path` as PNG.
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
    image::save_buffer_with_format(
        path,
        rgba,
        width,
        height,
        ExtendedColorType::Rgba8,
        ImageFormat::Png,
    )
    .map_err(|e| write(e.to_string()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn png_roundtrip() {
        let dir = std::env::temp_dir().join(format!("crsh-output-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
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
    }
}
