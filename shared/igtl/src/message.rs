//! OpenIGTLink messages as bytes, written from the protocol's published specification (version 3, header version
//! 2: the 58-byte header, then a body of a 12-byte extended header, the content and the metadata). Only what
//! bdis-slam sends: TRANSFORM, STRING, POINT and POLYDATA. Everything is big-endian.
//!
//! Header: version (u16) · type (12 bytes) · device name (20 bytes) · timestamp (u64: seconds since 1970 in the
//! upper 32 bits, the fraction of a second in 1/2³² in the lower) · body size (u64) · CRC-64 of the body (u64).
//! Extended header: its own size (u16, 12) · metadata header size (u16) · metadata size (u32) · message id (u32).
//! Metadata header: entry count (u16), then per entry key size (u16), value encoding (u16, IANA: 3 US-ASCII,
//! 106 UTF-8), value size (u32); then the keys and values, in order.

use nalgebra::Isometry3;

use crate::IgtlError;

/// Bytes of the fixed header before every body.
pub const HEADER_BYTES: usize = 58;
/// The header version that carries an extended header and metadata (OpenIGTLink 3).
pub const HEADER_VERSION: u16 = 2;
const EXTENDED_HEADER_BYTES: usize = 12;
const TYPE_BYTES: usize = 12;
const DEVICE_BYTES: usize = 20;
const IANA_US_ASCII: u16 = 3;
const IANA_UTF8: u16 = 106;

/// A device name as the header holds it: ASCII, at most 20 bytes (receivers key what they show by it: 3D Slicer
/// makes one node per device name).
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub struct DeviceName([u8; DEVICE_BYTES]);

impl DeviceName {
    pub fn new(name: &str) -> Result<Self, IgtlError> {
        if name.is_empty() || name.len() > DEVICE_BYTES || !name.bytes().all(|b| b.is_ascii_graphic()) {
            return Err(IgtlError::DeviceName(name.to_string()));
        }
        let mut bytes = [0u8; DEVICE_BYTES];
        bytes[..name.len()].copy_from_slice(name.as_bytes());
        Ok(Self(bytes))
    }

    pub fn as_str(&self) -> &str {
        let end = self.0.iter().position(|&b| b == 0).unwrap_or(DEVICE_BYTES);
        std::str::from_utf8(&self.0[..end]).unwrap_or_default()
    }
}

/// A time as the header holds it: seconds since 1970 and the fraction of a second in units of 2⁻³² s.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Timestamp(pub u64);

impl Timestamp {
    /// From nanoseconds since 1970 (`CLOCK_REALTIME`).
    pub fn from_unix_ns(ns: u64) -> Self {
        let seconds = ns / 1_000_000_000;
        let fraction = ((ns % 1_000_000_000) << 32) / 1_000_000_000;
        Self((seconds << 32) | fraction)
    }
}

/// Writes messages into one buffer it reuses, numbering them (the extended header's message id).
#[derive(Debug, Default)]
pub struct Encoder {
    out: Vec<u8>,
    next_id: u32,
}

fn put_u16(out: &mut Vec<u8>, v: u16) {
    out.extend_from_slice(&v.to_be_bytes());
}

fn put_u32(out: &mut Vec<u8>, v: u32) {
    out.extend_from_slice(&v.to_be_bytes());
}

fn put_f32(out: &mut Vec<u8>, v: f32) {
    out.extend_from_slice(&v.to_be_bytes());
}

/// A fixed-size, NUL-padded text field, cut at `n` bytes.
fn put_fixed(out: &mut Vec<u8>, text: &str, n: usize) {
    let bytes = &text.as_bytes()[..text.len().min(n)];
    out.extend_from_slice(bytes);
    out.resize(out.len() + n - bytes.len(), 0);
}

/// One cell of `n` point indices 0…n−1, as POLYDATA's VERTICES and LINES hold cells.
fn put_cell_of_all(out: &mut Vec<u8>, n: u32) {
    put_u32(out, n);
    for i in 0..n {
        put_u32(out, i);
    }
}

impl Encoder {
    /// A TRANSFORM: the upper 3×4 of `world_from_camera`, column by column (R11 R21 R31 R12 … TX TY TZ).
    pub fn transform(
        &mut self,
        device: &DeviceName,
        time: Timestamp,
        world_from_camera: &Isometry3<f64>,
        metadata: &[(&str, &str)],
    ) -> &[u8] {
        let m = world_from_camera.to_homogeneous();
        self.message("TRANSFORM", device, time, metadata, |out| {
            for column in 0..4 {
                for row in 0..3 {
                    put_f32(out, m[(row, column)] as f32);
                }
            }
        })
    }

    /// A STRING (UTF-8 or ASCII, at most 65535 bytes: longer text is cut at a character boundary).
    pub fn string(&mut self, device: &DeviceName, time: Timestamp, text: &str, metadata: &[(&str, &str)]) -> &[u8] {
        let mut end = text.len().min(usize::from(u16::MAX));
        while !text.is_char_boundary(end) {
            end -= 1;
        }
        let text = &text[..end];
        self.message("STRING", device, time, metadata, |out| {
            put_u16(out, if text.is_ascii() { IANA_US_ASCII } else { IANA_UTF8 });
            put_u16(out, text.len() as u16);
            out.extend_from_slice(text.as_bytes());
        })
    }

    /// A POLYDATA of bare points: the points and one vertex cell holding all of them (a point cloud; no
    /// attributes).
    pub fn point_cloud(
        &mut self,
        device: &DeviceName,
        time: Timestamp,
        xyz: &[[f32; 3]],
        metadata: &[(&str, &str)],
    ) -> &[u8] {
        self.polydata(device, time, xyz, Cells::Vertices, metadata)
    }

    /// A POLYDATA of one line through `xyz` in order (a path).
    pub fn polyline(
        &mut self,
        device: &DeviceName,
        time: Timestamp,
        xyz: &[[f32; 3]],
        metadata: &[(&str, &str)],
    ) -> &[u8] {
        self.polydata(device, time, xyz, Cells::Line, metadata)
    }

    fn polydata(
        &mut self,
        device: &DeviceName,
        time: Timestamp,
        xyz: &[[f32; 3]],
        cells: Cells,
        metadata: &[(&str, &str)],
    ) -> &[u8] {
        let n = xyz.len().min(u32::MAX as usize / 4 - 1) as u32;
        let (cell_count, cell_bytes) = if n == 0 { (0, 0) } else { (1, 4 * (n + 1)) };
        self.message("POLYDATA", device, time, metadata, |out| {
            put_u32(out, n);
            // NVERTICES, SIZE_VERTICES, NLINES, SIZE_LINES, NPOLYGONS, SIZE_POLYGONS, NTRIANGLE_STRIPS,
            // SIZE_TRIANGLE_STRIPS, NATTRIBUTES.
            let (vertices, lines) = match cells {
                Cells::Vertices => ((cell_count, cell_bytes), (0, 0)),
                Cells::Line => ((0, 0), (cell_count, cell_bytes)),
            };
            for v in [vertices.0, vertices.1, lines.0, lines.1, 0, 0, 0, 0, 0] {
                put_u32(out, v);
            }
            for p in &xyz[..n as usize] {
                for &c in p {
                    put_f32(out, c);
                }
            }
            if n > 0 {
                put_cell_of_all(out, n);
            }
        })
    }

    /// A POINT message: per point a name and a group (both empty but for `group`), its colour (RGBA), position,
    /// a diameter and an owner (empty) — 136 bytes a point, what receivers that keep fiducials take.
    pub fn points(
        &mut self,
        device: &DeviceName,
        time: Timestamp,
        group: &str,
        xyz: &[[f32; 3]],
        rgb: &[[u8; 3]],
        metadata: &[(&str, &str)],
    ) -> &[u8] {
        self.message("POINT", device, time, metadata, |out| {
            for (p, c) in xyz.iter().zip(rgb) {
                put_fixed(out, "", 64);
                put_fixed(out, group, 32);
                out.extend_from_slice(&[c[0], c[1], c[2], 255]);
                for &v in p {
                    put_f32(out, v);
                }
                put_f32(out, 0.0);
                put_fixed(out, "", 20);
            }
        })
    }

    /// Header, extended header, `content`, metadata; the CRC over the body. Returns the whole message.
    fn message(
        &mut self,
        kind: &str,
        device: &DeviceName,
        time: Timestamp,
        metadata: &[(&str, &str)],
        content: impl FnOnce(&mut Vec<u8>),
    ) -> &[u8] {
        let out = &mut self.out;
        out.clear();
        out.resize(HEADER_BYTES + EXTENDED_HEADER_BYTES, 0);
        content(out);
        // Metadata: the header of every entry, then every key and value. Sizes that do not fit are cut.
        let entries = &metadata[..metadata.len().min(usize::from(u16::MAX))];
        let metadata_start = out.len();
        put_u16(out, entries.len() as u16);
        for (key, value) in entries {
            put_u16(out, key.len().min(usize::from(u16::MAX)) as u16);
            put_u16(out, if value.is_ascii() { IANA_US_ASCII } else { IANA_UTF8 });
            put_u32(out, value.len() as u32);
        }
        let metadata_header_bytes = out.len() - metadata_start;
        for (key, value) in entries {
            out.extend_from_slice(&key.as_bytes()[..key.len().min(usize::from(u16::MAX))]);
            out.extend_from_slice(value.as_bytes());
        }
        let metadata_bytes = out.len() - metadata_start - metadata_header_bytes;

        let id = self.next_id;
        self.next_id = self.next_id.wrapping_add(1);
        let extended = &mut out[HEADER_BYTES..HEADER_BYTES + EXTENDED_HEADER_BYTES];
        extended[0..2].copy_from_slice(&(EXTENDED_HEADER_BYTES as u16).to_be_bytes());
        extended[2..4].copy_from_slice(&(metadata_header_bytes as u16).to_be_bytes());
        extended[4..8].copy_from_slice(&(metadata_bytes as u32).to_be_bytes());
        extended[8..12].copy_from_slice(&id.to_be_bytes());

        let body = &out[HEADER_BYTES..];
        let crc = crate::crc64::update(0, body);
        let body_bytes = body.len() as u64;
        let header = &mut out[..HEADER_BYTES];
        header[0..2].copy_from_slice(&HEADER_VERSION.to_be_bytes());
        let kind = &kind.as_bytes()[..kind.len().min(TYPE_BYTES)];
        header[2..2 + kind.len()].copy_from_slice(kind);
        header[14..34].copy_from_slice(&device.0);
        header[34..42].copy_from_slice(&time.0.to_be_bytes());
        header[42..50].copy_from_slice(&body_bytes.to_be_bytes());
        header[50..58].copy_from_slice(&crc.to_be_bytes());
        out
    }
}

#[derive(Debug, Clone, Copy)]
enum Cells {
    Vertices,
    Line,
}

#[cfg(test)]
mod tests {
    use super::*;

    fn u32_at(b: &[u8], at: usize) -> u32 {
        u32::from_be_bytes(b[at..at + 4].try_into().unwrap())
    }

    #[test]
    fn a_transform_has_the_header_the_sizes_and_the_crc_of_its_body() {
        let mut encoder = Encoder::default();
        let device = DeviceName::new("CameraToWorld").unwrap();
        let pose = Isometry3::new(nalgebra::Vector3::new(1.0, 2.0, 3.0), nalgebra::Vector3::new(0.0, 0.0, 0.5));
        let bytes = encoder.transform(&device, Timestamp::from_unix_ns(1_500_000_000), &pose, &[("k", "v")]).to_vec();
        assert_eq!(u16::from_be_bytes([bytes[0], bytes[1]]), 2);
        assert_eq!(&bytes[2..11], b"TRANSFORM");
        assert_eq!(&bytes[14..27], b"CameraToWorld");
        // 1.5 s: one second and half of 2^32.
        assert_eq!(u64::from_be_bytes(bytes[34..42].try_into().unwrap()), (1 << 32) | (1 << 31));
        let body_size = u64::from_be_bytes(bytes[42..50].try_into().unwrap()) as usize;
        assert_eq!(body_size, bytes.len() - HEADER_BYTES);
        // Extended header 12 + content 48 + metadata header 2 + 8 + metadata 2.
        assert_eq!(body_size, 12 + 48 + 10 + 2);
        let crc = u64::from_be_bytes(bytes[50..58].try_into().unwrap());
        assert_eq!(crc, crate::crc64::update(0, &bytes[HEADER_BYTES..]));
        // TX is the tenth float of the content.
        let tx = f32::from_be_bytes(bytes[HEADER_BYTES + 12 + 36..][..4].try_into().unwrap());
        assert_eq!(tx, 1.0);
        // Message ids count up.
        let next = encoder.string(&device, Timestamp::default(), "ok", &[]).to_vec();
        assert_eq!(u32_at(&next, HEADER_BYTES + 8), 1);
    }

    #[test]
    fn a_point_cloud_is_one_vertex_cell_of_every_point_and_an_empty_one_has_none() {
        let mut encoder = Encoder::default();
        let device = DeviceName::new("MapKf7").unwrap();
        let bytes = encoder.point_cloud(&device, Timestamp::default(), &[[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]], &[]);
        let content = &bytes[HEADER_BYTES + 12..];
        assert_eq!(u32_at(content, 0), 2);
        assert_eq!((u32_at(content, 4), u32_at(content, 8)), (1, 12));
        assert_eq!(u32_at(content, 40 + 24), 2, "the cell's point count after the points");
        let empty = encoder.point_cloud(&device, Timestamp::default(), &[], &[]);
        assert_eq!(empty.len(), HEADER_BYTES + 12 + 40 + 2);
    }

    #[test]
    fn device_names_are_short_ascii() {
        assert!(DeviceName::new("MapKf999999999999999").is_ok());
        assert!(DeviceName::new("MapKf9999999999999999").is_err());
        assert!(DeviceName::new("with space").is_err());
        assert!(DeviceName::new("").is_err());
        assert_eq!(DeviceName::new("TrackingState").unwrap().as_str(), "TrackingState");
    }
}
