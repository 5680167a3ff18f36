#![allow(clippy::unwrap_used, clippy::expect_used)] // test code: a panic is the failure report
//! Helpers for end-to-end tests: they start the real binaries over real iceoryx2, each test under its own
//! shared-memory prefix so tests run in parallel without seeing each other.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

/// The `bdis-slam` binary under test.
pub fn bdis_slam() -> PathBuf {
    PathBuf::from(env!("CARGO_BIN_EXE_bdis-slam"))
}

/// A service binary built next to `bdis-slam` (cargo builds every workspace binary for the tests).
pub fn service_binary(name: &str) -> PathBuf {
    let p = bdis_slam().with_file_name(name);
    assert!(p.is_file(), "{} is missing: build the workspace (`cargo build --release`) before the tests", p.display());
    p
}

/// `../shared/data/bdis/<set>` beside the checkout, or None (the test then says it was skipped).
pub fn data_set(set: &str) -> Option<PathBuf> {
    shared_data(&format!("bdis/{set}"))
}

/// `../shared/data/<name>` beside the checkout (e.g. `kitti-a`), or None outside CI (the test then says it was
/// skipped).
pub fn shared_data(name: &str) -> Option<PathBuf> {
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data").join(name);
    if p.is_dir() {
        Some(p)
    } else {
        assert!(std::env::var_os("CI").is_none(), "CI must have ../shared/data ({})", p.display());
        eprintln!("skipped: {} is not present", p.display());
        None
    }
}

/// A fresh temporary folder, removed when dropped (kept when `BDIS_KEEP_TEST_DIRS` is set, to read a
/// passing run's logs).
pub struct TempDir(pub PathBuf);

impl TempDir {
    pub fn new(tag: &str) -> Self {
        let nanos = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).unwrap().subsec_nanos();
        let p = std::env::temp_dir().join(format!("bdis-test-{tag}-{}-{nanos:x}", std::process::id()));
        std::fs::create_dir_all(&p).unwrap();
        Self(p)
    }
    pub fn path(&self) -> &Path {
        &self.0
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        if std::env::var_os("BDIS_KEEP_TEST_DIRS").is_some() {
            eprintln!("kept {}", self.0.display());
            return;
        }
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// Folders shared by the tests of one binary (held in a `static`, which is never dropped), removed when the
/// test binary exits.
static REMOVE_AT_EXIT: std::sync::Mutex<Vec<PathBuf>> = std::sync::Mutex::new(Vec::new());

extern "C" fn remove_shared_dirs() {
    if let Ok(dirs) = REMOVE_AT_EXIT.lock() {
        for dir in dirs.iter() {
            let _ = std::fs::remove_dir_all(dir);
        }
    }
}

impl TempDir {
    /// For a folder kept in a `static` for every test of the binary: removed when the binary exits (unless
    /// `BDIS_KEEP_TEST_DIRS` is set).
    pub fn removed_at_exit(self) -> Self {
        if std::env::var_os("BDIS_KEEP_TEST_DIRS").is_none()
            && let Ok(mut dirs) = REMOVE_AT_EXIT.lock()
        {
            if dirs.is_empty() {
                // SAFETY: registers a plain function with no captured state; it runs once at exit.
                unsafe { libc::atexit(remove_shared_dirs) };
            }
            dirs.push(self.0.clone());
        }
        self
    }
}

/// A shared-memory prefix unique to this test.
pub fn prefix(tag: &str) -> String {
    let nanos = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).unwrap().subsec_nanos();
    format!(
        "bt{}{}{:x}_",
        tag.chars().filter(|c| c.is_ascii_alphanumeric()).take(6).collect::<String>(),
        std::process::id(),
        nanos & 0xffff
    )
}

/// Runs a command to its end, killing it (and failing the test) after `timeout`.
pub fn run_with_timeout(cmd: &mut Command, timeout: Duration) -> Output {
    let mut child =
        cmd.stdin(Stdio::null()).stdout(Stdio::piped()).stderr(Stdio::piped()).spawn().expect("start the command");
    let start = Instant::now();
    // Read the pipes on threads so a chatty child never blocks on a full pipe.
    let mut out = child.stdout.take().unwrap();
    let mut err = child.stderr.take().unwrap();
    let out_t = std::thread::spawn(move || {
        let mut v = Vec::new();
        std::io::Read::read_to_end(&mut out, &mut v).ok();
        v
    });
    let err_t = std::thread::spawn(move || {
        let mut v = Vec::new();
        std::io::Read::read_to_end(&mut err, &mut v).ok();
        v
    });
    let status = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break s;
        }
        if start.elapsed() > timeout {
            let _ = child.kill();
            let _ = child.wait();
            panic!(
                "{cmd:?} did not finish within {timeout:?}\nstderr:\n{}",
                String::from_utf8_lossy(&err_t.join().unwrap())
            );
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    Output { status, stdout: out_t.join().unwrap(), stderr: err_t.join().unwrap() }
}

pub fn text(bytes: &[u8]) -> String {
    String::from_utf8_lossy(bytes).into_owned()
}

/// Removes the shared-memory files of the run with `prefix` when dropped, also when the test fails: a failed
/// test reports its own failure, not a second one about files it left behind.
pub struct RunFiles<'a>(pub &'a str);

impl Drop for RunFiles<'_> {
    fn drop(&mut self) {
        if std::thread::panicking() {
            bdis_slam::run_dir::remove_leftovers(self.0);
        }
    }
}

/// Asserts that nothing of the run with `prefix` is left in /dev/shm or /tmp/iceoryx2.
pub fn assert_no_leftovers(prefix: &str) {
    let left = bdis_slam::run_dir::leftovers(prefix);
    assert!(left.is_empty(), "shared-memory leftovers of {prefix}: {left:?}");
}

/// Writes a small plain-layout stereo sequence: `n` pairs of w×h textured RGB images, the right one shifted by
/// `shift` pixels (a fronto-parallel plane), named 1.png … n.png.
pub fn write_sequence(root: &Path, n: usize, w: u32, h: u32, shift: u32) {
    std::fs::create_dir_all(root.join("left")).unwrap();
    std::fs::create_dir_all(root.join("right")).unwrap();
    let texture = |x: u32, y: u32, k: u32| -> image::Rgb<u8> {
        let v = (x.wrapping_mul(2_654_435_761) ^ y.wrapping_mul(40_503) ^ k.wrapping_mul(97)) >> 7;
        image::Rgb([(v & 0xff) as u8, ((v >> 8) & 0xff) as u8, ((x + y + k) & 0xff) as u8])
    };
    for i in 1..=n as u32 {
        let left = image::RgbImage::from_fn(w, h, |x, y| texture(x + i, y, i));
        let right = image::RgbImage::from_fn(w, h, |x, y| texture(x + i + shift, y, i));
        left.save(root.join(format!("left/{i}.png"))).unwrap();
        right.save(root.join(format!("right/{i}.png"))).unwrap();
    }
}

/// A settings file for the small sequences.
pub fn write_settings(path: &Path, w: u32, h: u32) {
    std::fs::write(
        path,
        format!(
            "%YAML:1.0\nCamera.fx: 100.0\nCamera.fy: 100.0\nCamera.cx: {}\nCamera.cy: {}\nCamera.width: {w}\nCamera.height: {h}\nCamera.fps: 30\nCamera.bf: 500.0\n",
            w / 2,
            h / 2
        ),
    )
    .unwrap();
}

/// `python3` when it has numpy (the independent readers in tests/interop need it). CI installs it (.ci/run);
/// elsewhere the Rust half of a test still runs.
pub fn python_with_numpy() -> Option<String> {
    let ok = Command::new("python3").args(["-c", "import numpy"]).output().is_ok_and(|o| o.status.success());
    if ok {
        Some("python3".into())
    } else {
        // CI installs numpy (.ci/run); elsewhere the Rust half of this test still runs.
        assert!(std::env::var_os("CI").is_none(), "CI must have python3 with numpy");
        eprintln!("skipped the Python half: python3 with numpy is not available");
        None
    }
}

/// ATE RMSE (mm) of a run's trajectory (`trajectory.tum`, SE(3)-aligned), and the ground-truth path length.
pub fn ate(seq: &Path, run_dir: &Path) -> (f64, f64) {
    let gt = bdis_core::formats::trajectory::read_tum(&seq.join("gt/poses.tum")).unwrap();
    let est = bdis_core::formats::trajectory::read_tum(&run_dir.join("trajectory.tum")).unwrap();
    assert_eq!(est.len(), gt.len(), "a pose for every frame");
    let ate = bdis_eval::traj::ate(&gt, &est, 0.01).unwrap();
    let length: f64 = gt
        .windows(2)
        .map(|w| (w[1].world_from_camera.translation.vector - w[0].world_from_camera.translation.vector).norm())
        .sum();
    (ate.translation.rmse, length)
}

/// The map scored against the renderer's mesh (`bdis-slam eval map`), moved into the ground truth's frame by
/// the alignment of the keyframe trajectory (the poses that place the map's points).
pub fn map_score(seq: &Path, run_dir: &Path) -> serde_json::Value {
    map_score_aligned_by(seq, run_dir, "keyframes.tum")
}

/// [`map_score`] with the map moved by the alignment of `trajectory` (a TUM file in the run folder): a hover has
/// too few keyframes to align by, its whole trajectory has enough.
pub fn map_score_aligned_by(seq: &Path, run_dir: &Path, trajectory: &str) -> serde_json::Value {
    eval_map(seq, run_dir, trajectory, "trajectory")
}

/// [`map_score`] with the map placed by the first frame's pose (`eval map --align-by first`): no fit, so a short
/// hover's loose rotation does not tilt the map.
pub fn map_score_from_first_frame(seq: &Path, run_dir: &Path) -> serde_json::Value {
    eval_map(seq, run_dir, "trajectory.tum", "first")
}

fn eval_map(seq: &Path, run_dir: &Path, trajectory: &str, align_by: &str) -> serde_json::Value {
    let out = run_with_timeout(
        Command::new(bdis_slam())
            .args(["eval", "map", "--json", "--mesh"])
            .arg(seq.join("gt/mesh.ply"))
            .arg("--map")
            .arg(run_dir.join("map.ply"))
            .arg("--align-est")
            .arg(run_dir.join(trajectory))
            .arg("--align-gt")
            .arg(seq.join("gt/poses.tum"))
            .args(["--align-by", align_by]),
        Duration::from_secs(300),
    );
    assert!(out.status.success(), "{}", text(&out.stderr));
    serde_json::from_slice(&out.stdout).unwrap()
}

/// ffmpeg and ffprobe, which CI installs (.ci/run); elsewhere the test says it was skipped.
pub fn have_ffmpeg() -> bool {
    let ok = ["ffmpeg", "ffprobe"]
        .iter()
        .all(|t| Command::new(t).arg("-version").output().is_ok_and(|o| o.status.success()));
    if !ok {
        assert!(std::env::var_os("CI").is_none(), "CI must have ffmpeg (.ci/run installs it)");
        eprintln!("skipped: ffmpeg is not installed (apt-get install ffmpeg)");
    }
    ok
}

/// Renders the small colon flight the input tests share into `out`: `frames` frames of 320×240 (focal length
/// 260 px, the renderer's field of view at that size).
pub fn render_small_colon(out: &Path, frames: usize) {
    let done = run_with_timeout(
        Command::new(bdis_slam())
            .args(["synth", "--frames", &frames.to_string(), "--width", "320", "--height", "240"])
            .args(["--focal", "260", "--out"])
            .arg(out),
        Duration::from_secs(900),
    );
    assert!(done.status.success(), "{}", text(&done.stderr));
}

/// Tracks and maps `source` (a sequence folder, or a `video:` or `live:` source) end to end through the
/// processes with `settings`, under a shared-memory prefix of its own, into `run_dir`: it must end cleanly and
/// leave no shared memory behind. `extra` goes on the command line after them.
pub fn track_run(source: impl AsRef<std::ffi::OsStr>, settings: &Path, run_dir: &Path, tag: &str, extra: &[&str]) {
    let prefix = prefix(tag);
    let out = run_with_timeout(
        Command::new(bdis_slam())
            .args(["run", "--track", "--sequence"])
            .arg(source)
            .arg("--settings")
            .arg(settings)
            .args(extra)
            .args(["--ipc-prefix", &prefix, "--out"])
            .arg(run_dir),
        Duration::from_secs(600),
    );
    assert!(out.status.success(), "{tag}: {}\n{}", text(&out.stdout), text(&out.stderr));
    assert_no_leftovers(&prefix);
}
