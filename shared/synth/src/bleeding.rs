//! Bleeding: a pool of blood that spreads over the tissue where the scope looks, changing its colour locally and
//! making it wet. It is a film on the surface, so it sticks to the tissue (it is drawn in surface coordinates)
//! and leaves the depth and the mesh alone; what changes is what the tissue looks like: its texture drowns
//! under a dark, even red with a mirror-like sheen that moves with the light.

use crate::value_noise;

/// Albedo of blood (dark red: it absorbs green and blue almost entirely).
pub const BLOOD_ALBEDO: [f64; 3] = [0.45, 0.035, 0.04];
/// A wet film reflects more, and in a tighter highlight, than the tissue's own surface.
pub const WET_SPECULAR: f64 = 0.9;
pub const WET_SHININESS: f64 = 120.0;

/// One bleed of a sequence.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Bleeding {
    /// When it starts (s) and how long the pool takes to reach its full size (s).
    pub start_s: f64,
    pub spread_s: f64,
    /// Surface coordinates of the source (mm, the scene's own: `Hit::uv`).
    pub source_uv: (f64, f64),
    /// Mean radius of the full pool (mm).
    pub radius_mm: f64,
    pub seed: u64,
}

/// The pool in one frame (the renderer's `Shading::bleeding`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pool {
    pub source_uv: (f64, f64),
    pub radius_mm: f64,
    pub seed: u64,
}

impl Bleeding {
    /// A bleed from `source_uv` starting at `start_s`, spreading over 2 s to a pool a fifth of the working
    /// distance across in radius (about a fifth of the view's width), then staying.
    pub fn new(start_s: f64, source_uv: (f64, f64), working_distance_mm: f64, seed: u64) -> Self {
        Self { start_s, spread_s: 2.0, source_uv, radius_mm: 0.2 * working_distance_mm, seed }
    }

    /// The pool at `t_s`, or `None` before the bleed starts.
    pub fn pool_at(&self, t_s: f64) -> Option<Pool> {
        let grown = ((t_s - self.start_s) / self.spread_s).clamp(0.0, 1.0);
        // Fast at first, slowing as the pool widens (the area grows about linearly with the blood shed).
        (grown > 0.0).then(|| Pool {
            source_uv: self.source_uv,
            radius_mm: self.radius_mm * grown.sqrt(),
            seed: self.seed,
        })
    }
}

impl Pool {
    /// How much of the tissue's own look the blood replaces at surface coordinates `uv`: 1 in the pool, fading
    /// to 0 over a thin film at its uneven edge.
    pub fn cover(&self, uv: (f64, f64)) -> f64 {
        let (du, dv) = (uv.0 - self.source_uv.0, uv.1 - self.source_uv.1);
        let distance = (du * du + dv * dv).sqrt();
        if self.radius_mm <= 0.0 || distance > 1.6 * self.radius_mm {
            return 0.0;
        }
        // An uneven rim: the radius varies by ±30 % around the source (noise over the direction, so no seam).
        let (c, s) = if distance > 0.0 { (du / distance, dv / distance) } else { (1.0, 0.0) };
        let rim = self.radius_mm * (0.7 + 0.6 * value_noise(self.seed ^ 0xB100D, 3.0 * c + 7.0, 3.0 * s + 7.0));
        // The film thins over the outer fifth of the rim.
        let inside = (rim - distance) / (0.2 * rim);
        let x = inside.clamp(0.0, 1.0);
        x * x * (3.0 - 2.0 * x)
    }

    /// The tissue's albedo, specular share and shininess under the pool at `uv`.
    pub fn wet(&self, uv: (f64, f64), albedo: [f64; 3], specular: f64, shininess: f64) -> ([f64; 3], f64, f64) {
        let cover = self.cover(uv);
        if cover <= 0.0 {
            return (albedo, specular, shininess);
        }
        let mix = |a: f64, b: f64| a * (1.0 - cover) + b * cover;
        ([0, 1, 2].map(|k| mix(albedo[k], BLOOD_ALBEDO[k])), mix(specular, WET_SPECULAR), mix(shininess, WET_SHININESS))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_pool_spreads_from_its_source_and_stays() {
        let bleed = Bleeding::new(1.0, (3.0, -2.0), 50.0, 9);
        assert!(bleed.pool_at(0.9).is_none());
        let (early, full, later) =
            (bleed.pool_at(1.5).unwrap(), bleed.pool_at(3.0).unwrap(), bleed.pool_at(9.0).unwrap());
        assert!(early.radius_mm < full.radius_mm && full == later);
        assert_eq!(full.cover((3.0, -2.0)), 1.0, "covered at the source");
        assert_eq!(full.cover((3.0 + 20.0, -2.0)), 0.0, "beyond its rim");
        // Uneven: along a ring at the mean radius some directions are under blood and some are not.
        let ring: Vec<f64> = (0..72)
            .map(|k| {
                let a = std::f64::consts::TAU * f64::from(k) / 72.0;
                full.cover((3.0 + 10.0 * a.cos(), -2.0 + 10.0 * a.sin()))
            })
            .collect();
        assert!(ring.iter().any(|&c| c > 0.9) && ring.iter().any(|&c| c < 0.1), "{ring:?}");
        let (albedo, specular, _) = full.wet((3.0, -2.0), [0.8, 0.5, 0.5], 0.35, 40.0);
        assert_eq!((albedo, specular), (BLOOD_ALBEDO, WET_SPECULAR));
    }
}
