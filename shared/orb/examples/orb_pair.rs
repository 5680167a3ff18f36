//! Extracts and matches one 640×480 pair (the target of callgrind profiles).
#![allow(clippy::unwrap_used)]
use bdis_orb::{Features, OrbExtractor, OrbParams, StereoFeatures, StereoMatcher};
fn main() {
    let a: Vec<String> = std::env::args().collect();
    // The pipeline's grey (BT.601), as the acquisition service makes it.
    let l = bdis_core::pixel::gray_of_rgb(image::open(&a[1]).unwrap().to_rgb8().as_raw());
    let r = bdis_core::pixel::gray_of_rgb(image::open(&a[2]).unwrap().to_rgb8().as_raw());
    let params = OrbParams { n_features: 1000, ..OrbParams::default() };
    let (mut el, mut er) = (OrbExtractor::new(params, 640, 480).unwrap(), OrbExtractor::new(params, 640, 480).unwrap());
    let mut m = StereoMatcher::new();
    let (mut fl, mut fr, mut st) = (Features::default(), Features::default(), StereoFeatures::default());
    // Optional third argument: repetitions (for perf); two by default (the second is warmed up).
    let reps: usize = a.get(3).and_then(|s| s.parse().ok()).unwrap_or(2);
    for _ in 0..reps {
        el.extract(&l, &mut fl).unwrap();
        er.extract(&r, &mut fr).unwrap();
        let scales = el.scales().to_vec();
        m.match_features(&fl, &fr, &el.levels, &er.levels, &scales, 520.0, 260.0, &mut st);
    }
    println!("{} keypoints, {} matched", fl.keypoints.len(), st.matched());
}
