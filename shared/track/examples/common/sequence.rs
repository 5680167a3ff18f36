//! What the offline examples share: a sequence folder (left/*.png, right/*.png sorted by number, times.txt,
//! settings.yaml unless another is given) read as grey pairs, and a tracker made for it.
use bdis_track::{Tracker, TrackerSettings};
use std::path::{Path, PathBuf};

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
}

/// An image as 8-bit grey (BT.601 weights), with its size.
pub fn grey(path: &Path) -> (Vec<u8>, usize, usize) {
    let img = image::open(path).unwrap().to_rgb8();
    let (w, h) = (img.width() as usize, img.height() as usize);
    let g = img
        .pixels()
        .map(|p| ((u32::from(p[0]) * 4899 + u32::from(p[1]) * 9617 + u32::from(p[2]) * 1868 + 8192) >> 14) as u8)
        .collect();
    (g, w, h)
}
