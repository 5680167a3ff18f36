#![allow(clippy::unwrap_used, clippy::expect_used)] // test code: a panic is the failure report
//! The ground truth agrees with the images: stereo and temporal warps with GT disparity / depth / poses leave
//! a small photometric error, the mesh re-projects onto the GT depth, and rendering is deterministic.

use bdis_synth::RectifiedCamera;
use bdis_synth::abdomen::Abdomen;
use bdis_synth::breathing::Swell;
use bdis_synth::colon::Colon;
use bdis_synth::render::{Shading, Surface, render};
use nalgebra::{Isometry3, Point3};

type CameraPath = Box<dyn Fn(f64) -> Isometry3<f64>>;

/// Both scenes, each with a camera path.
fn scenes() -> Vec<(&'static str, Box<dyn Surface>, CameraPath)> {
    let colon = Colon::default();
    let abdomen = Abdomen::default();
    let (c2, a2) = (colon, abdomen.clone());
    vec![
        ("colon", Box::new(colon), Box::new(move |t| c2.forward_pose(t, 20.0))),
        ("abdomen", Box::new(abdomen), Box::new(move |t| a2.sweep_pose(t, 15.0))),
    ]
}

/// A small rig so each frame renders in a few tens of milliseconds.
fn rig() -> RectifiedCamera {
    RectifiedCamera { width: 200, height: 150, fx: 162.5, fy: 162.5, cx: 100.0, cy: 75.0, bf: 162.5 * 5.0 }
}

fn albedo_only() -> Shading {
    Shading { lighting: false, noise: 0.0, ..Shading::default() }
}

/// The bits of a depth image, for comparing two exactly (NaN included).
fn depth_bits(depth: &[f32]) -> Vec<u32> {
    depth.iter().map(|z| z.to_bits()).collect()
}

/// Texture contrast: the sum of the green channel's absolute horizontal second difference.
fn texture_contrast(img: &image::RgbImage) -> f64 {
    let g: Vec<f64> = img.pixels().map(|p| f64::from(p.0[1])).collect();
    let w = img.width() as usize;
    g.chunks(w).flat_map(|row| row.windows(3).map(|t| (t[0] - 2.0 * t[1] + t[2]).abs())).sum::<f64>()
}

fn bilinear(img: &image::RgbImage, x: f64, y: f64) -> Option<[f64; 3]> {
    let (x0, y0) = (x.floor(), y.floor());
    if x0 < 0.0 || y0 < 0.0 || x0 + 1.0 >= f64::from(img.width()) || y0 + 1.0 >= f64::from(img.height()) {
        return None;
    }
    let (fx, fy) = (x - x0, y - y0);
    let p = |dx: u32, dy: u32| img.get_pixel(x0 as u32 + dx, y0 as u32 + dy).0.map(f64::from);
    let (a, b, c, d) = (p(0, 0), p(1, 0), p(0, 1), p(1, 1));
    Some([0, 1, 2].map(|k| (a[k] * (1.0 - fx) + b[k] * fx) * (1.0 - fy) + (c[k] * (1.0 - fx) + d[k] * fx) * fy))
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// Mean absolute colour difference per pixel between `a` at (x, y) and `b` at the mapped position.
fn warp_errors(a: &image::RgbImage, b: &image::RgbImage, map: impl Fn(u32, u32) -> Option<(f64, f64)>) -> Vec<f64> {
    let mut errors = Vec::new();
    for y in 0..a.height() {
        for x in 0..a.width() {
            let Some((u, v)) = map(x, y) else { continue };
            let Some(s) = bilinear(b, u, v) else { continue };
            let t = a.get_pixel(x, y).0.map(f64::from);
            errors.push((0..3).map(|k| (s[k] - t[k]).abs()).sum::<f64>() / 3.0);
        }
    }
    errors
}

#[test]
fn warping_the_right_image_with_gt_disparity_reproduces_the_left() {
    let rig = rig();
    let bf = rig.bf;
    for (name, surface, path) in scenes() {
        let pose = path(0.7);
        // Thresholds: with albedo only, what remains is bilinear resampling of the texture (≪ 1 grey level); the
        // outliers (> 12) are pixels the right camera cannot see (behind folds) and silhouette edges. With
        // lighting, the views also differ by design: sensor noise (±2 per image), specular highlights that depend
        // on the view, and vignetting that depends on where a point falls in each image (a point 40 px apart in
        // the two images gets a few % different exposure): a median of a few grey levels, and more pixels above 12.
        for (shading, median_max, outlier_max) in [(albedo_only(), 1.0, 0.06), (Shading::default(), 5.0, 0.25)] {
            let pair = render(surface.as_ref(), &rig, &shading, &pose, 0);
            let w = rig.width;
            let errors = warp_errors(&pair.left, &pair.right, |x, y| {
                let z = f64::from(pair.depth[(y * w + x) as usize]);
                z.is_finite().then(|| (f64::from(x) - bf / z, f64::from(y)))
            });
            let m = median(errors.clone());
            let outliers = errors.iter().filter(|&&e| e > 12.0).count() as f64 / errors.len() as f64;
            eprintln!("{name}, lighting {}: median {m:.2}, > 12: {outliers:.3}", shading.lighting);
            assert!(errors.len() > 20_000, "{name}: {} pixels compared", errors.len());
            assert!(m < median_max, "{name}, lighting {}: median {m}", shading.lighting);
            assert!(outliers < outlier_max, "{name}, lighting {}: {outliers} of pixels off by > 12", shading.lighting);
        }
    }
}

#[test]
fn warping_frame_t_into_t_plus_1_with_gt_depth_and_poses_matches() {
    let rig = rig();
    for (name, surface, path) in scenes() {
        let (p0, p1) = (path(0.5), path(0.5 + 1.0 / 30.0));
        let f0 = render(surface.as_ref(), &rig, &albedo_only(), &p0, 0);
        let f1 = render(surface.as_ref(), &rig, &albedo_only(), &p1, 1);
        let w = rig.width;
        let cam1_from_cam0 = p1.inverse() * p0;
        let errors = warp_errors(&f0.left, &f1.left, |x, y| {
            let z = f64::from(f0.depth[(y * w + x) as usize]);
            if !z.is_finite() {
                return None;
            }
            let pc0 =
                Point3::new((f64::from(x) + 0.5 - rig.cx) * z / rig.fx, (f64::from(y) + 0.5 - rig.cy) * z / rig.fy, z);
            let pc1 = cam1_from_cam0 * pc0;
            (pc1.z > 0.0).then(|| (rig.fx * pc1.x / pc1.z + rig.cx - 0.5, rig.fy * pc1.y / pc1.z + rig.cy - 0.5))
        });
        assert!(errors.len() > 20_000, "{name}");
        // Same threshold reasoning as the stereo warp (albedo only: resampling error; outliers: disocclusions).
        assert!(median(errors.clone()) < 1.0, "{name}");
        assert!(errors.iter().filter(|&&e| e > 12.0).count() as f64 / (errors.len() as f64) < 0.06, "{name}");
    }
}

#[test]
fn the_mesh_reprojects_onto_the_gt_depth() {
    let rig = rig();
    let colon = Colon::default();
    let abdomen = Abdomen::default();
    type Case<'a> = (&'a str, &'a dyn Surface, Isometry3<f64>, Vec<[f32; 3]>);
    let cases: [Case; 2] = [
        ("colon", &colon, colon.forward_pose(1.0, 20.0), colon.mesh(0.0, 150.0, 0.5, 180).0),
        ("abdomen", &abdomen, abdomen.sweep_pose(1.0, 15.0), abdomen.mesh(90.0, 0.5).0),
    ];
    for (name, surface, pose, vertices) in cases {
        let pair = render(surface, &rig, &albedo_only(), &pose, 0);
        let cam_from_world = pose.inverse();
        let (mut agree, mut in_front) = (0usize, 0usize);
        for v in &vertices {
            let p = cam_from_world * Point3::new(f64::from(v[0]), f64::from(v[1]), f64::from(v[2]));
            if p.z <= 1.0 {
                continue;
            }
            let (u, w) = (rig.fx * p.x / p.z + rig.cx, rig.fy * p.y / p.z + rig.cy);
            if u < 0.0 || w < 0.0 || u >= f64::from(rig.width) || w >= f64::from(rig.height) {
                continue;
            }
            let (px, py) = (u as i64, w as i64);
            let z = f64::from(pair.depth[(py as u32 * rig.width + px as u32) as usize]);
            if !z.is_finite() {
                continue;
            }
            // The nearest wall around the vertex's pixel: at a fold's silhouette the pixel centre may see the wall
            // behind while the vertex sits on the fold's rim.
            let mut z_near = z;
            for dy in -1..=1 {
                for dx in -1..=1 {
                    let (qx, qy) = (px + dx, py + dy);
                    if qx >= 0 && qy >= 0 && qx < i64::from(rig.width) && qy < i64::from(rig.height) {
                        z_near = z_near.min(f64::from(pair.depth[(qy as u32 * rig.width + qx as u32) as usize]));
                    }
                }
            }
            // Vertices behind the visible wall are hidden, not wrong; a vertex in front of it would be.
            let tolerance = 0.02 * p.z + 0.2; // the depth varies across one pixel at grazing views
            if (p.z - z).abs() <= tolerance {
                agree += 1;
            } else if p.z < z_near - tolerance {
                in_front += 1;
            }
        }
        assert!(agree > 2_000, "{name}: {agree} visible vertices agree");
        assert!(
            (in_front as f64) < 0.01 * agree as f64,
            "{name}: {in_front} vertices in front of the rendered wall ({agree} agree)"
        );
    }
}

#[test]
fn same_seed_same_bytes() {
    let rig = rig();
    for (name, surface, path) in scenes() {
        let pose = path(0.3);
        let a = render(surface.as_ref(), &rig, &Shading::default(), &pose, 3);
        let b = render(surface.as_ref(), &rig, &Shading::default(), &pose, 3);
        assert_eq!(a.left.as_raw(), b.left.as_raw(), "{name}");
        assert_eq!(a.right.as_raw(), b.right.as_raw(), "{name}");
        assert_eq!(depth_bits(&a.depth), depth_bits(&b.depth), "{name}");
    }
    let pose = Colon::default().forward_pose(0.3, 20.0);
    let a = render(&Colon::default(), &rig, &Shading::default(), &pose, 3);
    let other = Colon { seed: 7, texture: bdis_synth::TissueTexture { seed: 7 }, ..Colon::default() };
    assert_ne!(render(&other, &rig, &Shading::default(), &pose, 3).left.as_raw(), a.left.as_raw());
}

#[test]
fn the_same_request_writes_identical_files() {
    let base = std::env::temp_dir().join(format!("bdis-synth-det-{}", std::process::id()));
    let rig = rig();
    let request = bdis_synth::SceneRequest { scene: "abdomen".into(), frames: 2, ..Default::default() };
    let (a, b) = (base.join("a"), base.join("b"));
    bdis_synth::write_scene(&a, &rig, &request, |_| {}).unwrap();
    bdis_synth::write_scene(&b, &rig, &request, |_| {}).unwrap();
    let mut files = Vec::new();
    let mut stack = vec![a.clone()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() { stack.push(p) } else { files.push(p) }
        }
    }
    assert!(files.len() >= 10, "{files:?}");
    for f in files {
        let twin = b.join(f.strip_prefix(&a).unwrap());
        assert_eq!(std::fs::read(&f).unwrap(), std::fs::read(&twin).unwrap(), "{} differs", f.display());
    }
    std::fs::remove_dir_all(&base).unwrap();
}

#[test]
fn the_optics_blur_softens_the_image_keeps_its_light_and_leaves_depth_alone() {
    let rig = rig();
    let pose = Colon::default().forward_pose(0.3, 20.0);
    let sharp = render(&Colon::default(), &rig, &albedo_only(), &pose, 3);
    let blurred = render(&Colon::default(), &rig, &Shading { optics_blur_px: 0.7, ..albedo_only() }, &pose, 3);
    // Energy of the horizontal second difference: the image's finest detail.
    let detail = |img: &image::RgbImage| {
        let g: Vec<f64> = img.pixels().map(|p| f64::from(p.0[1])).collect();
        let w = img.width() as usize;
        g.chunks(w).flat_map(|row| row.windows(3).map(|t| (t[0] - 2.0 * t[1] + t[2]).powi(2))).sum::<f64>()
    };
    let mean = |img: &image::RgbImage| {
        img.pixels().map(|p| f64::from(p.0[1])).sum::<f64>() / f64::from(img.width() * img.height())
    };
    assert!(detail(&blurred.left) < 0.5 * detail(&sharp.left), "{} vs {}", detail(&blurred.left), detail(&sharp.left));
    // A blur moves light around, it does not make or lose it (up to the image border and rounding).
    assert!((mean(&blurred.left) - mean(&sharp.left)).abs() < 0.02 * mean(&sharp.left));
    assert_eq!(depth_bits(&blurred.depth), depth_bits(&sharp.depth));
    // σ out of range is refused before anything is rendered.
    let request = bdis_synth::SceneRequest { optics_blur_px: -1.0, ..Default::default() };
    assert!(request.validate().unwrap_err().to_string().contains("optics blur"));
}

#[test]
fn instruments_are_in_the_images_depth_and_mask_but_not_the_tissue() {
    use bdis_synth::instruments::{InstrumentKind, Instruments};
    let rig = rig();
    let abdomen = Abdomen::default();
    let shading = Shading { exposure_distance_mm: 65.0, ..Shading::default() };
    let tools = Instruments::new(InstrumentKind::Laparoscopic, bdis_synth::abdomen::STANDOFF_MM, 65.0);
    let pose = abdomen.hover_pose(0.4);
    let plain = render(&abdomen, &rig, &shading, &pose, 3);
    let with = bdis_synth::render::render_scene(&abdomen, &tools.parts_at(0.4, &pose), &rig, &shading, &pose, 3);
    let masked: Vec<usize> = (0..with.instrument_mask.len()).filter(|&i| with.instrument_mask[i] == 255).collect();
    let share = masked.len() as f64 / with.instrument_mask.len() as f64;
    // Two graspers cover about a fifth of a laparoscopic view, as in the footage the issue was checked on.
    assert!((0.08..0.35).contains(&share), "instruments cover {share}");
    assert!(plain.instrument_mask.iter().all(|&m| m == 0));
    let (mut nearer, mut chroma) = (0usize, 0.0);
    for &i in &masked {
        // The depth is the instrument's, well in front of the tissue; elsewhere nothing changed.
        nearer += usize::from(with.depth[i] < 0.8 * plain.depth[i]);
        let p = with.left.as_raw()[3 * i..3 * i + 3].iter().map(|&c| f64::from(c)).collect::<Vec<_>>();
        chroma += p.iter().cloned().fold(0.0, f64::max) - p.iter().cloned().fold(255.0, f64::min);
    }
    assert!(nearer as f64 > 0.98 * masked.len() as f64, "{nearer} of {} nearer", masked.len());
    let unmasked = (0..with.depth.len()).filter(|&i| with.instrument_mask[i] == 0);
    let changed = unmasked.filter(|&i| with.depth[i].to_bits() != plain.depth[i].to_bits()).count();
    assert_eq!(changed, 0, "depth away from the instruments is the tissue's");
    // Metal is grey (up to the sensor noise of 2 levels per channel); the tissue is red.
    assert!(chroma / (masked.len() as f64) < 8.0, "mean chroma on the instruments {}", chroma / masked.len() as f64);

    // Written: a mask per frame, and the tissue's mesh without them.
    let base = std::env::temp_dir().join(format!("bdis-synth-tools-{}", std::process::id()));
    let request = bdis_synth::SceneRequest {
        scene: "abdomen".into(),
        trajectory: Some("hover".into()),
        frames: 2,
        instruments: true,
        ..Default::default()
    };
    let small = RectifiedCamera { width: 64, height: 48, fx: 52.0, fy: 52.0, cx: 32.0, cy: 24.0, bf: 52.0 * 5.0 };
    bdis_synth::write_scene(&base, &small, &request, |_| {}).unwrap();
    let mask = image::open(base.join("gt/masks/2.png")).unwrap().into_luma8();
    assert_eq!(mask.dimensions(), (64, 48));
    assert!(mask.pixels().any(|p| p.0[0] == 255) && mask.pixels().any(|p| p.0[0] == 0));
    let mesh = bdis_core::formats::ply::read(&base.join("gt/mesh.ply")).unwrap();
    let deepest_tool = |p: &[f32; 3]| p[2] < (abdomen.distance_mm - bdis_synth::abdomen::STANDOFF_MM + 37.0) as f32;
    assert!(!mesh.positions.iter().any(deepest_tool), "the mesh is the wall only");
    std::fs::remove_dir_all(&base).unwrap();
}

#[test]
fn smoke_lowers_the_contrast_and_leaves_the_ground_truth_alone() {
    let rig = rig();
    let abdomen = Abdomen::default();
    let pose = abdomen.hover_pose(0.4);
    let smoke = bdis_synth::smoke::Smoke::puff(0.0, bdis_synth::abdomen::STANDOFF_MM, 5);
    let clear = Shading { exposure_distance_mm: 65.0, ..Shading::default() };
    let hazy = Shading { haze: smoke.haze_at(0.5), ..clear };
    let (a, b) = (render(&abdomen, &rig, &clear, &pose, 3), render(&abdomen, &rig, &hazy, &pose, 3));
    assert_eq!(depth_bits(&a.depth), depth_bits(&b.depth), "the ground truth is the tissue's");
    // Texture contrast: the green channel's second difference, lower through the haze (the sensor's noise,
    // which the haze does not lower, keeps it from falling by the haze's full share: ~0.7 at its peak).
    assert!(
        texture_contrast(&b.left) < 0.8 * texture_contrast(&a.left),
        "{} vs {}",
        texture_contrast(&b.left),
        texture_contrast(&a.left)
    );
    assert!(smoke.haze_at(2.0).is_none(), "cleared");
}

#[test]
fn smoke_in_the_cavity_stays_where_it_was_made_and_a_scope_that_flies_on_leaves_it_behind() {
    let rig = rig();
    let colon = Colon::default();
    // Made in front of the scope where it is at 0 s, seen at its peak (0.5 s) from 6 mm further on (inside the
    // cloud: it is 0.75 radii across either side of a centre 0.6 radii ahead) and from 30 mm further on.
    let made_at = colon.forward_pose(0.0, 20.0);
    let (here, on) = (colon.forward_pose(0.3, 20.0), colon.forward_pose(1.5, 20.0));
    let cloud = bdis_synth::smoke::Smoke::cavity_puff(0.0, colon.radius_mm, &made_at, 5);
    let sheet = bdis_synth::smoke::Smoke::puff(0.0, colon.radius_mm, 5);
    // Without the sensor's noise, which the haze does not lower, the contrast is the texture's.
    let clear = Shading { noise: 0.0, ..Shading::default() };
    let (in_cloud, in_sheet) =
        (Shading { haze: cloud.haze_at(0.5), ..clear }, Shading { haze: sheet.haze_at(0.5), ..clear });
    for pose in [here, on] {
        let a = render(&colon, &rig, &clear, &pose, 3);
        let b = render(&colon, &rig, &in_cloud, &pose, 3);
        assert_eq!(depth_bits(&a.depth), depth_bits(&b.depth), "the ground truth is the tissue's");
        let sheeted = render(&colon, &rig, &in_sheet, &pose, 3);
        assert!(
            texture_contrast(&sheeted.left) < 0.8 * texture_contrast(&a.left),
            "the sheet rides with the scope everywhere"
        );
        if pose == here {
            assert!(
                texture_contrast(&b.left) < 0.6 * texture_contrast(&a.left),
                "veiled in the cloud: {} vs {}",
                texture_contrast(&b.left),
                texture_contrast(&a.left)
            );
            // Smoke scatters the scope's light back: the view turns paler, towards grey.
            let mean = |img: &image::RgbImage, c: usize| img.pixels().map(|p| f64::from(p.0[c])).sum::<f64>();
            assert!(mean(&b.left, 1) > mean(&a.left, 1), "the haze is lit");
        } else {
            assert_eq!(a.left, b.left, "the cloud is behind the scope that flew on");
        }
    }
}

#[test]
fn breathing_moves_the_tissue_both_ways_by_its_amplitude_and_leaves_the_mean_surface_in_the_mesh() {
    let rig = rig();
    let abdomen = Abdomen::default();
    let colon = Colon::default();
    let amplitude_mm = 2.0;
    // How far a point lies from the mean (still) surface, along the surface's depth: towards the scope over the
    // abdomen, towards the axis in the colon.
    let (a2, c2) = (abdomen.clone(), colon);
    let above_abdomen = move |p: Point3<f64>| a2.height(p.x, p.y) - p.z;
    let inside_colon = move |p: Point3<f64>| {
        let (cx, cy) = c2.centre(p.z);
        c2.radius(p.z, (p.y - cy).atan2(p.x - cx)) - ((p.x - cx).powi(2) + (p.y - cy).powi(2)).sqrt()
    };
    type Offset = Box<dyn Fn(Point3<f64>) -> f64>;
    type Case = (&'static str, Box<dyn Surface>, Isometry3<f64>, Offset);
    let cases: [Case; 2] = [
        (
            "abdomen",
            Box::new(Abdomen { swell: Swell { mm: amplitude_mm, ..Swell::default() }, ..abdomen.clone() }),
            abdomen.hover_pose(0.0),
            Box::new(above_abdomen),
        ),
        (
            "colon",
            Box::new(Colon { swell: Swell { mm: amplitude_mm, ..Swell::default() }, ..colon }),
            colon.forward_pose(1.0, 20.0),
            Box::new(inside_colon),
        ),
    ];
    for (name, breathing, pose, offset) in cases {
        let pair = render(breathing.as_ref(), &rig, &albedo_only(), &pose, 0);
        let mut moved = Vec::new();
        for (i, &z) in pair.depth.iter().enumerate() {
            let (x, y) = ((i as u32 % rig.width) as f64 + 0.5, (i as u32 / rig.width) as f64 + 0.5);
            if z.is_finite() {
                let z = f64::from(z);
                moved.push(offset(pose * Point3::new((x - rig.cx) * z / rig.fx, (y - rig.cy) * z / rig.fy, z)));
            }
        }
        assert!(moved.len() > 10_000, "{name}: {} pixels see tissue", moved.len());
        let rms = (moved.iter().map(|d| d * d).sum::<f64>() / moved.len() as f64).sqrt();
        let mean = moved.iter().sum::<f64>() / moved.len() as f64;
        let largest = moved.iter().fold(0.0f64, |m, d| m.max(d.abs()));
        let (nearer, farther) =
            (moved.iter().filter(|&&d| d > 0.5).count(), moved.iter().filter(|&&d| d < -0.5).count());
        // Moved by up to its amplitude, both ways, without a rigid part to mistake for the scope's motion.
        assert!(largest <= amplitude_mm * 1.001 && largest > 0.8 * amplitude_mm, "{name}: largest {largest:.2} mm");
        assert!(rms > 0.25 * amplitude_mm, "{name}: rms {rms:.2} mm");
        assert!(nearer > moved.len() / 10 && farther > moved.len() / 10, "{name}: {nearer} nearer, {farther} farther");
        // Over the wall, the mean depth offset is the rigid part (the wall as a whole nearer or farther). In the
        // tube the mean radial offset is a narrowing, not a motion; its rigid part, a sideways shift, is absent by
        // construction (breathing's own unit test).
        if name == "abdomen" {
            assert!(mean.abs() < 0.25 * rms, "{name}: mean {mean:.2} mm against rms {rms:.2} mm");
        }
    }

    // Through the sequence writer: the mesh is the mean surface (the still scene's), the first frame is at rest,
    // and a breath a quarter period in has moved it.
    let small = RectifiedCamera { width: 64, height: 48, fx: 52.0, fy: 52.0, cx: 32.0, cy: 24.0, bf: 52.0 * 5.0 };
    let base = std::env::temp_dir().join(format!("bdis-synth-breath-{}", std::process::id()));
    let still = bdis_synth::SceneRequest {
        scene: "abdomen".into(),
        trajectory: Some("hover".into()),
        frames: 2,
        fps: 1.0,
        ..Default::default()
    };
    let breathing = bdis_synth::SceneRequest { breathing_mm: amplitude_mm, ..still.clone() };
    bdis_synth::write_scene(&base.join("still"), &small, &still, |_| {}).unwrap();
    bdis_synth::write_scene(&base.join("breathing"), &small, &breathing, |_| {}).unwrap();
    let read = |seq: &str, file: &str| std::fs::read(base.join(seq).join(file)).unwrap();
    assert_eq!(read("still", "gt/mesh.ply"), read("breathing", "gt/mesh.ply"), "the mesh is the mean surface");
    assert_eq!(read("still", "gt/depth/1.pfm"), read("breathing", "gt/depth/1.pfm"), "at rest at t = 0");
    assert_ne!(read("still", "gt/depth/2.pfm"), read("breathing", "gt/depth/2.pfm"), "a quarter breath in");
    std::fs::remove_dir_all(&base).unwrap();
    let too_much = bdis_synth::SceneRequest { breathing_mm: 11.0, ..still };
    assert!(too_much.validate().is_err());
}

#[test]
fn bleeding_reddens_and_wets_the_tissue_under_the_pool_and_leaves_the_ground_truth_alone() {
    let rig = rig();
    let abdomen = Abdomen::default();
    let pose = abdomen.hover_pose(0.0);
    // The pool at the tissue the view's centre sees.
    let bleed = bdis_synth::bleeding::Bleeding::new(0.0, (pose.translation.x, pose.translation.y), 55.0, 5);
    let dry = Shading { exposure_distance_mm: 65.0, ..Shading::default() };
    let wet = Shading { bleeding: bleed.pool_at(5.0), ..dry };
    let (a, b) = (render(&abdomen, &rig, &dry, &pose, 3), render(&abdomen, &rig, &wet, &pose, 3));
    assert_eq!(depth_bits(&a.depth), depth_bits(&b.depth), "a film on the tissue: the depth is the tissue's");
    let centre = |img: &image::RgbImage| *img.get_pixel(rig.width / 2, rig.height / 2);
    let (dry_px, wet_px) = (centre(&a.left), centre(&b.left));
    // Blood absorbs green: the centre loses most of its green and keeps more of its red.
    assert!(u32::from(wet_px.0[1]) * 3 < u32::from(dry_px.0[1]), "green {} → {}", dry_px.0[1], wet_px.0[1]);
    assert!(wet_px.0[0] > 2 * wet_px.0[1], "red over green under blood: {wet_px:?}");
    // Far from the pool nothing changed.
    assert_eq!(a.left.get_pixel(2, 2), b.left.get_pixel(2, 2));
    // Changed pixels: a pool of about its size (radius 11 mm ≈ 33 px at 55 mm with f = 162.5), not the frame.
    let changed = a.left.pixels().zip(b.left.pixels()).filter(|(p, q)| p != q).count();
    let share = changed as f64 / f64::from(rig.width * rig.height);
    assert!(share > 0.05 && share < 0.35, "{share:.3} of the image changed");
}

#[test]
fn each_lighting_switches_off_its_own_part_of_the_light_and_keeps_the_sensor_noise() {
    use bdis_synth::Lighting;
    let rig = rig();
    let abdomen = Abdomen::default();
    let pose = abdomen.sweep_pose(0.5, 15.0);
    let lit = |lighting: Lighting, frame: u64| {
        let shading = lighting.apply(Shading { exposure_distance_mm: 65.0, ..Shading::default() });
        render(&abdomen, &rig, &shading, &pose, frame).left
    };
    let grey = |img: &image::RgbImage| {
        img.pixels().map(|p| p.0.iter().map(|&c| f64::from(c)).sum::<f64>()).collect::<Vec<_>>()
    };
    let scope = grey(&lit(Lighting::Scope, 3));
    // Highlights only ever add light: without them no pixel is brighter (beyond the noise, ±2 per channel), and
    // where they were some are much darker.
    let matte = grey(&lit(Lighting::NoHighlights, 3));
    assert!(scope.iter().zip(&matte).all(|(s, m)| m - s <= 6.0));
    let dimmed = scope.iter().zip(&matte).filter(|(s, m)| *s - *m > 60.0).count();
    assert!(dimmed > 0, "the scope light has highlights on this wall");
    // Without the relief's shading the picture changes all over, not only in the highlights.
    let flat = grey(&lit(Lighting::FlatDiffuse, 3));
    let changed = scope.iter().zip(&flat).filter(|(s, f)| (*s - *f).abs() > 15.0).count();
    assert!(changed > scope.len() / 10, "{changed} of {} pixels changed", scope.len());
    // Albedo only: the texture as it is, but with the sensor's noise (it differs frame to frame at the same pose,
    // by at most the noise), unlike the noiseless albedo the geometry tests use.
    let (a, b) = (grey(&lit(Lighting::Albedo, 3)), grey(&lit(Lighting::Albedo, 4)));
    let clean = grey(&render(&abdomen, &rig, &albedo_only(), &pose, 3).left);
    assert!(a.iter().zip(&b).filter(|(x, y)| x != y).count() > a.len() / 2, "the noise changes frame to frame");
    assert!(a.iter().zip(&clean).all(|(x, c)| (x - c).abs() <= 3.0 * 2.0 + 1e-9), "noise within ±2 per channel");
}

/// A path that leaves the modelled scene is told where it is made: a sweep far past the abdominal wall's edge
/// sees the black beyond it in its last frames, a hover over the wall sees tissue everywhere.
#[test]
fn a_path_past_the_scene_s_edge_is_reported_and_one_over_the_tissue_is_not() {
    let base = std::env::temp_dir().join(format!("bdis-synth-past-{}", std::process::id()));
    let small = RectifiedCamera { width: 64, height: 48, fx: 52.0, fy: 52.0, cx: 32.0, cy: 24.0, bf: 52.0 * 5.0 };
    let request = |trajectory: &str, speed_mm_s: f64| bdis_synth::SceneRequest {
        scene: "abdomen".into(),
        trajectory: Some(trajectory.into()),
        frames: 4,
        fps: 10.0,
        speed_mm_s,
        ..Default::default()
    };
    // 40 mm/frame: from x = −40 to 80 mm, where the wall falls away out of the renderer's range on one side.
    let far = bdis_synth::write_scene(&base.join("far"), &small, &request("sweep", 400.0), |_| {}).unwrap();
    let past = far.past_the_scene.expect("the sweep's last frames see past the wall");
    assert_eq!(past.last, 3, "{past:?}");
    assert!(past.first > 0, "the first frame is over the wall: {past:?}");
    assert!(past.worst_share > bdis_synth::render::VOID_SHARE_NOTED && past.worst_share < 1.0, "{past:?}");
    let hover = bdis_synth::write_scene(&base.join("hover"), &small, &request("hover", 20.0), |_| {}).unwrap();
    assert_eq!(hover.past_the_scene, None);
    std::fs::remove_dir_all(&base).unwrap();
}
