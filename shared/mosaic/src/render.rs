//! A headless picture of the map a person can read: a perspective view from the scope's side — behind the mean
//! keyframe camera and raised above it, looking at the map — with every point shaded from its surface normal
//! (a light at the eye and one from above), contours darkened where a nearer surface passes in front of a
//! farther one, and the keyframes' path drawn in with a frustum at the newest keyframe. Points are splatted as
//! squares about their spacing on the surface, with a depth buffer, so the view reads as a surface.

use image::{Rgb, RgbImage};
use nalgebra::{Isometry3, Matrix3, Point3, SymmetricEigen, Vector3};

use crate::Mosaic;
use crate::normals::keyframe_normals;

/// How the preview was framed (for the log line under it).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PreviewView {
    /// World direction the virtual camera looks along.
    pub looking_along: [f64; 3],
    /// Map units (millimetres) per preview pixel at the map's centre.
    pub mm_per_pixel: f64,
    pub points_drawn: usize,
}

const BACKGROUND: Rgb<u8> = Rgb([24, 24, 28]);
const PATH: [f32; 3] = [255.0, 205.0, 60.0];
const FRUSTUM: [f32; 3] = [90.0, 200.0, 255.0];
/// How far above the scope's axis the view is raised: enough that a surface seen face-on shows its relief, little
/// enough that it is still the scope's side of the surface.
const ELEVATION_RAD: f64 = 0.6;
/// Horizontal field of view of the virtual camera.
const HALF_FOV_X_RAD: f64 = 0.45;
/// A nearer surface this share of the depth in front of a pixel's neighbour marks a contour there.
const CONTOUR_DEPTH_RATIO: f32 = 0.03;

fn percentile(values: &mut [f64], q: f64) -> f64 {
    bdis_core::stats::percentile(values, q).unwrap_or(0.0)
}

/// The virtual camera: pixel (u, v) = centre + focal · (x, y) / z in its frame.
struct View {
    world_to_view: Isometry3<f64>,
    focal_px: f64,
    centre: (f64, f64),
    width: usize,
    height: usize,
}

impl View {
    /// Pixel position and depth of a world point; None behind the near plane.
    fn project(&self, p: &Point3<f64>) -> Option<(f64, f64, f64)> {
        let q = self.world_to_view * p;
        (q.z > 1e-9)
            .then(|| (self.centre.0 + self.focal_px * q.x / q.z, self.centre.1 + self.focal_px * q.y / q.z, q.z))
    }
}

/// Renders the map `width` pixels wide (the height follows the map's shape). `None` for an empty map.
pub fn render_preview(mosaic: &Mosaic, width: u32) -> Option<(RgbImage, PreviewView)> {
    let n = mosaic.n_points();
    if n == 0 || width == 0 {
        return None;
    }
    let seen_from: Vec<_> = mosaic.keyframes().filter(|k| !k.points.is_empty()).collect();
    let path: Vec<Point3<f64>> =
        mosaic.keyframes().map(|k| Point3::from(k.world_from_camera.translation.vector)).collect();

    // The middle of the map (per-axis medians: a few stray points do not move it) and its longest extent.
    let mut world = Vec::with_capacity(n);
    mosaic.for_each_world_point(|xyz, _, _| world.push(Point3::from(xyz.map(f64::from))));
    let axis = |k: usize| percentile(&mut world.iter().map(|p| p[k]).collect::<Vec<_>>(), 0.5);
    let target = Point3::new(axis(0), axis(1), axis(2));
    let covariance = world.iter().fold(Matrix3::zeros(), |acc, p| {
        let d = p - target;
        acc + d * d.transpose()
    }) / n as f64;
    let eigen = SymmetricEigen::new(covariance);
    let longest = (0..3).max_by(|&a, &b| eigen.eigenvalues[a].total_cmp(&eigen.eigenvalues[b])).unwrap_or(0);
    let length: Vector3<f64> = eigen.eigenvectors.column(longest).into();

    // The scope's mean view: its forward and up (camera y points down the image).
    let forward = seen_from.iter().map(|k| k.world_from_camera.rotation * Vector3::z()).sum::<Vector3<f64>>();
    let down = seen_from.iter().map(|k| k.world_from_camera.rotation * Vector3::y()).sum::<Vector3<f64>>();
    let forward = forward.try_normalize(1e-9).unwrap_or(Vector3::z());
    let up = (-down + forward * down.dot(&forward)).try_normalize(1e-9).unwrap_or_else(|| any_perpendicular(&forward));
    // Look across the map's length, so all of it is in view: from where the scope looked, when it looked across
    // the map (a hover over tissue); from above its path, when it flew along the map (a colon). Then raise the
    // view, so the relief shows.
    let across_length = |v: Vector3<f64>| v - length * v.dot(&length);
    let (base, raise) = match across_length(forward).try_normalize(0.5) {
        Some(f) => (f, across_length(up).try_normalize(1e-9).unwrap_or_else(|| any_perpendicular(&f))),
        None => {
            let from_above = across_length(-up).try_normalize(1e-9).unwrap_or_else(|| any_perpendicular(&length));
            // Tilted to look the way the scope looked, from behind it.
            (from_above, -length * forward.dot(&length).signum())
        }
    };
    let raise = (raise - base * raise.dot(&base)).try_normalize(1e-9).unwrap_or_else(|| any_perpendicular(&base));
    let view_dir = base * ELEVATION_RAD.cos() - raise * ELEVATION_RAD.sin();
    // The map's length across the image, the scope's way along it to the right.
    let mut view_right = (length - view_dir * length.dot(&view_dir)).normalize();
    if view_right.dot(&forward) < 0.0 {
        view_right = -view_right;
    }
    let view_down = view_dir.cross(&view_right);

    // Frame the map and the path: the 1st–99th percentiles of the map's extent across the view (a few stray
    // points do not shrink the picture), widened to the whole path, and the depth that fits them in the field of
    // view.
    let across = |p: &Point3<f64>, a: &Vector3<f64>| (p - target).dot(a);
    let extent = |a: &Vector3<f64>| {
        let mut values: Vec<f64> = world.iter().map(|p| across(p, a)).collect();
        let (lo, hi) = (percentile(&mut values, 0.01), percentile(&mut values, 0.99));
        path.iter().map(|p| across(p, a)).fold((lo, hi), |(lo, hi), v| (lo.min(v), hi.max(v)))
    };
    let ((x0, x1), (y0, y1), (nearest, _)) = (extent(&view_right), extent(&view_down), extent(&view_dir));
    let half_x = (x1 - x0).max(1e-9) * 0.5 * 1.1;
    let half_y = (y1 - y0).max(1e-9) * 0.5 * 1.1;
    let aspect = (half_y / half_x).clamp(0.4, 0.85);
    let height = ((f64::from(width) * aspect).round() as u32).max(1);
    let half_fov_y = (HALF_FOV_X_RAD.tan() * aspect).atan();
    let distance = (half_x / HALF_FOV_X_RAD.tan()).max(half_y / half_fov_y.tan()) - nearest;
    let frame_centre = target + view_right * 0.5 * (x0 + x1) + view_down * 0.5 * (y0 + y1);
    let eye = frame_centre - view_dir * distance;
    let view_from_world = nalgebra::Rotation3::from_basis_unchecked(&[view_right, view_down, view_dir]).transpose();
    let world_to_view = Isometry3::from_parts(
        nalgebra::Translation3::from(view_from_world * -eye.coords),
        nalgebra::UnitQuaternion::from_rotation_matrix(&view_from_world),
    );
    let focal_px = f64::from(width) * 0.5 / HALF_FOV_X_RAD.tan();
    let view = View {
        world_to_view,
        focal_px,
        centre: (f64::from(width) * 0.5, f64::from(height) * 0.5),
        width: width as usize,
        height: height as usize,
    };

    // Splat size: the lifted grid's spacing on the surface where each point was seen (gap · z / f).
    let (w, h) = (view.width, view.height);
    let mut colour = vec![[0f32; 3]; w * h];
    let mut depth = vec![f32::INFINITY; w * h];
    let key_light = (up * 0.7 - view_right * 0.4 - view_dir * 0.6).normalize();
    let (mut grid, mut normals) = (Vec::new(), Vec::new());
    let mut drawn = 0;
    for k in &seen_from {
        let gap = mosaic.params.grid_gap(k.intrinsics.width, k.intrinsics.height);
        keyframe_normals(k, gap, &mut grid, &mut normals);
        for (pt, n_cam) in k.points.iter().zip(&normals) {
            let p = k.world_from_camera * Point3::from(pt.xyz.map(f64::from));
            let Some((u, v, z)) = view.project(&p) else { continue };
            let normal = k.world_from_camera.rotation * Vector3::from(n_cam.map(f64::from));
            let to_eye = (eye - p).normalize();
            // Two-sided: the map may be looked at from behind the surface the scope saw.
            let lit = 0.28 + 0.62 * normal.dot(&to_eye).abs() + 0.3 * normal.dot(&key_light).abs();
            let shade = lit.min(1.15) as f32;
            let rgb = pt.rgb.map(|c| f32::from(c) * shade);
            let spacing = gap as f64 * f64::from(pt.xyz[2]) / k.intrinsics.fx;
            // A square of side 2·half + 1 pixels covers the spacing: no gaps between neighbours.
            let half = (0.5 * (spacing * focal_px / z - 1.0)).ceil().clamp(0.0, 6.0) as i64;
            let (u, v) = (u.floor() as i64, v.floor() as i64);
            let mut hit = false;
            for vv in (v - half).max(0)..=(v + half).min(h as i64 - 1) {
                for uu in (u - half).max(0)..=(u + half).min(w as i64 - 1) {
                    let i = vv as usize * w + uu as usize;
                    if (z as f32) < depth[i] {
                        depth[i] = z as f32;
                        colour[i] = rgb;
                        hit = true;
                    }
                }
            }
            drawn += usize::from(hit);
        }
    }
    darken_contours(&depth, &mut colour, w, h);

    let mut image = RgbImage::from_pixel(width, height, BACKGROUND);
    for (i, c) in colour.iter().enumerate() {
        if depth[i].is_finite() {
            image.put_pixel((i % w) as u32, (i / w) as u32, Rgb(c.map(|x| x.clamp(0.0, 255.0) as u8)));
        }
    }
    draw_path(&mut image, &depth, &view, &path);
    if let Some(newest) = mosaic.keyframes().last() {
        draw_frustum(&mut image, &depth, &view, newest, 0.08 * (half_x + half_y));
    }
    let mm_per_pixel = distance / focal_px;
    Some((image, PreviewView { looking_along: view_dir.into(), mm_per_pixel, points_drawn: drawn }))
}

fn any_perpendicular(v: &Vector3<f64>) -> Vector3<f64> {
    let other = if v.x.abs() < 0.9 { Vector3::x() } else { Vector3::y() };
    v.cross(&other).normalize()
}

/// Where a pixel's neighbour two pixels away is clearly nearer, the pixel is just behind a contour: darkened, so
/// folds and the edges of the map read as edges.
fn darken_contours(depth: &[f32], colour: &mut [[f32; 3]], w: usize, h: usize) {
    const REACH: usize = 2;
    for y in 0..h {
        for x in 0..w {
            let z = depth[y * w + x];
            if !z.is_finite() {
                continue;
            }
            let behind = [(x.wrapping_sub(REACH), y), (x + REACH, y), (x, y.wrapping_sub(REACH)), (x, y + REACH)]
                .iter()
                .filter(|&&(nx, ny)| nx < w && ny < h)
                .any(|&(nx, ny)| depth[ny * w + nx] < z * (1.0 - CONTOUR_DEPTH_RATIO));
            if behind {
                colour[y * w + x] = colour[y * w + x].map(|c| c * 0.55);
            }
        }
    }
}

/// One pixel of an overlay: full colour where it is in front of the map, faint where the map hides it.
fn overlay(image: &mut RgbImage, depth: &[f32], x: i64, y: i64, z: f64, rgb: [f32; 3]) {
    let (w, h) = (image.width() as i64, image.height() as i64);
    if x < 0 || y < 0 || x >= w || y >= h {
        return;
    }
    let alpha = if (z as f32) <= depth[(y * w + x) as usize] { 1.0 } else { 0.35 };
    let px = image.get_pixel_mut(x as u32, y as u32);
    for (channel, over) in px.0.iter_mut().zip(rgb) {
        *channel = (f32::from(*channel) * (1.0 - alpha) + over * alpha) as u8;
    }
}

fn draw_segment(image: &mut RgbImage, depth: &[f32], view: &View, a: &Point3<f64>, b: &Point3<f64>, rgb: [f32; 3]) {
    let (Some((ua, va, za)), Some((ub, vb, zb))) = (view.project(a), view.project(b)) else { return };
    let steps = ((ub - ua).abs().max((vb - va).abs()).ceil() as usize).clamp(1, 4 * (view.width + view.height));
    for s in 0..=steps {
        let t = s as f64 / steps as f64;
        let (u, v, z) = (ua + t * (ub - ua), va + t * (vb - va), za + t * (zb - za));
        // At least two pixels thick, and thicker on a wide preview, so the path still reads when it is shrunk
        // to fit a screen.
        let thick = (view.width / 400).max(2) as i64;
        for dy in 0..thick {
            for dx in 0..thick {
                overlay(image, depth, u.floor() as i64 + dx, v.floor() as i64 + dy, z, rgb);
            }
        }
    }
}

fn draw_path(image: &mut RgbImage, depth: &[f32], view: &View, path: &[Point3<f64>]) {
    for pair in path.windows(2) {
        draw_segment(image, depth, view, &pair[0], &pair[1], PATH);
    }
    for p in path {
        if let Some((u, v, z)) = view.project(p) {
            let reach = (view.width / 400).max(2) as i64;
            for dy in -reach..=reach {
                for dx in -reach..=reach {
                    overlay(image, depth, u.floor() as i64 + dx, v.floor() as i64 + dy, z, PATH);
                }
            }
        }
    }
}

/// The newest keyframe's camera: its centre and the four corners of its image at `size` in front of it.
fn draw_frustum(image: &mut RgbImage, depth: &[f32], view: &View, k: &crate::KeyframeCloud, size: f64) {
    let c = &k.intrinsics;
    let corner = |u: f64, v: f64| {
        let ray = Vector3::new((u - c.cx) / c.fx, (v - c.cy) / c.fy, 1.0);
        k.world_from_camera * Point3::from(ray * size)
    };
    let (w, h) = (f64::from(c.width), f64::from(c.height));
    let corners = [corner(0.0, 0.0), corner(w, 0.0), corner(w, h), corner(0.0, h)];
    let apex = Point3::from(k.world_from_camera.translation.vector);
    for i in 0..4 {
        draw_segment(image, depth, view, &apex, &corners[i], FRUSTUM);
        draw_segment(image, depth, view, &corners[i], &corners[(i + 1) % 4], FRUSTUM);
    }
}
