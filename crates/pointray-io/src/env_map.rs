//! Environment maps: equirectangular HDR panoramas, as Radiance `.hdr` (RGBE: flat, old or new
//! run-length encoding) or OpenEXR (the first RGB layer), recognised by content.
//!
//! Our own RGBE decoder, as for PLY: the crates that read the format do not bound a header's
//! size against the file, and a run length against the scanline, without panicking.

use std::path::Path;

use pointray::env_map::EnvMap;

use crate::IoError;

/// The largest map read: 16384 × 8192 texels (1.5 GiB as linear RGB).
const MAX_TEXELS: usize = 16384 * 8192;

/// Reads an equirectangular map of linear radiance from a Radiance `.hdr` or OpenEXR file.
pub fn read_env_map(path: &Path) -> Result<EnvMap, IoError> {
    let bytes = std::fs::read(path).map_err(|e| IoError::io(path, e))?;
    parse_env_map(path, &bytes)
}

/// [`read_env_map`] of the file's `bytes` (`path` names it in errors).
pub fn parse_env_map(path: &Path, bytes: &[u8]) -> Result<EnvMap, IoError> {
    let (width, height, mut texels) = if bytes.starts_with(b"#?") {
        decode_rgbe(path, bytes)?
    } else if bytes.starts_with(&[0x76, 0x2f, 0x31, 0x01]) {
        decode_exr(path, bytes)?
    } else {
        return Err(IoError::invalid(path, "not an environment map: expected a Radiance .hdr or an OpenEXR file"));
    };
    // Lossy EXR compression (DWA) rings below zero round a bright sun: no light is negative.
    let negative = texels.iter_mut().flatten().filter(|v| **v < 0.0).map(|v| *v = 0.0).count();
    if negative > 0 {
        tracing::warn!("{}: {negative} negative values (lossy compression) read as 0", path.display());
    }
    EnvMap::new(width, height, texels).map_err(|e| IoError::invalid(path, e.to_string()))
}

/// A Radiance picture: the header's lines up to an empty one, the resolution line, then the
/// scanlines from the top.
fn decode_rgbe(path: &Path, bytes: &[u8]) -> Result<(usize, usize, Vec<[f32; 3]>), IoError> {
    let mut at = 0;
    let mut line_no = 0;
    let mut next_line = |at: &mut usize| -> Result<&[u8], IoError> {
        line_no += 1;
        let rest = &bytes[*at..];
        let end = rest
            .iter()
            .position(|&b| b == b'\n')
            .ok_or_else(|| IoError::at_line(path, line_no, "the header ends early"))?;
        *at += end + 1;
        Ok(&rest[..end])
    };
    let magic = next_line(&mut at)?;
    if magic != b"#?RADIANCE" && magic != b"#?RGBE" {
        return Err(IoError::at_line(path, 1, "not a Radiance picture (#?RADIANCE)"));
    }
    let mut exposure = 1.0f64;
    loop {
        let line = next_line(&mut at)?;
        if line.is_empty() {
            break;
        }
        let text = String::from_utf8_lossy(line);
        if let Some(format) = text.strip_prefix("FORMAT=") {
            if format.trim() != "32-bit_rle_rgbe" {
                return Err(IoError::invalid(
                    path,
                    format!("pixel format {}: only 32-bit_rle_rgbe is read", format.trim()),
                ));
            }
        } else if let Some(e) = text.strip_prefix("EXPOSURE=") {
            // Pixels were multiplied by each EXPOSURE: radiance is the value over their product.
            match e.trim().parse::<f64>() {
                Ok(e) if e > 0.0 && e.is_finite() => exposure *= e,
                _ => return Err(IoError::invalid(path, format!("EXPOSURE={}: not a positive number", e.trim()))),
            }
        }
    }
    let resolution = String::from_utf8_lossy(next_line(&mut at)?).into_owned();
    let (width, height, flip) = match resolution.split_whitespace().collect::<Vec<_>>()[..] {
        [y @ ("-Y" | "+Y"), h, "+X", w] => (parse_size(path, w)?, parse_size(path, h)?, y == "+Y"),
        _ => return Err(IoError::invalid(path, format!("resolution {resolution:?}: only -Y H +X W (or +Y) is read"))),
    };
    if width.checked_mul(height).is_none_or(|n| n > MAX_TEXELS) {
        return Err(IoError::invalid(path, format!("{width} x {height} texels: at most {MAX_TEXELS} are read")));
    }
    let scale = (1.0 / exposure) as f32;
    // Grown a scanline at a time: a header that claims more than the file holds ends in an
    // error, not in a huge allocation.
    let mut texels = Vec::new();
    let mut rgbe = vec![[0u8; 4]; width];
    for row in 0..height {
        at = scanline(bytes, at, &mut rgbe)
            .map_err(|(offset, message)| IoError::at_byte(path, offset, format!("scanline {row}: {message}")))?;
        texels.extend(rgbe.iter().map(|&p| to_float(p, scale)));
    }
    if flip {
        let rows: Vec<&[[f32; 3]]> = texels.chunks(width).rev().collect();
        texels = rows.concat();
    }
    Ok((width, height, texels))
}

fn parse_size(path: &Path, s: &str) -> Result<usize, IoError> {
    s.parse::<usize>()
        .ok()
        .filter(|&n| n > 0)
        .ok_or_else(|| IoError::invalid(path, format!("size {s:?}: not a positive integer")))
}

/// One scanline into `out` from `bytes[at..]`; where the next begins, or the offset and what
/// is wrong.
fn scanline(bytes: &[u8], at: usize, out: &mut [[u8; 4]]) -> Result<usize, (usize, String)> {
    let w = out.len();
    let head = bytes.get(at..at + 4);
    match head {
        // New run-length encoding: a marker with the width, then each channel in runs.
        Some(&[2, 2, hi, lo]) if (8..0x8000).contains(&w) && (usize::from(hi) << 8 | usize::from(lo)) == w => {
            let mut at = at + 4;
            for channel in 0..4 {
                let mut x = 0;
                while x < w {
                    let &count = bytes.get(at).ok_or((at, "the file ends early".to_string()))?;
                    at += 1;
                    let (run, literal) =
                        if count > 128 { (usize::from(count - 128), false) } else { (usize::from(count), true) };
                    if run == 0 || x + run > w {
                        return Err((at - 1, format!("a run of {run} past the scanline's {w} pixels")));
                    }
                    if literal {
                        let data = bytes.get(at..at + run).ok_or((at, "the file ends early".to_string()))?;
                        data.iter().enumerate().for_each(|(i, &b)| out[x + i][channel] = b);
                        at += run;
                    } else {
                        let &b = bytes.get(at).ok_or((at, "the file ends early".to_string()))?;
                        out[x..x + run].iter_mut().for_each(|p| p[channel] = b);
                        at += 1;
                    }
                    x += run;
                }
            }
            Ok(at)
        }
        // Flat pixels, where (1, 1, 1, n) repeats the one before (old run-length encoding).
        _ => {
            let (mut at, mut x, mut shift) = (at, 0, 0u32);
            while x < w {
                let p: [u8; 4] =
                    bytes.get(at..at + 4).ok_or((at, "the file ends early".to_string()))?.try_into().expect("4 bytes");
                at += 4;
                if p[..3] == [1, 1, 1] && x > 0 {
                    // Consecutive repeats count in higher bytes; a ninth would shift past 64 bits.
                    let run = usize::from(p[3]).checked_shl(shift).unwrap_or(usize::MAX);
                    if run > w - x {
                        return Err((at - 4, format!("a repeat of {run} past the scanline's {w} pixels")));
                    }
                    let previous = out[x - 1];
                    out[x..x + run].fill(previous);
                    x += run;
                    shift += 8;
                } else {
                    out[x] = p;
                    x += 1;
                    shift = 0;
                }
            }
            Ok(at)
        }
    }
}

/// An RGBE pixel as linear RGB (Ward's conversion: mantissa × 2^(e − 136)).
fn to_float([r, g, b, e]: [u8; 4], scale: f32) -> [f32; 3] {
    if e == 0 {
        return [0.0; 3];
    }
    let f = 2f32.powi(i32::from(e) - 136) * scale;
    [f32::from(r) * f, f32::from(g) * f, f32::from(b) * f]
}

/// The first layer with R, G and B channels of an OpenEXR file, at full resolution.
fn decode_exr(path: &Path, bytes: &[u8]) -> Result<(usize, usize, Vec<[f32; 3]>), IoError> {
    use exr::prelude::*;
    let image = read()
        .no_deep_data()
        .largest_resolution_level()
        .rgb_channels(
            |size, _| (size.width(), vec![[0.0f32; 3]; size.area()]),
            |(width, texels), pos, (r, g, b): (f32, f32, f32)| texels[pos.y() * *width + pos.x()] = [r, g, b],
        )
        .first_valid_layer()
        .all_attributes()
        .from_buffered(std::io::Cursor::new(bytes))
        .map_err(|e| IoError::invalid(path, format!("OpenEXR: {e}")))?;
    let size = image.layer_data.size;
    if size.area() > MAX_TEXELS {
        return Err(IoError::invalid(
            path,
            format!("{} x {} texels: at most {MAX_TEXELS} are read", size.width(), size.height()),
        ));
    }
    Ok((size.width(), size.height(), image.layer_data.channel_data.pixels.1))
}

/// A Radiance picture of `width` × `height` linear RGB texels, flat RGBE (for tests and tools).
pub fn encode_rgbe(width: usize, height: usize, texels: &[[f32; 3]]) -> Vec<u8> {
    let mut out = format!("#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y {height} +X {width}\n").into_bytes();
    for &[r, g, b] in texels {
        let m = r.max(g).max(b);
        if m < 1e-32 {
            out.extend([0, 0, 0, 0]);
            continue;
        }
        // m = f × 2^e with f in [0.5, 1): the mantissas are channel × 256 / 2^e.
        let e = m.log2().floor() as i32 + 1;
        let f = 256.0 / 2f32.powi(e);
        let byte = |c: f32| (c * f).min(255.0) as u8;
        out.extend([byte(r), byte(g), byte(b), (e + 128) as u8]);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn texels(w: usize, h: usize) -> Vec<[f32; 3]> {
        (0..w * h).map(|i| [(i % w) as f32 * 0.25 + 0.5, (i / w) as f32, 100.0 * (i % 3) as f32]).collect()
    }

    #[test]
    fn flat_rgbe_reads_back_within_its_precision() {
        let (w, h) = (6, 3);
        let bytes = encode_rgbe(w, h, &texels(w, h));
        let (rw, rh, read) = decode_rgbe(Path::new("t.hdr"), &bytes).unwrap();
        assert_eq!((rw, rh), (w, h));
        for (a, b) in read.iter().zip(texels(w, h)) {
            for k in 0..3 {
                // Eight bits of mantissa against the pixel's largest channel.
                assert!((a[k] - b[k]).abs() <= b.iter().fold(0.0f32, |m, v| m.max(*v)) / 128.0, "{a:?} {b:?}");
            }
        }
    }

    #[test]
    fn new_run_length_encoding_reads_runs_and_literals() {
        // 8 pixels: R a run of 8 × 128, G literals 0..8, B a run of 4 then 4 literals, E 129.
        let mut bytes = b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\nEXPOSURE=2\n\n-Y 1 +X 8\n".to_vec();
        bytes.extend([2, 2, 0, 8]);
        bytes.extend([128 + 8, 128]);
        bytes.extend([8, 0, 1, 2, 3, 4, 5, 6, 7]);
        bytes.extend([128 + 4, 9, 4, 1, 2, 3, 4]);
        bytes.extend([128 + 8, 129]);
        let (w, h, t) = decode_rgbe(Path::new("t.hdr"), &bytes).unwrap();
        assert_eq!((w, h), (8, 1));
        // e = 129: mantissa × 2^-7, then / EXPOSURE 2.
        let f = 2f32.powi(-7) / 2.0;
        assert_eq!(t[0], [128.0 * f, 0.0, 9.0 * f]);
        assert_eq!(t[7], [128.0 * f, 7.0 * f, 4.0 * f]);
    }

    #[test]
    fn damaged_pictures_are_refused_with_their_place() {
        let good = encode_rgbe(8, 2, &texels(8, 2));
        let err = |bytes: &[u8]| decode_rgbe(Path::new("bad.hdr"), bytes).unwrap_err().to_string();
        assert!(
            err(&good[..good.len() - 3]).contains("scanline 1: the file ends early"),
            "{}",
            err(&good[..good.len() - 3])
        );
        assert!(err(b"#?RADIANCE\nFORMAT=32-bit_rle_xyze\n\n-Y 1 +X 8\n").contains("only 32-bit_rle_rgbe"));
        assert!(err(b"#?RADIANCE\n\n+X 8 -Y 1\n").contains("only -Y H +X W"));
        assert!(err(b"#?RADIANCE\n\n-Y 100000 +X 100000\n").contains("at most"));
        assert!(err(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe").contains("line 2: the header ends early"));
        // A run longer than the scanline.
        let mut long = b"#?RADIANCE\n\n-Y 1 +X 8\n".to_vec();
        long.extend([2, 2, 0, 8, 128 + 9, 1]);
        assert!(err(&long).contains("a run of 9 past the scanline's 8 pixels"), "{}", err(&long));
        // Every prefix of a good file is refused, none panics.
        for n in 0..good.len() {
            assert!(decode_rgbe(Path::new("bad.hdr"), &good[..n]).is_err(), "{n} bytes");
        }
    }

    #[test]
    fn corrupted_bytes_never_panic() {
        // A run-length encoded picture with bytes changed at random: read or refused, never a
        // panic (the fuzz target `env_map` does this at length).
        let mut good = b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 2 +X 8\n".to_vec();
        for _ in 0..2 {
            good.extend([2, 2, 0, 8, 128 + 8, 128, 8, 0, 1, 2, 3, 4, 5, 6, 7, 128 + 4, 9, 4, 1, 2, 3, 4, 128 + 8, 129]);
        }
        assert!(parse_env_map(Path::new("t.hdr"), &good).is_ok());
        // Repeats of nothing, one after another, until the count would shift out of range.
        let mut zeros = b"#?RADIANCE\n\n-Y 1 +X 4\n".to_vec();
        zeros.extend([9, 9, 9, 129]);
        (0..12).for_each(|_| zeros.extend([1, 1, 1, 0]));
        assert!(parse_env_map(Path::new("t.hdr"), &zeros).is_err());
        let mut state = 0x9e37_79b9_7f4a_7c15u64;
        let mut next = || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            state
        };
        for _ in 0..5000 {
            let mut bytes = good.clone();
            for _ in 0..1 + next() % 4 {
                let at = next() as usize % bytes.len();
                bytes[at] = next() as u8;
            }
            let _ = parse_env_map(Path::new("t.hdr"), &bytes);
        }
    }

    #[test]
    fn old_run_length_encoding_repeats_the_pixel_before() {
        let mut bytes = b"#?RGBE\n\n+Y 2 +X 3\n".to_vec();
        // Bottom row first (+Y): a pixel repeated twice; then three flat pixels.
        bytes.extend([64, 0, 0, 129, 1, 1, 1, 2]);
        bytes.extend([0, 64, 0, 129, 0, 64, 0, 129, 0, 0, 64, 129]);
        let (w, h, t) = decode_rgbe(Path::new("t.hdr"), &bytes).unwrap();
        assert_eq!((w, h), (3, 2));
        let f = 64.0 * 2f32.powi(-7);
        assert_eq!(t[..3], [[0.0, f, 0.0], [0.0, f, 0.0], [0.0, 0.0, f]]);
        assert_eq!(t[3..], [[f, 0.0, 0.0]; 3]);
    }
}
