//! Synthetic stereo endoscopy with exact ground truth.
//!
//! For now one scene: a textured tissue plane facing the scope, seen by a rectified stereo pair that sweeps
//! sideways. Every pixel is the procedural texture evaluated exactly where its ray meets the plane, so the
//! ground-truth disparity is `bf / depth` everywhere. The colon and abdomen scenes of issue #4 grow from here.

pub mod abdomen;
pub mod bleeding;
pub mod breathing;
pub mod colon;
pub mod instruments;
pub mod interlace;
pub mod render;
pub mod smoke;
mod texture;

use std::path::{Path, PathBuf};

/// The renderer's camera: a rectified stereo rig of known size (`bf` = fx · baseline, in mm).
pub use bdis_core::RectifiedCamera;

pub use texture::TissueTexture;
pub(crate) use texture::{floor, value_noise, value_noise3};

/// 640×480, fx = fy = 520, principal point at the centre, 5 mm baseline (a stereo laparoscope).
pub fn default_camera() -> RectifiedCamera {
    RectifiedCamera { width: 640, height: 480, fx: 520.0, fy: 520.0, cx: 320.0, cy: 240.0, bf: 520.0 * 5.0 }
}

/// A tissue plane at `depth_mm` facing the scope; the scope moves in its own x/y plane.
#[derive(Debug, Clone, Copy)]
pub struct PlaneScene {
    pub depth_mm: f64,
    pub texture: TissueTexture,
}

impl PlaneScene {
    /// Renders the pair seen with the left camera at (`x_mm`, `y_mm`) into `left` and `right` (reused).
    pub fn render_pair(
        &self,
        rig: &RectifiedCamera,
        x_mm: f64,
        y_mm: f64,
        left: &mut image::RgbImage,
        right: &mut image::RgbImage,
    ) {
        let z = self.depth_mm;
        for (img, offset) in [(left, 0.0), (right, rig.baseline())] {
            if img.dimensions() != (rig.width, rig.height) {
                *img = image::RgbImage::new(rig.width, rig.height);
            }
            for (px, py, pixel) in img.enumerate_pixels_mut() {
                let u = (f64::from(px) + 0.5 - rig.cx) * z / rig.fx + x_mm + offset;
                let v = (f64::from(py) + 0.5 - rig.cy) * z / rig.fy + y_mm;
                *pixel = image::Rgb(self.texture.rgb(u, v));
            }
        }
    }

    /// Ground-truth disparity (px) of every pixel: `fx · baseline / depth`.
    pub fn disparity_px(&self, rig: &RectifiedCamera) -> f64 {
        rig.bf / self.depth_mm
    }
}

#[derive(Debug, thiserror::Error)]
pub enum SynthError {
    #[error("{path}: {detail}")]
    Write { path: PathBuf, detail: String },
    #[error("{detail}")]
    Request { detail: String },
}

/// Writes a sideways sweep over the plane as a plain sequence (`left/`, `right/`, `times.txt`) and a settings
/// file, calling `progress(i)` after each frame.
pub fn write_plane_sweep(
    dir: &Path,
    rig: &RectifiedCamera,
    scene: &PlaneScene,
    frames: usize,
    fps: f64,
    speed_mm_s: f64,
    mut progress: impl FnMut(usize),
) -> Result<PathBuf, SynthError> {
    let fail =
        |path: &Path, e: &dyn std::fmt::Display| SynthError::Write { path: path.to_path_buf(), detail: e.to_string() };
    for side in ["left", "right"] {
        std::fs::create_dir_all(dir.join(side)).map_err(|e| fail(&dir.join(side), &e))?;
    }
    let mut left = image::RgbImage::new(rig.width, rig.height);
    let mut right = image::RgbImage::new(rig.width, rig.height);
    let mut times = String::new();
    for i in 0..frames {
        let t = i as f64 / fps;
        // Sideways sweep with a gentle vertical wobble.
        let (x, y) = (speed_mm_s * t, 2.0 * (t * 0.7).sin());
        scene.render_pair(rig, x, y, &mut left, &mut right);
        for (side, img) in [("left", &left), ("right", &right)] {
            let path = dir.join(format!("{side}/{}.png", i + 1));
            img.save(&path).map_err(|e| fail(&path, &e))?;
        }
        times += &format!("{t:.6}\n");
        progress(i);
    }
    let times_path = dir.join("times.txt");
    std::fs::write(&times_path, times).map_err(|e| fail(&times_path, &e))?;
    let settings = dir.join("settings.yaml");
    let text = format!(
        "%YAML:1.0\n# Synthetic tissue plane at {:.1} mm, written by bdis-slam demo. Units: millimetres.\n\
Camera.fx: {}\nCamera.fy: {}\nCamera.cx: {}\nCamera.cy: {}\nCamera.width: {}\nCamera.height: {}\nCamera.fps: {}\nCamera.bf: {}\nCamera.RGB: 1\nThDepth: 20\n",
        scene.depth_mm, rig.fx, rig.fy, rig.cx, rig.cy, rig.width, rig.height, fps, rig.bf
    );
    std::fs::write(&settings, text).map_err(|e| fail(&settings, &e))?;
    Ok(settings)
}

#[cfg(test)]
mod tests {
    #[test]
    fn motion_profiles_are_continuous_with_the_speeds_they_promise() {
        let (total, fps) = (3.0, 30.0);
        let dt = 1.0 / fps;
        for motion in [Motion::Steady, Motion::Jerk, Motion::Stop] {
            let mut last = motion.path_time(0.0, total, fps);
            assert_eq!(last, 0.0);
            for i in 1..=90 {
                let t = motion.path_time(f64::from(i) * dt, total, fps);
                let step = (t - last) / dt;
                assert!((-1e-9..=10.0 + 1e-9).contains(&step), "{motion:?} frame {i}: ×{step}");
                last = t;
            }
        }
        let steps = |m: Motion| -> Vec<f64> {
            (1..=90)
                .map(|i| {
                    (m.path_time(f64::from(i) * dt, total, fps) - m.path_time(f64::from(i - 1) * dt, total, fps)) / dt
                })
                .collect()
        };
        let jerk = steps(Motion::Jerk);
        assert_eq!(jerk.iter().filter(|s| (**s - 10.0).abs() < 1e-6).count(), 3, "three frames at 10×");
        let stop = steps(Motion::Stop);
        assert_eq!(stop.iter().filter(|s| s.abs() < 1e-9).count(), 30, "a second stopped");
        assert_eq!(Motion::parse("jerk"), Some(Motion::Jerk));
        assert_eq!(Motion::parse("wobble"), None);
    }

    use super::*;

    #[test]
    fn right_image_is_the_left_shifted_by_the_ground_truth_disparity() {
        // With a disparity of exactly 13 px, right(x) must equal left(x + 13) pixel for pixel.
        let rig = RectifiedCamera { width: 96, height: 24, fx: 260.0, fy: 260.0, cx: 48.0, cy: 12.0, bf: 260.0 * 2.5 };
        let scene = PlaneScene { depth_mm: 50.0, texture: TissueTexture { seed: 7 } };
        assert_eq!(scene.disparity_px(&rig), 13.0);
        let (mut l, mut r) = (image::RgbImage::new(1, 1), image::RgbImage::new(1, 1));
        scene.render_pair(&rig, 1.0, -2.0, &mut l, &mut r);
        let mut differing = 0;
        for y in 0..24 {
            for x in 0..(96 - 13) {
                let (a, b) = (l.get_pixel(x + 13, y), r.get_pixel(x, y));
                if a.0.iter().zip(b.0.iter()).any(|(p, q)| (i32::from(*p) - i32::from(*q)).abs() > 1) {
                    differing += 1;
                }
            }
        }
        assert_eq!(differing, 0, "rounding of the sample positions may differ by 1 grey level, no more");
    }

    #[test]
    fn texture_is_deterministic_and_has_contrast() {
        let t = TissueTexture { seed: 3 };
        assert_eq!(t.rgb(1.25, -3.5), TissueTexture { seed: 3 }.rgb(1.25, -3.5));
        let reds: Vec<u8> = (0..400).map(|i| t.rgb(i as f64 * 0.1, 0.0)[0]).collect();
        let (min, max) = (reds.iter().min().unwrap(), reds.iter().max().unwrap());
        assert!(max - min > 40, "texture needs contrast for matching ({min}..{max})");
    }
}

/// How the camera moves along its path over time: the hard cases of a tracker's motion prior.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Motion {
    /// At the requested speed throughout (the camera is already moving at the first frame).
    #[default]
    Steady,
    /// A third of the way in, three frames at ten times the speed (a jerk of the scope), then steady again.
    Jerk,
    /// A third of the way in, a dead stop for a second, then on at full speed at once.
    Stop,
}

/// How the scene is lit: the scope's own light, or parts of it switched off — to vary the renderer, and to tell
/// which part of the light an error comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Lighting {
    /// The light at the scope's tip: falloff with distance, the relief's shading, highlights, vignetting.
    #[default]
    Scope,
    /// As `Scope` without the specular highlights.
    NoHighlights,
    /// As `Scope` with the diffuse term blind to the surface's orientation (no relief shading).
    FlatDiffuse,
    /// No light model: each pixel is the texture's albedo (and the sensor's noise).
    Albedo,
}

impl Lighting {
    pub const NAMES: &'static str = "scope, no-highlights, flat-diffuse, albedo";

    pub fn parse(name: &str) -> Option<Self> {
        match name {
            "scope" => Some(Self::Scope),
            "no-highlights" => Some(Self::NoHighlights),
            "flat-diffuse" => Some(Self::FlatDiffuse),
            "albedo" => Some(Self::Albedo),
            _ => None,
        }
    }

    /// `shading` lit this way.
    pub fn apply(self, shading: render::Shading) -> render::Shading {
        match self {
            Self::Scope => shading,
            Self::NoHighlights => render::Shading { specular: 0.0, ..shading },
            Self::FlatDiffuse => render::Shading { relief: false, ..shading },
            Self::Albedo => render::Shading { lighting: false, ..shading },
        }
    }
}

impl Motion {
    pub const NAMES: &'static str = "steady, jerk, stop";

    pub fn parse(name: &str) -> Option<Self> {
        match name {
            "steady" => Some(Self::Steady),
            "jerk" => Some(Self::Jerk),
            "stop" => Some(Self::Stop),
            _ => None,
        }
    }

    /// The time along the path (as if at the steady speed) at time `t_s` of a sequence `total_s` long at `fps`.
    pub fn path_time(self, t_s: f64, total_s: f64, fps: f64) -> f64 {
        let start = total_s / 3.0;
        match self {
            Self::Steady => t_s,
            Self::Jerk => {
                let burst = 3.0 / fps;
                if t_s < start {
                    t_s
                } else if t_s < start + burst {
                    start + 10.0 * (t_s - start)
                } else {
                    t_s + 9.0 * burst
                }
            }
            Self::Stop => {
                let pause = 1.0_f64.min(total_s / 3.0);
                if t_s < start {
                    t_s
                } else if t_s < start + pause {
                    start
                } else {
                    t_s - pause
                }
            }
        }
    }
}

/// A scene and camera path chosen by name, as `bdis-slam synth` and the `synthetic:` acquisition source do.
#[derive(Debug, Clone)]
pub struct SceneRequest {
    /// `colon` or `abdomen`.
    pub scene: String,
    /// Colon: `forward`, `revisit`; abdomen: `hover`, `sweep`, `revisit`, `pan`, `oblique`, `circle`, `twins` (the
    /// sweep over a wall that repeats, pattern and shape, every [`abdomen::TWIN_SPACING_MM`]: a place that looks
    /// and is shaped exactly like one seen before but is not it, a loop that must not be closed). `None`:
    /// forward / sweep.
    pub trajectory: Option<String>,
    pub frames: usize,
    pub fps: f64,
    /// Speed along the path, mm/s.
    pub speed_mm_s: f64,
    /// How the speed varies in time.
    pub motion: Motion,
    pub seed: u64,
    /// A raw rig ([`render::RawLens::preset`]: `mild`, `strong`): distorted, turned cameras and `calib.yaml`
    /// instead of rectified pairs and `settings.yaml`. `None`: rectified.
    pub raw: Option<String>,
    /// σ (px) of the optics' blur ([`render::Shading::optics_blur_px`]); 0: none.
    pub optics_blur_px: f64,
    /// Instruments in the view (two laparoscopic graspers over the abdomen, a working-channel tool in the
    /// colon), with a ground-truth mask per frame in `gt/masks/`.
    pub instruments: bool,
    /// A puff of surgical smoke 40 % of the way in: up in 0.3 s, 0.5 s thick, gone 0.8 s later, hanging in the
    /// cavity or riding with the scope ([`smoke`]); `None`: clear air.
    pub smoke: Option<smoke::Anchoring>,
    /// Breathing ([`breathing`]): the largest displacement of the tissue from its mean surface, mm; 0: still.
    pub breathing_mm: f64,
    /// A bleed 30 % of the way in ([`bleeding`]): a pool of blood spreading over the tissue in view for 2 s.
    pub bleeding: bool,
    /// Breathing's wavelength over the tissue ([`breathing::WAVELENGTH_MM`] by default), mm.
    pub breathing_wavelength_mm: f64,
    /// How the scene is lit.
    pub lighting: Lighting,
}

impl Default for SceneRequest {
    fn default() -> Self {
        Self {
            scene: "colon".into(),
            trajectory: None,
            frames: 60,
            fps: 30.0,
            speed_mm_s: 20.0,
            motion: Motion::Steady,
            seed: 2026,
            raw: None,
            optics_blur_px: 0.0,
            instruments: false,
            smoke: None,
            breathing_mm: 0.0,
            breathing_wavelength_mm: breathing::WAVELENGTH_MM,
            bleeding: false,
            lighting: Lighting::Scope,
        }
    }
}

impl SceneRequest {
    /// Checks the scene and path names and the numbers before anything is rendered.
    pub fn validate(&self) -> Result<(), SynthError> {
        let invalid = |detail: String| Err(SynthError::Request { detail });
        if self.frames == 0 || !(self.fps.is_finite() && self.fps > 0.0) || !self.speed_mm_s.is_finite() {
            return invalid("give frames ≥ 1, fps > 0 and a finite speed".into());
        }
        let paths: &[&str] = match self.scene.as_str() {
            "colon" => &["forward", "revisit"],
            "abdomen" => &["hover", "sweep", "revisit", "pan", "oblique", "circle", "twins"],
            other => return invalid(format!("`{other}` is not a scene (colon, abdomen)")),
        };
        if !(0.0..=10.0).contains(&self.breathing_mm) {
            return invalid(format!("breathing {} mm is outside 0–10 mm", self.breathing_mm));
        }
        if !(self.breathing_wavelength_mm.is_finite() && self.breathing_wavelength_mm >= 5.0) {
            return invalid(format!("breathing wavelength {} mm is not ≥ 5 mm", self.breathing_wavelength_mm));
        }
        if !(0.0..=5.0).contains(&self.optics_blur_px) {
            return invalid(format!("optics blur σ {} px is outside 0–5 px", self.optics_blur_px));
        }
        if let Some(raw) = &self.raw
            && !RAW_LENSES.contains(&raw.as_str())
        {
            return invalid(format!("`{raw}` is not a raw rig ({})", RAW_LENSES.join(", ")));
        }
        match &self.trajectory {
            Some(t) if !paths.contains(&t.as_str()) => {
                invalid(format!("trajectory `{t}` does not fit scene `{}` ({})", self.scene, paths.join(", ")))
            }
            _ => Ok(()),
        }
    }
}

/// The raw rigs [`render::RawLens::preset`] knows.
pub const RAW_LENSES: &[&str] = &["mild", "strong"];

/// Renders the requested scene and path into `dir` with its ground truth (see [`render::write_sequence`]).
pub fn write_scene(
    dir: &Path,
    rig: &RectifiedCamera,
    request: &SceneRequest,
    progress: impl FnMut(usize),
) -> Result<render::WrittenSequence, SynthError> {
    request.validate()?;
    let total_s = (request.frames - 1) as f64 / request.fps;
    let (speed, seed, fps, motion) = (request.speed_mm_s, request.seed, request.fps, request.motion);
    // The path is drawn in path time; with a steady motion it is the sequence's time. The path's extent (for
    // the mesh) is that of its last frame.
    let warp = move |t: f64| motion.path_time(t, total_s, fps);
    let path_total_s = warp(total_s);
    let trajectory = request.trajectory.clone();
    let lens = request.raw.as_deref().and_then(|name| render::RawLens::preset(name, rig));
    let optics_blur_px = request.optics_blur_px;
    let lighting = request.lighting;
    let breathing = (request.breathing_mm > 0.0)
        .then(|| breathing::Breathing::new(request.breathing_mm, request.breathing_wavelength_mm));
    let swell_at = move |t: f64| breathing.map_or_else(breathing::Swell::default, |b| b.swell_at(t));
    // Per scene: the tissue at a time, the path, the mean surface's mesh, the light, and the depth the
    // instruments and smoke work at (the scope's working distance).
    type SurfaceAt = Box<dyn Fn(f64) -> Box<dyn render::Surface>>;
    type CameraPath = Box<dyn Fn(f64) -> nalgebra::Isometry3<f64>>;
    let (surface_at, path, mesh, shading, tool_kind, working_distance_mm): (SurfaceAt, CameraPath, _, _, _, _) =
        match (request.scene.as_str(), trajectory.as_deref()) {
            ("colon", None | Some("forward") | Some("revisit")) => {
                let colon = colon::Colon { seed, texture: TissueTexture { seed }, ..colon::Colon::default() };
                let revisit = trajectory.as_deref() == Some("revisit");
                let path = move |t: f64| {
                    let t = warp(t);
                    if revisit { colon.revisit_pose(t, path_total_s, speed) } else { colon.forward_pose(t, speed) }
                };
                let far = speed.abs() * if revisit { 0.5 * path_total_s } else { path_total_s };
                (
                    Box::new(move |t| Box::new(colon::Colon { swell: swell_at(t), ..colon })),
                    Box::new(path),
                    colon.mesh(-20.0, far + 150.0, 0.5, 180),
                    lighting.apply(render::Shading { lens, optics_blur_px, ..render::Shading::default() }),
                    instruments::InstrumentKind::WorkingChannel,
                    colon.radius_mm,
                )
            }
            (
                "abdomen",
                None | Some("hover") | Some("sweep") | Some("revisit") | Some("pan") | Some("oblique") | Some("circle")
                | Some("twins"),
            ) => {
                let repeat_mm = (trajectory.as_deref() == Some("twins")).then_some(abdomen::TWIN_SPACING_MM);
                let abdomen = abdomen::Abdomen {
                    seed,
                    texture: TissueTexture { seed },
                    repeat_mm,
                    ..abdomen::Abdomen::default()
                };
                let a = abdomen.clone();
                let name = trajectory.clone();
                let path = move |t: f64| {
                    let t = warp(t);
                    match name.as_deref() {
                        Some("hover") => a.hover_pose(t),
                        Some("revisit") => a.revisit_pose(t, path_total_s, speed),
                        Some("pan") => a.pan_pose(t, speed),
                        Some("oblique") => a.oblique_pose(t, speed),
                        Some("circle") => a.circle_pose(t, speed),
                        _ => a.sweep_pose(t, speed),
                    }
                };
                // The circle stays within its radius of the centre; the other paths move along x.
                let travel = if trajectory.as_deref() == Some("circle") {
                    abdomen::CIRCLE_RADIUS_MM
                } else {
                    speed.abs() * path_total_s
                };
                let mesh = abdomen.mesh(60.0 + travel, 0.5);
                let surface_at = move |t| -> Box<dyn render::Surface> {
                    Box::new(abdomen::Abdomen { swell: swell_at(t), ..abdomen.clone() })
                };
                // A laparoscope's light is stronger and the wall farther away than in a colon; the graspers work
                // at the depth the scope hovers at over the wall.
                (
                    Box::new(surface_at),
                    Box::new(path),
                    mesh,
                    lighting.apply(render::Shading {
                        exposure_distance_mm: 65.0,
                        lens,
                        optics_blur_px,
                        ..render::Shading::default()
                    }),
                    instruments::InstrumentKind::Laparoscopic,
                    abdomen::STANDOFF_MM,
                )
            }
            _ => {
                return Err(SynthError::Request {
                    detail: format!("`{}` with {:?} cannot be rendered", request.scene, request.trajectory),
                });
            }
        };
    let tools = request
        .instruments
        .then(|| instruments::Instruments::new(tool_kind, working_distance_mm, shading.exposure_distance_mm));
    let smoke_start_s = 0.4 * total_s;
    let smoke = request.smoke.map(|anchoring| match anchoring {
        smoke::Anchoring::Scope => smoke::Smoke::puff(smoke_start_s, working_distance_mm, seed),
        smoke::Anchoring::Cavity => {
            smoke::Smoke::cavity_puff(smoke_start_s, working_distance_mm, &path(smoke_start_s), seed)
        }
    });
    // The bleed's source: the tissue a little below the centre of the view when it starts (the centre of a colon
    // view looks down the lumen).
    let bleeding = if request.bleeding {
        let start_s = 0.3 * total_s;
        let pose = path(start_s);
        let dir = pose.rotation * nalgebra::Vector3::new(0.0, 0.2 * rig.height as f64 / rig.fy, 1.0).normalize();
        let Some(hit) = surface_at(start_s).hit(&(pose * nalgebra::Point3::origin()), &dir, 150.0) else {
            return Err(SynthError::Request { detail: "no tissue in view where the bleed should start".into() });
        };
        Some(bleeding::Bleeding::new(start_s, hit.uv, working_distance_mm, seed))
    } else {
        None
    };
    let events = render::Events { instruments: tools.as_ref(), smoke: smoke.as_ref(), bleeding: bleeding.as_ref() };
    render::write_sequence(dir, rig, &surface_at, events, &path, mesh, &shading, request.frames, request.fps, progress)
}
