//! Something a person can look at: a colour-mapped disparity image.

/// Maps t ∈ [0, 1] to a blue → cyan → green → yellow → red ramp (far → near).
pub fn ramp(t: f32) -> [u8; 3] {
    let t = t.clamp(0.0, 1.0);
    let stops: [(f32, [f32; 3]); 5] = [
        (0.0, [30.0, 40.0, 160.0]),
        (0.25, [20.0, 170.0, 230.0]),
        (0.5, [60.0, 200.0, 80.0]),
        (0.75, [250.0, 220.0, 40.0]),
        (1.0, [220.0, 40.0, 30.0]),
    ];
    let i = stops.iter().rposition(|(s, _)| *s <= t).unwrap_or(0).min(stops.len() - 2);
    let (t0, c0) = stops[i];
    let (t1, c1) = stops[i + 1];
    let f = (t - t0) / (t1 - t0);
    [0, 1, 2].map(|k| (c0[k] + f * (c1[k] - c0[k])).round() as u8)
}

/// RGB bytes (w·h·3) of a disparity map: colour from the 2nd to the 98th percentile of valid disparities,
/// invalid pixels black. Returns the range used.
pub fn colorize(disparity: &[f32], rgb_out: &mut Vec<u8>) -> (f32, f32) {
    let mut valid: Vec<f32> = disparity.iter().copied().filter(|d| d.is_finite()).collect();
    rgb_out.clear();
    if valid.is_empty() {
        rgb_out.resize(disparity.len() * 3, 0);
        return (0.0, 0.0);
    }
    valid.sort_by(f32::total_cmp);
    let (mut lo, mut hi) = (valid[valid.len() * 2 / 100], valid[(valid.len() * 98 / 100).min(valid.len() - 1)]);
    // At least 2 px or 20 % of the median wide, centred: sub-pixel noise on a flat scene should not be painted
    // as a rainbow.
    let median = valid[valid.len() / 2];
    let min_span = (0.2 * median).max(2.0);
    if hi - lo < min_span {
        let mid = 0.5 * (lo + hi);
        lo = mid - 0.5 * min_span;
        hi = mid + 0.5 * min_span;
    }
    for &d in disparity {
        let c = if d.is_finite() { ramp((d - lo) / (hi - lo)) } else { [0, 0, 0] };
        rgb_out.extend_from_slice(&c);
    }
    (lo, hi)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ramp_ends_and_invalid_black() {
        assert_eq!(ramp(0.0), [30, 40, 160]);
        assert_eq!(ramp(1.0), [220, 40, 30]);
        let mut out = Vec::new();
        let (lo, hi) = colorize(&[f32::NAN, 1.0, 2.0, 3.0], &mut out);
        assert_eq!(&out[..3], &[0, 0, 0]);
        assert!(lo <= 1.0 && hi >= 2.0);
    }
}
