//! The undistort–rectify map of one camera, computed once, and the remap that applies it per frame.
//!
//! Every rectified pixel keeps the source pixel to its upper left and its bilinear fractions in 1/32 px, as
//! OpenCV's fixed-point maps do (`INTER_BITS` = 5): a remap is then four loads, integer multiplies and a
//! shift per pixel and channel, with no floating point and no allocation. Rectified pixels whose source lies
//! outside the raw image are black (OpenCV's `BORDER_CONSTANT` 0).

use std::mem::MaybeUninit;

use crate::calib::CameraModel;
use nalgebra::{Matrix3, Matrix3x4, Vector3};

/// A byte a remap writes: a plain buffer's, or a not yet initialised one's (a loaned shared-memory frame,
/// written once).
pub trait OutByte {
    fn set(&mut self, value: u8);
}

impl OutByte for u8 {
    #[inline]
    fn set(&mut self, value: u8) {
        *self = value;
    }
}

impl OutByte for MaybeUninit<u8> {
    #[inline]
    fn set(&mut self, value: u8) {
        self.write(value);
    }
}

/// Sub-pixel steps per pixel of the fixed-point map (5 bits).
pub const FRACTION_STEPS: u32 = 32;
const WEIGHT_SHIFT: u32 = 10; // 32 × 32
const OUTSIDE: u32 = u32::MAX;

/// The map of one camera: for each rectified pixel, the raw pixel to sample.
#[derive(Debug, Clone)]
pub struct RectifyMap {
    /// Rectified image size.
    pub width: usize,
    pub height: usize,
    /// Raw image size.
    pub source_width: usize,
    pub source_height: usize,
    /// Index of the upper-left source pixel of the 2 × 2 neighbourhood, or `OUTSIDE`.
    upper_left: Vec<u32>,
    /// Horizontal and vertical fractions, 0..=32.
    fraction: Vec<[u8; 2]>,
}

impl RectifyMap {
    /// The map of `camera` rectified by rotation `r` into the image of projection `p` (`width` × `height`),
    /// sampling a raw image of `source` size.
    pub fn new(
        camera: &CameraModel,
        r: &Matrix3<f64>,
        p: &Matrix3x4<f64>,
        (width, height): (usize, usize),
        source: (usize, usize),
    ) -> Self {
        let mut map = Self {
            width,
            height,
            source_width: source.0,
            source_height: source.1,
            upper_left: Vec::with_capacity(width * height),
            fraction: Vec::with_capacity(width * height),
        };
        for y in 0..height {
            for x in 0..width {
                let (sx, sy) = source_point(camera, r, p, x as f64, y as f64);
                let (upper_left, fraction) = map.quantise(sx, sy);
                map.upper_left.push(upper_left);
                map.fraction.push(fraction);
            }
        }
        map
    }

    /// The exact (floating-point) source point of rectified pixel (x, y): what the fixed-point map rounds.
    pub fn exact(camera: &CameraModel, r: &Matrix3<f64>, p: &Matrix3x4<f64>, x: f64, y: f64) -> (f64, f64) {
        source_point(camera, r, p, x, y)
    }

    fn quantise(&self, sx: f64, sy: f64) -> (u32, [u8; 2]) {
        let (w, h) = (self.source_width as f64, self.source_height as f64);
        // A source point in [0, w − 1] × [0, h − 1] is inside (the last column and row are reached with a
        // fraction of a whole step from the one before).
        if !(sx >= 0.0 && sy >= 0.0 && sx <= w - 1.0 && sy <= h - 1.0)
            || self.source_width < 2
            || self.source_height < 2
        {
            return (OUTSIDE, [0, 0]);
        }
        let steps = f64::from(FRACTION_STEPS);
        let (qx, qy) = ((sx * steps).round() as u64, (sy * steps).round() as u64);
        let split = |q: u64, size: usize| -> (usize, u8) {
            let whole = (q / u64::from(FRACTION_STEPS)) as usize;
            let fraction = (q % u64::from(FRACTION_STEPS)) as u8;
            if whole >= size - 1 { (size - 2, FRACTION_STEPS as u8) } else { (whole, fraction) }
        };
        let (x0, fx) = split(qx, self.source_width);
        let (y0, fy) = split(qy, self.source_height);
        ((y0 * self.source_width + x0) as u32, [fx, fy])
    }

    /// Rectifies a raw image of `channels` (1 or 3) interleaved channels into `out` (rectified size ×
    /// channels). Panics if the buffers' lengths do not match the map or `channels` is neither 1 nor 3 (a
    /// programming error, not bad input).
    pub fn remap<T: OutByte>(&self, raw: &[u8], channels: usize, out: &mut [T]) {
        assert_eq!(raw.len(), self.source_width * self.source_height * channels, "raw image size");
        assert_eq!(out.len(), self.width * self.height * channels, "rectified image size");
        match channels {
            1 => self.remap_channels::<1, T>(raw, out),
            3 => self.remap_channels::<3, T>(raw, out),
            _ => panic!("remap: {channels} channels (1 or 3 are supported)"),
        }
    }

    // The channel count is a constant so that the per-pixel work unrolls and the slices' bounds are known.
    fn remap_channels<const C: usize, T: OutByte>(&self, raw: &[u8], out: &mut [T]) {
        let row = self.source_width * C;
        let round = 1u32 << (WEIGHT_SHIFT - 1);
        for ((px, &ul), fr) in out.chunks_exact_mut(C).zip(&self.upper_left).zip(&self.fraction) {
            if ul == OUTSIDE {
                px.iter_mut().for_each(|b| b.set(0));
                continue;
            }
            let (fx, fy) = (u32::from(fr[0]), u32::from(fr[1]));
            let w01 = fx * (FRACTION_STEPS - fy);
            let w11 = fx * fy;
            let w00 = (FRACTION_STEPS - fy) * FRACTION_STEPS - w01;
            let w10 = fy * FRACTION_STEPS - w11;
            let base = ul as usize * C;
            let top = &raw[base..base + 2 * C];
            let bottom = &raw[base + row..base + row + 2 * C];
            for c in 0..C {
                let sum = w00 * u32::from(top[c])
                    + w01 * u32::from(top[C + c])
                    + w10 * u32::from(bottom[c])
                    + w11 * u32::from(bottom[C + c]);
                px[c].set(((sum + round) >> WEIGHT_SHIFT) as u8);
            }
        }
    }
}

fn source_point(camera: &CameraModel, r: &Matrix3<f64>, p: &Matrix3x4<f64>, x: f64, y: f64) -> (f64, f64) {
    // Rectified pixel → ray in the rectified frame (P's intrinsics inverted) → raw camera frame (Rᵀ) →
    // distorted pixel. P's 4th column (the baseline) does not move pixels.
    let (f_x, f_y, c_x, c_y) = (p[(0, 0)], p[(1, 1)], p[(0, 2)], p[(1, 2)]);
    let ray = r.transpose() * Vector3::new((x - c_x) / f_x, (y - c_y) / f_y, 1.0);
    if ray.z <= 0.0 {
        return (f64::NAN, f64::NAN);
    }
    camera.project_normalised(ray.x / ray.z, ray.y / ray.z)
}
