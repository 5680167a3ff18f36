//! A headless preview of the map: an orthographic view that frames the whole map, looking along the direction in
//! which the map is thinnest (for a scanned surface, its normal), from the side the cameras were on, with a depth
//! buffer so the nearest surface wins. Points are splatted as squares about their spacing on the surface, so
//! the view reads as a surface rather than a scatter of dots.

use image::{Rgb, RgbImage};
use nalgebra::{Matrix3, SymmetricEigen, Vector3};

use crate::Mosaic;

/// How the preview was framed (for the log line under it).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PreviewView {
    /// World direction the virtual camera looks along.
    pub looking_along: [f64; 3],
    /// Millimetres per preview pixel.
    pub mm_per_pixel: f64,
    pub points_drawn: usize,
}

const BACKGROUND: Rgb<u8> = Rgb([24, 24, 28]);

fn percentile(values: &mut [f64], q: f64) -> f64 {
    bdis_core::stats::percentile(values, q).unwrap_or(0.0)
}

/// Renders the map `width` pixels wide (the height follows the map's shape). `None` for an empty map.
pub fn render_preview(mosaic: &Mosaic, width: u32) -> Option<(RgbImage, PreviewView)> {
    let n = mosaic.n_points();
    if n == 0 || width == 0 {
        return None;
    }
    let mut world = Vec::with_capacity(n);
    let mut colour = Vec::with_capacity(n);
    mosaic.for_each_world_point(|xyz, pt, _| {
        world.push(Vector3::from(xyz.map(f64::from)));
        colour.push(pt.rgb);
    });
    let centroid = world.iter().sum::<Vector3<f64>>() / n as f64;
    let covariance = world.iter().fold(Matrix3::zeros(), |acc, p| {
        let d = p - centroid;
        acc + d * d.transpose()
    }) / n as f64;
    let eigen = SymmetricEigen::new(covariance);
    let mut order = [0usize, 1, 2];
    order.sort_by(|&a, &b| eigen.eigenvalues[b].total_cmp(&eigen.eigenvalues[a]));
    let axis_x: Vector3<f64> = eigen.eigenvectors.column(order[0]).into();
    let mut view_dir: Vector3<f64> = eigen.eigenvectors.column(order[2]).into();
    // Look from the cameras' side: the mean camera centre is where the surface was seen from.
    let cameras: Vector3<f64> = mosaic
        .keyframes()
        .filter(|k| !k.points.is_empty())
        .map(|k| k.world_from_camera.translation.vector)
        .fold(Vector3::zeros(), |a, c| a + c);
    let mean_camera_axis: Vector3<f64> = mosaic
        .keyframes()
        .filter(|k| !k.points.is_empty())
        .map(|k| k.world_from_camera.rotation * Vector3::z())
        .fold(Vector3::zeros(), |a, c| a + c);
    let seen_from = mosaic.keyframes().filter(|k| !k.points.is_empty()).count().max(1);
    let towards_cameras = cameras / seen_from as f64 - centroid;
    let score = if towards_cameras.norm() > 1e-9 { -towards_cameras.dot(&view_dir) } else { 0.0 }
        + 1e-3 * mean_camera_axis.dot(&view_dir);
    if score < 0.0 {
        view_dir = -view_dir;
    }
    // A right-handed image frame: x along the longest extent, y down the image.
    let axis_y = view_dir.cross(&axis_x).normalize();

    let mut xs: Vec<f64> = world.iter().map(|p| (p - centroid).dot(&axis_x)).collect();
    let mut ys: Vec<f64> = world.iter().map(|p| (p - centroid).dot(&axis_y)).collect();
    // The 0.5th–99.5th percentiles frame the map: a few stray points do not shrink the picture.
    let (x0, x1) = (percentile(&mut xs, 0.005), percentile(&mut xs, 0.995));
    let (y0, y1) = (percentile(&mut ys, 0.005), percentile(&mut ys, 0.995));
    let margin = 0.04 * (x1 - x0).max(y1 - y0).max(1e-6);
    let (x0, x1, y0, y1) = (x0 - margin, x1 + margin, y0 - margin, y1 + margin);
    let height = ((f64::from(width) * (y1 - y0) / (x1 - x0)).round() as u32).clamp(width / 4, width).max(1);
    let mm_per_pixel = ((x1 - x0) / f64::from(width)).max((y1 - y0) / f64::from(height));

    // Splat size: the lifted grid's spacing on the surface (gap · z / f), in preview pixels.
    let mut spacing: Vec<f64> = mosaic
        .keyframes()
        .flat_map(|k| {
            let gap = mosaic.params.depth_gap_px.max(1) as f64;
            k.points.iter().step_by(16).map(move |p| gap * f64::from(p.xyz[2]) / k.intrinsics.fx)
        })
        .collect();
    let spacing_mm = percentile(&mut spacing, 0.5);
    let half = ((spacing_mm / mm_per_pixel) * 0.5).round().clamp(0.0, 6.0) as i64;

    let (w, h) = (width as usize, height as usize);
    let mut image = RgbImage::from_pixel(width, height, BACKGROUND);
    let mut depth = vec![f64::INFINITY; w * h];
    let cx = 0.5 * (x0 + x1);
    let cy = 0.5 * (y0 + y1);
    let mut drawn = 0;
    for (p, rgb) in world.iter().zip(&colour) {
        let d = p - centroid;
        let u = ((d.dot(&axis_x) - cx) / mm_per_pixel + f64::from(width) * 0.5).floor() as i64;
        let v = ((d.dot(&axis_y) - cy) / mm_per_pixel + f64::from(height) * 0.5).floor() as i64;
        let z = d.dot(&view_dir);
        let mut hit = false;
        for vv in (v - half).max(0)..=(v + half).min(h as i64 - 1) {
            for uu in (u - half).max(0)..=(u + half).min(w as i64 - 1) {
                let i = vv as usize * w + uu as usize;
                if z < depth[i] {
                    depth[i] = z;
                    image.put_pixel(uu as u32, vv as u32, Rgb(*rgb));
                    hit = true;
                }
            }
        }
        drawn += usize::from(hit);
    }
    Some((image, PreviewView { looking_along: view_dir.into(), mm_per_pixel, points_drawn: drawn }))
}
