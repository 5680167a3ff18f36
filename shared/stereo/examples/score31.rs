#![allow(clippy::unwrap_used, clippy::expect_used)] // test code: a panic is the failure report
//! Prints the set-31 scores of BDIS and plain DIS (development aid; the CI test asserts them), or with
//! `SEQUENCE BF STEP` BDIS's scores on a rendered sequence's pairs against their ground-truth depth.
use bdis_eval::stereo::StereoScore;
use bdis_stereo::{Algorithm, GrayImage, Matcher, Params};

fn gray(path: &std::path::Path) -> (Vec<u8>, Vec<bool>, usize, usize) {
    let rgb = image::open(path).unwrap().to_rgb8();
    let (w, h) = rgb.dimensions();
    let g = bdis_core::pixel::gray_of_rgb(rgb.as_raw());
    let region = rgb.pixels().map(|p| p[0] != 0).collect();
    (g, region, w as usize, h as usize)
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    if let [_, seq, bf, step] = &args[..] {
        score_rendered(std::path::Path::new(seq), bf.parse().unwrap(), step.parse().unwrap());
        return;
    }
    set_31();
}

/// A rendered sequence (`bdis-slam synth`): every `step`-th pair against its `gt/depth`, over the pixels with
/// ground truth and a non-black left image; BDIS as published, with the colon parameters (as set 31).
fn score_rendered(seq: &std::path::Path, bf: f32, step: usize) {
    let mut m = Matcher::new(Params::colon().as_published()).unwrap();
    let mut score = StereoScore::new();
    let mut pairs = 0;
    for n in (1..).step_by(step) {
        let left = seq.join(format!("left/{n}.png"));
        if !left.exists() {
            break;
        }
        let (l, region, w, h) = gray(&left);
        let (r, _, _, _) = gray(&seq.join(format!("right/{n}.png")));
        let out = m
            .compute(GrayImage { width: w, height: h, data: &l }, GrayImage { width: w, height: h, data: &r })
            .unwrap();
        let gt = bdis_core::formats::pfm::read(&seq.join(format!("gt/depth/{n}.pfm"))).unwrap();
        score.add(&out.disparity, &gt.data, &region, bf);
        pairs += 1;
    }
    println!("{} ({pairs} pairs): {:?}", seq.display(), score.summary());
}

fn set_31() {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data/bdis/31");
    // Each as published (lr_check 0) and with the left–right check the service runs.
    for (algorithm, lr_check) in
        [(Algorithm::Bdis, 0.0), (Algorithm::Bdis, 1.0), (Algorithm::Dis, 0.0), (Algorithm::Dis, 1.0)]
    {
        let mut m = Matcher::new(Params { algorithm, lr_check, ..Params::colon() }).unwrap();
        let mut score = StereoScore::new();
        let t = std::time::Instant::now();
        for n in 1..=16 {
            let (l, region, w, h) = gray(&root.join(format!("left/{n}.png")));
            let (r, _, _, _) = gray(&root.join(format!("right/{n}.png")));
            let out = m
                .compute(GrayImage { width: w, height: h, data: &l }, GrayImage { width: w, height: h, data: &r })
                .unwrap();
            let gt = bdis_core::formats::pfm::read_disparity(&root.join(format!("depth/{n}.pfm"))).unwrap();
            score.add(&out.disparity, &gt.data, &region, 260.0);
        }
        println!(
            "{algorithm:?} (lr_check {lr_check}): {:?} in {:.1} ms/pair",
            score.summary(),
            t.elapsed().as_secs_f64() * 1000.0 / 16.0
        );
    }
}

#[allow(dead_code)]
fn unused() {}
