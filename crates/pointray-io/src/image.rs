//! Rendered images out (PNG, 8-bit sRGB; OpenEXR, linear 32-bit float with any named channels)
//! and PNG back in for comparing them.

use std::path::Path;

use crate::{IoError, atomic_write};

/// Writes 8-bit RGB pixels, rows top to bottom, `rgb8.len() == width * height * 3`.
/// The file appears only when complete (see [`atomic_write`]).
pub fn write_png(path: &Path, width: u32, height: u32, rgb8: &[u8]) -> Result<(), IoError> {
    write_png_of(path, width, height, rgb8, (png::ColorType::Rgb, png::BitDepth::Eight))
}

/// [`write_png`] for 8-bit RGBA pixels (straight, not premultiplied, alpha).
pub fn write_png_rgba(path: &Path, width: u32, height: u32, rgba8: &[u8]) -> Result<(), IoError> {
    write_png_of(path, width, height, rgba8, (png::ColorType::Rgba, png::BitDepth::Eight))
}

/// A 16-bit PNG of sRGB samples, three a pixel, row-major, top row first.
pub fn write_png16(path: &Path, width: u32, height: u32, rgb16: &[u16]) -> Result<(), IoError> {
    let bytes: Vec<u8> = rgb16.iter().flat_map(|v| v.to_be_bytes()).collect();
    write_png_of(path, width, height, &bytes, (png::ColorType::Rgb, png::BitDepth::Sixteen))
}

/// [`write_png16`] for RGBA samples (straight alpha).
pub fn write_png16_rgba(path: &Path, width: u32, height: u32, rgba16: &[u16]) -> Result<(), IoError> {
    let bytes: Vec<u8> = rgba16.iter().flat_map(|v| v.to_be_bytes()).collect();
    write_png_of(path, width, height, &bytes, (png::ColorType::Rgba, png::BitDepth::Sixteen))
}

/// The PNG of `pixels` (big-endian samples at 16 bits), of this colour type and depth.
fn write_png_of(
    path: &Path,
    width: u32,
    height: u32,
    pixels: &[u8],
    (color, depth): (png::ColorType, png::BitDepth),
) -> Result<(), IoError> {
    let channels = color.samples() as u64;
    let sample_bytes = if depth == png::BitDepth::Sixteen { 2 } else { 1 };
    let expected = u64::from(width) * u64::from(height) * channels * sample_bytes;
    if width == 0 || height == 0 || pixels.len() as u64 != expected {
        let kind = if channels == 4 { "RGBA" } else { "RGB" };
        return Err(IoError::invalid(
            path,
            format!("cannot write a {width}x{height} {kind} image from {} bytes (need {expected})", pixels.len()),
        ));
    }
    atomic_write(path, |out| Ok(encode_into(out, width, height, pixels, (color, depth))?))
}

/// The PNG of 8-bit RGB pixels, rows top to bottom, in memory (a viewer's frames).
///
/// # Panics
/// If `rgb8.len() != width * height * 3` or a side is 0.
pub fn encode_png(width: u32, height: u32, rgb8: &[u8]) -> Vec<u8> {
    let mut out = Vec::new();
    encode_into(&mut out, width, height, rgb8, (png::ColorType::Rgb, png::BitDepth::Eight))
        .expect("an RGB image of its size, in memory");
    out
}

fn encode_into(
    out: impl std::io::Write,
    width: u32,
    height: u32,
    pixels: &[u8],
    (color, depth): (png::ColorType, png::BitDepth),
) -> Result<(), png::EncodingError> {
    let mut encoder = png::Encoder::new(out, width, height);
    encoder.set_color(color);
    encoder.set_depth(depth);
    // fdeflate's PNG-tuned compressor: a 512² render encoded in ~60 instructions a pixel
    // against ~430 with the default zlib level, for files about 10 % larger (callgrind,
    // `docs/RESULTS.md`).
    encoder.set_compression(png::Compression::Fast);
    let mut writer = encoder.write_header()?;
    writer.write_image_data(pixels)?;
    writer.finish()
}

/// The most a deflate stream can expand (zlib's documented limit is 1032:1): a header that
/// declares more raw image data than its file could hold is refused before allocating.
const MAX_DEFLATE_RATIO: u128 = 1032;

/// Reads a PNG as `(width, height, rgb8)`, rows top to bottom, 3 bytes per pixel. Gray, gray +
/// alpha, RGB, RGBA and palette images of any bit depth are accepted: 16-bit samples keep their
/// high byte, gray is replicated into all three channels, and alpha is dropped (not composited).
/// Only the first frame of an animated PNG is read.
pub fn read_png(path: &Path) -> Result<(u32, u32, Vec<u8>), IoError> {
    decode_png(path, &std::fs::read(path).map_err(|e| IoError::io(path, e))?)
}

/// [`read_png`] for a file already in memory (`path` names it in errors).
pub fn decode_png(path: &Path, bytes: &[u8]) -> Result<(u32, u32, Vec<u8>), IoError> {
    let decode_error = |e: png::DecodingError| match e {
        png::DecodingError::IoError(io) if io.kind() == std::io::ErrorKind::UnexpectedEof => {
            IoError::invalid(path, "the PNG ends early (truncated file?)")
        }
        e => IoError::invalid(path, format!("not a readable PNG: {e}")),
    };
    let mut decoder = png::Decoder::new(std::io::Cursor::new(bytes));
    decoder.set_transformations(png::Transformations::normalize_to_color8());
    let mut reader = decoder.read_info().map_err(decode_error)?;

    let info = reader.info();
    let (width, height) = (info.width, info.height);
    let bits_per_pixel = info.color_type.samples() as u128 * info.bit_depth as u128;
    // One filter byte per row, then the packed samples.
    let raw_bytes = u128::from(height) * (1 + (u128::from(width) * bits_per_pixel).div_ceil(8));
    if raw_bytes > bytes.len() as u128 * MAX_DEFLATE_RATIO {
        return Err(IoError::invalid(
            path,
            format!("declares {width}x{height} pixels, more than its {} bytes can hold", bytes.len()),
        ));
    }
    let size = reader
        .output_buffer_size()
        .ok_or_else(|| IoError::invalid(path, format!("{width}x{height} pixels do not fit in memory")))?;
    let mut buffer = vec![0; size];
    let frame = reader.next_frame(&mut buffer).map_err(decode_error)?;
    buffer.truncate(frame.buffer_size());

    let rgb8 = match frame.color_type {
        png::ColorType::Rgb => buffer,
        png::ColorType::Rgba => buffer.chunks_exact(4).flat_map(|p| [p[0], p[1], p[2]]).collect(),
        png::ColorType::Grayscale => buffer.iter().flat_map(|&g| [g; 3]).collect(),
        png::ColorType::GrayscaleAlpha => buffer.chunks_exact(2).flat_map(|p| [p[0]; 3]).collect(),
        // `normalize_to_color8` expands palettes, so this would be a bug in the png crate.
        png::ColorType::Indexed => return Err(IoError::invalid(path, "palette was not expanded")),
    };
    debug_assert_eq!(rgb8.len() as u64, u64::from(width) * u64::from(height) * 3);
    Ok((width, height, rgb8))
}

/// Writes an OpenEXR image of `width × height` 32-bit float channels, each named (`"R"`,
/// `"G"`, `"B"`, and e.g. `"depth.Z"` or `"normal.X"` for extra layers) with one value per
/// pixel, rows top to bottom. The file appears only when complete.
pub fn write_exr(path: &Path, width: u32, height: u32, channels: Vec<(String, Vec<f32>)>) -> Result<(), IoError> {
    use exr::prelude::*;
    let pixels = width as usize * height as usize;
    if pixels == 0 || channels.is_empty() || channels.iter().any(|(_, c)| c.len() != pixels) {
        return Err(IoError::invalid(path, format!("cannot write a {width}x{height} EXR from these channels")));
    }
    let list: SmallVec<[AnyChannel<FlatSamples>; 4]> =
        channels.into_iter().map(|(name, values)| AnyChannel::new(name.as_str(), FlatSamples::F32(values))).collect();
    let image = Image::from_channels((width as usize, height as usize), AnyChannels::sort(list));
    // The encoder seeks, so it writes to memory; the file is then written atomically.
    let mut encoded = std::io::Cursor::new(Vec::new());
    image.write().to_buffered(&mut encoded).map_err(|e| IoError::invalid(path, format!("EXR encoding: {e}")))?;
    atomic_write(path, |out| out.write_all(encoded.get_ref()))
}
