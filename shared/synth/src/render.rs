//! Rendering any scene surface as a rectified stereo pair with exact depth, and writing sequences with their
//! ground truth.

use nalgebra::{Isometry3, Point3, Translation3, Vector3};

use crate::RectifiedCamera;

/// Where a ray met the surface.
#[derive(Debug, Clone, Copy)]
pub struct Hit {
    pub t: f64,
    pub point: Point3<f64>,
    /// Unit normal pointing towards the viewer's side.
    pub normal: Vector3<f64>,
    /// Surface coordinates in mm (for the texture).
    pub uv: (f64, f64),
}

/// A scene's tissue surface.
pub trait Surface: Sync {
    /// The first surface point along `origin + t·dir` (dir unit) with t < `max_t`.
    fn hit(&self, origin: &Point3<f64>, dir: &Vector3<f64>, max_t: f64) -> Option<Hit>;
    /// Albedo at surface coordinates, filtered for a pixel footprint of `footprint_mm` on the surface (detail
    /// smaller than a pixel fades instead of aliasing).
    fn albedo(&self, uv: (f64, f64), footprint_mm: f64) -> [u8; 3];
    /// Seed of the sensor noise.
    fn seed(&self) -> u64;
}

/// How images are lit and degraded.
#[derive(Debug, Clone, Copy)]
pub struct Shading {
    /// Off: images show the texture's albedo only, without light, shading or highlights (the sensor's noise is
    /// `noise`'s alone).
    pub lighting: bool,
    /// Off: the diffuse term ignores the surface's orientation, as if every patch faced the light; the falloff
    /// with distance, the vignetting and the highlights stay.
    pub relief: bool,
    /// Radiance scale: a wall at this distance, facing the light, is exposed to about 80 %.
    pub exposure_distance_mm: f64,
    /// Light scattered inside the lumen, as a fraction of full exposure.
    pub ambient: f64,
    pub specular: f64,
    pub shininess: f64,
    /// Darkening towards the image corners.
    pub vignetting: f64,
    /// Uniform sensor noise amplitude, grey levels.
    pub noise: f64,
    /// σ (px) of the optics' blur — the lens's spread and the pixel's area — applied to the radiance in the
    /// camera's own pixel grid (the raw one, for a raw rig), before the sensor's noise. 0: one ray per pixel
    /// centre, as sharp as the texture's own band limit.
    pub optics_blur_px: f64,
    /// Raw optics: `None` renders a rectified pair; `Some` renders what distorted, slightly turned cameras at
    /// the same centres see ([`RawLens`]), to be rectified by `bdis-slam rectify`.
    pub lens: Option<RawLens>,
    /// Smoke in front of the scope in this frame ([`crate::smoke`]); `None`: clear air.
    pub haze: Option<crate::smoke::Haze>,
    /// Blood on the tissue in this frame ([`crate::bleeding`]); `None`: none.
    pub bleeding: Option<crate::bleeding::Pool>,
}

/// A raw stereo camera for rendering: each side's lens (intrinsics and distortion, pixel centres at integer
/// coordinates) and its rotation relative to the rectified camera of the rig at the same centre.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RawLens {
    pub left: bdis_rectify::CameraModel,
    pub right: bdis_rectify::CameraModel,
    /// Rectified frame from raw frame: `X_rectified = rectified_from_raw · X_raw`.
    pub left_rectified_from_raw: nalgebra::Matrix3<f64>,
    pub right_rectified_from_raw: nalgebra::Matrix3<f64>,
}

impl RawLens {
    /// The named raw rigs of `bdis-slam synth --raw` for a rectified `rig`: `mild` (5-coefficient barrel
    /// distortion, cameras turned by up to 0.5°, focal lengths and principal points a little off) and `strong`
    /// (the 8-coefficient rational model of a wide endoscope lens, turned by up to 1.5°).
    pub fn preset(name: &str, rig: &RectifiedCamera) -> Option<Self> {
        let (distortion_left, distortion_right, turn) = match name {
            "mild" => (
                [-0.12, 0.05, 0.0006, -0.0004, 0.0, 0.0, 0.0, 0.0],
                [-0.11, 0.045, -0.0003, 0.0005, -0.005, 0.0, 0.0, 0.0],
                1.0,
            ),
            "strong" => (
                [-0.32, 0.11, 0.0008, -0.0006, -0.015, 0.05, 0.01, 0.002],
                [-0.30, 0.10, -0.0005, 0.0007, -0.01, 0.045, 0.008, 0.001],
                3.0,
            ),
            _ => return None,
        };
        let degrees = |x: f64, y: f64, z: f64| {
            nalgebra::Rotation3::from_scaled_axis(
                nalgebra::Vector3::new(x, y, z) * (turn * std::f64::consts::PI / 180.0),
            )
            .into_inner()
        };
        // Pixel centres at integer coordinates, as the written settings have them (see `write_sequence`).
        let k = |scale_x: f64, scale_y: f64, dx: f64, dy: f64| {
            nalgebra::Matrix3::new(
                rig.fx * scale_x,
                0.0,
                rig.cx - 0.5 + dx * f64::from(rig.width) / 640.0,
                0.0,
                rig.fy * scale_y,
                rig.cy - 0.5 + dy * f64::from(rig.height) / 480.0,
                0.0,
                0.0,
                1.0,
            )
        };
        Some(Self {
            left: bdis_rectify::CameraModel { k: k(1.01, 1.012, 3.0, -2.0), distortion: distortion_left },
            right: bdis_rectify::CameraModel { k: k(0.99, 0.991, -2.5, 1.5), distortion: distortion_right },
            left_rectified_from_raw: degrees(0.15, -0.1, 0.05),
            right_rectified_from_raw: degrees(-0.2, 0.25, -0.1),
        })
    }

    /// The calibration of this rig with a rectified baseline `baseline` along x: `X_right = R · X_left + T`
    /// between the raw cameras.
    pub fn calibration(&self, baseline: f64) -> (nalgebra::Matrix3<f64>, nalgebra::Vector3<f64>) {
        let rotation = self.right_rectified_from_raw.transpose() * self.left_rectified_from_raw;
        let translation = -(self.right_rectified_from_raw.transpose() * nalgebra::Vector3::new(baseline, 0.0, 0.0));
        (rotation, translation)
    }

    /// The ray (rectified frame, z = 1 not implied) through raw pixel (u, v) of a view (1 left, 2 right),
    /// with (u, v) in the renderer's pixel-corner convention.
    pub(crate) fn ray(&self, view: u64, u: f64, v: f64) -> Option<Vector3<f64>> {
        let (camera, turn) = if view == 1 {
            (&self.left, &self.left_rectified_from_raw)
        } else {
            (&self.right, &self.right_rectified_from_raw)
        };
        let (x, y) = camera.undistort(u - 0.5, v - 0.5)?;
        Some(turn * Vector3::new(x, y, 1.0))
    }
}

impl Default for Shading {
    fn default() -> Self {
        Self {
            lighting: true,
            relief: true,
            exposure_distance_mm: 40.0,
            ambient: 0.06,
            specular: 0.35,
            shininess: 40.0,
            vignetting: 0.3,
            noise: 2.0,
            optics_blur_px: 0.0,
            lens: None,
            haze: None,
            bleeding: None,
        }
    }
}

/// One rendered stereo frame with its ground truth.
#[derive(Debug, Clone)]
pub struct RenderedPair {
    pub left: image::RgbImage,
    pub right: image::RgbImage,
    /// z-depth of the left camera per pixel (mm); +inf where no wall is within range.
    pub depth: Vec<f32>,
    /// 255 where the left view's pixel centre sees an instrument, else 0 (row-major, one byte per pixel).
    pub instrument_mask: Vec<u8>,
}

fn hash_noise(seed: u64, frame: u64, k: u64) -> f64 {
    let mut h = seed ^ frame.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ k.wrapping_mul(0xC2B2_AE3D_27D4_EB4F);
    h ^= h >> 31;
    h = h.wrapping_mul(0xBF58_476D_1CE4_E5B9);
    h ^= h >> 29;
    (h >> 11) as f64 / (1u64 << 53) as f64
}

/// Renders the pair seen from `left_from_world⁻¹ = world_from_left`. The light sits at the scope tip, midway
/// between the two cameras, so both views share the shading but not the specular highlights.
pub fn render(
    surface: &dyn Surface,
    rig: &RectifiedCamera,
    shading: &Shading,
    world_from_left: &Isometry3<f64>,
    frame: u64,
) -> RenderedPair {
    render_scene(surface, &[], rig, shading, world_from_left, frame)
}

/// [`render`] with instruments in front of the tissue ([`crate::instruments`]): metal, lit by the same light,
/// in the images and the depth, and marked in the left view's mask.
pub fn render_scene(
    surface: &dyn Surface,
    instruments: &[crate::instruments::Part],
    rig: &RectifiedCamera,
    shading: &Shading,
    world_from_left: &Isometry3<f64>,
    frame: u64,
) -> RenderedPair {
    let (w, h) = (rig.width, rig.height);
    let mut left = image::RgbImage::new(w, h);
    let mut right = image::RgbImage::new(w, h);
    let mut depth = vec![f32::INFINITY; (w * h) as usize];
    let mut right_depth = vec![f32::INFINITY; (w * h) as usize];
    let mut instrument_mask = vec![0u8; (w * h) as usize];
    let mut right_mask = vec![0u8; (w * h) as usize];
    let world_from_right = world_from_left * Translation3::new(rig.baseline(), 0.0, 0.0);
    let light = world_from_left * Point3::new(0.5 * rig.baseline(), 0.0, 0.0);
    let half_diag2 = (rig.cx * rig.cx + rig.cy * rig.cy).max(1.0);
    let max_t = 150.0;
    let exposure = 0.8 * shading.exposure_distance_mm.powi(2);

    // Radiance (0..255 per channel, before noise) and z-depth of the ray through image point (u, v).
    // Also whether the ray met an instrument.
    let shade = |pose: &Isometry3<f64>, view: u64, u: f64, v: f64| -> Option<([f64; 3], f64, bool)> {
        let dir_cam = match &shading.lens {
            None => Vector3::new((u - rig.cx) / rig.fx, (v - rig.cy) / rig.fy, 1.0),
            Some(lens) => lens.ray(view, u, v)?,
        };
        let dir = (pose.rotation * dir_cam).normalize();
        let origin = pose * Point3::origin();
        let tissue = surface.hit(&origin, &dir, max_t);
        let tool = crate::instruments::hit(instruments, &origin, &dir, tissue.map_or(max_t, |hit| hit.t));
        // Point, normal, albedo and the material's highlight.
        let (t, point, normal, albedo, specular, shininess) = match (tool, tissue) {
            (Some(tool), _) => (tool.t, tool.point, tool.normal, [tool.albedo; 3], tool.specular, tool.shininess),
            (None, Some(hit)) => {
                // One pixel's footprint on the surface (ignoring obliqueness).
                let footprint_mm = hit.t / rig.fx;
                let albedo = surface.albedo(hit.uv, footprint_mm).map(|c| f64::from(c) / 255.0);
                let (albedo, specular, shininess) = match &shading.bleeding {
                    Some(pool) => pool.wet(hit.uv, albedo, shading.specular, shading.shininess),
                    None => (albedo, shading.specular, shading.shininess),
                };
                (hit.t, hit.point, hit.normal, albedo, specular, shininess)
            }
            (None, None) => return None,
        };
        let (diffuse, spec) = if shading.lighting {
            let to_light = light - point;
            let d2 = to_light.norm_squared();
            let l = to_light / d2.sqrt();
            let half = (l - dir).normalize();
            let facing = normal.dot(&l).max(0.0);
            let n_l = if shading.relief { facing } else { 1.0 };
            let spec = if facing > 0.0 { specular * normal.dot(&half).max(0.0).powf(shininess) } else { 0.0 };
            let r2 = ((u - rig.cx).powi(2) + (v - rig.cy).powi(2)) / half_diag2;
            let vignette = 1.0 - shading.vignetting * r2;
            ((shading.ambient + exposure * n_l / d2) * vignette, exposure * spec / d2 * vignette)
        } else {
            (1.0, 0.0)
        };
        // z-depth (of the rectified camera) = t · (camera-z of the unit ray).
        Some(([0, 1, 2].map(|c| 255.0 * (albedo[c] * diffuse + spec)), t * dir_cam.z / dir_cam.norm(), tool.is_some()))
    };
    // Radiance per pixel and channel, before the optics' blur and the sensor's noise; NaN where no ray met a
    // wall (black, and without noise unless the optics blur light into it).
    let mut left_radiance = vec![f64::NAN; 3 * (w * h) as usize];
    let mut right_radiance = vec![f64::NAN; 3 * (w * h) as usize];
    // One ray through each pixel centre; rows are split between two threads (two cores on these machines).
    let render_rows =
        |pose: &Isometry3<f64>, rows: &mut [f64], depth_rows: &mut [f32], mask_rows: &mut [u8], y0: u32, view: u64| {
            for (row_i, row) in rows.chunks_mut(3 * w as usize).enumerate() {
                let y = y0 + row_i as u32;
                for x in 0..w {
                    if let Some((radiance, z, tool)) = shade(pose, view, f64::from(x) + 0.5, f64::from(y) + 0.5) {
                        let at = row_i * w as usize + x as usize;
                        depth_rows[at] = z as f32;
                        mask_rows[at] = if tool { 255 } else { 0 };
                        row[3 * x as usize..3 * x as usize + 3].copy_from_slice(&radiance);
                    }
                }
            }
        };
    let split = (h / 2) as usize * 3 * w as usize;
    let dsplit = (h / 2) as usize * w as usize;
    let world_from_right = &world_from_right;
    std::thread::scope(|s| {
        let (l_top, l_bottom) = left_radiance.split_at_mut(split);
        let (d_top, d_bottom) = depth.split_at_mut(dsplit);
        let (r_top, r_bottom) = right_radiance.split_at_mut(split);
        let (rd_top, rd_bottom) = right_depth.split_at_mut(dsplit);
        let (m_top, m_bottom) = instrument_mask.split_at_mut(dsplit);
        let (rm_top, rm_bottom) = right_mask.split_at_mut(dsplit);
        let render = &render_rows;
        s.spawn(move || {
            render(world_from_left, l_top, d_top, m_top, 0, 1);
            render(world_from_right, r_top, rd_top, rm_top, 0, 2);
        });
        render(world_from_left, l_bottom, d_bottom, m_bottom, h / 2, 1);
        render(world_from_right, r_bottom, rd_bottom, rm_bottom, h / 2, 2);
    });
    // A little anti-aliasing where it matters: pixels on a depth edge (a fold's rim, a blob's flank against the
    // background) get the mean of four sub-pixel rays. The texture is band-limited, so elsewhere one ray is
    // enough; the ground-truth depth stays that of the pixel centre.
    for (radiance_image, zbuf, pose, view) in
        [(&mut left_radiance, &depth, world_from_left, 1u64), (&mut right_radiance, &right_depth, world_from_right, 2)]
    {
        let at = |x: u32, y: u32| f64::from(zbuf[(y * w + x) as usize]);
        for y in 0..h {
            for x in 0..w {
                let z = at(x, y);
                let edge =
                    [(x.wrapping_sub(1), y), (x + 1, y), (x, y.wrapping_sub(1)), (x, y + 1)].iter().any(|&(nx, ny)| {
                        nx < w && ny < h && {
                            let n = at(nx, ny);
                            (n.is_finite() != z.is_finite()) || (n.is_finite() && (n - z).abs() > 0.03 * z.min(n))
                        }
                    });
                if !edge {
                    continue;
                }
                let mut sum = [0.0; 3];
                for (dx, dy) in [(0.25, 0.25), (0.75, 0.25), (0.25, 0.75), (0.75, 0.75)] {
                    if let Some((radiance, _, _)) = shade(pose, view, f64::from(x) + dx, f64::from(y) + dy) {
                        for c in 0..3 {
                            sum[c] += radiance[c] / 4.0;
                        }
                    }
                }
                let at = 3 * (y * w + x) as usize;
                radiance_image[at..at + 3].copy_from_slice(&sum);
            }
        }
    }
    // The optics, then the sensor: blur in the camera's pixel grid, noise per pixel, rounding to grey levels.
    for (radiance_image, img, view, pose, zbuf) in [
        (&mut left_radiance, &mut left, 1u64, world_from_left, &depth),
        (&mut right_radiance, &mut right, 2, world_from_right, &right_depth),
    ] {
        if shading.optics_blur_px > 0.0 {
            radiance_image.iter_mut().filter(|r| r.is_nan()).for_each(|r| *r = 0.0);
            gaussian_blur_rgb(radiance_image, w as usize, h as usize, shading.optics_blur_px);
        }
        if let Some(haze) = &shading.haze {
            // Through the camera's pixel grid as it is (raw or rectified): the view's ray through each pixel.
            let ray = |x: f64, y: f64| match &shading.lens {
                None => Some(Vector3::new((x - rig.cx) / rig.fx, (y - rig.cy) / rig.fy, 1.0)),
                Some(lens) => lens.ray(view, x, y),
            };
            let seen = crate::smoke::View { rig, ray: &ray, right: view == 2, world_from_camera: pose, z_depth: zbuf };
            haze.veil(radiance_image, &seen, shading.exposure_distance_mm);
        }
        for (i, (px, radiance)) in img.chunks_exact_mut(3).zip(radiance_image.chunks_exact(3)).enumerate() {
            if radiance[0].is_nan() {
                px.copy_from_slice(&[0, 0, 0]);
                continue;
            }
            for c in 0..3 {
                let noise =
                    (hash_noise(surface.seed() ^ view, frame, i as u64 * 3 + c as u64) - 0.5) * 2.0 * shading.noise;
                px[c] = (radiance[c] + noise).round().clamp(0.0, 255.0) as u8;
            }
        }
    }
    RenderedPair { left, right, depth, instrument_mask }
}

/// Blurs an interleaved RGB image in place by a Gaussian of `sigma_px` (separable, kernel out to 3σ, edges
/// repeated).
fn gaussian_blur_rgb(image: &mut [f64], w: usize, h: usize, sigma_px: f64) {
    let radius = (3.0 * sigma_px).ceil() as isize;
    let weights: Vec<f64> = (-radius..=radius).map(|d| (-0.5 * (d as f64 / sigma_px).powi(2)).exp()).collect();
    let total: f64 = weights.iter().sum();
    let weights: Vec<f64> = weights.iter().map(|x| x / total).collect();
    let mut scratch = vec![0.0f64; image.len()];
    // Rows into the scratch image, then columns back.
    let pass = |from: &[f64], to: &mut [f64], along_rows: bool| {
        let (n, m) = if along_rows { (w, h) } else { (h, w) };
        for line in 0..m {
            for i in 0..n {
                let mut sum = [0.0f64; 3];
                for (k, &wk) in weights.iter().enumerate() {
                    let j = (i as isize + k as isize - radius).clamp(0, n as isize - 1) as usize;
                    let at = if along_rows { 3 * (line * w + j) } else { 3 * (j * w + line) };
                    for c in 0..3 {
                        sum[c] += wk * from[at + c];
                    }
                }
                let at = if along_rows { 3 * (line * w + i) } else { 3 * (i * w + line) };
                to[at..at + 3].copy_from_slice(&sum);
            }
        }
    };
    pass(image, &mut scratch, true);
    pass(&scratch, image, false);
}

/// What a written sequence holds, for the caller's summary.
#[derive(Debug, Clone)]
pub struct WrittenSequence {
    pub settings: std::path::PathBuf,
    pub frames: usize,
    pub mean_depth_mm: f64,
    /// The frames whose left view sees past the modelled scene over more than [`VOID_SHARE_NOTED`] of the
    /// image (`None`: none does).
    pub past_the_scene: Option<PastTheScene>,
}

/// Share of the view above which a frame that sees nothing (no tissue within the renderer's range: black,
/// without texture) is reported: a path that leaves its scene, or a view across it into the distance. The
/// colon's lumen, far down the tube, is about 2 % of a forward view.
pub const VOID_SHARE_NOTED: f64 = 0.05;

/// Frames that see past the modelled scene: how many, the first and last (0-based), and the largest share of a
/// view that saw nothing.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PastTheScene {
    pub frames: usize,
    pub first: usize,
    pub last: usize,
    pub worst_share: f64,
}

impl PastTheScene {
    /// Adds frame `i`, whose view saw nothing over `share` of it.
    fn note(seen: &mut Option<Self>, i: usize, share: f64) {
        match seen {
            None => *seen = Some(Self { frames: 1, first: i, last: i, worst_share: share }),
            Some(s) => {
                s.frames += 1;
                s.last = i;
                s.worst_share = s.worst_share.max(share);
            }
        }
    }
}

/// What happens in front of and on the tissue during a sequence, besides the tissue itself.
#[derive(Debug, Clone, Copy, Default)]
pub struct Events<'a> {
    pub instruments: Option<&'a crate::instruments::Instruments>,
    pub smoke: Option<&'a crate::smoke::Smoke>,
    pub bleeding: Option<&'a crate::bleeding::Bleeding>,
}

/// Writes a camera path over a surface as a plain sequence (`left/`, `right/`, `times.txt`, `settings.yaml`) with
/// its ground truth in `gt/`: `poses.tum` (world_from_camera of the left camera), `depth/<n>.pfm` (z, mm, +inf
/// where no wall), `disparity/<n>.pfm` (px), `mesh.ply` (the wall along the flight). `progress(i)` after each
/// frame. `surface_at(t)` is the tissue at time t: the same surface every frame, or a breathing one
/// ([`crate::breathing`]), whose depth is each frame's while `mesh` is the mean surface. With `smoke`, its haze
/// is in the images (not in the ground truth), and so is `bleeding`'s blood (a film on the tissue). With
/// `instruments`, they are rendered in front of the tissue (not in the mesh) and each frame's mask of them is
/// written to `gt/masks/<n>.png` (left view, 255 = instrument), the layout `--masks` reads.
#[allow(clippy::too_many_arguments)] // each is one thing the sequence is made of
pub fn write_sequence(
    dir: &std::path::Path,
    rig: &RectifiedCamera,
    surface_at: &dyn Fn(f64) -> Box<dyn Surface>,
    events: Events,
    path: &dyn Fn(f64) -> Isometry3<f64>,
    mesh: (Vec<[f32; 3]>, Vec<[u32; 3]>),
    shading: &Shading,
    frames: usize,
    fps: f64,
    mut progress: impl FnMut(usize),
) -> Result<WrittenSequence, crate::SynthError> {
    use bdis_core::formats::{pfm, ply, trajectory};
    let fail = |path: &std::path::Path, e: &dyn std::fmt::Display| crate::SynthError::Write {
        path: path.to_path_buf(),
        detail: e.to_string(),
    };
    for sub in ["left", "right", "gt/depth", "gt/disparity"] {
        std::fs::create_dir_all(dir.join(sub)).map_err(|e| fail(&dir.join(sub), &e))?;
    }
    let Events { instruments, smoke, bleeding } = events;
    if instruments.is_some() {
        std::fs::create_dir_all(dir.join("gt/masks")).map_err(|e| fail(&dir.join("gt/masks"), &e))?;
    }
    let bf = rig.bf;
    let mut poses = Vec::with_capacity(frames);
    let mut times = String::new();
    let (mut depth_sum, mut depth_n) = (0.0, 0usize);
    let mut past_the_scene = None;
    for i in 0..frames {
        let t = i as f64 / fps;
        let pose = path(t);
        let parts = instruments.map(|tools| tools.parts_at(t, &pose)).unwrap_or_default();
        let shading = Shading {
            haze: smoke.and_then(|smoke| smoke.haze_at(t)),
            bleeding: bleeding.and_then(|bleeding| bleeding.pool_at(t)),
            ..*shading
        };
        let pair = render_scene(surface_at(t).as_ref(), &parts, rig, &shading, &pose, i as u64);
        for (side, img) in [("left", &pair.left), ("right", &pair.right)] {
            let path = dir.join(format!("{side}/{}.png", i + 1));
            img.save(&path).map_err(|e| fail(&path, &e))?;
        }
        let (w, h) = (rig.width as usize, rig.height as usize);
        if instruments.is_some() {
            let mask_path = dir.join(format!("gt/masks/{}.png", i + 1));
            image::GrayImage::from_raw(rig.width, rig.height, pair.instrument_mask)
                .ok_or_else(|| fail(&mask_path, &"mask size"))?
                .save(&mask_path)
                .map_err(|e| fail(&mask_path, &e))?;
        }
        let depth_path = dir.join(format!("gt/depth/{}.pfm", i + 1));
        pfm::write(&depth_path, w, h, 1, &pair.depth).map_err(|e| fail(&depth_path, &e))?;
        // A raw pair has no disparity: its rows do not line up until it is rectified.
        if shading.lens.is_none() {
            let disparity: Vec<f32> =
                pair.depth.iter().map(|&z| if z.is_finite() { (bf / f64::from(z)) as f32 } else { f32::NAN }).collect();
            let disp_path = dir.join(format!("gt/disparity/{}.pfm", i + 1));
            pfm::write_disparity(&disp_path, w, h, &disparity).map_err(|e| fail(&disp_path, &e))?;
        }
        let mut seen = 0usize;
        for &z in pair.depth.iter().filter(|z| z.is_finite()) {
            depth_sum += f64::from(z);
            depth_n += 1;
            seen += 1;
        }
        let void_share = 1.0 - seen as f64 / pair.depth.len().max(1) as f64;
        if void_share > VOID_SHARE_NOTED {
            PastTheScene::note(&mut past_the_scene, i, void_share);
        }
        poses.push(bdis_core::geometry::StampedPose { t_s: t, world_from_camera: pose });
        times += &format!("{t:.6}\n");
        progress(i);
    }
    let path = dir.join("times.txt");
    std::fs::write(&path, times).map_err(|e| fail(&path, &e))?;
    let path = dir.join("gt/poses.tum");
    trajectory::write_tum(&path, &poses).map_err(|e| fail(&path, &e))?;
    let (vertices, triangles) = mesh;
    let path = dir.join("gt/mesh.ply");
    ply::write(&path, &ply::PointCloud { positions: vertices, faces: triangles, ..Default::default() })
        .map_err(|e| fail(&path, &e))?;
    let orb = "# ORB settings for tracking (ORB-SLAM2's defaults; 1000 features at 640×480).\n\
ORBextractor.nFeatures: 1000\nORBextractor.scaleFactor: 1.2\nORBextractor.nLevels: 8\nORBextractor.iniThFAST: 20\nORBextractor.minThFAST: 7\n";
    let (settings, text) = match &shading.lens {
        None => (
            dir.join("settings.yaml"),
            format!(
                "%YAML:1.0\n# Synthetic sequence written by bdis-slam synth. Units: millimetres.\n\
# Pixel centres are at integer coordinates: the rays went through (x + 0.5, y + 0.5) with the rig's principal\n\
# point, so the principal point here is half a pixel less.\n\
Camera.fx: {}\nCamera.fy: {}\nCamera.cx: {}\nCamera.cy: {}\nCamera.width: {}\nCamera.height: {}\nCamera.fps: {}\nCamera.bf: {}\nCamera.RGB: 1\nThDepth: 20\n{orb}",
                rig.fx,
                rig.fy,
                rig.cx - 0.5,
                rig.cy - 0.5,
                rig.width,
                rig.height,
                fps,
                bf
            ),
        ),
        Some(lens) => (dir.join("calib.yaml"), raw_calibration_text(lens, rig, fps, orb)),
    };
    std::fs::write(&settings, text).map_err(|e| fail(&settings, &e))?;
    Ok(WrittenSequence {
        settings,
        frames,
        mean_depth_mm: if depth_n > 0 { depth_sum / depth_n as f64 } else { f64::NAN },
        past_the_scene,
    })
}

/// The OpenCV `stereoCalibrate` layout of a raw rig (what `bdis-slam rectify --settings` reads), with the
/// sequence's frame rate and ORB settings for the rectified settings it writes.
fn raw_calibration_text(lens: &RawLens, rig: &RectifiedCamera, fps: f64, orb: &str) -> String {
    let matrix = |key: &str, rows: usize, cols: usize, data: &[f64]| {
        let values: Vec<String> = data.iter().map(|v| format!("{v:e}")).collect();
        format!(
            "{key}: !!opencv-matrix\n   rows: {rows}\n   cols: {cols}\n   dt: d\n   data: [ {} ]\n",
            values.join(", ")
        )
    };
    let row_major =
        |m: &nalgebra::Matrix3<f64>| -> Vec<f64> { (0..3).flat_map(|r| (0..3).map(move |c| m[(r, c)])).collect() };
    let (rotation, translation) = lens.calibration(rig.baseline());
    format!(
        "%YAML:1.0\n# Raw synthetic stereo rig written by bdis-slam synth --raw: distorted, turned cameras. Units: millimetres.\n\
# Rectify with `bdis-slam rectify --settings calib.yaml --sequence . --out <dir>`.\n{}{}{}{}{}{}width: {}\nheight: {}\nCamera.fps: {fps}\nThDepth: 20\n{orb}",
        matrix("M1", 3, 3, &row_major(&lens.left.k)),
        matrix("D1", 1, 8, &lens.left.distortion),
        matrix("M2", 3, 3, &row_major(&lens.right.k)),
        matrix("D2", 1, 8, &lens.right.distortion),
        matrix("R", 3, 3, &row_major(&rotation)),
        matrix("T", 3, 1, translation.as_slice()),
        rig.width,
        rig.height,
    )
}
