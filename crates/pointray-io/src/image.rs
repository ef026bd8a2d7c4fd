//! PNG output for rendered images.

use std::path::Path;

use crate::{IoError, atomic_write};

/// Writes 8-bit RGB pixels, rows top to bottom, `rgb8.len() == width * height * 3`.
/// The file appears only when complete (see [`atomic_write`]).
pub fn write_png(path: &Path, width: u32, height: u32, rgb8: &[u8]) -> Result<(), IoError> {
    let expected = u64::from(width) * u64::from(height) * 3;
    if width == 0 || height == 0 || rgb8.len() as u64 != expected {
        return Err(IoError::invalid(
            path,
            format!("cannot write a {width}x{height} RGB image from {} bytes (need {expected})", rgb8.len()),
        ));
    }
    atomic_write(path, |out| {
        let mut encoder = png::Encoder::new(out, width, height);
        encoder.set_color(png::ColorType::Rgb);
        encoder.set_depth(png::BitDepth::Eight);
        let mut writer = encoder.write_header()?;
        writer.write_image_data(rgb8)?;
        writer.finish()?;
        Ok(())
    })
}
