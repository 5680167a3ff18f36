//! Sub-pixel measurements by patch alignment: not in ORB-SLAM2 (its measurements are FAST corners at whole pixels
//! of their pyramid level). Each map point keeps an **anchor**, a patch of the image it was first measured in,
//! centred on that measurement; a later match is moved to where the anchor's patch, warped into the new view,
//! fits best (inverse-compositional Lucas–Kanade over the position, with the brightness fitted as a gain and an
//! offset).
//!
//! Why: on the synthetic hover a matched corner moves by 0.5 px (σ, level 0) from frame to frame against the
//! tissue it belongs to — whole-pixel positions, and FAST firing on a slightly different pixel of the same dot
//! as the view and the lighting change. At 60 mm from a 5 mm-baseline scope the pose is weakly held in the
//! rotation-against-sideways-translation direction, so that jitter became ~0.1 mm of sideways pose jitter. The
//! aligned position follows the same piece of tissue in every frame, so keyframes also hand bundle adjustment
//! consistent observations.

use crate::geometry::{CameraFromWorld, RectifiedCamera};
use bdis_orb::{Level, image_to_level, level_to_image};
use nalgebra::{Matrix2, Matrix3, Point3, Vector2, Vector3};

/// σ of a refined measurement relative to its octave's σ (s^o px): where the running estimate starts, and
/// its bounds. The tracker measures it from every frame's residuals (`Map::refined_sigma`): on the synthetic
/// sequences it settles near the floor (a refined match moves 0.1 px, level 0, against the tissue between
/// frames instead of 0.5 px; its disparity error is 0.05 px instead of 0.12 px). The floor keeps the χ² gates
/// from rejecting good measurements for the alignment's own rounding.
pub const INITIAL_REFINED_SIGMA: f64 = 0.35;
pub const MIN_REFINED_SIGMA: f64 = 0.1;
pub const MAX_REFINED_SIGMA: f64 = 1.0;

/// Side of an anchor's patch (level pixels), centred on the anchored measurement.
pub const ANCHOR_SIDE: usize = 19;
const ANCHOR_HALF: f64 = (ANCHOR_SIDE / 2) as f64;
/// Half-side of the aligned template (9 × 9) and of its sampled border (one more, for its gradients).
const TEMPLATE_HALF: i32 = 4;
const SAMPLED_HALF: i32 = TEMPLATE_HALF + 1;
const SAMPLED_SIDE: usize = (2 * SAMPLED_HALF + 1) as usize;
const TEMPLATE_SIDE: usize = (2 * TEMPLATE_HALF + 1) as usize;
/// Gauss–Newton iterations at most, and the step (level px) below which the alignment has converged.
const MAX_ITERATIONS: usize = 10;
const CONVERGED_STEP: f64 = 0.03;
/// The aligned position may move at most this far (level px) from the matched keypoint: further means the
/// alignment slid to other texture.
pub const MAX_SHIFT: f64 = 1.5;

/// The patch a map point was anchored with, the scale of its pyramid level and the pose of the frame it was
/// cut from (for the warp into later views).
#[derive(Debug, Clone, PartialEq)]
pub struct Anchor {
    pub patch: [u8; ANCHOR_SIDE * ANCHOR_SIDE],
    pub scale: f64,
    pub camera_from_world: CameraFromWorld,
}

impl Anchor {
    /// The patch around level-0 position (u, v) of `level` (scale `scale`), bilinear where the centre falls
    /// between pixels; `None` when the patch does not fit inside the level.
    pub fn cut(level: &Level, scale: f64, u: f64, v: f64, camera_from_world: CameraFromWorld) -> Option<Self> {
        let (x, y) = (to_level(u, scale), to_level(v, scale));
        let (x0, y0) = (x - ANCHOR_HALF, y - ANCHOR_HALF);
        if x0 < 0.0
            || y0 < 0.0
            || x0 + ANCHOR_SIDE as f64 >= level.w as f64
            || y0 + ANCHOR_SIDE as f64 >= level.h as f64
        {
            return None;
        }
        let mut patch = [0u8; ANCHOR_SIDE * ANCHOR_SIDE];
        for (r, row) in patch.chunks_exact_mut(ANCHOR_SIDE).enumerate() {
            for (c, out) in row.iter_mut().enumerate() {
                *out = bilinear(&level.data, level.w, x0 + c as f64, y0 + r as f64).round() as u8;
            }
        }
        Some(Self { patch, scale, camera_from_world })
    }

    fn sample(&self, x: f64, y: f64) -> f64 {
        bilinear(&self.patch, ANCHOR_SIDE, x, y)
    }
}

/// Bilinear sample at (x, y) of an image stored row by row with `stride`; the caller keeps (x, y) inside
/// [0, w − 1) × [0, h − 1).
fn bilinear(data: &[u8], stride: usize, x: f64, y: f64) -> f64 {
    // Truncation is the floor there (x, y ≥ 0), and one instruction where `floor` is a library call (the x86-64
    // baseline has no rounding instruction).
    let (xi, yi) = ((x as usize) as f64, (y as usize) as f64);
    let (ax, ay) = (x - xi, y - yi);
    let i = yi as usize * stride + xi as usize;
    let (a, b, c, e) =
        (f64::from(data[i]), f64::from(data[i + 1]), f64::from(data[i + stride]), f64::from(data[i + stride + 1]));
    (1.0 - ay) * ((1.0 - ax) * a + ax * b) + ay * ((1.0 - ax) * c + ax * e)
}

/// Why a measurement was not refined.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Unrefined {
    /// The view changed so much that the anchor's patch no longer covers the warped template: anchor anew.
    OutOfAnchor,
    /// Too close to the image border, no texture, no convergence, or slid too far: keep the keypoint.
    Failed,
}

/// The alignment's template (an anchor's patch warped into a frame's level) and its fixed normal matrices.
#[derive(Debug, Clone)]
pub struct Aligner {
    template: [f64; SAMPLED_SIDE * SAMPLED_SIDE],
    /// The template's inner 9 × 9 values and their (∂T/∂x, ∂T/∂y, 1), row by row.
    values: [f64; TEMPLATE_SIDE * TEMPLATE_SIDE],
    jacobians: [Vector3<f64>; TEMPLATE_SIDE * TEMPLATE_SIDE],
    /// Inverse normal matrix of (x, y, brightness offset), and of (x, offset) for the right image's row.
    inverse_2d: Matrix3<f64>,
    inverse_1d: Matrix2<f64>,
    /// See [`Self::spread`].
    last_spread: f64,
}

impl Default for Aligner {
    fn default() -> Self {
        Self {
            template: [0.0; SAMPLED_SIDE * SAMPLED_SIDE],
            values: [0.0; TEMPLATE_SIDE * TEMPLATE_SIDE],
            jacobians: [Vector3::zeros(); TEMPLATE_SIDE * TEMPLATE_SIDE],
            inverse_2d: Matrix3::zeros(),
            inverse_1d: Matrix2::zeros(),
            last_spread: f64::NAN,
        }
    }
}

impl Aligner {
    /// σ (level px) of the last [`Self::refine`]'s position as its own fit sees it: the residual's variance
    /// (81 pixels, 4 parameters) through the inverse normal matrix of the position, over the gain (the template
    /// scaled by it has its gradients scaled too). A residual the gain and offset could not take out (a
    /// highlight or a shadow that moved with the scope's light) widens it, as image noise does.
    pub fn spread(&self) -> f64 {
        self.last_spread
    }

    /// Refines the level-0 measurement (u, v) of the point `x_world`, matched at a keypoint of `level` (scale
    /// `scale`) in a frame at `camera_from_world`, against the point's anchor. Returns the refined level-0
    /// position; the template stays loaded for [`Self::refine_right`].
    #[allow(clippy::too_many_arguments)]
    pub fn refine(
        &mut self,
        cam: &RectifiedCamera,
        level: &Level,
        scale: f64,
        u: f64,
        v: f64,
        x_world: &Point3<f64>,
        camera_from_world: &CameraFromWorld,
        anchor: &Anchor,
    ) -> Result<(f64, f64), Unrefined> {
        let warp = warp_to_anchor(cam, scale, u, v, x_world, camera_from_world, anchor).ok_or(Unrefined::Failed)?;
        self.load(anchor, &warp)?;
        let start = Vector2::new(to_level(u, scale), to_level(v, scale));
        let (aligned, spread) = self.align(level, start, false)?;
        self.last_spread = spread;
        Ok((to_image(aligned.x, scale), to_image(aligned.y, scale)))
    }

    /// Loads `anchor`'s patch as it is (no warp): for the right image of the anchor's own frame, which a
    /// rectified rig sees at the same scale and orientation.
    pub fn load_unwarped(&mut self, anchor: &Anchor) -> Result<(), Unrefined> {
        self.load(anchor, &Matrix2::identity())
    }

    /// Aligns the loaded template along row `v` (level 0) of the right image's `level` (scale `scale`), from
    /// `u_right`; returns the refined level-0 u of the right-image match.
    pub fn refine_right(&self, level: &Level, scale: f64, u_right: f64, v: f64) -> Result<f64, Unrefined> {
        let start = Vector2::new(to_level(u_right, scale), to_level(v, scale));
        let (aligned, _) = self.align(level, start, true)?;
        Ok(to_image(aligned.x, scale))
    }

    /// The template: the anchor's patch seen in a level's pixel grid through `warp` (this level's pixel
    /// offsets → the anchor's), with its gradients' normal matrices (fixed over the iterations: inverse
    /// compositional).
    fn load(&mut self, anchor: &Anchor, warp: &Matrix2<f64>) -> Result<(), Unrefined> {
        let centre = Vector2::new(ANCHOR_HALF, ANCHOR_HALF);
        for corner in [(-1.0, -1.0), (1.0, -1.0), (-1.0, 1.0), (1.0, 1.0)] {
            let p = centre + warp * Vector2::new(corner.0, corner.1) * f64::from(SAMPLED_HALF);
            if p.x < 0.0 || p.y < 0.0 || p.x >= (ANCHOR_SIDE - 1) as f64 || p.y >= (ANCHOR_SIDE - 1) as f64 {
                return Err(Unrefined::OutOfAnchor);
            }
        }
        for r in 0..SAMPLED_SIDE {
            for c in 0..SAMPLED_SIDE {
                let offset = Vector2::new(c as f64, r as f64) - Vector2::repeat(f64::from(SAMPLED_HALF));
                let p = centre + warp * offset;
                self.template[r * SAMPLED_SIDE + c] = anchor.sample(p.x, p.y);
            }
        }
        let (mut h2, mut h1) = (Matrix3::<f64>::zeros(), Matrix2::<f64>::zeros());
        for r in -TEMPLATE_HALF..=TEMPLATE_HALF {
            for c in -TEMPLATE_HALF..=TEMPLATE_HALF {
                let j = self.jacobian(c, r);
                let k = (r + TEMPLATE_HALF) as usize * TEMPLATE_SIDE + (c + TEMPLATE_HALF) as usize;
                self.values[k] = self.at(c, r);
                self.jacobians[k] = j;
                h2 += j * j.transpose();
                let j1 = Vector2::new(j.x, 1.0);
                h1 += j1 * j1.transpose();
            }
        }
        self.inverse_2d = h2.try_inverse().ok_or(Unrefined::Failed)?;
        self.inverse_1d = h1.try_inverse().ok_or(Unrefined::Failed)?;
        Ok(())
    }

    fn at(&self, c: i32, r: i32) -> f64 {
        self.template[(r + SAMPLED_HALF) as usize * SAMPLED_SIDE + (c + SAMPLED_HALF) as usize]
    }

    /// (∂T/∂x, ∂T/∂y, 1) of the template at (c, r), central differences.
    fn jacobian(&self, c: i32, r: i32) -> Vector3<f64> {
        Vector3::new(0.5 * (self.at(c + 1, r) - self.at(c - 1, r)), 0.5 * (self.at(c, r + 1) - self.at(c, r - 1)), 1.0)
    }

    /// Gauss–Newton from `start` (level pixels) over the position (x only when `horizontal`), minimising the
    /// squared difference of the level and the template under a brightness change: along the right image's row
    /// an offset (the two cameras see the same light at the same moment), in a later view a gain and an offset,
    /// fitted to the window at every step.
    ///
    /// Why a gain: an endoscope's light rides on the scope, so a patch seen from half the distance is about
    /// four times as bright — a factor, not an offset. With an offset alone, the part of the difference that
    /// is the template's own contrast pulls the position towards where the template's contrast is stronger,
    /// the same way in every later view; the point's later observations then sit off its first by a common
    /// offset that bundle adjustment cannot average away (BENCHMARKS, issue #16: on the 640×480 colon revisit
    /// 14.5 % of the points were off by > 0.4 px of their octave, and the median ATE over 12 starts went
    /// 0.031 → 0.018 mm with the gain).
    fn align(&self, level: &Level, start: Vector2<f64>, horizontal: bool) -> Result<(Vector2<f64>, f64), Unrefined> {
        let mut position = start;
        let mut offset = 0.0;
        let reach = f64::from(TEMPLATE_HALF) + 1.0;
        for _ in 0..MAX_ITERATIONS {
            if position.x - reach < 0.0
                || position.y - reach < 0.0
                || position.x + reach >= level.w as f64
                || position.y + reach >= level.h as f64
            {
                return Err(Unrefined::Failed);
            }
            // Every sample of the window shares the position's fraction, so one set of bilinear weights.
            let corner = position - Vector2::repeat(f64::from(TEMPLATE_HALF));
            let (x0, y0) = (corner.x.floor(), corner.y.floor());
            let (ax, ay) = (corner.x - x0, corner.y - y0);
            let (w00, w10, w01, w11) = ((1.0 - ax) * (1.0 - ay), ax * (1.0 - ay), (1.0 - ax) * ay, ax * ay);
            let mut window = [0.0; TEMPLATE_SIDE * TEMPLATE_SIDE];
            // Sums of the template t and the window i over the window, for the brightness's least squares.
            let (mut t_sum, mut i_sum, mut tt_sum, mut it_sum) = (0.0, 0.0, 0.0, 0.0);
            for r in 0..TEMPLATE_SIDE {
                let top = (y0 as usize + r) * level.w + x0 as usize;
                let (upper, lower) =
                    (&level.data[top..top + TEMPLATE_SIDE + 1], &level.data[top + level.w..][..TEMPLATE_SIDE + 1]);
                let row = r * TEMPLATE_SIDE;
                for c in 0..TEMPLATE_SIDE {
                    let image = w00 * f64::from(upper[c])
                        + w10 * f64::from(upper[c + 1])
                        + w01 * f64::from(lower[c])
                        + w11 * f64::from(lower[c + 1]);
                    let t = self.values[row + c];
                    window[row + c] = image;
                    t_sum += t;
                    i_sum += image;
                    tt_sum += t * t;
                    it_sum += image * t;
                }
            }
            let gain = if horizontal {
                1.0
            } else {
                let n = window.len() as f64;
                let t_var = tt_sum - t_sum * t_sum / n;
                // A gain beyond 4× (a patch at half or twice the anchor's distance, or more) is saturation or
                // other tissue, not light: the alignment keeps the nearest plausible one.
                let gain = if t_var > 0.0 { ((it_sum - t_sum * i_sum / n) / t_var).clamp(0.25, 4.0) } else { 1.0 };
                offset = (i_sum - gain * t_sum) / n;
                gain
            };
            let mut gradient = Vector3::<f64>::zeros();
            let mut ssr = 0.0;
            for ((j, &t), &image) in self.jacobians.iter().zip(&self.values).zip(&window) {
                let r = image - gain * t - offset;
                gradient += j * r;
                ssr += r * r;
            }
            let step = if horizontal {
                let s = self.inverse_1d * Vector2::new(gradient.x, gradient.z);
                offset += s.y;
                Vector3::new(s.x, 0.0, s.y)
            } else {
                // The template scaled by the gain has its gradients scaled too: the step by its inverse.
                self.inverse_2d * gradient / gain
            };
            position -= Vector2::new(step.x, step.y);
            if step.x * step.x + step.y * step.y < CONVERGED_STEP * CONVERGED_STEP {
                let var = ssr / (window.len() as f64 - 4.0);
                let spread = (var * 0.5 * (self.inverse_2d[(0, 0)] + self.inverse_2d[(1, 1)])).sqrt() / gain;
                return if (position - start).norm() > MAX_SHIFT {
                    Err(Unrefined::Failed)
                } else {
                    Ok((position, spread))
                };
            }
        }
        Err(Unrefined::Failed)
    }
}

fn to_level(u: f64, scale: f64) -> f64 {
    f64::from(image_to_level(u as f32, scale as f32))
}

fn to_image(x: f64, scale: f64) -> f64 {
    f64::from(level_to_image(x as f32, scale as f32))
}

/// The linear map from pixel offsets of this frame's level (around the measurement) to pixel offsets of the
/// anchor's level: the point's neighbourhood taken as facing this camera at the point's depth, carried into
/// the anchor's frame.
fn warp_to_anchor(
    cam: &RectifiedCamera,
    scale: f64,
    u: f64,
    v: f64,
    x_world: &Point3<f64>,
    camera_from_world: &CameraFromWorld,
    anchor: &Anchor,
) -> Option<Matrix2<f64>> {
    let z = (camera_from_world * x_world).z;
    if z <= 0.0 {
        return None;
    }
    let anchor_from_camera = anchor.camera_from_world * camera_from_world.inverse();
    // Offsets of several level pixels: the patch is that large, and the map is then its average over it.
    let d = f64::from(SAMPLED_HALF);
    let in_anchor = |du: f64, dv: f64| -> Option<Vector2<f64>> {
        let p = anchor_from_camera * cam.unproject(u + du * scale, v + dv * scale, z);
        if p.z <= 0.0 {
            return None;
        }
        let (au, av) = cam.project(&p);
        Some(Vector2::new(au, av) / anchor.scale)
    };
    let centre = in_anchor(0.0, 0.0)?;
    let x = (in_anchor(d, 0.0)? - centre) / d;
    let y = (in_anchor(0.0, d)? - centre) / d;
    Some(Matrix2::from_columns(&[x, y]))
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Isometry3, Translation3, UnitQuaternion};

    fn cam() -> RectifiedCamera {
        RectifiedCamera { fx: 520.0, fy: 520.0, cx: 319.5, cy: 239.5, bf: 2600.0, width: 640, height: 480 }
    }

    /// A smooth texture of dots on the plane z = 60 mm, rendered by a camera at `camera_from_world` (area
    /// sampled, so that sub-pixel positions are in the image).
    fn render(camera_from_world: &CameraFromWorld) -> Level {
        let c = cam();
        let world_from_camera = camera_from_world.inverse();
        let texture = |x: f64, y: f64| {
            let mut value = 180.0;
            for k in 0..40 {
                let (cx, cy) = ((k * 37 % 23) as f64 * 0.9 - 10.0, (k * 53 % 19) as f64 * 0.9 - 8.0);
                let r2 = (x - cx).powi(2) + (y - cy).powi(2);
                value -= 120.0 * (-r2 / 0.08).exp();
            }
            value
        };
        let (width, height) = (c.width as usize, c.height as usize);
        let mut data = vec![0u8; width * height];
        for y in 0..height {
            for x in 0..width {
                let mut sum = 0.0;
                for (sx, sy) in [(-0.25, -0.25), (0.25, -0.25), (-0.25, 0.25), (0.25, 0.25)] {
                    let ray = Vector3::new((x as f64 + sx - c.cx) / c.fx, (y as f64 + sy - c.cy) / c.fy, 1.0);
                    let origin = world_from_camera.translation.vector;
                    let dir = world_from_camera.rotation * ray;
                    let t = (60.0 - origin.z) / dir.z;
                    let hit = origin + dir * t;
                    sum += texture(hit.x, hit.y);
                }
                data[y * width + x] = (sum / 4.0).round().clamp(0.0, 255.0) as u8;
            }
        }
        Level { w: width, h: height, data }
    }

    /// The dots' rims seen from the identity and from 0.8 mm sideways, 1.5 mm closer with a small turn (the dots
    /// move by tens of pixels and grow by 2.5 %), the second view's grey levels through `light`: each point's
    /// aligned error and its matched keypoint's (the true position rounded, as FAST reports it), sorted, px.
    fn align_moved_view(light: impl Fn(u8) -> u8) -> (Vec<f64>, Vec<f64>) {
        let aligned = align_points_in_moved_view(|_, _, value| light(value));
        let mut errors: Vec<f64> = aligned.iter().map(|a| a.error).collect();
        let mut rounded: Vec<f64> = aligned.iter().map(|a| a.rounded).collect();
        errors.sort_by(f64::total_cmp);
        rounded.sort_by(f64::total_cmp);
        (errors, rounded)
    }

    struct AlignedPoint {
        error: f64,
        rounded: f64,
        spread: f64,
    }

    /// [`align_moved_view`]'s 40 points in order, the second view's grey level at (x, y) through `light`.
    fn align_points_in_moved_view(light: impl Fn(usize, usize, u8) -> u8) -> Vec<AlignedPoint> {
        let c = cam();
        let first = Isometry3::identity();
        let second = Isometry3::from_parts(
            Translation3::new(0.8, -0.4, 1.5),
            UnitQuaternion::from_euler_angles(0.01, -0.008, 0.02),
        )
        .inverse();
        let a = render(&first);
        let mut b = render(&second);
        let width = b.w;
        b.data.iter_mut().enumerate().for_each(|(i, value)| *value = light(i % width, i / width, *value));
        let mut aligner = Aligner::default();
        let mut aligned = Vec::new();
        for k in 0..40 {
            let (x, y) = ((k * 37 % 23) as f64 * 0.9 - 10.0, (k * 53 % 19) as f64 * 0.9 - 8.0);
            // A point at the dot's rim: texture in both directions.
            let world = Point3::new(x + 0.2, y + 0.1, 60.0);
            let (u0, v0) = c.project(&(first * world));
            let anchor = Anchor::cut(&a, 1.0, u0, v0, first).expect("inside");
            let (u1, v1) = c.project(&(second * world));
            let (ku, kv) = (u1.round(), v1.round());
            let (ru, rv) = aligner.refine(&c, &b, 1.0, ku, kv, &world, &second, &anchor).expect("aligned");
            aligned.push(AlignedPoint {
                error: ((ru - u1).powi(2) + (rv - v1).powi(2)).sqrt(),
                rounded: ((ku - u1).powi(2) + (kv - v1).powi(2)).sqrt(),
                spread: aligner.spread(),
            });
        }
        aligned
    }

    #[test]
    fn alignment_finds_the_anchored_tissue_in_a_moved_view_to_a_tenth_of_a_pixel() {
        let (errors, rounded) = align_moved_view(|value| value);
        let (median, before) = (errors[errors.len() / 2], rounded[rounded.len() / 2]);
        eprintln!("median error: {before:.3} px at the whole pixel, {median:.3} px aligned");
        assert!(median < 0.1 && median < 0.3 * before, "median error {median:.3} px (errors {errors:?})");
    }

    /// The scope's light nearer the tissue: the second view 1.35× as bright (a tenth closer to the light is
    /// 1.23×). The dots are off-centre in most patches, so an offset-only fit is pulled towards their contrast.
    #[test]
    fn a_brighter_view_is_aligned_as_well_as_an_equally_lit_one() {
        let (errors, _) = align_moved_view(|value| (f64::from(value) * 1.35).round().min(255.0) as u8);
        let (median, worst) = (errors[errors.len() / 2], errors[errors.len() - 1]);
        eprintln!("1.35× brighter: median error {median:.3} px, worst {worst:.3} px");
        // With an offset alone: median 0.064 px, worst 0.088 px.
        assert!(median < 0.03 && worst < 0.06, "errors {errors:?}");
    }

    /// A highlight the scope's light moved onto a patch since its anchor was cut (a bright spot 3 px beside
    /// the point, in every fourth patch): those fits are worse, and their own σ says so — the weight the tracker
    /// gives each aligned measurement ([`Aligner::spread`]).
    #[test]
    fn a_fit_a_moved_highlight_spoiled_reports_a_wider_spread() {
        let c = cam();
        let second = Isometry3::from_parts(
            Translation3::new(0.8, -0.4, 1.5),
            UnitQuaternion::from_euler_angles(0.01, -0.008, 0.02),
        )
        .inverse();
        let spots: Vec<(f64, f64)> = (0..40)
            .step_by(4)
            .map(|k| {
                let (x, y) = ((k * 37 % 23) as f64 * 0.9 - 10.0, (k * 53 % 19) as f64 * 0.9 - 8.0);
                let (u, v) = c.project(&(second * Point3::new(x + 0.2, y + 0.1, 60.0)));
                (u + 3.0, v - 1.0)
            })
            .collect();
        let highlight = |x: usize, y: usize, value: u8| {
            let lift: f64 = spots
                .iter()
                .map(|&(u, v)| 70.0 * (-((x as f64 - u).powi(2) + (y as f64 - v).powi(2)) / 8.0).exp())
                .sum();
            (f64::from(value) + lift).round().min(255.0) as u8
        };
        let clean = align_points_in_moved_view(|_, _, value| value);
        let lit = align_points_in_moved_view(highlight);
        let median = |mut v: Vec<f64>| {
            v.sort_by(f64::total_cmp);
            v[v.len() / 2]
        };
        let spoiled = |k: usize| k.is_multiple_of(4);
        let pick = |points: &[AlignedPoint], keep: &dyn Fn(usize) -> bool, field: fn(&AlignedPoint) -> f64| {
            points.iter().enumerate().filter(|(k, _)| keep(*k)).map(|(_, p)| field(p)).collect::<Vec<_>>()
        };
        let spread_spoiled = median(pick(&lit, &spoiled, |p| p.spread));
        let spread_others = median(pick(&lit, &|k| !spoiled(k), |p| p.spread));
        let spread_clean = median(pick(&clean, &spoiled, |p| p.spread));
        let error_spoiled = median(pick(&lit, &spoiled, |p| p.error));
        let error_clean = median(pick(&clean, &spoiled, |p| p.error));
        eprintln!(
            "spoiled patches: spread {spread_spoiled:.4} (clean {spread_clean:.4}, the others {spread_others:.4}), \
             error {error_spoiled:.3} px (clean {error_clean:.3})"
        );
        assert!(error_spoiled > 2.0 * error_clean, "the highlight did not spoil the fits");
        assert!(spread_spoiled > 3.0 * spread_clean && spread_spoiled > 3.0 * spread_others);
    }

    #[test]
    fn the_right_image_match_is_found_along_the_row_to_a_twentieth_of_a_pixel() {
        let c = cam();
        let left = Isometry3::identity();
        // The right camera: the baseline (bf / fx = 5 mm) along x.
        let right = Isometry3::from_parts(Translation3::new(5.0, 0.0, 0.0), UnitQuaternion::identity()).inverse();
        let (l, r) = (render(&left), render(&right));
        let true_disparity = c.bf / 60.0;
        let mut aligner = Aligner::default();
        let mut errors = Vec::new();
        for k in 0..40 {
            let (x, y) = ((k * 37 % 23) as f64 * 0.9 - 10.0, (k * 53 % 19) as f64 * 0.9 - 8.0);
            let (u, v) = c.project(&Point3::new(x + 0.2, y + 0.1, 60.0));
            let (u, v) = (u.round(), v.round());
            let anchor = Anchor::cut(&l, 1.0, u, v, left).expect("inside");
            aligner.load_unwarped(&anchor).expect("textured");
            // The SAD match, a few tenths of a pixel off.
            let start = (u - true_disparity).round() + 0.4;
            let u_right = aligner.refine_right(&r, 1.0, start, v).expect("aligned");
            errors.push((u - u_right - true_disparity).abs());
        }
        errors.sort_by(f64::total_cmp);
        let median = errors[errors.len() / 2];
        assert!(median < 0.05, "median disparity error {median:.3} px (errors {errors:?})");
    }

    #[test]
    fn a_patch_outside_the_level_or_a_view_far_from_the_anchor_is_refused() {
        let c = cam();
        let level = render(&Isometry3::identity());
        assert!(Anchor::cut(&level, 1.0, 3.0, 200.0, Isometry3::identity()).is_none());
        let world = Point3::new(0.0, 0.0, 60.0);
        let anchor = Anchor::cut(&level, 1.0, 319.5, 239.5, Isometry3::identity()).expect("inside");
        // Twice as far: a pixel here spans two of the anchor's, so its patch covers only half of the template.
        let farther = Isometry3::from_parts(Translation3::new(0.0, 0.0, -60.0), UnitQuaternion::identity()).inverse();
        let mut aligner = Aligner::default();
        let got = aligner.refine(&c, &level, 1.0, 319.5, 239.5, &world, &farther, &anchor);
        assert_eq!(got, Err(Unrefined::OutOfAnchor));
    }
}
