//! One OpenEXR file holding the image and its AOV layers, with the `exr` crate.
//!
//! A single part whose channels are named by OpenEXR's layer convention (`layer.channel`,
//! the part before the last dot naming the layer), which every compositor and
//! `exrheader`/`oiiotool` read; multi-part files are newer and less widely supported:
//! - `R`, `G`, `B`: the image (linear), the default layer;
//! - `albedo.R`, `albedo.G`, `albedo.B`: first-hit reflectance;
//! - `normal.X`, `normal.Y`, `normal.Z`: first-hit world-space shading normal (the layer
//!   named as `--aov` names it; X/Y/Z mark a vector, not a colour);
//! - `Z`: camera-ray distance to the first hit, OpenEXR's standard depth channel
//!   (infinite where nothing was hit).
//!
//! 32-bit float, ZIP-compressed (lossless), written to a temporary file and renamed.

use std::path::Path;

use exr::prelude::{
    AnyChannel, AnyChannels, Encoding, FlatSamples, Image, Layer, LayerAttributes, SmallVec, WritableImage,
};

use crate::aov::Resolved;
use crate::output::{Format, OutputError};

/// Why a layered image could not be written.
#[derive(Debug, thiserror::Error)]
pub enum LayersError {
    /// The path does not end in `.exr`.
    #[error("cannot write {path}: AOV layers need an OpenEXR output (.exr), not {format}")]
    NotExr {
        /// The path.
        path: String,
        /// What it names.
        format: &'static str,
    },
    /// The path names no known format.
    #[error(transparent)]
    Output(#[from] OutputError),
    /// Encoding or I/O failed.
    #[error("cannot write {path}: {source}")]
    Write {
        /// The path.
        path: String,
        /// The cause.
        source: exr::error::Error,
    },
    /// Renaming the finished file into place failed.
    #[error("cannot write {path}: {source}")]
    Io {
        /// The path.
        path: String,
        /// The cause.
        source: std::io::Error,
    },
    /// A layer's length does not fit the image size.
    #[error("cannot write {path}: the {layer} layer has {got} values, expected {expected}")]
    Size {
        /// The path.
        path: String,
        /// The layer.
        layer: &'static str,
        /// What it has.
        got: usize,
        /// What the size needs.
        expected: usize,
    },
}

/// Refuses a path that is not an OpenEXR file, before anything is rendered.
pub fn check_path(path: &Path) -> Result<(), LayersError> {
    match Format::from_path(path)? {
        Format::Exr => Ok(()),
        Format::Png => Err(LayersError::NotExr { path: path.display().to_string(), format: "PNG" }),
    }
}

/// The channel names written for the layers `layers` holds, in the file's (sorted) order.
pub fn channel_names(layers: &Resolved) -> Vec<&'static str> {
    let mut names = vec!["B", "G", "R"];
    if !layers.albedo.is_empty() {
        names.extend(["albedo.R", "albedo.G", "albedo.B"]);
    }
    if !layers.normal.is_empty() {
        names.extend(["normal.X", "normal.Y", "normal.Z"]);
    }
    if !layers.depth.is_empty() {
        names.push("Z");
    }
    names.sort_unstable();
    names
}

/// Writes `rgb` (linear, top row first, 3 floats a pixel) and the resolved `layers` (the
/// empty ones left out) to the OpenEXR file `path`.
pub fn write_layers(
    path: &Path,
    width: u32,
    height: u32,
    rgb: &[f32],
    layers: &Resolved,
) -> Result<(), LayersError> {
    check_path(path)?;
    let shown = path.display().to_string();
    let n = width as usize * height as usize;
    let size = |layer, got: usize, expected| {
        if got == expected || (layer != "RGB" && got == 0) {
            Ok(())
        } else {
            Err(LayersError::Size { path: shown.clone(), layer, got, expected })
        }
    };
    size("RGB", rgb.len(), 3 * n)?;
    size("albedo", layers.albedo.len(), 3 * n)?;
    size("normal", layers.normal.len(), 3 * n)?;
    size("depth", layers.depth.len(), n)?;
    let channel = |name: &str, values: &[f32], k: usize, stride: usize| {
        AnyChannel::new(name, FlatSamples::F32(values.iter().skip(k).step_by(stride).copied().collect()))
    };
    let mut channels: Vec<AnyChannel<FlatSamples>> =
        vec![channel("R", rgb, 0, 3), channel("G", rgb, 1, 3), channel("B", rgb, 2, 3)];
    if !layers.albedo.is_empty() {
        for (k, c) in ["albedo.R", "albedo.G", "albedo.B"].into_iter().enumerate() {
            channels.push(channel(c, &layers.albedo, k, 3));
        }
    }
    if !layers.normal.is_empty() {
        for (k, c) in ["normal.X", "normal.Y", "normal.Z"].into_iter().enumerate() {
            channels.push(channel(c, &layers.normal, k, 3));
        }
    }
    if !layers.depth.is_empty() {
        channels.push(channel("Z", &layers.depth, 0, 1));
    }
    let layer = Layer::new(
        (width as usize, height as usize),
        LayerAttributes::default(),
        Encoding::SMALL_LOSSLESS,
        AnyChannels::sort(SmallVec::from_vec(channels)),
    );
    let tmp = {
        let mut name = path.file_name().map(|n| n.to_os_string()).unwrap_or_default();
        name.push(format!(".tmp{}", std::process::id()));
        path.with_file_name(name)
    };
    if let Err(source) = Image::from_layer(layer).write().to_file(&tmp) {
        let _ = std::fs::remove_file(&tmp);
        return Err(LayersError::Write { path: shown, source });
    }
    std::fs::rename(&tmp, path).map_err(|source| LayersError::Io { path: shown, source })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn writes_every_layer_and_reads_back_its_channels() {
        let dir = std::env::temp_dir().join(format!("tessera-exr-layers-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("layers.exr");
        let (w, h) = (3, 2);
        let rgb: Vec<f32> = (0..18).map(|v| v as f32 / 18.0).collect();
        let layers = Resolved {
            albedo: vec![0.5; 18],
            normal: (0..6).flat_map(|_| [0.0, 1.0, 0.0]).collect(),
            depth: vec![2.0, 2.0, 2.0, 4.0, 4.0, f32::INFINITY],
        };
        write_layers(&path, w, h, &rgb, &layers).unwrap();
        let image = exr::prelude::read_all_flat_layers_from_file(&path).unwrap();
        let layer = &image.layer_data[0];
        let names: Vec<String> = layer.channel_data.list.iter().map(|c| c.name.to_string()).collect();
        assert_eq!(names, channel_names(&layers));
        let z = layer.channel_data.list.iter().find(|c| c.name.to_string() == "Z").unwrap();
        assert_eq!(z.sample_data.values_as_f32().collect::<Vec<_>>(), layers.depth);
        let ny = layer.channel_data.list.iter().find(|c| c.name.to_string() == "normal.Y").unwrap();
        assert!(ny.sample_data.values_as_f32().all(|v| v == 1.0));
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn png_and_wrong_sizes_are_refused() {
        let e = check_path(Path::new("out.png")).unwrap_err().to_string();
        assert!(e.contains("need an OpenEXR output"), "{e}");
        let layers = Resolved { depth: vec![1.0], ..Resolved::default() };
        let e = write_layers(Path::new("/nonexistent/x.exr"), 2, 1, &[0.0; 6], &layers).unwrap_err();
        assert!(e.to_string().contains("the depth layer has 1 values, expected 2"), "{e}");
    }
}
