//! Surgical instruments in the view: rigid shafts with jaws that enter from the image borders and move on their
//! own, shaded as metal. They are in the images and the ground-truth depth, never in the tissue's mesh, and every
//! frame gets a ground-truth mask of the pixels they cover (`gt/masks/<n>.png`, left view).
//!
//! An instrument is posed in the left camera's frame (so it stays in view however the scope moves) and then
//! placed in the world for the frame; relative to the tissue it moves with the scope *and* on its own, which is
//! what makes its features disagree with the camera's motion. Every size is a fraction of the scene's working
//! distance, so the same instruments fit a laparoscopic view at 55 mm and a colon at 16 mm.

use nalgebra::{Isometry3, Point3, Vector3};

/// Which instruments a scene shows.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum InstrumentKind {
    /// Two laparoscopic graspers from opposite borders (shaft ⌀ ≈ a tenth of the working distance: 5 mm tools
    /// at 55 mm).
    Laparoscopic,
    /// One thin tool out of the scope's working channel, from the bottom of the image.
    WorkingChannel,
}

/// How a part of an instrument looks.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Metal {
    /// Grey albedo (achromatic), 0..1.
    pub albedo: f64,
    pub specular: f64,
    pub shininess: f64,
}

/// A capsule (a cylinder with round ends) of an instrument, posed in the world for one frame.
#[derive(Debug, Clone, Copy)]
pub struct Part {
    /// The end towards the tip.
    pub a: Point3<f64>,
    pub b: Point3<f64>,
    pub radius: f64,
    /// Dark insulation rings along a shaft, every `ring_spacing` from `a` (0: none).
    pub ring_spacing: f64,
    pub metal: Metal,
    /// The rings' albedo.
    pub ring_albedo: f64,
}

/// Where a ray met an instrument.
#[derive(Debug, Clone, Copy)]
pub struct PartHit {
    pub t: f64,
    pub point: Point3<f64>,
    pub normal: Vector3<f64>,
    pub albedo: f64,
    pub specular: f64,
    pub shininess: f64,
}

// Brushed steel: grey in diffuse light, far brighter in its highlights. Albedos are relative to the shaft's,
// which [`Instruments::new`] sets from the light (a tool sits nearer the light than the tissue: at the tissue's
// albedo it would be white).
const SHAFT: Metal = Metal { albedo: 1.0, specular: 0.3, shininess: 60.0 };
const RING: Metal = Metal { albedo: 0.15, specular: 0.2, shininess: 20.0 };
const JAW: Metal = Metal { albedo: 0.3, specular: 0.25, shininess: 40.0 };

/// The instruments of a sequence: their motion in the camera's frame over time.
#[derive(Debug, Clone)]
pub struct Instruments {
    tools: Vec<Tool>,
    /// The shaft's albedo.
    albedo: f64,
}

#[derive(Debug, Clone, Copy)]
struct Tool {
    /// Mean tip position in the camera frame.
    tip: Vector3<f64>,
    /// Unit vector from the tip back along the shaft (out of the image, towards the camera).
    back: Vector3<f64>,
    /// Sway of the tip: amplitude (camera frame) and angular rates per axis.
    sway: Vector3<f64>,
    rates: Vector3<f64>,
    phase: f64,
    radius: f64,
    length: f64,
    jaw_length: f64,
}

impl Instruments {
    /// The instruments of `kind` for a scene seen at `working_distance_mm` (the usual camera-to-tissue depth)
    /// and lit with `exposure_distance_mm` (the renderer's shading).
    pub fn new(kind: InstrumentKind, working_distance_mm: f64, exposure_distance_mm: f64) -> Self {
        let w = working_distance_mm;
        let tools = match kind {
            InstrumentKind::Laparoscopic => vec![
                // From the left border, a little below the centre, reaching in towards the middle.
                Tool {
                    tip: Vector3::new(-0.12 * w, 0.06 * w, 0.55 * w),
                    back: Vector3::new(-1.0, 0.35, -0.55).normalize(),
                    sway: Vector3::new(0.08 * w, 0.05 * w, 0.06 * w),
                    rates: Vector3::new(1.3, 0.9, 0.7),
                    phase: 0.0,
                    radius: 0.045 * w,
                    length: 3.0 * w,
                    jaw_length: 0.17 * w,
                },
                // From the top-right corner.
                Tool {
                    tip: Vector3::new(0.13 * w, -0.07 * w, 0.6 * w),
                    back: Vector3::new(0.8, -0.6, -0.5).normalize(),
                    sway: Vector3::new(0.07 * w, 0.06 * w, 0.05 * w),
                    rates: Vector3::new(0.8, 1.4, 1.1),
                    phase: 1.9,
                    radius: 0.045 * w,
                    length: 3.0 * w,
                    jaw_length: 0.17 * w,
                },
            ],
            // A channel tool: thin, from just below the lens, straight ahead and a little up.
            InstrumentKind::WorkingChannel => vec![Tool {
                tip: Vector3::new(0.12 * w, 0.22 * w, 0.55 * w),
                back: Vector3::new(0.15, 0.45, -1.0).normalize(),
                sway: Vector3::new(0.05 * w, 0.04 * w, 0.1 * w),
                rates: Vector3::new(1.1, 0.8, 0.6),
                phase: 0.7,
                radius: 0.07 * w,
                length: 2.0 * w,
                jaw_length: 0.16 * w,
            }],
        };
        // A shaft facing the light at its tip's mean depth is exposed to 60 % (the renderer exposes a wall at
        // the exposure distance to 80 % at albedo 1, falling with the square of the distance).
        let tip_depth = tools.iter().map(|tool| tool.tip.z).sum::<f64>() / tools.len() as f64;
        let albedo = (0.6 / 0.8 * (tip_depth / exposure_distance_mm).powi(2)).min(1.0);
        Self { tools, albedo }
    }

    fn metal(&self, metal: Metal) -> Metal {
        Metal { albedo: metal.albedo * self.albedo, ..metal }
    }

    /// The instruments' parts at time `t_s`, placed in the world by the left camera's pose.
    pub fn parts_at(&self, t_s: f64, world_from_left: &Isometry3<f64>) -> Vec<Part> {
        let mut parts = Vec::with_capacity(3 * self.tools.len());
        for tool in &self.tools {
            let s = |k: usize| (tool.rates[k] * t_s + tool.phase + k as f64).sin();
            let tip = tool.tip + Vector3::new(tool.sway.x * s(0), tool.sway.y * s(1), tool.sway.z * s(2));
            let butt = tip + tool.back * tool.length;
            // The jaws open and close in the plane of the shaft and the camera's x axis.
            let side = tool.back.cross(&Vector3::z()).try_normalize(1e-9).unwrap_or_else(Vector3::x);
            let opening = 0.15 + 0.2 * (0.5 + 0.5 * (1.7 * t_s + tool.phase).sin());
            let forward = -tool.back;
            let place = |p: Vector3<f64>| world_from_left * Point3::from(p);
            parts.push(Part {
                a: place(tip),
                b: place(butt),
                radius: tool.radius,
                ring_spacing: 1.5 * tool.radius,
                metal: self.metal(SHAFT),
                ring_albedo: self.metal(RING).albedo,
            });
            for sign in [-1.0, 1.0] {
                let dir = (forward * opening.cos() + side * (sign * opening.sin())).normalize();
                parts.push(Part {
                    a: place(tip + dir * tool.jaw_length),
                    b: place(tip),
                    radius: 0.5 * tool.radius,
                    ring_spacing: 0.0,
                    metal: self.metal(JAW),
                    ring_albedo: 0.0,
                });
            }
        }
        parts
    }
}

/// The nearest instrument along `origin + t·dir` (dir unit) with 0 < t < `max_t`.
pub fn hit(parts: &[Part], origin: &Point3<f64>, dir: &Vector3<f64>, max_t: f64) -> Option<PartHit> {
    let mut best: Option<(f64, &Part)> = None;
    for part in parts {
        if let Some(t) = capsule_t(origin, dir, &part.a, &part.b, part.radius)
            && t < best.map_or(max_t, |b| b.0)
        {
            best = Some((t, part));
        }
    }
    let (t, part) = best?;
    let point = origin + dir * t;
    let axis = part.b - part.a;
    let along = ((point - part.a).dot(&axis) / axis.norm_squared()).clamp(0.0, 1.0);
    let normal = (point - (part.a + axis * along)).normalize();
    // Rings: bands a quarter of the spacing wide, the first three spacings from the tip end.
    let distance = along * axis.norm();
    let metal = if part.ring_spacing > 0.0
        && (1.0..4.0).contains(&(distance / part.ring_spacing))
        && (distance / part.ring_spacing).fract() > 0.75
    {
        Metal { albedo: part.ring_albedo, ..RING }
    } else {
        part.metal
    };
    Some(PartHit { t, point, normal, albedo: metal.albedo, specular: metal.specular, shininess: metal.shininess })
}

/// The ray parameter where `origin + t·dir` (dir unit) enters the capsule from `a` to `b`, if it does at t > 0.
fn capsule_t(origin: &Point3<f64>, dir: &Vector3<f64>, a: &Point3<f64>, b: &Point3<f64>, radius: f64) -> Option<f64> {
    let axis = b - a;
    let from_a = origin - a;
    let axis2 = axis.norm_squared();
    let (axis_dir, axis_from) = (axis.dot(dir), axis.dot(&from_a));
    // The infinite cylinder: |(p − a) − ((p − a)·axiŝ) axiŝ|² = r², a quadratic in t.
    let qa = axis2 - axis_dir * axis_dir;
    let qb = axis2 * dir.dot(&from_a) - axis_from * axis_dir;
    let qc = axis2 * from_a.norm_squared() - axis_from * axis_from - radius * radius * axis2;
    let disc = qb * qb - qa * qc;
    if disc < 0.0 {
        return None;
    }
    if qa > 1e-12 {
        let t = (-qb - disc.sqrt()) / qa;
        let along = axis_from + t * axis_dir;
        if t > 0.0 && along > 0.0 && along < axis2 {
            return Some(t);
        }
    }
    // Otherwise the ray meets a round end first (or misses).
    let sphere = |centre: &Point3<f64>| {
        let oc = origin - centre;
        let b = dir.dot(&oc);
        let h = b * b - (oc.norm_squared() - radius * radius);
        (h >= 0.0).then(|| -b - h.sqrt()).filter(|&t| t > 0.0)
    };
    match (sphere(a), sphere(b)) {
        (Some(x), Some(y)) => Some(x.min(y)),
        (x, y) => x.or(y),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_ray_meets_a_capsule_on_its_side_and_its_round_end() {
        let (a, b) = (Point3::new(0.0, 0.0, 10.0), Point3::new(0.0, 20.0, 10.0));
        // Straight down the z axis at x = 0.5 onto a shaft of radius 1 along y: enters at z = 10 − √0.75.
        let t = capsule_t(&Point3::new(0.5, 5.0, 0.0), &Vector3::z(), &a, &b, 1.0).unwrap();
        assert!((t - (10.0 - 0.75f64.sqrt())).abs() < 1e-9, "{t}");
        // Beyond the end at y = −0.5: the sphere round `a`.
        let t = capsule_t(&Point3::new(0.0, -0.5, 0.0), &Vector3::z(), &a, &b, 1.0).unwrap();
        assert!((t - (10.0 - 0.75f64.sqrt())).abs() < 1e-9, "{t}");
        // Past both: a miss; behind the origin: a miss.
        assert!(capsule_t(&Point3::new(0.0, -1.5, 0.0), &Vector3::z(), &a, &b, 1.0).is_none());
        assert!(capsule_t(&Point3::new(0.0, 5.0, 20.0), &Vector3::z(), &a, &b, 1.0).is_none());
        let part = Part { a, b, radius: 1.0, ring_spacing: 0.0, metal: SHAFT, ring_albedo: 0.0 };
        let h = hit(&[part], &Point3::new(0.0, 5.0, 0.0), &Vector3::z(), 100.0).unwrap();
        assert!((h.normal - Vector3::new(0.0, 0.0, -1.0)).norm() < 1e-9);
        assert!(hit(&[part], &Point3::new(0.0, 5.0, 0.0), &Vector3::z(), 5.0).is_none(), "beyond max_t");
    }
}
