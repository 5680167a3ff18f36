//! The fuzz targets on stable Rust, in CI: each target's committed corpus, then a fixed number of
//! deterministic mutations of it (bit flips, interesting bytes and numbers, cuts, splices). Not a substitute
//! for the coverage-guided runs (`tests/fuzz/README.md`), but any input they once found is in the corpus and
//! replayed here, and a target that panics on a near miss of a good file fails CI.

use std::path::PathBuf;

/// Mutations per target: a few seconds for all targets together in release.
const MUTATIONS: usize = 20_000;

fn corpus(target: &str) -> Vec<Vec<u8>> {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("corpus").join(target);
    let mut files: Vec<PathBuf> = std::fs::read_dir(&dir).into_iter().flatten().flatten().map(|e| e.path()).collect();
    files.sort();
    let mut seeds: Vec<Vec<u8>> = files.iter().filter_map(|p| std::fs::read(p).ok()).collect();
    seeds.extend(bdis_fuzz::generated_seeds(target));
    seeds
}

/// xorshift64*: the same mutations on every machine.
struct Rng(u64);
impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_f491_4f6c_dd1d)
    }
    fn below(&mut self, n: usize) -> usize {
        if n == 0 { 0 } else { (self.next() % n as u64) as usize }
    }
}

const TOKENS: &[&[u8]] = &[
    b"nan",
    b"inf",
    b"-inf",
    b"1e309",
    b"-0",
    b"0",
    b"-1",
    b"4294967296",
    b"18446744073709551616",
    b"\n",
    b" ",
    b":",
    b"[",
    b"]",
    b"\"",
    b"=",
    b"#",
    b"e",
    b".",
    b"\xff\xff\xff\xff",
    b"\x00\x00\x00\x00",
    b"\x00\x00\xc0\x7f",
];

fn mutate(rng: &mut Rng, input: &[u8], other: &[u8]) -> Vec<u8> {
    let mut v = input.to_vec();
    for _ in 0..1 + rng.below(4) {
        let at = rng.below(v.len() + 1);
        match rng.below(7) {
            0 if !v.is_empty() => {
                let i = rng.below(v.len());
                v[i] ^= 1 << rng.below(8);
            }
            1 if !v.is_empty() => {
                let i = rng.below(v.len());
                v[i] = [0u8, 0xff, 0x7f, 0x80, b'9', b'-', b'\n'][rng.below(7)];
            }
            2 => {
                let t = TOKENS[rng.below(TOKENS.len())];
                v.splice(at..at, t.iter().copied());
            }
            3 if !v.is_empty() => {
                // Replace a run with a token: numbers become odd numbers, fields disappear.
                let end = (at + 1 + rng.below(8)).min(v.len());
                let t = TOKENS[rng.below(TOKENS.len())];
                let at = at.min(end);
                v.splice(at..end, t.iter().copied());
            }
            4 => v.truncate(at),
            5 if !other.is_empty() => {
                let from = rng.below(other.len());
                let len = rng.below(other.len() - from + 1);
                v.splice(at..at, other[from..from + len].iter().copied());
            }
            _ if v.len() > 1 => {
                let end = (at + rng.below(16)).min(v.len());
                let chunk: Vec<u8> = v[at.min(end)..end].to_vec();
                v.splice(end..end, chunk);
            }
            _ => {}
        }
    }
    v
}

#[test]
fn every_target_survives_its_corpus_and_mutations_of_it() {
    for &(name, target) in bdis_fuzz::TARGETS {
        let seeds = corpus(name);
        assert!(!seeds.is_empty(), "target {name} has no corpus in tests/fuzz/corpus/{name}");
        for seed in &seeds {
            target(seed);
        }
        let mut rng = Rng(0x9e37_79b9_7f4a_7c15 ^ name.len() as u64);
        for i in 0..MUTATIONS {
            let a = &seeds[i % seeds.len()];
            let b = &seeds[rng.below(seeds.len())];
            let input = mutate(&mut rng, a, b);
            target(&input);
        }
    }
}

#[test]
fn good_seeds_are_accepted_so_the_targets_reach_past_the_first_check() {
    // A target whose seeds are all refused would fuzz only its error paths.
    use bdis_core::formats;
    let p = std::path::Path::new("seed");
    let read =
        |t: &str, f: &str| std::fs::read(PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("corpus").join(t).join(f));
    let text = |t: &str, f: &str| String::from_utf8(read(t, f).unwrap()).unwrap();
    assert!(formats::pfm::parse(&read("pfm", "small-pf").unwrap(), p).is_ok());
    assert!(formats::ply::parse(&read("ply", "binary-le").unwrap(), p).is_ok());
    assert!(formats::ply::parse(&read("ply", "ascii").unwrap(), p).is_ok());
    assert_eq!(formats::trajectory::parse_tum(&text("tum", "traj.tum"), p).unwrap().len(), 2);
    assert_eq!(formats::trajectory::parse_kitti(&text("kitti_poses", "poses.txt"), p).unwrap().len(), 2);
    assert_eq!(bdis_source::source::parse_times(&text("times", "times.txt"), p).unwrap().len(), 4);
    assert!(bdis_source::source::parse_kitti_calib(&text("kitti_calib", "calib.txt"), p).is_ok());
    assert_eq!(bdis_track::journal::Continuation::parse(&text("journal", "journal.txt")).unwrap().frames.len(), 3);
    let raw =
        bdis_core::settings::raw::RawSettings::parse_opencv_yaml(&text("settings_yaml", "small.yaml"), p).unwrap();
    bdis_core::settings::Settings::from_raw(&raw).unwrap();
    let raw = bdis_core::settings::raw::RawSettings::parse_toml(&text("settings_toml", "small.toml"), p).unwrap();
    bdis_core::settings::Settings::from_raw(&raw).unwrap();
    assert!(bdis_slam::launch_file::LaunchFile::parse(&text("launch_file", "hamlyn6.toml"), p).is_ok());
    for seed in ["opencv-rational8.yaml", "opencv-mild-with-size.yaml", "orbslam2-left-right.yaml"] {
        let raw =
            bdis_core::settings::raw::RawSettings::parse_opencv_yaml(&text("stereo_calibration", seed), p).unwrap();
        bdis_rectify::StereoCalibration::from_raw(&raw).unwrap();
    }
    let map = bdis_fuzz::generated_seeds("map_bin");
    assert!(bdis_mosaic::decode(&map[0], p).is_ok());
}

/// Writes the generated seeds into `corpus/` for libFuzzer (`cargo test -p bdis-fuzz -- --ignored`); the smoke
/// test makes them itself, so the corpus needs them only for the long runs.
#[test]
#[ignore]
fn write_generated_seeds() {
    for &(name, _) in bdis_fuzz::TARGETS {
        for (i, seed) in bdis_fuzz::generated_seeds(name).iter().enumerate() {
            let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("corpus").join(name);
            std::fs::create_dir_all(&dir).unwrap();
            std::fs::write(dir.join(format!("generated-{i}")), seed).unwrap();
        }
    }
}
