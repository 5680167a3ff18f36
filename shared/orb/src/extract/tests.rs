use super::*;
use super::{describe::*, fast::*, pyramid::*};

/// A textured test level: smooth gradients, hashed noise, and a black disc corner like an endoscope's edge.
pub(crate) fn test_level(w: usize, h: usize) -> Level {
    let data = (0..w * h)
        .map(|i| {
            let (x, y) = (i % w, i / w);
            if x * x + y * y < 40 * 40 || (x > w - 20 && y > h - 30) {
                return 0;
            }
            let hash = (i as u32).wrapping_mul(2_654_435_761) >> 24;
            ((x * 3 + y * 5) % 160 + (hash as usize) % 90 + 1) as u8
        })
        .collect();
    Level { w, h, data }
}

#[test]
pub(super) fn the_avx2_copies_give_the_portable_results_bit_for_bit() {
    let src = test_level(640, 480);
    let params = OrbParams::default();
    let ex = OrbExtractor::new(params, 640, 480).unwrap();
    // Pyramid step.
    let taps = &ex.taps[1];
    let (dw, dh) = (taps.x.len(), taps.y.len());
    let (mut a, mut b) =
        (Level { w: dw, h: dh, data: vec![0; dw * dh] }, Level { w: dw, h: dh, data: vec![1; dw * dh] });
    let mut row = vec![0u16; 641];
    resize_level(&src, &mut a, taps, &mut row);
    resize_level_portable(&src, &mut b, taps, &mut row);
    assert_eq!(a.data, b.data);
    // Blur.
    let (mut tmp, mut acc) = (vec![0u16; 640 * 480], vec![0u16; 640]);
    let (mut a, mut b) =
        (Level { w: 640, h: 480, data: vec![0; 640 * 480] }, Level { w: 640, h: 480, data: vec![1; 640 * 480] });
    blur_level(&src, &mut a, &mut tmp, &mut acc);
    blur_level_portable(&src, &mut b, &mut tmp, &mut acc);
    assert_eq!(a.data, b.data);
    // FAST scores, over every pixel of a band (partial batches included).
    let ring: [isize; 16] = CIRCLE.map(|(dx, dy)| dy as isize * 640 + dx as isize);
    let at: Vec<u32> = (100 * 640 + 20..100 * 640 + 620).collect();
    for batch in at.chunks(SCORE_LANES) {
        for t in [7u8, 20] {
            let (mut sa, mut sb) = ([0u8; SCORE_LANES], [1u8; SCORE_LANES]);
            fast_scores(&src.data, &ring, batch, t, &mut sa);
            fast_scores_portable(&src.data, &ring, batch, t, &mut sb);
            assert_eq!(sa[..batch.len()], sb[..batch.len()]);
            // And the definition, one pixel and one arc at a time.
            for (&p, &score) in batch.iter().zip(&sa) {
                let c = i16::from(src.data[p as usize]);
                let ring_values = ring.map(|o| src.data[(p as isize + o) as usize]);
                let d = ring_values.map(|v| i16::from(v) - c);
                let mut best = i16::MIN;
                for start in 0..16 {
                    let arc = (0..9).map(|k| d[(start + k) % 16]);
                    best = best.max(arc.clone().min().unwrap()).max(arc.map(|v| -v).min().unwrap());
                }
                let want =
                    if ring_values.contains(&0) || best - 1 < i16::from(t) { 0 } else { (best - 1).min(255) as u8 };
                assert_eq!(score, want, "pixel {p} threshold {t}");
            }
        }
    }
}

#[test]
fn every_pyramid_step_of_the_avx2_gather_equals_the_portable_one() {
    // Sizes whose rows end at every place in the 5-output period and in the 8-output vector step, scattered
    // black (a tap on black gives black, else never 0), and every level's step down to the coarsest.
    for (w, h, n_levels) in [(640, 480, 8), (1280, 720, 8), (1921, 1081, 8), (333, 201, 4), (203, 97, 3)] {
        let mut src = test_level(w, h);
        for (i, v) in src.data.iter_mut().enumerate() {
            if (i as u32).wrapping_mul(2_246_822_519) >> 27 == 0 {
                *v = 0;
            }
        }
        let params = OrbParams { first_level: Some(0), n_levels, ..OrbParams::default() };
        let ex = OrbExtractor::new(params, w, h).unwrap();
        let mut row = vec![0u16; w + 1];
        let mut level = src;
        for taps in &ex.taps[1..] {
            let (dw, dh) = (taps.x.len(), taps.y.len());
            let (mut a, mut b) =
                (Level { w: dw, h: dh, data: vec![0; dw * dh] }, Level { w: dw, h: dh, data: vec![1; dw * dh] });
            resize_level(&level, &mut a, taps, &mut row);
            resize_level_portable(&level, &mut b, taps, &mut row);
            assert_eq!(a.data, b.data, "{w}×{h} → {dw}×{dh}");
            level = a;
        }
    }
}

#[test]
fn the_avx2_candidate_masks_equal_the_portable_ones() {
    // Rows of 634, 324, 64 and 29 pixels (a last step overlapping the one before twice, none, and a row too
    // short for a step); black;
    // both thresholds, and extremes that saturate the centre ± t.
    for (w, h) in [(640, 480), (333, 101), (71, 40), (37, 20)] {
        let src = test_level(w, h);
        for t in [(20u8, 7u8), (1, 0), (255, 254)] {
            let (x_lo, x_hi) = (3 + w % 5, w - 3);
            let mut masks: [Vec<u8>; 4] = std::array::from_fn(|_| vec![7u8; w * h]);
            let [a_ini, a_min, b_ini, b_min] = &mut masks;
            candidate_masks(&src, 3, h - 3, x_lo, x_hi, t, a_ini, a_min);
            candidate_masks_portable(&src, 3, h - 3, x_lo, x_hi, t, b_ini, b_min);
            assert!(a_ini == b_ini && a_min == b_min, "{w}×{h}, thresholds {t:?}");
        }
    }
}

#[cfg(target_arch = "x86_64")]
#[test]
fn dense_scores_equal_the_gathered_ones() {
    if !std::arch::is_x86_feature_detected!("avx2") {
        return;
    }
    // The test level (smooth gradients, noise, black corners) and a harsher one (noise over the full range):
    // every pixel of a band, at thresholds from 0 to beyond most scores.
    let harsh = {
        let mut level = test_level(640, 480);
        for (i, v) in level.data.iter_mut().enumerate() {
            let hash = (i as u32).wrapping_mul(2_246_822_519).rotate_left(13).wrapping_mul(3_266_489_917);
            if *v != 0 {
                *v = (hash >> 24) as u8;
            }
        }
        level
    };
    for src in [test_level(640, 480), harsh] {
        let ring: [isize; 16] = CIRCLE.map(|(dx, dy)| dy as isize * 640 + dx as isize);
        for y in [3usize, 50, 100, 476] {
            for x in (3..640 - 35).step_by(32).chain([640 - 35]) {
                let mut dense = [0u8; 32];
                // SAFETY: the CPU has AVX2 (checked above).
                unsafe { dense_scores_avx2(&src.data, 640, &ring, y * 640 + x, &mut dense) };
                let at: Vec<u32> = (0..32).map(|i| (y * 640 + x + i) as u32).collect();
                for t in [0u8, 1, 7, 20, 60] {
                    for (batch, dense) in at.chunks(SCORE_LANES).zip(dense.chunks(SCORE_LANES)) {
                        let mut gathered = [0u8; SCORE_LANES];
                        fast_scores_portable(&src.data, &ring, batch, t, &mut gathered);
                        // A black centre is never a candidate (the masks), so never gathered: dense gives it 0.
                        for ((&p, &g), &d) in batch.iter().zip(&gathered).zip(dense) {
                            let want = if d >= t.max(1) { d } else { 0 };
                            if src.data[p as usize] != 0 {
                                assert_eq!(g, want, "pixel {p}, threshold {t}");
                            } else {
                                assert_eq!(d, 0, "pixel {p}: a black centre");
                            }
                        }
                    }
                }
            }
        }
    }
}

#[test]
pub(super) fn the_candidate_masks_keep_every_corner() {
    let src = test_level(640, 480);
    let ring: [isize; 16] = CIRCLE.map(|(dx, dy)| dy as isize * 640 + dx as isize);
    let (mut ini, mut min) = (vec![0u8; 640 * 480], vec![0u8; 640 * 480]);
    candidate_masks(&src, 19, 461, 19, 621, (20, 7), &mut ini, &mut min);
    let (mut corners, mut candidates) = (0, 0);
    for y in 19..461 {
        let at: Vec<u32> = (y * 640 + 19..y * 640 + 621).map(|p| p as u32).collect();
        for batch in at.chunks(SCORE_LANES) {
            for (t, mask) in [(20u8, &ini), (7, &min)] {
                let mut scores = [0u8; SCORE_LANES];
                fast_scores(&src.data, &ring, batch, t, &mut scores);
                for (&p, &s) in batch.iter().zip(&scores) {
                    assert!(s == 0 || mask[p as usize] == 1, "corner at {p} (t {t}) not a candidate");
                    corners += usize::from(s > 0);
                    candidates += usize::from(mask[p as usize]);
                }
            }
        }
    }
    // The filter must filter: far fewer candidates than pixels.
    assert!(corners > 1000 && candidates < 2 * 442 * 602 / 2, "{corners} corners, {candidates} candidates");
}

#[test]
pub(super) fn the_table_free_pyramid_gather_equals_the_tap_table() {
    let src = test_level(640, 480);
    let ex = OrbExtractor::new(OrbParams::default(), 640, 480).unwrap();
    let taps = &ex.taps[1];
    assert!(taps.periodic >= 500, "the 6→5 pattern should cover most of the row: {}", taps.periodic);
    let generic = LevelTaps { periodic: 0, ..taps.clone() };
    let (dw, dh) = (taps.x.len(), taps.y.len());
    let (mut a, mut b) =
        (Level { w: dw, h: dh, data: vec![0; dw * dh] }, Level { w: dw, h: dh, data: vec![1; dw * dh] });
    let mut row = vec![0u16; 641];
    resize_level(&src, &mut a, taps, &mut row);
    resize_level(&src, &mut b, &generic, &mut row);
    assert_eq!(a.data, b.data);
    // Bilinear at the nominal scale: output (x, y) is the input at ((x + 0.5)·1.2 − 0.5, …) — checked
    // against floating point away from black.
    for (x, y) in [(100usize, 100usize), (257, 311), (400, 50)] {
        let (sx, sy) = ((x as f64 + 0.5) * 1.2 - 0.5, (y as f64 + 0.5) * 1.2 - 0.5);
        let (x0, y0) = (sx.floor() as usize, sy.floor() as usize);
        let (fx, fy) = (sx - x0 as f64, sy - y0 as f64);
        let p = |x: usize, y: usize| f64::from(src.data[y * 640 + x]);
        let want = (p(x0, y0) * (1.0 - fx) + p(x0 + 1, y0) * fx) * (1.0 - fy)
            + (p(x0, y0 + 1) * (1.0 - fx) + p(x0 + 1, y0 + 1) * fx) * fy;
        assert!((f64::from(a.data[y * dw + x]) - want).abs() < 1.0, "({x}, {y})");
    }
}

#[test]
pub(super) fn a_keep_out_mask_moves_the_features_off_it_and_keeps_the_budget() {
    let (w, h) = (320, 240);
    let image = test_level(w, h).data;
    let params = OrbParams { n_features: 500, ..OrbParams::default() };
    let mut extractor = OrbExtractor::new(params, w, h).unwrap();
    let mut free = Features::default();
    extractor.extract(&image, &mut free).unwrap();
    // The right third of the image is an instrument.
    let mask: Vec<u8> = (0..w * h).map(|i| if i % w >= 2 * w / 3 { 255 } else { 0 }).collect();
    let mut kept = Features::default();
    extractor.extract_masked(&image, Some(&mask), &mut kept).unwrap();
    let on_mask = |f: &Features| f.keypoints.iter().filter(|k| k.x >= (2 * w / 3) as f32 - 3.0).count();
    assert!(on_mask(&free) > 100, "the test image has features there: {}", on_mask(&free));
    // Nothing within the FAST ring of the mask (3 px at level 0; ≥ 3 px further out at coarser levels).
    assert_eq!(on_mask(&kept), 0);
    // The budget goes to the rest of the image rather than being lost.
    let left_free = free.keypoints.len() - on_mask(&free);
    assert!(kept.keypoints.len() > left_free + 50, "{} kept, {left_free} there without the mask", kept.keypoints.len());
    assert_eq!(kept.keypoints.len(), kept.descriptors.len());
    // A short mask is an error, not a panic.
    assert!(extractor.extract_masked(&image, Some(&mask[..10]), &mut kept).is_err());
}

#[test]
fn hd_detects_from_the_level_nearest_vga_and_vga_from_level_0() {
    assert_eq!(auto_first_level(640, 480, 1.2), 0);
    assert_eq!(auto_first_level(320, 240, 1.2), 0);
    assert_eq!(auto_first_level(720, 288, 1.2), 0);
    assert_eq!(auto_first_level(1280, 720, 1.2), 3);
    assert_eq!(auto_first_level(1280, 1024, 1.2), 4);
    assert_eq!(auto_first_level(1920, 1080, 1.2), 5);
    assert_eq!(auto_first_level(3840, 2160, 1.2), 9);
    // Another scale factor: the level nearest the same pixel count (1920×1080 / 4 = 1.69× VGA, / 16 = 0.42×).
    assert_eq!(auto_first_level(1920, 1080, 2.0), 1);
}

#[test]
fn a_first_level_gives_the_same_features_as_those_levels_of_a_full_pyramid() {
    // Detection from level 2 of a 10-level pyramid, against detection from level 0 of the same pyramid:
    // the levels, their corners and descriptors are those of the full pyramid (only the budget moves), every
    // octave is ≥ 2, and the keypoints are in level-0 pixels.
    let (w, h) = (640, 480);
    let image = test_level(w, h).data;
    let full = OrbParams { n_features: 1000, n_levels: 10, first_level: Some(0), ..OrbParams::default() };
    let from2 = OrbParams { n_features: 1000, n_levels: 8, first_level: Some(2), ..OrbParams::default() };
    let (mut a, mut b) = (OrbExtractor::new(full, w, h).unwrap(), OrbExtractor::new(from2, w, h).unwrap());
    assert_eq!(a.scales(), b.scales(), "the same pyramid");
    assert_eq!(b.first_level(), 2);
    let (mut fa, mut fb) = (Features::default(), Features::default());
    a.extract(&image, &mut fa).unwrap();
    b.extract(&image, &mut fb).unwrap();
    for (l, (la, lb)) in a.levels.iter().zip(&b.levels).enumerate() {
        assert_eq!(la.data, lb.data, "level {l}");
    }
    assert!(fb.keypoints.iter().all(|k| k.octave >= 2));
    assert!(fb.keypoints.len() >= 900, "the whole budget on the detection levels: {}", fb.keypoints.len());
    assert!(fb.keypoints.iter().all(|k| k.x >= 0.0 && k.x < w as f32 && k.y >= 0.0 && k.y < h as f32));
    // A keypoint found at an octave by both has the same position and descriptor.
    let mut common = 0;
    for (k, d) in fb.keypoints.iter().zip(&fb.descriptors) {
        if let Some(j) = fa.keypoints.iter().position(|q| q.octave == k.octave && q.x == k.x && q.y == k.y) {
            assert_eq!(&fa.descriptors[j], d);
            assert_eq!(fa.keypoints[j].angle, k.angle);
            common += 1;
        }
    }
    assert!(common >= 100, "{common} keypoints in common");
    // Bad values are named.
    let e = OrbExtractor::new(OrbParams { first_level: Some(17), ..OrbParams::default() }, w, h).unwrap_err();
    assert!(e.to_string().contains("firstLevel"), "{e}");
}
