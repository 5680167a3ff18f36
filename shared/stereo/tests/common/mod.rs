#![allow(clippy::unwrap_used, clippy::expect_used)] // test code: a panic is the failure report
//! Test data access for the stereo tests.
#![allow(dead_code)]

use std::path::{Path, PathBuf};

/// `../shared/data/bdis/<set>` beside the checkout, or None (the test then says it was skipped).
pub fn data_set(set: &str) -> Option<PathBuf> {
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data/bdis").join(set);
    if p.is_dir() {
        Some(p)
    } else {
        assert!(std::env::var_os("CI").is_none(), "CI must have ../shared/data ({})", p.display());
        eprintln!("skipped: {} is not present", p.display());
        None
    }
}

/// Grey (BT.601) and RGB of an image file.
pub fn load(path: &Path) -> (image::GrayImage, image::RgbImage) {
    let rgb = image::open(path).unwrap().to_rgb8();
    let gray = image::GrayImage::from_fn(rgb.width(), rgb.height(), |x, y| {
        let p = rgb.get_pixel(x, y);
        image::Luma([bdis_core::pixel::gray_of(p[0], p[1], p[2])])
    });
    (gray, rgb)
}

/// Image names of a set's left folder, sorted numerically.
pub fn names(set: &Path) -> Vec<String> {
    let mut n: Vec<u32> = std::fs::read_dir(set.join("left"))
        .unwrap()
        .map(|e| e.unwrap().path().file_stem().unwrap().to_str().unwrap().parse().unwrap())
        .collect();
    n.sort();
    n.into_iter().map(|v| format!("{v}.png")).collect()
}
