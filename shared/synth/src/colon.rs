//! A colon-like tube rendered by ray marching, with exact ground truth: depth and disparity per pixel, poses,
//! and a mesh of the wall.
//!
//! The wall is the surface `ρ = r(z, θ)` around a curved centreline `c(z)`: ρ and θ are polar coordinates of a
//! point's (x, y) about `c(z)`. Haustral folds narrow the tube every `fold_spacing_mm`, and low-frequency bumps
//! roughen it. Tissue texture is evaluated in surface coordinates (arc length around, length along), so it
//! sticks to the wall and the same wall point looks the same from any view but for the lighting.

use nalgebra::{Isometry3, Point3, Rotation3, Translation3, UnitQuaternion, Vector3};

use crate::{StereoRig, TissueTexture, value_noise};

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
        }
    }
}

/// Where a ray met the wall.
#[derive(Debug, Clone, Copy)]
pub struct Hit {
    pub t: f64,
    pub point: Point3<f64>,
    /// Unit normal pointing into the tube (towards the viewer).
    pub normal: Vector3<f64>,
    /// Surface coordinates in mm: around, along.
    pub uv: (f64, f64),
}

impl Colon {
    /// The centreline at height z.
    pub fn centre(&self, z: f64) -> (f64, f64) {
        (6.0 * (z / 40.0).sin(), 4.0 * (z / 55.0 + 1.0).sin())
    }

    /// Wall radius at height z and angle θ.
    pub fn radius(&self, z: f64, theta: f64) -> f64 {
        let phase = (z / self.fold_spacing_mm).rem_euclid(1.0) - 0.5;
        // A fold is a smooth inward ring a few mm wide; its depth varies a little around the circumference.
        let fold = (-(phase * self.fold_spacing_mm).powi(2) / (2.0 * 3.0f64.powi(2))).exp();
        // Noise over (cos θ, sin θ) is periodic around the tube: no seam in the wall.
        let (c, s) = (theta.cos(), theta.sin());
        let fold_depth = self.fold_depth * (0.8 + 0.4 * value_noise(self.seed ^ 11, 2.0 * c + z / 20.0, 2.0 * s));
        let k = self.radius_mm / 6.0;
        let bumps = self.bump_mm * (value_noise(self.seed ^ 7, k * c + z / 6.0, k * s - z / 9.0) - 0.5) * 2.0;
        self.radius_mm * (1.0 - fold_depth * fold) + bumps
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

/// How images are lit and degraded.
#[derive(Debug, Clone, Copy)]
pub struct Shading {
    /// Off: images show the texture's albedo only (for tests of the geometry).
    pub lighting: bool,
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
}

impl Default for Shading {
    fn default() -> Self {
        Self {
            lighting: true,
            exposure_distance_mm: 40.0,
            ambient: 0.06,
            specular: 0.35,
            shininess: 40.0,
            vignetting: 0.3,
            noise: 2.0,
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
pub fn render_colon(
    colon: &Colon,
    rig: &StereoRig,
    shading: &Shading,
    world_from_left: &Isometry3<f64>,
    frame: u64,
) -> RenderedPair {
    let (w, h) = (rig.width, rig.height);
    let mut left = image::RgbImage::new(w, h);
    let mut right = image::RgbImage::new(w, h);
    let mut depth = vec![f32::INFINITY; (w * h) as usize];
    let world_from_right = world_from_left * Translation3::new(rig.baseline_mm, 0.0, 0.0);
    let light = world_from_left * Point3::new(0.5 * rig.baseline_mm, 0.0, 0.0);
    let half_diag2 = (rig.cx * rig.cx + rig.cy * rig.cy).max(1.0);
    let max_t = 150.0;
    let exposure = 0.8 * shading.exposure_distance_mm.powi(2);
    // Rows are split between two threads: the machine this runs on has two cores.
    let render_rows = |pose: &Isometry3<f64>,
                       img_rows: &mut [u8],
                       depth_rows: Option<&mut [f32]>,
                       y0: u32,
                       view: u64| {
        let mut depth_rows = depth_rows;
        let origin = pose * Point3::origin();
        for (row_i, row) in img_rows.chunks_mut(3 * w as usize).enumerate() {
            let y = y0 + row_i as u32;
            for x in 0..w {
                let dir_cam =
                    Vector3::new((f64::from(x) + 0.5 - rig.cx) / rig.fx, (f64::from(y) + 0.5 - rig.cy) / rig.fy, 1.0);
                let dir = (pose.rotation * dir_cam).normalize();
                let px = &mut row[3 * x as usize..3 * x as usize + 3];
                let Some(hit) = colon.hit(&origin, &dir, max_t) else {
                    px.copy_from_slice(&[0, 0, 0]);
                    continue;
                };
                if let Some(d) = depth_rows.as_deref_mut() {
                    // z-depth = t · (ray direction's camera-z component); dir_cam has z = 1 before normalising.
                    d[row_i * w as usize + x as usize] = (hit.t / dir_cam.norm()) as f32;
                }
                let albedo = colon.texture.rgb(hit.uv.0, hit.uv.1).map(|c| f64::from(c) / 255.0);
                let (diffuse, spec) = if shading.lighting {
                    let to_light = light - hit.point;
                    let d2 = to_light.norm_squared();
                    let l = to_light / d2.sqrt();
                    let v = -dir;
                    let half = (l + v).normalize();
                    let n_l = hit.normal.dot(&l).max(0.0);
                    let spec = if n_l > 0.0 {
                        shading.specular * hit.normal.dot(&half).max(0.0).powf(shading.shininess)
                    } else {
                        0.0
                    };
                    let r2 =
                        ((f64::from(x) + 0.5 - rig.cx).powi(2) + (f64::from(y) + 0.5 - rig.cy).powi(2)) / half_diag2;
                    let vignette = 1.0 - shading.vignetting * r2;
                    ((shading.ambient + exposure * n_l / d2) * vignette, exposure * spec / d2 * vignette)
                } else {
                    (1.0, 0.0)
                };
                for c in 0..3 {
                    let noise = if shading.lighting {
                        (hash_noise(colon.seed ^ view, frame, u64::from(y * w + x) * 3 + c as u64) - 0.5)
                            * 2.0
                            * shading.noise
                    } else {
                        0.0
                    };
                    let v = 255.0 * (albedo[c] * diffuse + spec) + noise;
                    px[c] = v.round().clamp(0.0, 255.0) as u8;
                }
            }
        }
    };
    let split = (h / 2) as usize * 3 * w as usize;
    let dsplit = (h / 2) as usize * w as usize;
    let world_from_right = &world_from_right;
    std::thread::scope(|s| {
        let (l_top, l_bottom) = left.split_at_mut(split);
        let (d_top, d_bottom) = depth.split_at_mut(dsplit);
        let (r_top, r_bottom) = right.split_at_mut(split);
        let render = &render_rows;
        s.spawn(move || {
            render(world_from_left, l_top, Some(d_top), 0, 1);
            render(world_from_right, r_top, None, 0, 2);
        });
        render(world_from_left, l_bottom, Some(d_bottom), h / 2, 1);
        render(world_from_right, r_bottom, None, h / 2, 2);
    });
    RenderedPair { left, right, depth }
}

/// What a written sequence holds, for the caller's summary.
#[derive(Debug, Clone)]
pub struct WrittenSequence {
    pub settings: std::path::PathBuf,
    pub frames: usize,
    pub mean_depth_mm: f64,
}

/// Writes a flight through the colon as a plain sequence (`left/`, `right/`, `times.txt`, `settings.yaml`) with
/// its ground truth in `gt/`: `poses.tum` (world_from_camera of the left camera), `depth/<n>.pfm` (z, mm, +inf
/// where no wall), `disparity/<n>.pfm` (px), `mesh.ply` (the wall along the flight). `progress(i)` after each
/// frame.
#[allow(clippy::too_many_arguments)]
pub fn write_colon_sequence(
    dir: &std::path::Path,
    rig: &StereoRig,
    colon: &Colon,
    shading: &Shading,
    frames: usize,
    fps: f64,
    speed_mm_s: f64,
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
    let bf = rig.fx * rig.baseline_mm;
    let mut poses = Vec::with_capacity(frames);
    let mut times = String::new();
    let (mut depth_sum, mut depth_n) = (0.0, 0usize);
    for i in 0..frames {
        let t = i as f64 / fps;
        let pose = colon.forward_pose(t, speed_mm_s);
        let pair = render_colon(colon, rig, shading, &pose, i as u64);
        for (side, img) in [("left", &pair.left), ("right", &pair.right)] {
            let path = dir.join(format!("{side}/{}.png", i + 1));
            img.save(&path).map_err(|e| fail(&path, &e))?;
        }
        let (w, h) = (rig.width as usize, rig.height as usize);
        let depth_path = dir.join(format!("gt/depth/{}.pfm", i + 1));
        pfm::write(&depth_path, w, h, 1, &pair.depth).map_err(|e| fail(&depth_path, &e))?;
        let disparity: Vec<f32> =
            pair.depth.iter().map(|&z| if z.is_finite() { (bf / f64::from(z)) as f32 } else { f32::NAN }).collect();
        let disp_path = dir.join(format!("gt/disparity/{}.pfm", i + 1));
        pfm::write_disparity(&disp_path, w, h, &disparity).map_err(|e| fail(&disp_path, &e))?;
        for &z in pair.depth.iter().filter(|z| z.is_finite()) {
            depth_sum += f64::from(z);
            depth_n += 1;
        }
        poses.push(bdis_core::geometry::StampedPose { t_s: t, world_from_camera: pose });
        times += &format!("{t:.6}\n");
        progress(i);
    }
    let path = dir.join("times.txt");
    std::fs::write(&path, times).map_err(|e| fail(&path, &e))?;
    let path = dir.join("gt/poses.tum");
    trajectory::write_tum(&path, &poses).map_err(|e| fail(&path, &e))?;
    // The wall from a little behind the first pose to well beyond the last one's view.
    let z_last = speed_mm_s * (frames.max(1) - 1) as f64 / fps;
    let (vertices, triangles) = colon.mesh(-20.0, z_last + 150.0, 0.5, 180);
    let path = dir.join("gt/mesh.ply");
    ply::write(&path, &ply::PointCloud { positions: vertices, faces: triangles, ..Default::default() })
        .map_err(|e| fail(&path, &e))?;
    let settings = dir.join("settings.yaml");
    let text = format!(
        "%YAML:1.0\n# Synthetic colon flight written by bdis-slam synth. Units: millimetres.\n\
Camera.fx: {}\nCamera.fy: {}\nCamera.cx: {}\nCamera.cy: {}\nCamera.width: {}\nCamera.height: {}\nCamera.fps: {}\nCamera.bf: {}\nCamera.RGB: 1\nThDepth: 20\n",
        rig.fx, rig.fy, rig.cx, rig.cy, rig.width, rig.height, fps, bf
    );
    std::fs::write(&settings, text).map_err(|e| fail(&settings, &e))?;
    Ok(WrittenSequence {
        settings,
        frames,
        mean_depth_mm: if depth_n > 0 { depth_sum / depth_n as f64 } else { f64::NAN },
    })
}
