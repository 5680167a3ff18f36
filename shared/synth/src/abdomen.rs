//! A laparoscopic view: an uneven abdominal wall with organ-like blobs, seen from above. The surface is the
//! height field `z = d(x, y)` (world z points away from the scope, as the camera looks down the z axis at rest):
//! a gently curved wall at `distance_mm`, organ blobs rising towards the scope, and millimetre-scale bumps.

use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};

use crate::render::{Hit, Surface};
use crate::{TissueTexture, value_noise};

/// How far above the wall's mean level the scope hovers on most paths.
pub const STANDOFF_MM: f64 = 55.0;

/// Radius of the `circle` trajectory's path over the wall.
pub const CIRCLE_RADIUS_MM: f64 = 40.0;

/// How far apart the `twins` path's two look-alike places are (along x): farther than the view is wide at the
/// stand-off (about 68 mm for a 4:3 camera whose focal length is the width's 0.81, as the renders use), so the
/// two share no tissue, only its look.
pub const TWIN_SPACING_MM: f64 = 80.0;

#[derive(Debug, Clone)]
pub struct Abdomen {
    pub distance_mm: f64,
    /// Organ blobs: centre (x, y), radius, height towards the scope (mm).
    pub blobs: Vec<(f64, f64, f64, f64)>,
    pub bump_mm: f64,
    pub texture: TissueTexture,
    pub seed: u64,
    /// Breathing's displacement in this frame ([`crate::breathing::Breathing::swell_at`]); 0: the mean wall.
    pub swell: crate::breathing::Swell,
    /// When set, the wall repeats every this many mm along x, pattern and shape: places that no view of them can
    /// tell apart, a period apart — the adversary of loop detection. `None`: no repeat.
    pub repeat_mm: Option<f64>,
}

impl Default for Abdomen {
    fn default() -> Self {
        Self {
            distance_mm: 70.0,
            blobs: vec![
                (-25.0, -10.0, 22.0, 14.0),
                (18.0, 12.0, 18.0, 10.0),
                (5.0, -30.0, 14.0, 7.0),
                (40.0, -20.0, 20.0, 12.0),
                (-45.0, 25.0, 25.0, 9.0),
            ],
            bump_mm: 1.2,
            texture: TissueTexture { seed: 4242 },
            seed: 4242,
            swell: crate::breathing::Swell::default(),
            repeat_mm: None,
        }
    }
}

impl Abdomen {
    /// Depth of the wall below the point (x, y).
    pub fn height(&self, x: f64, y: f64) -> f64 {
        // A shallow bowl, organ blobs (smooth bumps towards the scope) and small irregularities.
        // Repeated: x² made periodic and smooth ((P/π)² sin²(πx/P), x² near the centre), each blob seen at its
        // nearest copy (half a period away a blob is at most 0.6 % of its height, 0.05 mm: no visible seam), the
        // fine relief tiled.
        let bowl_x2 = self.repeat_mm.map_or(x * x, |period| {
            (period / std::f64::consts::PI * (std::f64::consts::PI * x / period).sin()).powi(2)
        });
        let dx_to = |bx: f64| self.repeat_mm.map_or(x - bx, |period| centred(x - bx, period));
        let bowl = 0.004 * (bowl_x2 + y * y);
        let blobs: f64 = self
            .blobs
            .iter()
            .map(|&(bx, by, r, h)| h * (-(dx_to(bx).powi(2) + (y - by).powi(2)) / (2.0 * r * r / 4.0)).exp())
            .sum();
        let relief = |x: f64| value_noise(self.seed ^ 3, x / 7.0, y / 7.0);
        let relief = match self.repeat_mm {
            None => relief(x),
            // Tiled without a step: across each period the relief fades into its copy one period back.
            Some(period) => {
                let along = x.rem_euclid(period);
                ((period - along) * relief(along) + along * relief(along - period)) / period
            }
        };
        let bumps = self.bump_mm * (relief - 0.5) * 2.0;
        // Breathing lifts the wall towards the scope (−z) where its share is positive. A still wall skips the
        // share's two sines (a fifth of a render's time); its height is the same to the bit, as `h - 0·share` is `h`.
        let swell = if self.swell.mm == 0.0 {
            0.0
        } else {
            self.swell.mm * crate::breathing::wall_share(x, y, self.swell.wavelength_mm)
        };
        self.distance_mm + bowl - blobs + bumps - swell
    }

    /// Positive in front of the wall (on the scope's side).
    fn front(&self, p: &Point3<f64>) -> f64 {
        self.height(p.x, p.y) - p.z
    }

    fn normal(&self, p: &Point3<f64>) -> Vector3<f64> {
        let e = 1e-3;
        let dx = (self.height(p.x + e, p.y) - self.height(p.x - e, p.y)) / (2.0 * e);
        let dy = (self.height(p.x, p.y + e) - self.height(p.x, p.y - e)) / (2.0 * e);
        // The wall faces −z (towards the scope).
        Vector3::new(dx, dy, -1.0).normalize()
    }

    /// A camera above the wall looking down +z, at (x, y) and `height_mm` above the wall's mean level, tilted a
    /// little: `world_from_camera`.
    fn looking_down(&self, x: f64, y: f64, standoff_mm: f64, tilt_x: f64, tilt_y: f64) -> Isometry3<f64> {
        let rotation = UnitQuaternion::from_euler_angles(tilt_x, tilt_y, 0.0);
        Isometry3::from_parts(Translation3::new(x, y, self.distance_mm - standoff_mm), rotation)
    }

    /// Hovering: slow drift around a point with small tilts.
    pub fn hover_pose(&self, t_s: f64) -> Isometry3<f64> {
        self.looking_down(
            4.0 * (t_s * 0.6).sin(),
            3.0 * (t_s * 0.45).cos(),
            STANDOFF_MM + 3.0 * (t_s * 0.3).sin(),
            0.05 * (t_s * 0.7).sin(),
            0.04 * (t_s * 0.5).cos(),
        )
    }

    /// Sweeping sideways across the wall at `speed_mm_s`.
    pub fn sweep_pose(&self, t_s: f64, speed_mm_s: f64) -> Isometry3<f64> {
        self.looking_down(
            -40.0 + speed_mm_s * t_s,
            5.0 * (t_s * 0.8).sin(),
            STANDOFF_MM,
            0.03 * (t_s * 1.1).sin(),
            0.05,
        )
    }

    /// Panning: the scope swings from side to side (±17° about its vertical axis, 1.1 Hz: up to 120°/s, 4° a
    /// frame at 30 fps) while it drifts sideways at `speed_mm_s`: fast rotations, the hard case of a motion prior.
    pub fn pan_pose(&self, t_s: f64, speed_mm_s: f64) -> Isometry3<f64> {
        let (amplitude, omega) = (0.3, 7.0);
        self.looking_down(
            -20.0 + speed_mm_s * t_s,
            3.0 * (t_s * 0.8).sin(),
            STANDOFF_MM,
            0.03,
            amplitude * (omega * t_s).sin(),
        )
    }

    /// Looking across the wall rather than down on it (tilted 50°), sweeping sideways at `speed_mm_s`: the near
    /// wall fills the bottom of the image and the wall recedes to the renderer's range (150 mm, disparity a third
    /// of the near wall's) at the top — a far background, where points barely move as the scope translates.
    pub fn oblique_pose(&self, t_s: f64, speed_mm_s: f64) -> Isometry3<f64> {
        self.looking_down(
            -40.0 + speed_mm_s * t_s,
            40.0 + 2.0 * (t_s * 0.9).sin(),
            45.0,
            0.75,
            0.04 * (t_s * 0.7).sin(),
        )
    }

    /// Sweeping out and back over the same tissue.
    pub fn revisit_pose(&self, t_s: f64, total_s: f64, speed_mm_s: f64) -> Isometry3<f64> {
        let along = if t_s <= 0.5 * total_s { t_s } else { total_s - t_s };
        let mut pose = self.sweep_pose(along, speed_mm_s);
        if t_s > 0.5 * total_s {
            pose.translation.vector += Vector3::new(0.0, 1.5 * (t_s * 1.7).sin(), 0.7);
        }
        pose
    }

    /// Circling: a hover that moves round a circle of [`CIRCLE_RADIUS_MM`] at `speed_mm_s` (one lap in 12.6 s at
    /// 20 mm/s), so it comes back to where it started after leaving it. The circle is wider than the view
    /// (about 70 mm across at this stand-off with a 320-px, f = 260 camera), so opposite sides share no tissue and
    /// the start is seen again only at the end of a lap: a loop to close, not a scene that never leaves the view.
    pub fn circle_pose(&self, t_s: f64, speed_mm_s: f64) -> Isometry3<f64> {
        let angle = speed_mm_s * t_s / CIRCLE_RADIUS_MM;
        self.looking_down(
            CIRCLE_RADIUS_MM * angle.cos(),
            CIRCLE_RADIUS_MM * angle.sin(),
            STANDOFF_MM + 2.0 * (t_s * 0.4).sin(),
            0.04 * (t_s * 0.7).sin(),
            0.04 * (t_s * 0.5).cos(),
        )
    }

    /// The wall as a grid mesh over [−extent, extent]² every `step` mm; vertices lie exactly on the surface.
    pub fn mesh(&self, extent: f64, step: f64) -> (Vec<[f32; 3]>, Vec<[u32; 3]>) {
        let n = (2.0 * extent / step).ceil() as usize + 1;
        let mut vertices = Vec::with_capacity(n * n);
        for j in 0..n {
            for i in 0..n {
                let (x, y) = (-extent + i as f64 * step, -extent + j as f64 * step);
                vertices.push([x as f32, y as f32, self.height(x, y) as f32]);
            }
        }
        let mut triangles = Vec::with_capacity(2 * (n - 1) * (n - 1));
        for j in 0..n - 1 {
            for i in 0..n - 1 {
                let a = (j * n + i) as u32;
                let (b, c, d) = (a + 1, a + n as u32, a + n as u32 + 1);
                triangles.push([a, b, d]);
                triangles.push([a, d, c]);
            }
        }
        (vertices, triangles)
    }
}

/// `x` moved by whole periods into [−period/2, period/2).
fn centred(x: f64, period: f64) -> f64 {
    (x + 0.5 * period).rem_euclid(period) - 0.5 * period
}

impl Surface for Abdomen {
    fn hit(&self, origin: &Point3<f64>, dir: &Vector3<f64>, max_t: f64) -> Option<Hit> {
        if self.front(origin) <= 0.0 {
            return None;
        }
        let (mut t, mut prev) = (0.0, 0.0);
        while t < max_t {
            let f = self.front(&(origin + dir * t));
            if f <= 0.0 {
                // Bracketed: bisection to 1e-6 mm (the height field is smooth but steep at blob flanks).
                let (mut lo, mut hi) = (prev, t);
                while hi - lo > 1e-6 {
                    let mid = 0.5 * (lo + hi);
                    if self.front(&(origin + dir * mid)) > 0.0 { lo = mid } else { hi = mid }
                }
                let point = origin + dir * hi;
                return Some(Hit { t: hi, point, normal: self.normal(&point), uv: (point.x, point.y) });
            }
            prev = t;
            // The vertical gap over-estimates the distance where the wall is steep: step part of it.
            t += (0.5 * f).max(0.02);
        }
        None
    }
    fn albedo(&self, uv: (f64, f64), footprint_mm: f64) -> [u8; 3] {
        // A repeated pattern has a seam half a period from the centre (a straight edge across the view there), as
        // a texture tiled by hand would; what matters is that a place and its twin carry the same pattern.
        let u = self.repeat_mm.map_or(uv.0, |period| centred(uv.0, period));
        self.texture.rgb_filtered(u, uv.1, footprint_mm)
    }
    fn seed(&self) -> u64 {
        self.seed
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_repeated_wall_is_the_same_a_period_on_and_continuous_across_its_seams() {
        let wall = Abdomen { repeat_mm: Some(TWIN_SPACING_MM), ..Abdomen::default() };
        for &(x, y) in &[(-30.0, 2.0), (-12.5, -17.0), (0.0, 0.0), (33.3, 21.0)] {
            let twin_x = x + TWIN_SPACING_MM;
            assert!((wall.height(x, y) - wall.height(twin_x, y)).abs() < 1e-9, "shape at ({x}, {y})");
            assert_eq!(wall.albedo((x, y), 0.1), wall.albedo((twin_x, y), 0.1), "pattern at ({x}, {y})");
        }
        // Across its seams the wall has no step (a crease at most): a step would be an edge no real wall has.
        for seam in [0.0, 0.5 * TWIN_SPACING_MM] {
            for y in [-20.0, 0.0, 15.0] {
                let step = (wall.height(seam - 1e-7, y) - wall.height(seam + 1e-7, y)).abs();
                assert!(step < 1e-4, "a {step} mm step at the seam x = {seam}, y = {y}");
            }
        }
        // Without the repeat, the two places differ.
        let plain = Abdomen::default();
        assert!((plain.height(-30.0, 2.0) - plain.height(50.0, 2.0)).abs() > 1.0);
    }
}
