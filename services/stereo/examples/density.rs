//! Prints the density of BDIS on the in-vivo sets 6 and 20 (non-black pixels).
use bdis_stereo::{GrayImage, Matcher, Params};

fn main() {
    let base = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data/bdis");
    let p6 = Params { patch_size: 10, overlap: 0.55, ratio_patch_valid: 0.75, unit_disturb: 0.5, min_prob: 0.05, ..Params::default() };
    let p20 = Params { patch_size: 10, overlap: 0.60, ratio_patch_valid: 0.25, unit_disturb: 0.5, min_prob: 0.05, ..Params::default() };
    for (set, params) in [("6", p6), ("20", p20)] {
        let mut m = Matcher::new(params).unwrap();
        let (mut valid, mut region) = (0u64, 0u64);
        let mut names: Vec<_> = std::fs::read_dir(base.join(set).join("left")).unwrap().map(|e| e.unwrap().file_name()).collect();
        names.sort();
        let t = std::time::Instant::now();
        for n in &names {
            let l = image::open(base.join(set).join("left").join(n)).unwrap().to_rgb8();
            let r = image::open(base.join(set).join("right").join(n)).unwrap().to_luma8();
            let (w, h) = l.dimensions();
            let lg = image::DynamicImage::ImageRgb8(l.clone()).to_luma8();
            let out = m.compute(GrayImage { width: w as usize, height: h as usize, data: lg.as_raw() }, GrayImage { width: w as usize, height: h as usize, data: r.as_raw() }).unwrap();
            for (p, d) in l.pixels().zip(&out.disparity) {
                if p.0 != [0, 0, 0] {
                    region += 1;
                    valid += u64::from(d.is_finite());
                }
            }
        }
        println!("set {set}: density {:.1} % of non-black pixels, {:.1} ms/pair", 100.0 * valid as f64 / region as f64, t.elapsed().as_secs_f64() * 1000.0 / names.len() as f64);
    }
}
