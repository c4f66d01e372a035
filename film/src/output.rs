//! Writing images: PNG (8-bit sRGB) or OpenEXR (linear float), chosen by extension, written
//! to a temporary file and renamed, so that a reader never sees half an image.

use std::path::{Path, PathBuf};

/// Image formats Tessera writes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Format {
    /// 8-bit sRGB PNG.
    Png,
    /// 32-bit float linear OpenEXR.
    Exr,
}

/// Why an image could not be written.
#[derive(Debug, thiserror::Error)]
pub enum OutputError {
    /// The extension names no format Tessera writes.
    #[error("cannot write {path}: unknown image extension (use .png or .exr)")]
    UnknownFormat {
        /// The path.
        path: PathBuf,
    },
    /// Encoding or I/O failed.
    #[error("cannot write {path}: {source}")]
    Write {
        /// The path.
        path: PathBuf,
        /// The cause.
        source: image::ImageError,
    },
    /// Renaming the finished file into place failed.
    #[error("cannot write {path}: {source}")]
    Io {
        /// The path.
        path: PathBuf,
        /// The cause.
        source: std::io::Error,
    },
}

impl Format {
    /// The format for a path's extension.
    pub fn from_path(path: &Path) -> Result<Format, OutputError> {
        match path.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase).as_deref() {
            Some("png") => Ok(Format::Png),
            Some("exr") => Ok(Format::Exr),
            _ => Err(OutputError::UnknownFormat { path: path.to_owned() }),
        }
    }
}

/// The sRGB transfer function of a linear value, quantised to 8 bits.
pub fn srgb8(linear: f32) -> u8 {
    let v = if linear.is_nan() { 0.0 } else { linear.clamp(0.0, 1.0) };
    let s = if v <= 0.003_130_8 { 12.92 * v } else { 1.055 * libm::powf(v, 1.0 / 2.4) - 0.055 };
    (s * 255.0 + 0.5) as u8
}

/// Writes `rgb` (linear, top row first, 3 floats a pixel) to `path`.
pub fn write_image(path: &Path, width: u32, height: u32, rgb: &[f32]) -> Result<(), OutputError> {
    let format = Format::from_path(path)?;
    let tmp = tmp_path(path);
    let result = match format {
        Format::Png => {
            let bytes: Vec<u8> = rgb.iter().map(|&v| srgb8(v)).collect();
            image::RgbImage::from_raw(width, height, bytes)
                .expect("buffer matches size")
                .save_with_format(&tmp, image::ImageFormat::Png)
        }
        Format::Exr => image::Rgb32FImage::from_raw(width, height, rgb.to_vec())
            .expect("buffer matches size")
            .save_with_format(&tmp, image::ImageFormat::OpenExr),
    };
    if let Err(source) = result {
        let _ = std::fs::remove_file(&tmp);
        return Err(OutputError::Write { path: path.to_owned(), source });
    }
    std::fs::rename(&tmp, path).map_err(|source| OutputError::Io { path: path.to_owned(), source })
}

fn tmp_path(path: &Path) -> PathBuf {
    let mut name = path.file_name().map(|n| n.to_os_string()).unwrap_or_default();
    name.push(format!(".tmp{}", std::process::id()));
    path.with_file_name(name)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn srgb_endpoints_and_midpoint() {
        assert_eq!(srgb8(0.0), 0);
        assert_eq!(srgb8(1.0), 255);
        assert_eq!(srgb8(2.0), 255);
        assert_eq!(srgb8(f32::NAN), 0);
        assert_eq!(srgb8(0.2), 124);
    }

    #[test]
    fn format_by_extension() {
        assert_eq!(Format::from_path(Path::new("a.PNG")).unwrap(), Format::Png);
        assert_eq!(Format::from_path(Path::new("a.exr")).unwrap(), Format::Exr);
        assert!(Format::from_path(Path::new("a.jpg")).is_err());
    }
}
