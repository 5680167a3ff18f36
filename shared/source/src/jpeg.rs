//! Motion-JPEG frames as capture devices and AVI recorders write them: often without Huffman tables (no `DHT`
//! segment), because Motion-JPEG fixes them to the example tables of the JPEG standard (ITU-T T.81, Annex K.3;
//! the AVI1 / UVC convention). A still-image decoder refuses such a frame; it is completed here by inserting the
//! standard tables before the scan, the way ffmpeg's decoder assumes them.

/// Bits (code counts per length 1–16) and values of the four standard tables, as (class·16 + id, bits, values).
const STANDARD_TABLES: [(u8, [u8; 16], &[u8]); 4] = [
    (0x00, [0, 1, 5, 1, 1, 1, 1, 1, 1, 0, 0, 0, 0, 0, 0, 0], &[0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11]),
    (0x01, [0, 3, 1, 1, 1, 1, 1, 1, 1, 1, 1, 0, 0, 0, 0, 0], &[0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11]),
    (0x10, [0, 2, 1, 3, 3, 2, 4, 3, 5, 5, 4, 4, 0, 0, 1, 0x7d], &AC_LUMINANCE),
    (0x11, [0, 2, 1, 2, 4, 4, 3, 4, 7, 5, 4, 4, 0, 1, 2, 0x77], &AC_CHROMINANCE),
];

#[rustfmt::skip]
const AC_LUMINANCE: [u8; 162] = [
    0x01, 0x02, 0x03, 0x00, 0x04, 0x11, 0x05, 0x12, 0x21, 0x31, 0x41, 0x06, 0x13, 0x51, 0x61, 0x07,
    0x22, 0x71, 0x14, 0x32, 0x81, 0x91, 0xa1, 0x08, 0x23, 0x42, 0xb1, 0xc1, 0x15, 0x52, 0xd1, 0xf0,
    0x24, 0x33, 0x62, 0x72, 0x82, 0x09, 0x0a, 0x16, 0x17, 0x18, 0x19, 0x1a, 0x25, 0x26, 0x27, 0x28,
    0x29, 0x2a, 0x34, 0x35, 0x36, 0x37, 0x38, 0x39, 0x3a, 0x43, 0x44, 0x45, 0x46, 0x47, 0x48, 0x49,
    0x4a, 0x53, 0x54, 0x55, 0x56, 0x57, 0x58, 0x59, 0x5a, 0x63, 0x64, 0x65, 0x66, 0x67, 0x68, 0x69,
    0x6a, 0x73, 0x74, 0x75, 0x76, 0x77, 0x78, 0x79, 0x7a, 0x83, 0x84, 0x85, 0x86, 0x87, 0x88, 0x89,
    0x8a, 0x92, 0x93, 0x94, 0x95, 0x96, 0x97, 0x98, 0x99, 0x9a, 0xa2, 0xa3, 0xa4, 0xa5, 0xa6, 0xa7,
    0xa8, 0xa9, 0xaa, 0xb2, 0xb3, 0xb4, 0xb5, 0xb6, 0xb7, 0xb8, 0xb9, 0xba, 0xc2, 0xc3, 0xc4, 0xc5,
    0xc6, 0xc7, 0xc8, 0xc9, 0xca, 0xd2, 0xd3, 0xd4, 0xd5, 0xd6, 0xd7, 0xd8, 0xd9, 0xda, 0xe1, 0xe2,
    0xe3, 0xe4, 0xe5, 0xe6, 0xe7, 0xe8, 0xe9, 0xea, 0xf1, 0xf2, 0xf3, 0xf4, 0xf5, 0xf6, 0xf7, 0xf8,
    0xf9, 0xfa,
];

#[rustfmt::skip]
const AC_CHROMINANCE: [u8; 162] = [
    0x00, 0x01, 0x02, 0x03, 0x11, 0x04, 0x05, 0x21, 0x31, 0x06, 0x12, 0x41, 0x51, 0x07, 0x61, 0x71,
    0x13, 0x22, 0x32, 0x81, 0x08, 0x14, 0x42, 0x91, 0xa1, 0xb1, 0xc1, 0x09, 0x23, 0x33, 0x52, 0xf0,
    0x15, 0x62, 0x72, 0xd1, 0x0a, 0x16, 0x24, 0x34, 0xe1, 0x25, 0xf1, 0x17, 0x18, 0x19, 0x1a, 0x26,
    0x27, 0x28, 0x29, 0x2a, 0x35, 0x36, 0x37, 0x38, 0x39, 0x3a, 0x43, 0x44, 0x45, 0x46, 0x47, 0x48,
    0x49, 0x4a, 0x53, 0x54, 0x55, 0x56, 0x57, 0x58, 0x59, 0x5a, 0x63, 0x64, 0x65, 0x66, 0x67, 0x68,
    0x69, 0x6a, 0x73, 0x74, 0x75, 0x76, 0x77, 0x78, 0x79, 0x7a, 0x82, 0x83, 0x84, 0x85, 0x86, 0x87,
    0x88, 0x89, 0x8a, 0x92, 0x93, 0x94, 0x95, 0x96, 0x97, 0x98, 0x99, 0x9a, 0xa2, 0xa3, 0xa4, 0xa5,
    0xa6, 0xa7, 0xa8, 0xa9, 0xaa, 0xb2, 0xb3, 0xb4, 0xb5, 0xb6, 0xb7, 0xb8, 0xb9, 0xba, 0xc2, 0xc3,
    0xc4, 0xc5, 0xc6, 0xc7, 0xc8, 0xc9, 0xca, 0xd2, 0xd3, 0xd4, 0xd5, 0xd6, 0xd7, 0xd8, 0xd9, 0xda,
    0xe2, 0xe3, 0xe4, 0xe5, 0xe6, 0xe7, 0xe8, 0xe9, 0xea, 0xf2, 0xf3, 0xf4, 0xf5, 0xf6, 0xf7, 0xf8,
    0xf9, 0xfa,
];

/// Where the first scan (`SOS`) starts, when no `DHT` segment comes before it; `None` when the frame has its
/// tables (or is not a JPEG this can walk: the decoder then says what is wrong).
fn scan_without_tables(jpeg: &[u8]) -> Option<usize> {
    if jpeg.get(..2) != Some(&[0xFF, 0xD8]) {
        return None;
    }
    let mut at = 2;
    loop {
        // Fill bytes (0xFF) may pad before a marker.
        while jpeg.get(at) == Some(&0xFF) && jpeg.get(at + 1) == Some(&0xFF) {
            at += 1;
        }
        let marker = match jpeg.get(at..at + 2) {
            Some(&[0xFF, m]) => m,
            _ => return None,
        };
        match marker {
            0xC4 => return None,
            0xDA => return Some(at),
            // Markers without a length.
            0x01 | 0xD0..=0xD7 => at += 2,
            _ => {
                let length = usize::from(u16::from_be_bytes([*jpeg.get(at + 2)?, *jpeg.get(at + 3)?]));
                at += 2 + length;
            }
        }
    }
}

/// The frame as a decoder can read it: `jpeg` itself, or (no Huffman tables) a copy in `completed` with the
/// standard tables inserted before the scan. `completed` is reused: once grown, no allocation.
pub fn with_huffman_tables<'a>(jpeg: &'a [u8], completed: &'a mut Vec<u8>) -> &'a [u8] {
    let Some(scan) = scan_without_tables(jpeg) else {
        return jpeg;
    };
    completed.clear();
    completed.extend_from_slice(&jpeg[..scan]);
    let length: usize = 2 + STANDARD_TABLES.iter().map(|(_, _, values)| 17 + values.len()).sum::<usize>();
    completed.extend_from_slice(&[0xFF, 0xC4]);
    completed.extend_from_slice(&(length as u16).to_be_bytes());
    for (class_id, bits, values) in STANDARD_TABLES {
        completed.push(class_id);
        completed.extend_from_slice(&bits);
        completed.extend_from_slice(values);
    }
    completed.extend_from_slice(&jpeg[scan..]);
    completed
}

/// Removes the Huffman tables from a frame, as a UVC camera sends it (the emulated device does this).
pub(crate) fn strip_huffman_tables(jpeg: &mut Vec<u8>) {
    let mut at = 2;
    while let Some(&[0xFF, marker, hi, lo]) = jpeg.get(at..at + 4) {
        if marker == 0xDA {
            return;
        }
        let end = at + 2 + usize::from(u16::from_be_bytes([hi, lo]));
        if marker == 0xC4 {
            jpeg.drain(at..end.min(jpeg.len()));
        } else {
            at = end;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use image::ImageDecoder;

    fn decode(jpeg: &[u8]) -> Result<Vec<u8>, image::ImageError> {
        let decoder = image::codecs::jpeg::JpegDecoder::new(std::io::Cursor::new(jpeg))?;
        let mut out = vec![0u8; usize::try_from(decoder.total_bytes()).unwrap_or(0)];
        decoder.read_image(&mut out)?;
        Ok(out)
    }

    #[test]
    fn a_frame_without_tables_decodes_as_it_did_with_the_standard_ones() {
        // `image` encodes with the standard tables: without them the frame is what a UVC camera sends.
        let (w, h) = (48u32, 32u32);
        let rgb: Vec<u8> = (0..w * h * 3).map(|i| ((i * 37) % 251) as u8).collect();
        let mut jpeg = Vec::new();
        image::codecs::jpeg::JpegEncoder::new_with_quality(&mut jpeg, 90)
            .encode(&rgb, w, h, image::ExtendedColorType::Rgb8)
            .unwrap_or_else(|e| panic!("{e}"));
        let mut bare = jpeg.clone();
        strip_huffman_tables(&mut bare);
        assert!(bare.len() < jpeg.len() && decode(&bare).is_err(), "the decoder needs the tables");
        let mut completed = Vec::new();
        let fixed = with_huffman_tables(&bare, &mut completed).to_vec();
        assert_eq!(decode(&fixed).ok(), decode(&jpeg).ok());
        // A frame with its tables, or something else, is passed through untouched.
        assert_eq!(with_huffman_tables(&jpeg, &mut completed), &jpeg[..]);
        assert_eq!(with_huffman_tables(b"\xFF\xD8\xFF", &mut completed), b"\xFF\xD8\xFF");
        assert_eq!(with_huffman_tables(b"RIFF", &mut completed), b"RIFF");
    }
}
