//! Breathing: the tissue swells and settles at about 0.25 Hz (15 breaths a minute) by a few millimetres.
//!
//! The displacement is a standing wave over the tissue: where one patch rises another falls, about one
//! [`WAVELENGTH_MM`] apart. It has no rigid part over a view centred on the scene: a rigid shift of everything in
//! view looks exactly like the scope moving the other way, and no tracker can tell the two apart from images, so a
//! renderer that moved the tissue rigidly would be testing nothing but that. The deformation is what a tracker has
//! to survive: points that move against each other while the pose stays referred to the mean tissue.
//!
//! The mean surface is the surface at rest (swell 0): `gt/mesh.ply`. Each frame's `gt/depth` is the displaced
//! tissue of that frame.

use std::f64::consts::TAU;

/// One breath in this many seconds (0.25 Hz).
pub const PERIOD_S: f64 = 4.0;

/// Distance between a patch that rises and the next one that rises with it (mm): half of it apart, the tissue
/// moves the other way. By default about the size of the abdomen's organ blobs and twice the colon's radius;
/// the longer it is, the more of the deformation within one view is a rigid motion of everything in it.
pub const WAVELENGTH_MM: f64 = 40.0;

/// The displacement of a surface in one frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Swell {
    /// How far a point whose share is 1 has moved ([`Breathing::swell_mm`]); 0: the mean surface.
    pub mm: f64,
    pub wavelength_mm: f64,
}

impl Default for Swell {
    fn default() -> Self {
        Self { mm: 0.0, wavelength_mm: WAVELENGTH_MM }
    }
}

/// Breathing of a sequence.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Breathing {
    /// The largest displacement of any tissue point from the mean surface (mm).
    pub amplitude_mm: f64,
    pub period_s: f64,
    pub wavelength_mm: f64,
}

impl Breathing {
    pub fn new(amplitude_mm: f64, wavelength_mm: f64) -> Self {
        Self { amplitude_mm, period_s: PERIOD_S, wavelength_mm }
    }

    /// The surface's displacement at time `t_s`.
    pub fn swell_at(&self, t_s: f64) -> Swell {
        Swell { mm: self.swell_mm(t_s), wavelength_mm: self.wavelength_mm }
    }

    /// The displacement, at time `t_s`, of a point whose [`wall_share`] or [`tube_share`] is 1 (mm; positive:
    /// towards the scope / the tube's axis). It starts at the mean surface and is back there every half period.
    pub fn swell_mm(&self, t_s: f64) -> f64 {
        self.amplitude_mm * (TAU * t_s / self.period_s).sin()
    }
}

/// How much of the swell moves the abdominal wall at (x, y) (mm) along its depth: −1..1, zero on average over any
/// whole wavelength and odd about the scene's centre, where the hover looks.
pub fn wall_share(x: f64, y: f64, wavelength_mm: f64) -> f64 {
    (TAU * x / wavelength_mm).sin() * (TAU * y / wavelength_mm).sin()
}

/// How much of the swell narrows the colon at height `z` (mm) and angle `theta` around it: −1..1. The section
/// turns oval (cos 2θ) rather than moving sideways (cos θ would shift the whole tube, a rigid motion), and the oval
/// turns the other way every half wavelength along the tube.
pub fn tube_share(z: f64, theta: f64, wavelength_mm: f64) -> f64 {
    (2.0 * theta).cos() * (TAU * z / wavelength_mm).cos()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_swell_averages_to_the_mean_surface_over_a_breath_and_a_wavelength() {
        let breathing = Breathing::new(2.0, WAVELENGTH_MM);
        let n = 400;
        let mean_in_time: f64 =
            (0..n).map(|i| breathing.swell_mm(PERIOD_S * i as f64 / n as f64)).sum::<f64>() / n as f64;
        assert!(mean_in_time.abs() < 1e-9);
        let peak = (0..n).map(|i| breathing.swell_mm(PERIOD_S * i as f64 / n as f64).abs()).fold(0.0, f64::max);
        assert!((peak - 2.0).abs() < 1e-3, "{peak}");
        // Over a square of the wall a wavelength across, the shares cancel; so do their first moments (no tilt).
        let (mut mean, mut tilt_x, mut tilt_y) = (0.0, 0.0, 0.0);
        let m = 80;
        for j in 0..m {
            for i in 0..m {
                let (x, y) = (
                    WAVELENGTH_MM * ((i as f64 + 0.5) / m as f64 - 0.5),
                    WAVELENGTH_MM * ((j as f64 + 0.5) / m as f64 - 0.5),
                );
                mean += wall_share(x, y, WAVELENGTH_MM);
                tilt_x += x * wall_share(x, y, WAVELENGTH_MM);
                tilt_y += y * wall_share(x, y, WAVELENGTH_MM);
            }
        }
        assert!(mean.abs() < 1e-9 && tilt_x.abs() < 1e-6 && tilt_y.abs() < 1e-6, "{mean} {tilt_x} {tilt_y}");
        // Around the tube, the oval has no sideways part.
        let (sx, sy): (f64, f64) = (0..m).map(|i| TAU * i as f64 / m as f64).fold((0.0, 0.0), |(sx, sy), th| {
            (sx + th.cos() * tube_share(3.0, th, WAVELENGTH_MM), sy + th.sin() * tube_share(3.0, th, WAVELENGTH_MM))
        });
        assert!(sx.abs() < 1e-9 && sy.abs() < 1e-9);
    }
}
