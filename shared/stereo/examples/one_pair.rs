#![allow(clippy::unwrap_used, clippy::expect_used)] // test code: a panic is the failure report
//! Matches one pair `repeats` times: the target of the callgrind instruction counts in BENCHMARKS.md.
//! Usage: one_pair <slam|colon|slam-dis|colon-dis|colon-lr|colon-dis-lr|slam-lr>[-unhalved] LEFT RIGHT [repeats]
//! (`-unhalved`: an HD pair matched without halving it first, `Params::level_offset` 0.)
use bdis_stereo::{Algorithm, DisparityMap, GrayImage, Matcher, Params};

fn main() {
    let args: Vec<String> = std::env::args().collect();
    if args.len() < 4 {
        eprintln!("usage: one_pair <slam|colon|slam-dis|colon-dis|colon-lr|colon-dis-lr> LEFT RIGHT [repeats]");
        std::process::exit(2);
    }
    let (preset, unhalved) = match args[1].strip_suffix("-unhalved") {
        Some(p) => (p, true),
        None => (args[1].as_str(), false),
    };
    let params = match preset {
        // As published (no left–right check: the C++ comparison); `-lr`: with the check, as the service runs.
        "slam" => Params::default().as_published(),
        "colon" => Params::colon().as_published(),
        "slam-dis" => Params { algorithm: Algorithm::Dis, ..Params::default() }.as_published(),
        "colon-dis" => Params { algorithm: Algorithm::Dis, ..Params::colon() }.as_published(),
        "colon-lr" => Params::colon(),
        "colon-dis-lr" => Params { algorithm: Algorithm::Dis, ..Params::colon() },
        "slam-lr" => Params::default(),
        other => panic!("unknown preset {other}"),
    };
    let params = if unhalved { Params { level_offset: Some(0), ..params } } else { params };
    // The pipeline's grey (BT.601), as the acquisition service makes it.
    let (l, r) = (image::open(&args[2]).unwrap().to_rgb8(), image::open(&args[3]).unwrap().to_rgb8());
    let (w, h) = (l.width() as usize, l.height() as usize);
    let (l, r) = (bdis_core::pixel::gray_of_rgb(l.as_raw()), bdis_core::pixel::gray_of_rgb(r.as_raw()));
    let repeats: usize = args.get(4).map_or(1, |s| s.parse().unwrap());
    let mut m = Matcher::new(params).unwrap();
    let mut out = DisparityMap::default();
    for _ in 0..repeats {
        m.compute_into(
            GrayImage { width: w, height: h, data: &l },
            GrayImage { width: w, height: h, data: &r },
            &mut out,
        )
        .unwrap();
    }
    println!("density {:.3}", out.density());
}
