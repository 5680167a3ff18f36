//! The matcher's own unit tests (the halving; the level offset against the halved pair).

use super::*;

/// A textured pair: the right image is the left shifted by a disparity that varies along the rows, with a
/// black border as an endoscope's.
fn pair(w: usize, h: usize) -> (Vec<u8>, Vec<u8>) {
    let texture = |x: f32, y: f32| {
        let v = 128.0 + 50.0 * (0.21 * x).sin() * (0.17 * y).cos() + 40.0 * (0.05 * x + 0.09 * y).sin();
        v.clamp(1.0, 255.0) as u8
    };
    let mut left = vec![0u8; w * h];
    let mut right = vec![0u8; w * h];
    for y in 4..h - 4 {
        let d = 6.0 + 4.0 * y as f32 / h as f32;
        for x in 4..w - 4 {
            left[y * w + x] = texture(x as f32, y as f32);
            right[y * w + x] = texture(x as f32 + d, y as f32);
        }
    }
    (left, right)
}

#[test]
fn halving_keeps_the_pyramids_rules() {
    // 10 20  0
    // 40 30 41
    // 50 60  7      2×2 blocks, the last column and row partial.
    let data = [10, 20, 0, 40, 30, 41, 50, 60, 7];
    let image = GrayImage { width: 3, height: 3, data: &data };
    let (mut sums, mut out) = (Vec::new(), Vec::new());
    let left = halve(image, 1, HalvingRule::AllValid, &mut sums, &mut out);
    assert_eq!((left.width, left.height), (2, 2));
    // (0,0) 10 20 40 30 → 25; (1,0) 0 41 → invalid for the left; (0,1) 50 60 → 55; (1,1) 7.
    assert_eq!(left.data, &[25, 0, 55, 7]);
    let right = halve(image, 1, HalvingRule::ValidMean, &mut sums, &mut out);
    assert_eq!(right.data, &[25, 41, 55, 7], "the right takes the mean of its valid pixels");
    // Rounded to the nearest: 1 and 2 → 2 (1.5 up).
    let data = [1, 2, 1, 2];
    let image = GrayImage { width: 2, height: 2, data: &data };
    assert_eq!(halve(image, 1, HalvingRule::AllValid, &mut sums, &mut out).data, &[2]);
}

#[test]
fn halving_equals_its_definition_block_by_block() {
    // Odd sizes (partial last blocks), black scattered so that blocks of every valid count occur inside the
    // image (the 2×2 path) as well as at its edges (the general one), once and twice halved.
    let (w, h) = (37, 23);
    let data: Vec<u8> = (0..w * h)
        .map(|i: usize| {
            let mut hash = (i as u32).wrapping_mul(2_654_435_761);
            hash ^= hash >> 15;
            hash = hash.wrapping_mul(2_246_822_519);
            hash ^= hash >> 13;
            if hash >> 30 == 0 { 0 } else { (hash >> 8) as u8 | 1 }
        })
        .collect();
    let data = &data[..];
    let image = GrayImage { width: w, height: h, data };
    for times in [1, 2] {
        let n = 1 << times;
        for rule in [HalvingRule::AllValid, HalvingRule::ValidMean] {
            let (mut sums, mut out) = (Vec::new(), Vec::new());
            let halved = halve(image, times, rule, &mut sums, &mut out);
            for (i, &got) in halved.data.iter().enumerate() {
                let (bx, by) = (i % halved.width, i / halved.width);
                let block: Vec<u32> = (by * n..(by * n + n).min(h))
                    .flat_map(|y| (bx * n..(bx * n + n).min(w)).map(move |x| u32::from(data[y * w + x])))
                    .collect();
                let valid: Vec<u32> = block.iter().copied().filter(|&v| v != 0).collect();
                let want = if valid.is_empty() || (rule == HalvingRule::AllValid && valid.len() < block.len()) {
                    0
                } else {
                    ((f64::from(valid.iter().sum::<u32>()) / valid.len() as f64) + 0.5).floor() as u8
                };
                assert_eq!(got, want, "block ({bx}, {by}) of {times} halvings, {rule:?}");
            }
        }
    }
}

#[test]
fn an_offset_matches_the_halved_pair_exactly_and_outputs_input_pixels() {
    // Level 0 at offset 1 is the halved pair: the finest level's flow is the same number for number as
    // matching the halved pair at offset 0, and the output is that flow upsampled to the input, ×2 more.
    let (w, h) = (256, 192);
    let (left, right) = pair(w, h);
    let params = Params { level_offset: Some(1), ..Params::colon() };
    let mut at_offset = Matcher::new(params).unwrap();
    let full = at_offset
        .compute(GrayImage { width: w, height: h, data: &left }, GrayImage { width: w, height: h, data: &right })
        .unwrap();
    let (mut sums, mut hl, mut hr) = (Vec::new(), Vec::new(), Vec::new());
    let l = halve(GrayImage { width: w, height: h, data: &left }, 1, HalvingRule::AllValid, &mut sums, &mut hl);
    let r = halve(GrayImage { width: w, height: h, data: &right }, 1, HalvingRule::ValidMean, &mut sums, &mut hr);
    let mut halved = Matcher::new(Params { level_offset: Some(0), ..Params::colon() }).unwrap();
    let small = halved.compute(l, r).unwrap();
    let finest = Params::colon().lv_l as usize;
    let (a, b) = (&at_offset.levels[finest].flow, &halved.levels[finest].flow);
    assert_eq!(a.len(), b.len());
    assert!(a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits()), "the same flow");
    assert_eq!((full.width, full.height), (w, h));
    assert!(full.density() > 0.5, "density {}", full.density());
    // The true disparity is 6–10 input px; the halved pair's output is in its own pixels.
    let valid: Vec<f32> = full.disparity.iter().copied().filter(|d| d.is_finite()).collect();
    let mean = valid.iter().sum::<f32>() / valid.len() as f32;
    assert!((6.5..9.5).contains(&mean), "mean disparity {mean} input px");
    let small_valid: Vec<f32> = small.disparity.iter().copied().filter(|d| d.is_finite()).collect();
    let small_mean = small_valid.iter().sum::<f32>() / small_valid.len() as f32;
    assert!((mean / small_mean - 2.0).abs() < 0.05, "{mean} against 2 × {small_mean}");
}

#[test]
fn a_reused_matcher_gives_what_a_new_one_gives() {
    // Every buffer the matcher keeps between pairs (levels, halving, the upsampling's rows) must hold nothing
    // of the pair before: the second pair's output equals a new matcher's, bit for bit.
    let (w, h) = (160, 96);
    let (l1, r1) = pair(w, h);
    // Another pair: dimmer, and the right view 3 pixels further.
    let l2: Vec<u8> = l1.iter().map(|&v| v / 2 + u8::from(v > 0)).collect();
    let mut r2: Vec<u8> = r1.iter().map(|&v| v / 2 + u8::from(v > 0)).collect();
    r2.rotate_left(3);
    fn image(data: &[u8]) -> GrayImage<'_> {
        GrayImage { width: 160, height: 96, data }
    }
    for params in [Params::default(), Params { level_offset: Some(1), ..Params::colon() }] {
        let mut reused = Matcher::new(params).unwrap();
        let (mut first, mut second, mut fresh) =
            (DisparityMap::default(), DisparityMap::default(), DisparityMap::default());
        reused.compute_into(image(&l1), image(&r1), &mut first).unwrap();
        reused.compute_into(image(&l2), image(&r2), &mut second).unwrap();
        Matcher::new(params).unwrap().compute_into(image(&l2), image(&r2), &mut fresh).unwrap();
        let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&second.disparity), bits(&fresh.disparity));
        assert_eq!(bits(&second.confidence), bits(&fresh.confidence));
        assert_ne!(bits(&first.disparity), bits(&second.disparity), "the two pairs should differ");
    }
}
