//! Surgical smoke: a haze that rises and clears over a second or two (diathermy), lowering the contrast of
//! everything behind it. Two kinds, both seen by each camera from its own position (so the smoke has a disparity
//! of its own, as real smoke has), with the ground truth staying the tissue's:
//! - [`Anchoring::Cavity`]: a cloud that stays in the cavity where it was made, between the scope and the
//!   tissue, drifting up. A moving scope sees it move as a still scene would at its depth, and flies into and
//!   through it. This is what real smoke does.
//! - [`Anchoring::Scope`]: a billowed sheet at a fixed depth in front of the scope that rides with it. No real
//!   smoke does this; it is the harder case for a tracker (the veil says "standing still" whatever the scope
//!   does), kept because the figures measured on it before stay comparable.

use nalgebra::{Isometry3, Point3, Vector3};

use crate::{value_noise, value_noise3};

/// Where a puff's smoke hangs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Anchoring {
    /// A cloud fixed in the cavity, made in front of the scope where the puff starts: real smoke.
    #[default]
    Cavity,
    /// A sheet at half the working distance that moves with the scope.
    Scope,
}

/// A cloud of smoke fixed in the scene: a ball of billowed density, thinning towards its rim.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Cloud {
    /// Where its centre is when the puff starts (world, mm), its radius (mm), and which way is up (world, unit;
    /// it drifts that way).
    pub centre: Point3<f64>,
    pub radius_mm: f64,
    pub up: Vector3<f64>,
}

/// One smoke event of a sequence.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Smoke {
    /// When it starts to rise, how long it takes to reach its peak, stays, and takes to clear (s).
    pub start_s: f64,
    pub rise_s: f64,
    pub hold_s: f64,
    pub clear_s: f64,
    /// The share of the light from the tissue replaced by the haze's at the peak, where it is densest (the
    /// sheet) or through the middle of the cloud where it is of typical density.
    pub peak: f64,
    /// Depth of the sheet and how fast it drifts upwards (mm, mm/s). The billows are a quarter of the depth
    /// across, in the cloud too.
    pub depth_mm: f64,
    pub drift_mm_s: f64,
    /// `None`: a sheet riding with the scope; else the cloud in the cavity.
    pub cloud: Option<Cloud>,
    pub seed: u64,
}

/// The haze of one frame (the renderer's `Shading::haze`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Haze {
    pub density: f64,
    pub depth_mm: f64,
    /// How far the sheet or the cloud has drifted up (mm).
    pub drift_mm: f64,
    /// The cloud, its centre where it has drifted to; `None`: the sheet.
    pub cloud: Option<Cloud>,
    /// The share of the light a typical ray through the cloud's middle loses at the peak.
    pub peak: f64,
    pub seed: u64,
}

/// Samples along a ray's chord through the cloud: the chord is at most two radii, twelve billows, long, so
/// about two samples a billow where it is longest (a fixed count keeps every frame's cost the same).
const CLOUD_STEPS: usize = 24;

impl Smoke {
    /// A puff starting `start_s` into the sequence, at half the working distance: up in 0.3 s, 0.5 s at its
    /// peak (80 % of the light), gone 0.8 s later.
    pub fn puff(start_s: f64, working_distance_mm: f64, seed: u64) -> Self {
        Self {
            start_s,
            rise_s: 0.3,
            hold_s: 0.5,
            clear_s: 0.8,
            peak: 0.8,
            depth_mm: 0.5 * working_distance_mm,
            drift_mm_s: 0.2 * working_distance_mm,
            cloud: None,
            seed,
        }
    }

    /// The same puff made in the cavity in front of the scope at `world_from_camera` (where it is when the puff
    /// starts): a cloud centred 0.6 working distances ahead with a radius of 0.75, so it reaches the tissue
    /// and holds the scope's tip at its thin rim. Up is the view's up when it starts.
    pub fn cavity_puff(start_s: f64, working_distance_mm: f64, world_from_camera: &Isometry3<f64>, seed: u64) -> Self {
        let cloud = Cloud {
            centre: world_from_camera * Point3::new(0.0, 0.0, 0.6 * working_distance_mm),
            radius_mm: 0.75 * working_distance_mm,
            up: world_from_camera.rotation * Vector3::new(0.0, -1.0, 0.0),
        };
        Self { cloud: Some(cloud), ..Self::puff(start_s, working_distance_mm, seed) }
    }

    /// Density in [0, peak] at time `t_s` (smooth steps up and down).
    pub fn density(&self, t_s: f64) -> f64 {
        let smooth = |x: f64| {
            let x = x.clamp(0.0, 1.0);
            x * x * (3.0 - 2.0 * x)
        };
        let t = t_s - self.start_s;
        let up = smooth(t / self.rise_s);
        let down = 1.0 - smooth((t - self.rise_s - self.hold_s) / self.clear_s);
        self.peak * up.min(down)
    }

    /// The haze at `t_s`, or `None` when there is none.
    pub fn haze_at(&self, t_s: f64) -> Option<Haze> {
        let density = self.density(t_s);
        let drift_mm = self.drift_mm_s * (t_s - self.start_s);
        (density > 0.0).then_some(Haze {
            density,
            depth_mm: self.depth_mm,
            drift_mm,
            cloud: self.cloud.map(|cloud| Cloud { centre: cloud.centre + cloud.up * drift_mm, ..cloud }),
            peak: self.peak,
            seed: self.seed,
        })
    }
}

impl Haze {
    /// The share of the light replaced at the sheet's point (x, y) (mm, in the camera frame of the view).
    pub fn alpha(&self, x_mm: f64, y_mm: f64) -> f64 {
        // Billows a quarter of the depth across, with finer wisps.
        let scale = 0.25 * self.depth_mm;
        let (u, v) = (x_mm / scale, (y_mm + self.drift_mm) / scale);
        let billow =
            0.7 * value_noise(self.seed ^ 0x5EED, u, v) + 0.3 * value_noise(self.seed ^ 0xF00D, 2.3 * u, 2.3 * v);
        self.density * (0.5 + 1.2 * (billow - 0.5)).clamp(0.0, 1.0)
    }

    /// What the cloud does to a ray from `origin` along the unit `dir` (world) that meets the tissue at distance
    /// `t_end` (mm; infinite for none): the share of the tissue's light that gets through, and the light the
    /// smoke scatters back into the ray, given `light(t)`, what a white scatterer at distance t sends back
    /// (0..255). Nothing for the sheet.
    pub fn through_cloud(
        &self,
        origin: &Point3<f64>,
        dir: &Vector3<f64>,
        t_end: f64,
        light: impl Fn(f64) -> f64,
    ) -> (f64, f64) {
        let Some(cloud) = &self.cloud else { return (1.0, 0.0) };
        let r2 = cloud.radius_mm * cloud.radius_mm;
        let to_origin = origin - cloud.centre;
        let b = to_origin.dot(dir);
        let disc = b * b - (to_origin.norm_squared() - r2);
        if disc <= 0.0 {
            return (1.0, 0.0);
        }
        let (t0, t1) = ((-b - disc.sqrt()).max(0.0), (-b + disc.sqrt()).min(t_end));
        if t1 <= t0 {
            return (1.0, 0.0);
        }
        // Extinction per mm of typical density (billows at one half, the rim's thinning (1 − r²)² integrating
        // to 16/15 of a radius across the middle) such that a ray through the middle loses `peak` at the peak.
        let sigma = -(1.0 - self.peak).ln() / (0.5 * 16.0 / 15.0 * cloud.radius_mm) * (self.density / self.peak);
        let scale = 0.25 * self.depth_mm;
        let dt = (t1 - t0) / CLOUD_STEPS as f64;
        let (mut transmitted, mut glow) = (1.0, 0.0);
        for i in 0..CLOUD_STEPS {
            let t = t0 + (i as f64 + 0.5) * dt;
            let from_centre = origin + dir * t - cloud.centre;
            let rim = (1.0 - from_centre.norm_squared() / r2).max(0.0).powi(2);
            // The billows roll up through the cloud a little faster than the cloud rises.
            let q = (from_centre - cloud.up * (0.5 * self.drift_mm)) / scale;
            let billow = 0.7 * value_noise3(self.seed ^ 0x5EED, q.x, q.y, q.z)
                + 0.3 * value_noise3(self.seed ^ 0xF00D, 2.3 * q.x, 2.3 * q.y, 2.3 * q.z);
            let density = (0.5 + 1.6 * (billow - 0.5)).clamp(0.0, 1.0) * rim;
            let stopped = 1.0 - (-sigma * density * dt).exp();
            glow += transmitted * stopped * light(t);
            transmitted *= 1.0 - stopped;
        }
        (transmitted, glow)
    }
}

/// One view of the scene, as the haze needs it ([`Haze::veil`]).
pub(crate) struct View<'a> {
    pub rig: &'a crate::RectifiedCamera,
    /// The camera-frame ray (z = 1 scale or any) through image point (x, y); `None` outside the lens's field.
    pub ray: &'a dyn Fn(f64, f64) -> Option<Vector3<f64>>,
    /// The right camera of the pair (a baseline to the right of the left one).
    pub right: bool,
    pub world_from_camera: &'a Isometry3<f64>,
    /// z-depth of the tissue per pixel (mm; +inf where none).
    pub z_depth: &'a [f32],
}

impl Haze {
    /// Lays the haze over one view's radiance (RGB per pixel, 0..255, NaN where no ray met a wall), lit by the
    /// scope's light as the renderer lights the tissue (`exposure_distance_mm`: where a white wall facing it is
    /// at 80 % of full scale, the renderer's `Shading::exposure_distance_mm`).
    pub(crate) fn veil(&self, radiance_image: &mut [f64], view: &View, exposure_distance_mm: f64) {
        let w = view.rig.width as usize;
        // What the smoke sends back at a distance (along the ray for the cloud, the depth for the sheet): the
        // scope's light there, as on a wall of albedo 0.6, never white.
        let light = |distance_mm: f64| (0.8 * (exposure_distance_mm / distance_mm).powi(2) * 0.6).min(0.85) * 255.0;
        if self.cloud.is_some() {
            // The cloud, marched along each pixel's ray up to the tissue.
            let origin = view.world_from_camera * Point3::origin();
            for (i, radiance) in radiance_image.chunks_exact_mut(3).enumerate() {
                let (x, y) = ((i % w) as f64 + 0.5, (i / w) as f64 + 0.5);
                let Some(dir_cam) = (view.ray)(x, y) else { continue };
                // The tissue's distance along the ray from its z-depth.
                let t_end = f64::from(view.z_depth[i]) * dir_cam.norm() / dir_cam.z;
                let dir = (view.world_from_camera.rotation * dir_cam).normalize();
                let (through, glow) = self.through_cloud(&origin, &dir, t_end, light);
                for r in radiance {
                    *r = if r.is_nan() { 0.0 } else { *r } * through + glow;
                }
            }
        } else {
            // The sheet seen from this view's centre: the right camera sits a baseline to the right.
            let rig = view.rig;
            let offset = if view.right { rig.baseline() } else { 0.0 };
            let z = self.depth_mm;
            let exposure = light(z);
            for (i, radiance) in radiance_image.chunks_exact_mut(3).enumerate() {
                let (x, y) = ((i % w) as f64 + 0.5, (i / w) as f64 + 0.5);
                let a = self.alpha((x - rig.cx) * z / rig.fx + offset, (y - rig.cy) * z / rig.fy);
                for r in radiance {
                    *r = if r.is_nan() { 0.0 } else { *r } * (1.0 - a) + exposure * a;
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_puff_rises_holds_and_clears() {
        let smoke = Smoke::puff(1.0, 50.0, 3);
        assert_eq!(smoke.density(0.9), 0.0);
        assert!(smoke.haze_at(0.9).is_none());
        assert!((smoke.density(1.5) - 0.8).abs() < 1e-12, "at its peak");
        assert!(smoke.density(1.9) > 0.0 && smoke.density(1.9) < 0.8, "clearing");
        assert_eq!(smoke.density(2.7), 0.0, "gone 1.6 s after it started");
        let haze = smoke.haze_at(1.5).unwrap();
        let alphas: Vec<f64> = (0..50).map(|i| haze.alpha(f64::from(i) * 0.7, 3.0)).collect();
        let (lo, hi) = alphas.iter().fold((1.0f64, 0.0f64), |(lo, hi), &a| (lo.min(a), hi.max(a)));
        assert!(hi - lo > 0.1 && hi <= 1.0 && lo >= 0.0, "uneven: {lo}..{hi}");
    }
}
