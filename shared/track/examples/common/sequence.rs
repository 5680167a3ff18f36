//! What the offline examples share: a sequence folder (left/*.png, right/*.png sorted by number, times.txt,
//! settings.yaml unless another is given) read as grey pairs, a tracker made for it, and the instrument estimate
//! the tracking service runs by default.
// Each example uses part of this.
#![allow(dead_code)]
use bdis_track::{Tracker, TrackerSettings};
use std::path::{Path, PathBuf};

/// The arguments, after `--help` (the usage on standard output, exit 0) and a missing `<dir>` (the usage on
/// standard error, exit 2) were answered: these tools are run by hand.
pub fn args(usage: &str, positional: usize) -> Vec<String> {
    let a: Vec<String> = std::env::args().collect();
    if a.iter().any(|x| x == "--help" || x == "-h") {
        println!("{usage}");
        std::process::exit(0);
    }
    if a.len() <= positional || a[1..=positional].iter().any(|x| x.starts_with("--")) {
        eprintln!("{usage}");
        std::process::exit(2);
    }
    a
}

pub struct Sequence {
    pub lefts: Vec<PathBuf>,
    pub rights: Vec<PathBuf>,
    pub times: Vec<f64>,
    pub settings: bdis_core::settings::Settings,
    pub width: usize,
    pub height: usize,
}

impl Sequence {
    pub fn open(dir: &Path, settings_path: Option<&Path>) -> Self {
        let settings_path = settings_path.map_or_else(|| dir.join("settings.yaml"), Path::to_path_buf);
        let settings = bdis_core::settings::Settings::load(&settings_path).unwrap();
        let times: Vec<f64> = std::fs::read_to_string(dir.join("times.txt"))
            .unwrap()
            .lines()
            .filter(|l| !l.trim().is_empty())
            .map(|l| l.trim().parse().unwrap())
            .collect();
        let list = |side: &str| {
            let mut files: Vec<PathBuf> =
                std::fs::read_dir(dir.join(side)).unwrap().map(|e| e.unwrap().path()).collect();
            files.sort_by_key(|p| p.file_stem().and_then(|s| s.to_str()).and_then(|s| s.parse::<u64>().ok()));
            files
        };
        let (lefts, rights) = (list("left"), list("right"));
        let (_, width, height) = grey(&lefts[0]);
        Self { lefts, rights, times, settings, width, height }
    }

    /// A tracker for this sequence's camera and settings.
    pub fn tracker(&self) -> Tracker {
        let cam = self.settings.camera.rectified(self.width as u32, self.height as u32).expect("rectified images");
        let ts = TrackerSettings {
            th_depth: self.settings.th_depth,
            fps: self.settings.fps,
            orb: bdis_orb::OrbParams::from_settings(&self.settings.orb),
        };
        Tracker::new(cam, ts).unwrap()
    }

    /// Frame i as grey left and right images.
    pub fn pair(&self, i: usize) -> (Vec<u8>, Vec<u8>) {
        (grey(&self.lefts[i]).0, grey(&self.rights[i]).0)
    }

    /// Frame i decoded once: grey left and right images, and the left in colour when `with_colour` (for the
    /// instrument estimate).
    pub fn frame(&self, i: usize, with_colour: bool) -> Frame {
        let left_rgb = image::open(&self.lefts[i]).unwrap().to_rgb8();
        Frame { left: grey_of(&left_rgb), right: grey(&self.rights[i]).0, left_rgb: with_colour.then_some(left_rgb) }
    }

    /// Tracks frame i as the tracking service does by default: with our instrument estimate from the left colour
    /// image (`--instrument-masks estimate`), unless `masker` is `None` (`off`). Without it, footage where the
    /// estimate finds something (instruments, and smoke reaching the border, which is grey too) tracks
    /// differently offline than through the processes.
    pub fn track(
        &self,
        tracker: &mut Tracker,
        masker: Option<&mut bdis_track::instruments::InstrumentMasker>,
        i: usize,
    ) -> bdis_track::FrameResult {
        let frame = self.frame(i, masker.is_some());
        let t_ns = (self.times[i] * 1e9).round() as u64;
        tracker.track_masked(t_ns, &frame.left, &frame.right, keep_out(masker, frame.left_rgb.as_ref())).unwrap()
    }
}

/// One frame's images ([`Sequence::frame`]).
pub struct Frame {
    pub left: Vec<u8>,
    pub right: Vec<u8>,
    pub left_rgb: Option<image::RgbImage>,
}

/// The instrument estimate's mask of `rgb`, as the tracking service takes it: `None` when it found nothing.
pub fn keep_out<'m>(
    masker: Option<&'m mut bdis_track::instruments::InstrumentMasker>,
    rgb: Option<&image::RgbImage>,
) -> Option<&'m [u8]> {
    let (m, img) = (masker?, rgb?);
    let found = m.estimate(img.as_raw(), img.width() as usize, img.height() as usize);
    (found.regions > 0).then(|| m.mask())
}

/// The instrument estimate the tracking service runs by default; `None` with `--instrument-masks off`.
pub fn masker(args: &[String]) -> Option<bdis_track::instruments::InstrumentMasker> {
    let mode = args.iter().position(|x| x == "--instrument-masks").map(|i| args.get(i + 1).map(String::as_str));
    match mode {
        None | Some(Some("estimate")) => Some(bdis_track::instruments::InstrumentMasker::new(Default::default())),
        Some(Some("off")) => None,
        Some(other) => panic!("--instrument-masks: estimate or off, not {other:?}"),
    }
}

/// An image as 8-bit grey (BT.601 weights), with its size.
pub fn grey(path: &Path) -> (Vec<u8>, usize, usize) {
    let img = image::open(path).unwrap().to_rgb8();
    let (w, h) = (img.width() as usize, img.height() as usize);
    (grey_of(&img), w, h)
}

/// A decoded colour image as 8-bit grey (BT.601 weights).
pub fn grey_of(img: &image::RgbImage) -> Vec<u8> {
    bdis_core::pixel::gray_of_rgb(img.as_raw())
}

/// The word after `flag` in the arguments, if the flag is there.
pub fn value<'a>(a: &'a [String], flag: &str) -> Option<&'a str> {
    a.iter().position(|x| x == flag).and_then(|i| a.get(i + 1)).map(String::as_str)
}
