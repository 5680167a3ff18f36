//! A user's own per-frame masks (`--masks DIR`): many surgical pipelines already run a tool segmentation
//! network, and its output keeps the instruments out of the pose and the map. One PNG (or any image `image`
//! reads) per frame, non-zero = instrument, in the published frame's geometry (rectified, or the field, when
//! acquisition rectifies or splits fields); named like the frame's left image with `.png`
//! (`left/000123.jpg` → `DIR/000123.png`), or for a video by frame number from 1 (`DIR/1.png` is the first).

use std::mem::MaybeUninit;
use std::path::{Path, PathBuf};

use crate::decode::{DecodeError, decode_into, rgb_at};
use crate::source::{Layout, Sequence};

#[derive(Debug, thiserror::Error)]
pub enum MaskError {
    #[error("{dir}: no mask for frame {frame} (expected {expected})")]
    Missing { dir: PathBuf, frame: usize, expected: PathBuf },
    #[error("{path}: mask is {w}×{h}, the frames are {ew}×{eh}")]
    Size { path: PathBuf, w: u32, h: u32, ew: u32, eh: u32 },
    #[error("{path}: {detail}")]
    Unreadable { path: PathBuf, detail: String },
    #[error(transparent)]
    Decode(#[from] DecodeError),
}

/// The masks of one sequence, checked at open (every frame has one, of the frames' size); decodes one at a
/// time into a buffer it owns.
#[derive(Debug)]
pub struct MaskFolder {
    paths: Vec<PathBuf>,
    width: u32,
    height: u32,
    decoded: Vec<u8>,
}

impl MaskFolder {
    /// The mask of every frame of `sequence` in `dir`, each `width × height` (the published frames' size).
    /// Only the files' headers are read here.
    pub fn open(dir: &Path, sequence: &Sequence, width: u32, height: u32) -> Result<Self, MaskError> {
        if !dir.is_dir() {
            return Err(MaskError::Unreadable { path: dir.to_path_buf(), detail: "not a folder".into() });
        }
        let video = matches!(sequence.layout, Layout::Video(_));
        let mut paths = Vec::with_capacity(sequence.frames.len());
        for (i, entry) in sequence.frames.iter().enumerate() {
            let name = match (video, entry.left.file_stem()) {
                (false, Some(stem)) => Path::new(stem).with_extension("png"),
                _ => PathBuf::from(format!("{}.png", entry.source_index + 1)),
            };
            let path = dir.join(name);
            if !path.is_file() {
                return Err(MaskError::Missing { dir: dir.to_path_buf(), frame: i, expected: path });
            }
            let (w, h) = image::image_dimensions(&path)
                .map_err(|e| MaskError::Unreadable { path: path.clone(), detail: e.to_string() })?;
            if (w, h) != (width, height) {
                return Err(MaskError::Size { path, w, h, ew: width, eh: height });
            }
            paths.push(path);
        }
        Ok(Self { paths, width, height, decoded: Vec::new() })
    }

    /// Frames the folder has masks for (the sequence's, from its first frame).
    pub fn len(&self) -> usize {
        self.paths.len()
    }

    pub fn is_empty(&self) -> bool {
        self.paths.is_empty()
    }

    /// The mask file of frame `i` of the sequence.
    pub fn path(&self, i: usize) -> Option<&Path> {
        self.paths.get(i).map(PathBuf::as_path)
    }

    /// Writes frame `i`'s mask into `out` (`width × height` bytes): 255 where the file is non-zero in any
    /// channel, else 0.
    pub fn read_into(&mut self, i: usize, out: &mut [MaybeUninit<u8>]) -> Result<(), MaskError> {
        let Some(path) = self.paths.get(i) else {
            return Err(MaskError::Missing { dir: PathBuf::new(), frame: i, expected: PathBuf::new() });
        };
        let decoded = decode_into(path, &mut self.decoded, self.width, self.height)?;
        let n = self.width as usize * self.height as usize;
        for (k, byte) in out[..n].iter_mut().enumerate() {
            let (r, g, b) = rgb_at(&self.decoded, decoded.color, k);
            byte.write(if (r | g | b) != 0 { 255 } else { 0 });
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn masks_are_found_by_the_left_images_names_and_checked_before_use() {
        let dir = std::env::temp_dir().join(format!("bdis-masks-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        for side in ["left", "right"] {
            std::fs::create_dir_all(dir.join(side)).unwrap();
            for n in [1, 2] {
                image::GrayImage::from_pixel(4, 3, image::Luma([90]))
                    .save(dir.join(format!("{side}/{n}.png")))
                    .unwrap();
            }
        }
        let sequence = Sequence::open(&dir).unwrap();
        let masks = dir.join("masks");
        std::fs::create_dir_all(&masks).unwrap();
        // One mask of two: refused, naming the file that is missing.
        let first = image::GrayImage::from_fn(4, 3, |x, _| image::Luma([if x == 0 { 7 } else { 0 }]));
        first.save(masks.join("1.png")).unwrap();
        let e = MaskFolder::open(&masks, &sequence, 4, 3).unwrap_err();
        assert!(e.to_string().contains("2.png"), "{e}");
        // The wrong size: refused, naming the file and both sizes.
        image::GrayImage::new(5, 3).save(masks.join("2.png")).unwrap();
        let e = MaskFolder::open(&masks, &sequence, 4, 3).unwrap_err();
        assert!(e.to_string().contains("2.png") && e.to_string().contains("5×3"), "{e}");
        image::RgbImage::new(4, 3).save(masks.join("2.png")).unwrap();
        let mut folder = MaskFolder::open(&masks, &sequence, 4, 3).unwrap();
        let mut out = vec![MaybeUninit::new(9u8); 12];
        folder.read_into(0, &mut out).unwrap();
        // SAFETY: read_into wrote all 12 bytes (they were initialised before, too).
        let bytes: Vec<u8> = out.iter().map(|b| unsafe { b.assume_init() }).collect();
        assert_eq!(bytes, [255, 0, 0, 0, 255, 0, 0, 0, 255, 0, 0, 0]);
        folder.read_into(1, &mut out).unwrap();
        // A file that broke after the check: an error naming it, not a panic.
        std::fs::write(masks.join("2.png"), b"not a png").unwrap();
        let e = folder.read_into(1, &mut out).unwrap_err();
        assert!(e.to_string().contains("2.png"), "{e}");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
