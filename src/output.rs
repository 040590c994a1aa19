//! Writing results: linear EXR, tone-mapped PNG preview, JSON — always atomically
//! (a temporary file in the target directory, renamed into place), so a crash
//! never leaves a half-written file behind.

use std::io::{Cursor, Write};
use std::path::{Path, PathBuf};

/// Why an output could not be written. Names the file.
#[derive(Debug, thiserror::Error)]
pub enum OutputError {
    /// Creating, writing or renaming failed.
    #[error("cannot write '{path}': {message}")]
    Write {
        /// The destination.
        path: PathBuf,
        /// Why.
        message: String,
    },
}

/// Why an image could not be encoded.
#[derive(Debug, thiserror::Error)]
pub enum EncodeError {
    /// The pixel count is not width x height.
    #[error("{pixels} pixels do not make a {width} x {height} image")]
    Size {
        /// Pixels given.
        pixels: usize,
        /// Image width.
        width: u32,
        /// Image height.
        height: u32,
    },
    /// The EXR encoder failed.
    #[error("EXR: {0}")]
    Exr(#[from] exr::error::Error),
    /// The PNG encoder failed.
    #[error("PNG: {0}")]
    Png(#[from] image::ImageError),
}

fn err(path: &Path, e: impl std::fmt::Display) -> OutputError {
    OutputError::Write {
        path: path.to_path_buf(),
        message: e.to_string(),
    }
}

/// The directory `path` is written in (`.` for a bare file name).
fn directory_of(path: &Path) -> &Path {
    match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    }
}

/// Creates `path`'s directory and its parents as needed. Where a file
/// stands in the way, the error names it: `create_dir_all` only says
/// "File exists".
fn make_directory(path: &Path) -> Result<&Path, OutputError> {
    let dir = directory_of(path);
    if let Some(file) = dir.ancestors().find(|a| a.is_file()) {
        return Err(err(
            path,
            format!("'{}' is a file, not a directory", file.display()),
        ));
    }
    std::fs::create_dir_all(dir).map_err(|e| err(path, e))?;
    Ok(dir)
}

/// A new temporary file beside `path` (deleted when dropped).
fn temporary_beside(path: &Path) -> Result<tempfile::NamedTempFile, OutputError> {
    tempfile::Builder::new()
        .prefix(".radiosity-")
        .suffix(".tmp")
        .tempfile_in(make_directory(path)?)
        .map_err(|e| err(path, e))
}

/// Checks, before any work, that [`write_atomic`] will be able to write
/// `path`: its directory exists or can be made, takes a new file, and
/// `path` is not a directory. A render checks every output this way, so a
/// mistyped or read-only place fails at once, not after a long solve whose
/// results it would lose. (Creates the directory, as writing would.)
pub fn check_writable(path: &Path) -> Result<(), OutputError> {
    if path.is_dir() {
        return Err(err(path, "it is a directory"));
    }
    temporary_beside(path).map(drop)
}

/// Writes `bytes` to `path` atomically, creating parent directories.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), OutputError> {
    let mut tmp = temporary_beside(path)?;
    tmp.write_all(bytes).map_err(|e| err(path, e))?;
    tmp.as_file().sync_all().map_err(|e| err(path, e))?;
    // Temporary files are private (0600); results are ordinary files.
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        tmp.as_file()
            .set_permissions(std::fs::Permissions::from_mode(0o644))
            .map_err(|e| err(path, e))?;
    }
    tmp.persist(path).map_err(|e| err(path, e.error))?;
    Ok(())
}

/// Encodes linear RGB pixels (top row first) as an OpenEXR file in memory.
pub fn encode_exr(width: u32, height: u32, pixels: &[[f32; 3]]) -> Result<Vec<u8>, EncodeError> {
    use exr::prelude::*;
    check_size(width, height, pixels)?;
    let w = width as usize;
    let channels = SpecificChannels::rgb(|Vec2(x, y): Vec2<usize>| {
        let p = pixels[y * w + x];
        (p[0], p[1], p[2])
    });
    let image = Image::from_channels((w, height as usize), channels);
    let mut buf = Cursor::new(Vec::new());
    image.write().non_parallel().to_buffered(&mut buf)?;
    Ok(buf.into_inner())
}

/// Reads the first RGB(A) layer of an OpenEXR file: width, height and linear
/// RGB pixels, top row first.
pub fn read_exr(path: &Path) -> Result<(u32, u32, Vec<[f32; 3]>), EncodeError> {
    use exr::prelude::*;
    let image = read_first_rgba_layer_from_file(
        path,
        |size, _| (size.0, vec![[0.0f32; 3]; size.0 * size.1]),
        |(w, px): &mut (usize, Vec<[f32; 3]>), pos, (r, g, b, _a): (f32, f32, f32, f32)| {
            px[pos.1 * *w + pos.0] = [r, g, b];
        },
    )?;
    let (w, pixels) = image.layer_data.channel_data.pixels;
    let h = pixels.len() / w.max(1);
    Ok((w as u32, h as u32, pixels))
}

fn check_size(width: u32, height: u32, pixels: &[[f32; 3]]) -> Result<(), EncodeError> {
    if pixels.len() as u64 != width as u64 * height as u64 {
        return Err(EncodeError::Size {
            pixels: pixels.len(),
            width,
            height,
        });
    }
    Ok(())
}

/// Automatic exposure: the scale that maps the 95th percentile of the lit
/// pixels' luminance to 0.8, times 2^`ev`.
pub fn auto_exposure(pixels: &[[f32; 3]], ev: f32) -> f32 {
    let mut lum: Vec<f32> = pixels
        .iter()
        .map(|p| 0.2126 * p[0] + 0.7152 * p[1] + 0.0722 * p[2])
        .filter(|l| *l > 0.0 && l.is_finite())
        .collect();
    if lum.is_empty() {
        return 2f32.powf(ev);
    }
    let k = (lum.len() - 1) * 95 / 100;
    let (_, v, _) = lum.select_nth_unstable_by(k, f32::total_cmp);
    0.8 / v.max(1e-12) * 2f32.powf(ev)
}

fn srgb(x: f32) -> u8 {
    let x = if x.is_finite() {
        x.clamp(0.0, 1.0)
    } else {
        0.0
    };
    let v = if x <= 0.0031308 {
        12.92 * x
    } else {
        1.055 * x.powf(1.0 / 2.4) - 0.055
    };
    (v * 255.0 + 0.5) as u8
}

/// Linear pixels scaled by `exposure`, clipped and sRGB-encoded, as RGB bytes.
pub fn tone_map(pixels: &[[f32; 3]], exposure: f32) -> Vec<u8> {
    pixels
        .iter()
        .flat_map(|p| p.map(|c| srgb(c * exposure)))
        .collect()
}

/// Tone-maps linear pixels (scaled by `exposure`, clipped, sRGB) into PNG bytes.
pub fn encode_png(
    width: u32,
    height: u32,
    pixels: &[[f32; 3]],
    exposure: f32,
) -> Result<Vec<u8>, EncodeError> {
    check_size(width, height, pixels)?;
    let img = image::RgbImage::from_raw(width, height, tone_map(pixels, exposure)).ok_or(
        EncodeError::Size {
            pixels: pixels.len(),
            width,
            height,
        },
    )?;
    let mut buf = Cursor::new(Vec::new());
    img.write_to(&mut buf, image::ImageFormat::Png)?;
    Ok(buf.into_inner())
}

/// Writes the EXR at `path` and its PNG preview beside it (same stem, `.png`).
/// Returns the PNG's path.
pub fn write_image(
    path: &Path,
    width: u32,
    height: u32,
    pixels: &[[f32; 3]],
    ev: f32,
) -> Result<PathBuf, OutputError> {
    let exr = encode_exr(width, height, pixels).map_err(|e| err(path, e))?;
    write_atomic(path, &exr)?;
    let png_path = path.with_extension("png");
    let png = encode_png(width, height, pixels, auto_exposure(pixels, ev))
        .map_err(|e| err(&png_path, e))?;
    write_atomic(&png_path, &png)?;
    Ok(png_path)
}

/// Serialises `value` as pretty JSON to `path`, atomically.
pub fn write_json<T: serde::Serialize>(path: &Path, value: &T) -> Result<(), OutputError> {
    let mut text = serde_json::to_string_pretty(value).map_err(|e| err(path, e))?;
    text.push('\n');
    write_atomic(path, text.as_bytes())
}
