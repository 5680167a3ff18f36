#![allow(clippy::unwrap_used, clippy::expect_used)] // test code: a panic is the failure report
//! A raw render (`--raw mild|strong`: distorted, turned cameras) rectified by `bdis-rectify` is the image the
//! rectified camera itself would have taken: rendered directly through Bouguet's rectified cameras (same
//! centres, their rotations and projections, no distortion), the two agree to within the bilinear remap's
//! blur, and in every tile of the image they are shifted against each other by less than 0.03 px. So the
//! rig, its written calibration, the rectification and the maps all agree — to a fraction of the sub-pixel
//! alignment the tracker relies on.

use bdis_rectify::{CameraModel, RectifyMap, StereoCalibration, stereo_rectify};
use bdis_synth::RectifiedCamera;
use bdis_synth::render::{RawLens, Shading, render};

fn grey(rgb: &[u8]) -> Vec<f64> {
    rgb.chunks_exact(3).map(|p| 0.299 * f64::from(p[0]) + 0.587 * f64::from(p[1]) + 0.114 * f64::from(p[2])).collect()
}

/// (median |difference| in grey levels, mean tile shift in px, RMS tile shift in px) of the rectified raw
/// render against the direct render of the rectified camera, per side.
fn compare(preset: &str) -> [(f64, f64, f64); 2] {
    let rig = RectifiedCamera { width: 320, height: 240, fx: 260.0, fy: 260.0, cx: 160.0, cy: 120.0, bf: 1300.0 };
    let (w, h) = (320usize, 240usize);
    let colon = bdis_synth::colon::Colon::default();
    let lens = RawLens::preset(preset, &rig).unwrap();
    let (rotation, translation) = lens.calibration(rig.baseline());
    let calib = StereoCalibration {
        source: preset.into(),
        left: lens.left,
        right: lens.right,
        rotation,
        translation,
        size: Some((320, 240)),
        given: None,
    };
    let rect = stereo_rectify(&calib, (320, 240), None);
    let ideal = RawLens {
        left: CameraModel { k: rect.p_left.fixed_view::<3, 3>(0, 0).into_owned(), distortion: [0.0; 8] },
        right: CameraModel { k: rect.p_right.fixed_view::<3, 3>(0, 0).into_owned(), distortion: [0.0; 8] },
        // Bouguet's rectified frame → raw frame → the renderer's frame.
        left_rectified_from_raw: lens.left_rectified_from_raw * rect.r_left.transpose(),
        right_rectified_from_raw: lens.right_rectified_from_raw * rect.r_right.transpose(),
    };
    // No noise and no vignetting (it is drawn in each image's own pixels): only geometry differs.
    let base = Shading { noise: 0.0, vignetting: 0.0, ..Shading::default() };
    let pose = colon.forward_pose(0.4, 20.0);
    let raw = render(&colon, &rig, &Shading { lens: Some(lens), ..base }, &pose, 0);
    let direct = render(&colon, &rig, &Shading { lens: Some(ideal), ..base }, &pose, 0);
    let maps = [
        RectifyMap::new(&calib.left, &rect.r_left, &rect.p_left, (w, h), (w, h)),
        RectifyMap::new(&calib.right, &rect.r_right, &rect.p_right, (w, h), (w, h)),
    ];
    let mut result = [(0.0, 0.0, 0.0); 2];
    for (side, ((raw_img, direct_img), map)) in
        [(&raw.left, &direct.left), (&raw.right, &direct.right)].into_iter().zip(&maps).enumerate()
    {
        let mut ours = vec![0u8; w * h * 3];
        map.remap(raw_img.as_raw(), 3, &mut ours);
        let (a, b) = (grey(&ours), grey(direct_img.as_raw()));
        // Inside: every rectified pixel of a 2-pixel neighbourhood sampled the raw image, and rendered wall.
        let inside = |x: usize, y: usize| {
            (y - 2..=y + 2).all(|yy| (x - 2..=x + 2).all(|xx| a[yy * w + xx] > 0.0 && b[yy * w + xx] > 0.0))
        };
        let mut diffs = Vec::new();
        let mut shifts = Vec::new();
        const TILES: usize = 4;
        for ty in 0..TILES {
            for tx in 0..TILES {
                // Least squares: ours − direct ≈ ∇direct · shift over the tile.
                let (mut jtj, mut jtr) = (nalgebra::Matrix2::<f64>::zeros(), nalgebra::Vector2::<f64>::zeros());
                for y in (3 + ty * (h - 6) / TILES)..(3 + (ty + 1) * (h - 6) / TILES) {
                    for x in (3 + tx * (w - 6) / TILES)..(3 + (tx + 1) * (w - 6) / TILES) {
                        if !inside(x, y) {
                            continue;
                        }
                        let i = y * w + x;
                        let g = nalgebra::Vector2::new(0.5 * (b[i + 1] - b[i - 1]), 0.5 * (b[i + w] - b[i - w]));
                        jtj += g * g.transpose();
                        jtr += g * (b[i] - a[i]);
                        diffs.push((a[i] - b[i]).abs());
                    }
                }
                if jtj.determinant() > 1e3 {
                    let shift = jtj.try_inverse().unwrap() * jtr;
                    shifts.push(shift);
                }
            }
        }
        assert!(diffs.len() > w * h / 3, "{preset} side {side}: too few pixels compared ({})", diffs.len());
        diffs.sort_by(f64::total_cmp);
        assert!(shifts.len() >= 12, "{preset} side {side}: only {} tiles with texture", shifts.len());
        let n = shifts.len() as f64;
        let mean = shifts.iter().sum::<nalgebra::Vector2<f64>>() / n;
        let rms = (shifts.iter().map(|s| s.norm_squared()).sum::<f64>() / n).sqrt();
        result[side] = (diffs[diffs.len() / 2], mean.norm(), rms);
    }
    result
}

#[test]
fn a_rectified_raw_render_is_the_rectified_camera_s_own_image() {
    for preset in ["mild", "strong"] {
        for (side, (median_diff, mean, rms)) in compare(preset).into_iter().enumerate() {
            eprintln!(
                "{preset}, side {side}: median |Δ| {median_diff:.2} grey levels, tile shifts: mean {mean:.4} px, RMS {rms:.4} px"
            );
            assert!(median_diff < 1.0, "{preset} side {side}: median difference {median_diff}");
            assert!(mean < 0.01, "{preset} side {side}: shifted by {mean} px on average");
            assert!(rms < 0.03, "{preset} side {side}: tile shifts of {rms} px RMS");
        }
    }
}
