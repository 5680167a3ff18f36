#![allow(clippy::unwrap_used, clippy::expect_used)] // test code: a panic is the failure report
//! Bad input gives a clear error, never a panic; inputs without texture give an all-invalid map, not garbage.

use bdis_stereo::{Algorithm, GrayImage, MatchError, Matcher, Params};

fn img(w: usize, h: usize, f: impl Fn(usize, usize) -> u8) -> Vec<u8> {
    (0..w * h).map(|i| f(i % w, i / w)).collect()
}

/// A smooth texture every level of the pyramid can match.
fn smooth(x: usize, y: usize) -> u8 {
    let (xf, yf) = (x as f32, y as f32);
    (128.0 + 50.0 * (xf * 0.21).sin() * (yf * 0.17).cos() + 40.0 * ((xf + 2.0 * yf) * 0.07).sin()) as u8
}

fn textured(x: usize, y: usize) -> u8 {
    (((x * 2_654_435_761) ^ (y * 40_503)) >> 5) as u8 | 1
}

#[test]
fn different_sizes_and_short_buffers_are_errors() {
    let mut m = Matcher::new(Params::default()).unwrap();
    let a = img(64, 48, textured);
    let b = img(60, 48, textured);
    let e = m
        .compute(GrayImage { width: 64, height: 48, data: &a }, GrayImage { width: 60, height: 48, data: &b })
        .unwrap_err();
    assert_eq!(e, MatchError::SizeMismatch { lw: 64, lh: 48, rw: 60, rh: 48 });
    assert!(e.to_string().contains("left image is 64×48, right image is 60×48"));
    let e = m
        .compute(GrayImage { width: 64, height: 48, data: &a[..100] }, GrayImage { width: 64, height: 48, data: &a })
        .unwrap_err();
    assert!(matches!(e, MatchError::Buffer { len: 100, .. }), "{e}");
}

#[test]
fn empty_images_are_errors() {
    let mut m = Matcher::new(Params::default()).unwrap();
    let e = m
        .compute(GrayImage { width: 0, height: 0, data: &[] }, GrayImage { width: 0, height: 0, data: &[] })
        .unwrap_err();
    assert!(matches!(e, MatchError::TooSmall { .. }), "{e}");
}

#[test]
fn absurd_parameters_are_errors() {
    for (p, name) in [
        (Params { patch_size: 0, ..Params::default() }, "patchsz"),
        (Params { patch_size: 7, ..Params::default() }, "patchsz"),
        (Params { lv_f: 0, lv_l: 1, ..Params::default() }, "lv_f"),
        (Params { lv_l: 0, ..Params::default() }, "lv_l"),
        (Params { overlap: 1.0, ..Params::default() }, "poverl"),
        (Params { unit_disturb: -1.0, ..Params::default() }, "unit_disturb"),
        (Params { maxiter: 0, ..Params::default() }, "maxiter"),
    ] {
        let e = Matcher::new(p).unwrap_err();
        assert!(e.to_string().starts_with(&format!("BDISparam.{name}:")), "{e}");
    }
}

#[test]
fn black_and_textureless_pairs_give_all_invalid_maps() {
    for algorithm in [Algorithm::Bdis, Algorithm::Dis] {
        let mut m = Matcher::new(Params { algorithm, ..Params::default() }).unwrap();
        for value in [0u8, 128] {
            let a = img(160, 120, |_, _| value);
            let out = m
                .compute(
                    GrayImage { width: 160, height: 120, data: &a },
                    GrayImage { width: 160, height: 120, data: &a },
                )
                .unwrap();
            assert_eq!(out.density(), 0.0, "{algorithm:?}, constant {value}");
            assert!(out.confidence.iter().all(|&c| c == 0.0));
        }
    }
}

/// A 320×240 pair whose right image is `texture` shifted by 6 px (a fronto-parallel plane at disparity 6),
/// matched with `params`: the map and its mean error over the valid pixels.
fn match_shifted_by_6(texture: impl Fn(usize, usize) -> u8, params: Params) -> (bdis_stereo::DisparityMap, f32) {
    let (w, h) = (320, 240);
    let left = img(w, h, &texture);
    let right = img(w, h, |x, y| texture(x + 6, y));
    let out = Matcher::new(params)
        .unwrap()
        .compute(GrayImage { width: w, height: h, data: &left }, GrayImage { width: w, height: h, data: &right })
        .unwrap();
    let errors: Vec<f32> = out.disparity.iter().filter(|d| d.is_finite()).map(|d| (d - 6.0).abs()).collect();
    let mean = errors.iter().sum::<f32>() / errors.len() as f32;
    (out, mean)
}

#[test]
fn a_shifted_texture_gives_its_disparity() {
    // Right = left shifted by 6 px: a fronto-parallel plane at disparity 6.
    let (out, mean) = match_shifted_by_6(smooth, Params::colon());
    assert!(out.density() > 0.5, "density {}", out.density());
    assert!(mean < 0.25, "mean error {mean} px");
    assert!(out.confidence.iter().all(|c| (0.0..=1.0).contains(c)));
}

#[test]
fn a_coarse_level_that_finds_nothing_hands_over_to_the_next_instead_of_emptying_the_map() {
    // A black (invalid) dot every 8 px: every pixel of levels 3–5 covers one, so they have no valid template
    // pixel and find nothing; level 2 (4×4 blocks) is three quarters valid. The original would refine nothing
    // from nothing and return an empty map; the search starts again from zero at level 2 instead.
    let dotted = |x: usize, y: usize| if x.is_multiple_of(8) && y.is_multiple_of(8) { 0 } else { smooth(x, y) };
    for algorithm in [Algorithm::Bdis, Algorithm::Dis] {
        let (out, mean) = match_shifted_by_6(dotted, Params { algorithm, ..Params::colon() });
        assert!(out.density() > 0.3, "{algorithm:?}: density {}", out.density());
        assert!(mean < 0.5, "{algorithm:?}: mean error {mean} px");
    }
}
