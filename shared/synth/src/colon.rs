//! A colon-like tube rendered by ray marching, with exact ground truth: depth and disparity per pixel, poses,
//! and a mesh of the wall.
//!
//! The wall is the surface `ρ = r(z, θ)` around a curved centreline `c(z)`: ρ and θ are polar coordinates of a
//! point's (x, y) about `c(z)`. Haustral folds narrow the tube every `fold_spacing_mm`, and low-frequency bumps
//! roughen it. Tissue texture is evaluated in surface coordinates (arc length around, length along), so it
//! sticks to the wall and the same wall point looks the same from any view but for the lighting.

use nalgebra::{Isometry3, Point3, Rotation3, Translation3, UnitQuaternion, Vector3};

use crate::render::{Hit, Surface};
use crate::{TissueTexture, value_noise};

/// The tube's shape.
#[derive(Debug, Clone, Copy)]
pub struct Colon {
    pub radius_mm: f64,
    pub fold_spacing_mm: f64,
    /// Fold depth as a fraction of the radius.
    pub fold_depth: f64,
    pub bump_mm: f64,
    pub texture: TissueTexture,
    pub seed: u64,
    /// Breathing's displacement in this frame ([`crate::breathing::Breathing::swell_at`]); 0: the mean wall.
    pub swell: crate::breathing::Swell,
}

impl Default for Colon {
    fn default() -> Self {
        Self {
            radius_mm: 16.0,
            fold_spacing_mm: 28.0,
            fold_depth: 0.22,
            bump_mm: 0.9,
            texture: TissueTexture { seed: 2026 },
            seed: 2026,
            swell: crate::breathing::Swell::default(),
        }
    }
}

impl Colon {
    /// The centreline at height z.
    pub fn centre(&self, z: f64) -> (f64, f64) {
        (6.0 * (z / 40.0).sin(), 4.0 * (z / 55.0 + 1.0).sin())
    }

    /// Wall radius at height z and angle θ.
    pub fn radius(&self, z: f64, theta: f64) -> f64 {
        // `x - floor(x)` is `x.rem_euclid(1.0)` to the bit (one rounding of the same real number), without fmod.
        let folds = z / self.fold_spacing_mm;
        let phase = (folds - crate::floor(folds)) - 0.5;
        // A fold is a smooth inward ring a few mm wide; its depth varies a little around the circumference.
        let fold = (-(phase * self.fold_spacing_mm).powi(2) / (2.0 * 3.0f64.powi(2))).exp();
        // Noise over (cos θ, sin θ) is periodic around the tube: no seam in the wall.
        let (c, s) = (theta.cos(), theta.sin());
        let fold_depth = self.fold_depth * (0.8 + 0.4 * value_noise(self.seed ^ 11, 2.0 * c + z / 20.0, 2.0 * s));
        let k = self.radius_mm / 6.0;
        let bumps = self.bump_mm * (value_noise(self.seed ^ 7, k * c + z / 6.0, k * s - z / 9.0) - 0.5) * 2.0;
        // Breathing narrows the tube where its share is positive. Still tissue skips the share's two cosines (an
        // eighth of a render's time); the radius is the same to the bit, as `r - 0·share` is `r`.
        let swell = if self.swell.mm == 0.0 {
            0.0
        } else {
            self.swell.mm * crate::breathing::tube_share(z, theta, self.swell.wavelength_mm)
        };
        self.radius_mm * (1.0 - fold_depth * fold) + bumps - swell
    }

    /// Positive inside the tube, 0 on the wall (not a true distance; marching steps are scaled down for that).
    fn inside(&self, p: &Point3<f64>) -> f64 {
        let (cx, cy) = self.centre(p.z);
        let (dx, dy) = (p.x - cx, p.y - cy);
        self.radius(p.z, dy.atan2(dx)) - (dx * dx + dy * dy).sqrt()
    }

    fn uv(&self, p: &Point3<f64>) -> (f64, f64) {
        let (cx, cy) = self.centre(p.z);
        let theta = (p.y - cy).atan2(p.x - cx);
        (theta.rem_euclid(std::f64::consts::TAU) * self.radius_mm, p.z)
    }

    /// The first wall point along `origin + t·dir` (dir unit) with t < `max_t`.
    pub fn hit(&self, origin: &Point3<f64>, dir: &Vector3<f64>, max_t: f64) -> Option<Hit> {
        let mut t = 0.0;
        let mut prev = 0.0;
        let mut f_prev = self.inside(origin);
        if f_prev <= 0.0 {
            return None;
        }
        while t < max_t {
            let f = self.inside(&(origin + dir * t));
            if f <= 0.0 {
                // Refine between the last inside and the first outside sample by false position (Illinois):
                // `inside` is smooth there, so a few steps reach 1e-6 mm.
                let (mut lo, mut hi) = (prev, t);
                let (mut f_lo, mut f_hi) = (f_prev, f);
                let mut side = 0;
                for _ in 0..30 {
                    let mid = if f_lo != f_hi { hi - f_hi * (hi - lo) / (f_hi - f_lo) } else { 0.5 * (lo + hi) };
                    let mid = mid.clamp(lo.min(hi), lo.max(hi));
                    let fm = self.inside(&(origin + dir * mid));
                    if fm > 0.0 {
                        lo = mid;
                        f_lo = fm;
                        if side == -1 {
                            f_hi *= 0.5
                        }
                        side = -1;
                    } else {
                        hi = mid;
                        f_hi = fm;
                        if side == 1 {
                            f_lo *= 0.5
                        }
                        side = 1;
                    }
                    if (hi - lo).abs() < 1e-6 {
                        break;
                    }
                }
                let point = origin + dir * hi;
                return Some(Hit { t: hi, point, normal: self.normal(&point), uv: self.uv(&point) });
            }
            prev = t;
            f_prev = f;
            // `inside` changes a little faster than distance at folds and bumps: step most of it.
            t += (0.7 * f).max(0.02);
        }
        None
    }

    fn normal(&self, p: &Point3<f64>) -> Vector3<f64> {
        let e = 1e-3;
        let g = Vector3::new(
            self.inside(&(p + Vector3::x() * e)) - self.inside(&(p - Vector3::x() * e)),
            self.inside(&(p + Vector3::y() * e)) - self.inside(&(p - Vector3::y() * e)),
            self.inside(&(p + Vector3::z() * e)) - self.inside(&(p - Vector3::z() * e)),
        );
        // `inside` grows towards the axis, so its gradient points into the tube.
        g.normalize()
    }

    /// The left camera's pose at time `t_s` flying forward at `speed_mm_s` with a gentle wobble:
    /// `world_from_camera`, camera z along the tube, y down.
    pub fn forward_pose(&self, t_s: f64, speed_mm_s: f64) -> Isometry3<f64> {
        let z = speed_mm_s * t_s;
        let (cx, cy) = self.centre(z);
        let wobble = Vector3::new(2.0 * (t_s * 1.7).sin(), 1.5 * (t_s * 1.3).cos(), 0.0);
        let position = Point3::new(cx, cy, z) + wobble;
        // Look at the centreline a little ahead, with a slow roll.
        let (ax, ay) = self.centre(z + 20.0);
        let forward = (Point3::new(ax, ay, z + 20.0) - position).normalize();
        let roll = 0.15 * (t_s * 0.5).sin();
        let down = Vector3::new(roll.sin(), roll.cos(), 0.0);
        let x = down.cross(&forward).normalize();
        let y = forward.cross(&x);
        let r = Rotation3::from_basis_unchecked(&[x, y, forward]);
        Isometry3::from_parts(Translation3::from(position.coords), UnitQuaternion::from_rotation_matrix(&r))
    }

    /// Forward for half the time, then back over the same wall: `world_from_camera` at `t_s` of `total_s`.
    /// On the way back the scope keeps looking forward (it is pulled out, as in a withdrawal).
    pub fn revisit_pose(&self, t_s: f64, total_s: f64, speed_mm_s: f64) -> Isometry3<f64> {
        let along = if t_s <= 0.5 * total_s { t_s } else { total_s - t_s };
        let mut pose = self.forward_pose(along, speed_mm_s);
        // A little different wobble on the way back, so views are similar but not identical.
        if t_s > 0.5 * total_s {
            pose.translation.vector += Vector3::new(0.8 * (t_s * 2.3).sin(), -0.6 * (t_s * 1.9).cos(), 0.0);
        }
        pose
    }

    /// A triangle mesh of the wall between heights `z0` and `z1`: rings every `dz` mm, `segments` around. Its
    /// vertices lie exactly on the wall.
    pub fn mesh(&self, z0: f64, z1: f64, dz: f64, segments: usize) -> (Vec<[f32; 3]>, Vec<[u32; 3]>) {
        let rings = ((z1 - z0) / dz).ceil() as usize + 1;
        let mut vertices = Vec::with_capacity(rings * segments);
        for k in 0..rings {
            let z = z0 + k as f64 * dz;
            let (cx, cy) = self.centre(z);
            for s in 0..segments {
                let theta = std::f64::consts::TAU * s as f64 / segments as f64;
                let r = self.radius(z, theta);
                vertices.push([(cx + r * theta.cos()) as f32, (cy + r * theta.sin()) as f32, z as f32]);
            }
        }
        let mut triangles = Vec::with_capacity(2 * (rings - 1) * segments);
        for k in 0..rings - 1 {
            for s in 0..segments {
                let (a, b) = ((k * segments + s) as u32, (k * segments + (s + 1) % segments) as u32);
                let (c, d) = (a + segments as u32, b + segments as u32);
                triangles.push([a, b, d]);
                triangles.push([a, d, c]);
            }
        }
        (vertices, triangles)
    }
}

impl Surface for Colon {
    fn hit(&self, origin: &Point3<f64>, dir: &Vector3<f64>, max_t: f64) -> Option<Hit> {
        Colon::hit(self, origin, dir, max_t)
    }
    fn albedo(&self, uv: (f64, f64), footprint_mm: f64) -> [u8; 3] {
        // u runs once around the tube (0..2πR). The texture is not periodic, so over the last `blend` mm it fades
        // into its own continuation from u = 0: no seam along the tube.
        let circumference = std::f64::consts::TAU * self.radius_mm;
        let blend = 8.0;
        let a = self.texture.rgb_filtered(uv.0, uv.1, footprint_mm);
        let into_seam = uv.0 - (circumference - blend);
        if into_seam <= 0.0 {
            return a;
        }
        let b = self.texture.rgb_filtered(uv.0 - circumference, uv.1, footprint_mm);
        let t = (into_seam / blend).clamp(0.0, 1.0);
        [0, 1, 2].map(|c| (f64::from(a[c]) * (1.0 - t) + f64::from(b[c]) * t).round() as u8)
    }
    fn seed(&self) -> u64 {
        self.seed
    }
}
