//! Portable Float Map: `Pf` (1 channel) or `PF` (3 channels), a text header, then f32 samples with rows stored
//! **bottom to top**. A negative scale means little-endian. In memory we keep rows top to bottom, like images.
//!
//! Disparity convention (Middlebury): invalid pixels are NaN in memory and `+inf` in the file; use
//! [`write_disparity`] / [`read_disparity`] for that mapping, [`write`] / [`read`] for raw values.

use std::io::Write;
use std::path::Path;

use super::{FormatError, invalid, io_error, write_atomically};

/// A float image, rows top to bottom, channels interleaved.
#[derive(Debug, Clone, PartialEq)]
pub struct PfmImage {
    pub width: usize,
    pub height: usize,
    /// 1 (`Pf`) or 3 (`PF`).
    pub channels: usize,
    pub data: Vec<f32>,
}

impl PfmImage {
    pub fn get(&self, x: usize, y: usize, c: usize) -> f32 {
        self.data[(y * self.width + x) * self.channels + c]
    }
}

/// Writes `data` (rows top to bottom) as a little-endian PFM, values as they are.
pub fn write(path: &Path, width: usize, height: usize, channels: usize, data: &[f32]) -> Result<(), FormatError> {
    write_mapped(path, width, height, channels, data, |v| v)
}

/// Writes a disparity or depth map: non-finite (NaN) pixels become `+inf`, the Middlebury "invalid" marker.
pub fn write_disparity(path: &Path, width: usize, height: usize, data: &[f32]) -> Result<(), FormatError> {
    write_mapped(path, width, height, 1, data, |v| if v.is_finite() { v } else { f32::INFINITY })
}

fn write_mapped(
    path: &Path,
    width: usize,
    height: usize,
    channels: usize,
    data: &[f32],
    map: impl Fn(f32) -> f32,
) -> Result<(), FormatError> {
    if channels != 1 && channels != 3 {
        return Err(invalid(path, None, format!("PFM holds 1 or 3 channels, not {channels}")));
    }
    if data.len() != width * height * channels {
        return Err(invalid(path, None, format!("{} samples for a {width}×{height}×{channels} image", data.len())));
    }
    write_atomically(path, |w| {
        write!(w, "{}\n{} {}\n-1.0\n", if channels == 1 { "Pf" } else { "PF" }, width, height)?;
        let row_len = width * channels;
        let mut row_bytes = Vec::with_capacity(row_len * 4);
        for y in (0..height).rev() {
            row_bytes.clear();
            for &v in &data[y * row_len..(y + 1) * row_len] {
                row_bytes.extend_from_slice(&map(v).to_le_bytes());
            }
            w.write_all(&row_bytes)?;
        }
        Ok(())
    })
}

/// Reads a PFM (either endianness), rows returned top to bottom, values as stored.
pub fn read(path: &Path) -> Result<PfmImage, FormatError> {
    let bytes = std::fs::read(path).map_err(io_error(path))?;
    parse(&bytes, path)
}

/// Reads a disparity or depth map: `±inf` and NaN become NaN (invalid).
pub fn read_disparity(path: &Path) -> Result<PfmImage, FormatError> {
    let mut image = read(path)?;
    for v in &mut image.data {
        if !v.is_finite() {
            *v = f32::NAN;
        }
    }
    Ok(image)
}

/// Parses PFM bytes; `path` only names the source in errors.
pub fn parse(bytes: &[u8], path: &Path) -> Result<PfmImage, FormatError> {
    // The header is three whitespace-separated tokens after the magic, each line ended by one whitespace byte.
    let mut pos = 0;
    let mut token = |name: &str| -> Result<String, FormatError> {
        while pos < bytes.len() && bytes[pos].is_ascii_whitespace() {
            pos += 1;
        }
        let start = pos;
        while pos < bytes.len() && !bytes[pos].is_ascii_whitespace() {
            pos += 1;
        }
        if start == pos || pos - start > 32 {
            return Err(invalid(path, None, format!("PFM header: missing or malformed {name}")));
        }
        Ok(String::from_utf8_lossy(&bytes[start..pos]).into_owned())
    };
    let magic = token("magic")?;
    let channels = match magic.as_str() {
        "Pf" => 1,
        "PF" => 3,
        other => return Err(invalid(path, None, format!("not a PFM file (magic `{other}`, expected Pf or PF)"))),
    };
    let width: usize = token("width")?.parse().map_err(|_| invalid(path, None, "PFM header: bad width"))?;
    let height: usize = token("height")?.parse().map_err(|_| invalid(path, None, "PFM header: bad height"))?;
    let scale: f32 = token("scale")?.parse().map_err(|_| invalid(path, None, "PFM header: bad scale"))?;
    if width == 0 || height == 0 || !scale.is_finite() || scale == 0.0 {
        return Err(invalid(path, None, format!("PFM header: size {width}×{height}, scale {scale}")));
    }
    let data_start = pos + 1; // exactly one whitespace byte ends the header
    let n = width
        .checked_mul(height)
        .and_then(|v| v.checked_mul(channels))
        .ok_or_else(|| invalid(path, None, "PFM header: size overflows"))?;
    let expected = n.checked_mul(4).and_then(|v| v.checked_add(data_start));
    if expected != Some(bytes.len()) {
        return Err(invalid(
            path,
            None,
            format!(
                "PFM data: {} bytes after the header, expected {} for {width}×{height}×{channels}",
                bytes.len().saturating_sub(data_start),
                n * 4
            ),
        ));
    }
    let little_endian = scale < 0.0;
    let row_len = width * channels;
    let mut data = vec![0f32; n];
    for (file_row, chunk) in bytes[data_start..].chunks_exact(row_len * 4).enumerate() {
        let y = height - 1 - file_row;
        for (x, b) in chunk.chunks_exact(4).enumerate() {
            let raw = [b[0], b[1], b[2], b[3]];
            data[y * row_len + x] = if little_endian { f32::from_le_bytes(raw) } else { f32::from_be_bytes(raw) };
        }
    }
    Ok(PfmImage { width, height, channels, data })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn byte_layout_is_the_documented_one() {
        let dir = std::env::temp_dir().join(format!("bdis-pfm-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("d.pfm");
        // 2×2, top row (1, NaN), bottom row (3.5, -0).
        write_disparity(&path, 2, 2, &[1.0, f32::NAN, 3.5, -0.0]).unwrap();
        let bytes = std::fs::read(&path).unwrap();
        let mut expected = b"Pf\n2 2\n-1.0\n".to_vec();
        for v in [3.5f32, -0.0, 1.0, f32::INFINITY] {
            expected.extend_from_slice(&v.to_le_bytes()); // bottom row first
        }
        assert_eq!(bytes, expected);
        let back = read_disparity(&path).unwrap();
        assert_eq!((back.width, back.height, back.channels), (2, 2, 1));
        assert_eq!(back.data[0], 1.0);
        assert!(back.data[1].is_nan());
        assert_eq!(back.data[2].to_bits(), 3.5f32.to_bits());
        assert_eq!(back.data[3].to_bits(), (-0.0f32).to_bits());
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn reads_big_endian_and_rejects_truncation() {
        let mut bytes = b"PF\n1 1\n1.0\n".to_vec();
        for v in [1.0f32, 2.0, 3.0] {
            bytes.extend_from_slice(&v.to_be_bytes());
        }
        let img = parse(&bytes, Path::new("x.pfm")).unwrap();
        assert_eq!(img.data, vec![1.0, 2.0, 3.0]);
        let e = parse(&bytes[..bytes.len() - 1], Path::new("x.pfm")).unwrap_err().to_string();
        assert!(e.starts_with("x.pfm: PFM data: 11 bytes"), "{e}");
        let e = parse(b"P6\n1 1\n255\n", Path::new("x.pfm")).unwrap_err().to_string();
        assert!(e.contains("not a PFM file"), "{e}");
    }
}
