//! OpenEXR output of redirection textures (and a reader for checks).
//!
//! Files hold float32 channels R, G (the redirected u, v), optionally B (the
//! validity: 1 inside UV charts) and A, plus text attributes with the warp
//! settings. Arrays are `(height, width, channels)` with row 0 = lowest `v`
//! (Blender's bottom-up image order); EXR stores the top row first, so rows
//! are flipped on the way in and out and the file looks right in any viewer.
//! Writing is atomic: a temporary file in the same directory, then a rename.

use std::path::{Path, PathBuf};

use exr::prelude::*;

use crate::{Error, Result};

const NAMES: [&str; 4] = ["R", "G", "B", "A"];

/// Writes `data` (`height × width × channels`, 1 ≤ channels ≤ 4, interleaved)
/// with `metadata` as string attributes.
pub fn write_exr(path: &Path, width: usize, height: usize, channels: usize, data: &[f32], metadata: &[(String, String)]) -> Result<()> {
    if !(1..=4).contains(&channels) {
        return Err(Error::invalid(format!("an EXR image needs 1 to 4 channels, not {channels}")));
    }
    if width == 0 || height == 0 || data.len() != width * height * channels {
        return Err(Error::invalid(format!(
            "EXR data has {} floats, but {height}×{width}×{channels} = {} were expected",
            data.len(),
            width * height * channels
        )));
    }
    if let Some(i) = data.iter().position(|v| !v.is_finite()) {
        let texel = i / channels;
        return Err(Error::invalid(format!(
            "EXR data: channel {} of texel (row {}, column {}) is {}; refusing to write a file with NaN or infinite values",
            i % channels,
            texel / width,
            texel % width,
            data[i]
        )));
    }
    let list: Vec<AnyChannel<FlatSamples>> = (0..channels)
        .map(|c| {
            let mut samples = Vec::with_capacity(width * height);
            for y in (0..height).rev() {
                for x in 0..width {
                    samples.push(data[(y * width + x) * channels + c]);
                }
            }
            AnyChannel::new(NAMES[c], FlatSamples::F32(samples))
        })
        .collect();
    let mut attributes = LayerAttributes::named("");
    attributes.layer_name = None;
    for (k, v) in metadata {
        attributes.other.insert(Text::from(format!("tegument.{k}").as_str()), AttributeValue::Text(Text::from(v.as_str())));
    }
    let layer = Layer::new((width, height), attributes, Encoding::SMALL_LOSSLESS, AnyChannels::sort(list.into()));
    let image = Image::from_layer(layer);
    let tmp = temp_path(path);
    if let Err(e) = image.write().to_file(&tmp) {
        let _ = std::fs::remove_file(&tmp);
        return Err(Error::Io(format!("could not write EXR {}: {e}", path.display())));
    }
    std::fs::rename(&tmp, path).map_err(|e| {
        let _ = std::fs::remove_file(&tmp);
        Error::Io(format!("could not move the finished EXR into place at {}: {e}", path.display()))
    })
}

fn temp_path(path: &Path) -> PathBuf {
    let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    path.with_file_name(format!(".{name}.tmp-{}", std::process::id()))
}

/// An image read back: `(width, height, channels, data, metadata)` with the
/// same layout as [`write_exr`] takes; channels in R, G, B, A order (others
/// after, by name); metadata: every text attribute (the `tegument.` prefix removed).
pub type ExrImage = (usize, usize, usize, Vec<f32>, Vec<(String, String)>);

pub fn read_exr(path: &Path) -> Result<ExrImage> {
    let image = read()
        .no_deep_data()
        .largest_resolution_level()
        .all_channels()
        .first_valid_layer()
        .all_attributes()
        .from_file(path)
        .map_err(|e| Error::Io(format!("could not read EXR {}: {e}", path.display())))?;
    let layer = image.layer_data;
    let (width, height) = (layer.size.width(), layer.size.height());
    let mut chans: Vec<(usize, String, Vec<f32>)> = layer
        .channel_data
        .list
        .iter()
        .map(|c| {
            let name = c.name.to_string();
            let rank = NAMES.iter().position(|n| *n == name).unwrap_or(4);
            (rank, name, c.sample_data.values_as_f32().collect())
        })
        .collect();
    chans.sort_by(|a, b| (a.0, &a.1).cmp(&(b.0, &b.1)));
    let channels = chans.len();
    let mut data = vec![0.0f32; width * height * channels];
    for (c, (_, _, samples)) in chans.iter().enumerate() {
        for y in 0..height {
            for x in 0..width {
                data[((height - 1 - y) * width + x) * channels + c] = samples[y * width + x];
            }
        }
    }
    let mut metadata = Vec::new();
    for (k, v) in layer.attributes.other.iter().chain(image.attributes.other.iter()) {
        if let AttributeValue::Text(t) = v {
            let key = k.to_string();
            metadata.push((key.strip_prefix("tegument.").unwrap_or(&key).to_string(), t.to_string()));
        }
    }
    metadata.sort();
    Ok((width, height, channels, data, metadata))
}
