//! `bdis-slam calib show` (what a stereo calibration file says, and the rectification it gives) and
//! `bdis-slam rectify` (a raw stereo sequence written out rectified, with the rectified settings).

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use bdis_rectify::{Rectification, RectifyMap, StereoCalibration};

#[derive(Debug, clap::Subcommand)]
pub enum CalibCommand {
    /// Print what a stereo calibration file says (focal lengths, distortion, baseline, relative pose) and the
    /// rectified camera it gives, so it can be checked before a run. Reads OpenCV `stereoCalibrate` files
    /// (`M1 D1 M2 D2 R T`, e.g. SCARED's endoscope_calibration.yaml), ORB-SLAM2 settings with `LEFT.*`/`RIGHT.*`
    /// blocks, StereoMIS `StereoCalibration.ini` and `camcal.json`, Hamlyn's calibration text files (their
    /// folder or one of them) and SERV-CT rectified calibrations (JSON with `P1`, `P2`).
    Show(ShowArgs),
}

#[derive(Debug, clap::Args)]
pub struct ShowArgs {
    /// The calibration: a YAML, INI or JSON file, or a Hamlyn calibration folder (or one of its files).
    file: PathBuf,
    /// Image size `WxH`, when the file does not give it.
    #[arg(long, value_parser = parse_size)]
    size: Option<(u32, u32)>,
    /// Bouguet's free scaling: 0 keeps only valid pixels, 1 keeps every source pixel; unset leaves the scale
    /// at the cameras' mean focal length (OpenCV's −1).
    #[arg(long)]
    alpha: Option<f64>,
    /// Print the rectification as JSON (R1 R2 P1 P2 Q, row-major, and the rectified camera) instead of text.
    #[arg(long)]
    json: bool,
    /// Also write each camera's exact undistort–rectify map (`left_map_x.pfm`, `left_map_y.pfm`, `right_…`:
    /// the raw pixel each rectified pixel samples) into this folder.
    #[arg(long)]
    maps: Option<PathBuf>,
}

#[derive(Debug, clap::Args)]
pub struct RectifyArgs {
    /// The stereo calibration (as for `calib show`).
    #[arg(long)]
    settings: PathBuf,
    /// The raw sequence: `left/` and `right/` images (and `times.txt`), in any layout `run` reads.
    #[arg(long)]
    sequence: PathBuf,
    /// Output folder: `left/`, `right/` rectified PNGs with the input's names, `times.txt`, `settings.yaml`.
    #[arg(long)]
    out: PathBuf,
    /// As for `calib show`.
    #[arg(long)]
    alpha: Option<f64>,
}

fn parse_size(text: &str) -> Result<(u32, u32), String> {
    let (w, h) = text.split_once(['x', 'X', '×']).ok_or_else(|| format!("`{text}`: expected WxH, e.g. 640x480"))?;
    let dim = |s: &str| s.trim().parse::<u32>().ok().filter(|v| *v >= 2);
    match (dim(w), dim(h)) {
        (Some(w), Some(h)) => Ok((w, h)),
        _ => Err(format!("`{text}`: expected WxH with whole numbers ≥ 2")),
    }
}

fn check_alpha(alpha: Option<f64>) -> Result<()> {
    if let Some(a) = alpha
        && !(0.0..=1.0).contains(&a)
    {
        bail!("--alpha must be within 0..1, found {a}");
    }
    Ok(())
}

/// The calibration's rectification at `size`: the one the file gives, else Bouguet's.
fn rectification_of(calib: &StereoCalibration, size: (u32, u32), alpha: Option<f64>) -> Result<Rectification> {
    calib.rectification(size, alpha).map_err(anyhow::Error::from)
}

fn load(path: &Path) -> Result<StereoCalibration> {
    // The reader's errors name the file, line and field already.
    StereoCalibration::load(path).map_err(anyhow::Error::from)
}

fn size_of(calib: &StereoCalibration, given: Option<(u32, u32)>, what: &str) -> Result<(u32, u32)> {
    match (calib.size, given) {
        (Some(file), Some(other)) if file != other => bail!(
            "{}: the calibration is for {}×{} images, but {what} is {}×{}",
            calib.source.display(),
            file.0,
            file.1,
            other.0,
            other.1
        ),
        (Some(s), _) | (None, Some(s)) => Ok(s),
        (None, None) => {
            bail!("{}: the file gives no image size: pass --size WxH", calib.source.display())
        }
    }
}

pub fn calib(command: CalibCommand) -> Result<()> {
    let CalibCommand::Show(args) = command;
    check_alpha(args.alpha)?;
    let calib = load(&args.file)?;
    let size = size_of(&calib, args.size, "--size")?;
    let rect = rectification_of(&calib, size, args.alpha)?;
    if let Some(dir) = &args.maps {
        write_exact_maps(&calib, &rect, size, dir)?;
    }
    if args.json {
        println!("{}", json(&rect));
    } else {
        print!("{}", describe(&calib, &rect, args.alpha));
    }
    Ok(())
}

fn write_exact_maps(calib: &StereoCalibration, rect: &Rectification, size: (u32, u32), dir: &Path) -> Result<()> {
    std::fs::create_dir_all(dir).with_context(|| format!("{}: cannot create the folder", dir.display()))?;
    let (w, h) = (size.0 as usize, size.1 as usize);
    for (side, camera, r, p) in
        [("left", &calib.left, &rect.r_left, &rect.p_left), ("right", &calib.right, &rect.r_right, &rect.p_right)]
    {
        let (mut xs, mut ys) = (Vec::with_capacity(w * h), Vec::with_capacity(w * h));
        for y in 0..h {
            for x in 0..w {
                let (sx, sy) = RectifyMap::exact(camera, r, p, x as f64, y as f64);
                xs.push(sx as f32);
                ys.push(sy as f32);
            }
        }
        for (axis, data) in [("x", &xs), ("y", &ys)] {
            let path = dir.join(format!("{side}_map_{axis}.pfm"));
            bdis_core::formats::pfm::write(&path, w, h, 1, data).with_context(|| format!("{}", path.display()))?;
        }
    }
    Ok(())
}

fn json(rect: &Rectification) -> String {
    let rows = |m: &[f64], cols: usize| -> serde_json::Value {
        serde_json::Value::Array(m.chunks(cols).map(|r| serde_json::json!(r)).collect())
    };
    let row_major = |m: &dyn Fn(usize, usize) -> f64, r: usize, c: usize| -> Vec<f64> {
        (0..r).flat_map(|i| (0..c).map(move |j| (i, j))).map(|(i, j)| m(i, j)).collect()
    };
    let value = serde_json::json!({
        "R1": rows(&row_major(&|i, j| rect.r_left[(i, j)], 3, 3), 3),
        "R2": rows(&row_major(&|i, j| rect.r_right[(i, j)], 3, 3), 3),
        "P1": rows(&row_major(&|i, j| rect.p_left[(i, j)], 3, 4), 4),
        "P2": rows(&row_major(&|i, j| rect.p_right[(i, j)], 3, 4), 4),
        "Q": rows(&row_major(&|i, j| rect.q[(i, j)], 4, 4), 4),
        "vertical": rect.vertical,
        "size": [rect.size.0, rect.size.1],
        "camera": rect.camera(),
    });
    value.to_string()
}

fn describe(calib: &StereoCalibration, rect: &Rectification, alpha: Option<f64>) -> String {
    let mut s = String::new();
    let layout = calib.layout_name();
    let _ = writeln!(s, "{}: {layout}", calib.source.display());
    for (name, cam) in [("left ", &calib.left), ("right", &calib.right)] {
        let k = &cam.k;
        let d = &cam.distortion;
        let model = if d[5..].iter().any(|v| *v != 0.0) { "rational, 8 coefficients" } else { "radial–tangential" };
        let _ = writeln!(
            s,
            "  {name} camera: fx {:.3} fy {:.3} cx {:.3} cy {:.3} skew {:.3}; distortion ({model}) k1 {:.6} k2 {:.6} p1 {:.6} p2 {:.6} k3 {:.6} k4 {:.6} k5 {:.6} k6 {:.6}",
            k[(0, 0)],
            k[(1, 1)],
            k[(0, 2)],
            k[(1, 2)],
            k[(0, 1)],
            d[0],
            d[1],
            d[2],
            d[3],
            d[4],
            d[5],
            d[6],
            d[7]
        );
    }
    let angle = nalgebra::Rotation3::from_matrix_unchecked(calib.rotation).angle().to_degrees();
    let t = &calib.translation;
    let _ = writeln!(
        s,
        "  right camera from left: rotation {angle:.4}°, translation ({:.6}, {:.6}, {:.6}); baseline {:.6} in the unit of T (millimetres for endoscopes, metres for KITTI-like rigs)",
        t.x,
        t.y,
        t.z,
        calib.baseline()
    );
    let alpha_text = alpha.map_or("unset (mean focal length)".to_string(), |a| format!("{a}"));
    let _ = writeln!(s, "  image size {}×{}; alpha {alpha_text}", rect.size.0, rect.size.1);
    match rect.camera() {
        Some(c) => {
            let _ = writeln!(
                s,
                "  rectified camera: fx {:.3} fy {:.3} cx {:.3} cy {:.3}; bf {:.6} (focal × baseline, rows aligned, zero disparity at infinity)",
                c.fx, c.fy, c.cx, c.cy, c.bf
            );
        }
        None => {
            let _ = writeln!(
                s,
                "  rectified camera: none the tracker can use — the baseline is vertical; rotate both images by 90° (or mount the rig level) first"
            );
        }
    }
    s
}

/// `bdis-slam rectify`: every pair of a raw sequence, rectified; `times.txt` and the rectified `settings.yaml`.
pub fn rectify(args: RectifyArgs) -> Result<()> {
    let done = rectify_sequence(&args.settings, &args.sequence, &args.out, args.alpha)?;
    let c = &done.camera;
    println!(
        "{}: {} rectified pairs of {}×{} (fx {:.2}, cx {:.2}, cy {:.2}, bf {:.4}) and settings.yaml",
        args.out.display(),
        done.pairs,
        c.width,
        c.height,
        c.fx,
        c.cx,
        c.cy,
        c.bf
    );
    Ok(())
}

/// What [`rectify_sequence`] wrote.
#[derive(Debug)]
pub struct Rectified {
    pub pairs: usize,
    pub camera: bdis_core::calib::RectifiedCamera,
    pub settings: PathBuf,
}

/// The rectified camera's settings for a raw video that acquisition rectifies as it reads, written to
/// `out`; the rectified camera.
pub fn rectified_settings_for_video(
    calibration: &Path,
    video: &bdis_source::VideoSpec,
    out: &Path,
) -> Result<bdis_core::calib::RectifiedCamera> {
    let calib = load(calibration)?;
    let source = bdis_source::VideoSource::open(video)?;
    let raw_size = (source.width, source.height);
    let size = size_of(&calib, Some(raw_size), &format!("{} (its frames)", video.left_file().display()))?;
    write_rectified_settings(&calib, size, out)
}

/// Rectifies `calib` for raw images of `size` and writes the rectified camera's settings to `out`.
fn write_rectified_settings(
    calib: &StereoCalibration,
    size: (u32, u32),
    out: &Path,
) -> Result<bdis_core::calib::RectifiedCamera> {
    let rect = rectification_of(calib, size, None)?;
    let Some(camera) = rect.camera() else {
        bail!("{}: the baseline is vertical: the tracker needs a horizontal rig", calib.source.display());
    };
    write_settings(out, calib, &camera)?;
    Ok(camera)
}

/// The rectified camera's settings for a live source rectified in acquisition, written to `out`. The raw size
/// is the calibration's own, or the replayed folder's for an emulated device (a real device is not opened
/// here: it has one user, acquisition).
pub fn rectified_settings_for_live(
    calibration: &Path,
    live: &bdis_source::LiveSpec,
    out: &Path,
) -> Result<bdis_core::calib::RectifiedCamera> {
    let calib = load(calibration)?;
    let views = match &live.backend {
        bdis_source::live::Backend::Emulated { sequence, .. } => {
            let folder = bdis_source::Sequence::open(sequence)?;
            Some((folder.width, folder.height))
        }
        bdis_source::live::Backend::V4l2 { .. } => None,
    };
    let size = size_of(&calib, views, &format!("`{}` (its views)", live.text))
        .with_context(|| "a live device's image size comes from the calibration (its width and height)")?;
    write_rectified_settings(&calib, size, out)
}

/// Whether `path` is a raw stereo calibration (`M1 … T`, or ORB-SLAM2's `LEFT`/`RIGHT` blocks), i.e. the
/// images it goes with need rectifying first. A file that does not parse is not one (its reader says why).
pub fn is_raw_calibration(path: &Path) -> bool {
    StereoCalibration::is_calibration(path)
}

/// Rectifies every pair of `sequence` with the calibration `settings` into `out` (`left/`, `right/`,
/// `times.txt`, `settings.yaml`), with a progress bar on a terminal. Pairs written before an error stay, with
/// their times.
pub fn rectify_sequence(settings: &Path, sequence: &Path, out: &Path, alpha: Option<f64>) -> Result<Rectified> {
    check_alpha(alpha)?;
    let calib = load(settings)?;
    let sequence_files = bdis_source::Sequence::open(sequence).map_err(anyhow::Error::from)?;
    if sequence_files.video.is_some() {
        // Rectification inside acquisition (straight into the loaned frame) is what a video needs; until then,
        // ffmpeg writes the pairs: ffmpeg -i FILE -vf crop=iw:ih/2:0:0 left/%d.png (and :0:ih/2 for right/).
        bail!(
            "{}: rectifying a video is not supported yet: write its frames as left/ and right/ PNGs (ffmpeg), then rectify those",
            sequence.display()
        );
    }
    let raw_size = (sequence_files.width, sequence_files.height);
    let size = size_of(&calib, Some(raw_size), &format!("{} (its images)", sequence.display()))?;
    let rect = rectification_of(&calib, size, alpha)?;
    let Some(camera) = rect.camera() else {
        bail!("{}: the baseline is vertical: the tracker needs a horizontal rig", settings.display());
    };
    let maps = calib.maps(&rect, raw_size);
    for side in ["left", "right"] {
        let dir = out.join(side);
        std::fs::create_dir_all(&dir).with_context(|| format!("{}: cannot create the folder", dir.display()))?;
    }
    let settings_out = out.join("settings.yaml");
    write_settings(&settings_out, &calib, &camera)?;
    let bar = bdis_slam::progress::bar(
        sequence_files.frames.len() as u64,
        "rectifying {bar:40} {pos}/{len} pairs ({eta} left)",
    );
    let (w, h) = (rect.size.0 as usize, rect.size.1 as usize);
    let mut rectified = vec![0u8; w * h * 3];
    let mut times = String::new();
    let mut result = Ok(());
    for frame in &sequence_files.frames {
        let mut step = || -> Result<()> {
            for (raw_path, map, side) in [(&frame.left, &maps[0], "left"), (&frame.right, &maps[1], "right")] {
                let raw = image::open(raw_path)
                    .with_context(|| format!("{}: cannot decode the image", raw_path.display()))?
                    .to_rgb8();
                if (raw.width(), raw.height()) != raw_size {
                    bail!(
                        "{}: {}×{} image in a sequence of {}×{}",
                        raw_path.display(),
                        raw.width(),
                        raw.height(),
                        raw_size.0,
                        raw_size.1
                    );
                }
                map.remap(raw.as_raw(), 3, &mut rectified);
                let name = raw_path.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
                let path = out.join(side).join(format!("{name}.png"));
                image::save_buffer(&path, &rectified, w as u32, h as u32, image::ExtendedColorType::Rgb8)
                    .with_context(|| format!("{}: cannot write", path.display()))?;
            }
            Ok(())
        };
        if let Err(e) = step() {
            result = Err(e);
            break;
        }
        if let Some(t) = frame.t_source_s {
            let _ = writeln!(times, "{t:.9}");
        }
        bar.inc(1);
    }
    bar.finish_and_clear();
    // The pairs written so far stay usable, with their times, even when a later one failed.
    if !times.is_empty() {
        let path = out.join("times.txt");
        std::fs::write(&path, &times).with_context(|| format!("{}: cannot write", path.display()))?;
    }
    result?;
    Ok(Rectified { pairs: sequence_files.frames.len(), camera, settings: settings_out })
}

pub fn write_settings(
    path: &Path,
    calib: &StereoCalibration,
    camera: &bdis_core::calib::RectifiedCamera,
) -> Result<()> {
    // The tracking settings come from the calibration file where it has them (ORB-SLAM2 settings do), else
    // ORB-SLAM2's defaults; a malformed one is an error, not a silent default. Only YAML calibrations can
    // carry them (the data sets' INI, JSON and text layouts hold the cameras alone).
    let raw = match bdis_rectify::formats::Layout::of(&calib.source) {
        bdis_rectify::formats::Layout::OpenCvYaml => {
            Some(bdis_core::settings::RawSettings::load(&calib.source).map_err(anyhow::Error::from)?)
        }
        _ => None,
    };
    let number = |key: &str, default: f64| -> Result<f64> {
        let Some(raw) = &raw else { return Ok(default) };
        Ok(raw.number(key).map_err(anyhow::Error::from)?.map_or(default, |(v, _)| v))
    };
    let mut text = format!(
        "%YAML:1.0\n# Rectified by bdis-slam from {}.\n\
Camera.fx: {}\nCamera.fy: {}\nCamera.cx: {}\nCamera.cy: {}\nCamera.width: {}\nCamera.height: {}\nCamera.fps: {}\nCamera.bf: {}\nCamera.RGB: 1\nThDepth: {}\n\
ORBextractor.nFeatures: {}\nORBextractor.scaleFactor: {}\nORBextractor.nLevels: {}\nORBextractor.iniThFAST: {}\nORBextractor.minThFAST: {}\n",
        calib.source.display(),
        camera.fx,
        camera.fy,
        camera.cx,
        camera.cy,
        camera.width,
        camera.height,
        number("Camera.fps", 30.0)?,
        camera.bf,
        number("ThDepth", 20.0)?,
        number("ORBextractor.nFeatures", 1000.0)?,
        number("ORBextractor.scaleFactor", 1.2)?,
        number("ORBextractor.nLevels", 8.0)?,
        number("ORBextractor.iniThFAST", 20.0)?,
        number("ORBextractor.minThFAST", 7.0)?,
    );
    // The dense stereo's and the map's settings go along as written (the settings reader checks them).
    for (key, entry) in raw.iter().flat_map(|r| &r.entries) {
        if (key.starts_with("BDISparam.") || key.starts_with("Viewer3D."))
            && let bdis_core::settings::RawValue::Scalar(value) = &entry.value
        {
            let _ = writeln!(text, "{key}: {value}");
        }
    }
    std::fs::write(path, text).with_context(|| format!("{}: cannot write", path.display()))
}
