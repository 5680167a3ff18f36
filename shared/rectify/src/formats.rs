//! Readers for the stereo calibration layouts surgical data sets ship, beside the OpenCV FileStorage YAML of
//! [`crate::calib`]:
//! - StereoMIS `StereoCalibration.ini`: `[StereoLeft]` and `[StereoRight]` with `res_x res_y fc_x fc_y cc_x
//!   cc_y kc_0 … kc_7` (OpenCV's order, the rational model), and the right camera's pose `R_0 … R_8` (row-major)
//!   and `T_0 … T_2` under `[StereoRight]`;
//! - StereoMIS `camcal.json`: `data.intrinsics[0|1]` with `f` [fx, fy], `c` [cx, cy], `k` (distortion),
//!   `data.extrinsics` with `om` (a Rodrigues rotation vector) and `T`, and `data.width`/`data.height`;
//! - SERV-CT rectified calibrations (JSON, OpenCV matrices `P1`, `P2`, optionally `Q`): already rectified;
//! - Hamlyn: `Left_Camera_Calibration_Intrinsic.txt` and `Right_…` (three rows of K, then a row of distortion)
//!   and `camera_extrinsic.txt` (three rows of R then a row of T, or three rows of [R | T]), read from their
//!   folder or from any one of the three files.
//!
//! Every layout gives the same [`StereoCalibration`], with OpenCV's conventions (`X_right = R · X_left + T`).

use std::path::{Path, PathBuf};

use bdis_core::settings::{RawSettings, SettingsError};
use nalgebra::{Matrix3, Matrix3x4, Rotation3, Vector3};

use crate::bouguet::{Rectification, rectification_is_usable, stereo_rectify};
use crate::calib::{CalibrationError, CameraModel, GivenRectification, StereoCalibration};
use crate::remap::RectifyMap;

/// The Hamlyn layout's file names.
pub const HAMLYN_FILES: [&str; 3] =
    ["Left_Camera_Calibration_Intrinsic.txt", "Right_Camera_Calibration_Intrinsic.txt", "camera_extrinsic.txt"];

/// Which reader a calibration path needs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Layout {
    /// OpenCV FileStorage YAML (SCARED `M1 … T`, ORB-SLAM2 `LEFT.*`/`RIGHT.*`).
    OpenCvYaml,
    StereoMisIni,
    /// StereoMIS `camcal.json` or a SERV-CT rectified calibration, told apart by their keys.
    Json,
    Hamlyn,
}

impl Layout {
    /// The layout of `path` by its name (a folder or a `.txt` is Hamlyn's).
    pub fn of(path: &Path) -> Self {
        let ext = path.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase);
        match ext.as_deref() {
            _ if path.is_dir() => Layout::Hamlyn,
            Some("ini") => Layout::StereoMisIni,
            Some("json") => Layout::Json,
            Some("txt") => Layout::Hamlyn,
            _ => Layout::OpenCvYaml,
        }
    }
}

fn value_error(path: &Path, line: Option<usize>, key: &str, why: impl Into<String>) -> CalibrationError {
    SettingsError::value(path, line, key, why).into()
}

/// The checks every layout's camera gets: positive focal lengths, finite numbers.
fn checked_camera(
    path: &Path,
    line: Option<usize>,
    key: &str,
    k: Matrix3<f64>,
    distortion: &[f64],
) -> Result<CameraModel, CalibrationError> {
    let (fx, fy) = (k[(0, 0)], k[(1, 1)]);
    if !(fx > 0.0 && fy > 0.0) {
        return Err(value_error(path, line, key, format!("focal lengths must be > 0, found fx {fx}, fy {fy}")));
    }
    if k.iter().chain(distortion).any(|v| !v.is_finite()) {
        return Err(value_error(path, line, key, "a value is not a finite number"));
    }
    if distortion.len() > 8 {
        let why = format!("{} distortion coefficients; at most 8 (k1 k2 p1 p2 k3 k4 k5 k6)", distortion.len());
        return Err(value_error(path, line, key, why));
    }
    let mut d = [0.0; 8];
    d[..distortion.len()].copy_from_slice(distortion);
    Ok(CameraModel { k, distortion: d })
}

fn checked_rotation(path: &Path, line: Option<usize>, key: &str, r: Matrix3<f64>) -> Result<(), CalibrationError> {
    let off = (r.transpose() * r - Matrix3::identity()).abs().max();
    if !off.is_finite() || off > 1e-6 || (r.determinant() - 1.0).abs() > 1e-6 {
        let why = format!("not a rotation (RᵀR differs from I by {off:.2e}, det {:.6})", r.determinant());
        return Err(value_error(path, line, key, why));
    }
    Ok(())
}

fn checked_translation(path: &Path, line: Option<usize>, key: &str, t: Vector3<f64>) -> Result<(), CalibrationError> {
    if !t.iter().all(|v| v.is_finite()) || t.norm() <= 0.0 {
        return Err(value_error(path, line, key, "the baseline is zero (or not a number)"));
    }
    Ok(())
}

fn checked_size(path: &Path, line: Option<usize>, key: &str, w: f64, h: f64) -> Result<(u32, u32), CalibrationError> {
    let whole = |v: f64| v.fract() == 0.0 && v >= 1.0 && v <= f64::from(u32::MAX);
    if !(whole(w) && whole(h)) {
        return Err(value_error(path, line, key, format!("the image size must be whole numbers ≥ 1, found {w}×{h}")));
    }
    Ok((w as u32, h as u32))
}

fn intrinsic(fx: f64, fy: f64, cx: f64, cy: f64) -> Matrix3<f64> {
    Matrix3::new(fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0)
}

// ---------------------------------------------------------------------------------------------------------
// StereoMIS INI

/// One `key = value` of an INI section, with its line.
struct IniValue {
    text: String,
    line: usize,
}

struct Ini {
    path: PathBuf,
    sections: Vec<(String, Vec<(String, IniValue)>)>,
}

impl Ini {
    fn parse(path: &Path, text: &str) -> Result<Self, CalibrationError> {
        let mut sections: Vec<(String, Vec<(String, IniValue)>)> = Vec::new();
        for (i, raw) in text.lines().enumerate() {
            let line = raw.trim();
            if line.is_empty() || line.starts_with(';') || line.starts_with('#') {
                continue;
            }
            if let Some(name) = line.strip_prefix('[').and_then(|l| l.strip_suffix(']')) {
                sections.push((name.trim().to_string(), Vec::new()));
                continue;
            }
            let Some((key, value)) = line.split_once('=') else {
                return Err(value_error(path, Some(i + 1), line, "expected `key = value` or `[section]`"));
            };
            let Some((_, entries)) = sections.last_mut() else {
                return Err(value_error(path, Some(i + 1), key.trim(), "a value before any [section]"));
            };
            entries.push((key.trim().to_string(), IniValue { text: value.trim().to_string(), line: i + 1 }));
        }
        Ok(Self { path: path.to_path_buf(), sections })
    }

    fn section(&self, name: &str) -> Result<&[(String, IniValue)], CalibrationError> {
        self.sections
            .iter()
            .find(|(n, _)| n == name)
            .map(|(_, e)| e.as_slice())
            .ok_or_else(|| CalibrationError::Format { path: self.path.clone(), why: format!("no [{name}] section") })
    }

    /// The number under `key` in `section`; `default` when absent (None: required).
    fn number(&self, section: &str, key: &str, default: Option<f64>) -> Result<(f64, Option<usize>), CalibrationError> {
        let entries = self.section(section)?;
        match entries.iter().find(|(k, _)| k == key) {
            Some((_, v)) => v.text.parse::<f64>().map(|x| (x, Some(v.line))).map_err(|_| {
                value_error(
                    &self.path,
                    Some(v.line),
                    &format!("[{section}] {key}"),
                    format!("`{}` is not a number", v.text),
                )
            }),
            None => default.map(|d| (d, None)).ok_or_else(|| CalibrationError::Format {
                path: self.path.clone(),
                why: format!("missing `{key}` in [{section}]"),
            }),
        }
    }
}

/// Parses a StereoMIS `StereoCalibration.ini` (the text of the file at `path`).
pub fn parse_stereomis_ini(text: &str, path: &Path) -> Result<StereoCalibration, CalibrationError> {
    let ini = Ini::parse(path, text)?;
    let camera = |section: &str| -> Result<(CameraModel, (u32, u32)), CalibrationError> {
        let n = |key: &str| ini.number(section, key, None);
        let (fx, line) = n("fc_x")?;
        let k = intrinsic(fx, n("fc_y")?.0, n("cc_x")?.0, n("cc_y")?.0);
        let distortion: Vec<f64> = (0..8)
            .map(|i| ini.number(section, &format!("kc_{i}"), Some(0.0)).map(|v| v.0))
            .collect::<Result<_, _>>()?;
        let model = checked_camera(path, line, &format!("[{section}] fc_x"), k, &distortion)?;
        let (w, wl) = n("res_x")?;
        let size = checked_size(path, wl, &format!("[{section}] res_x"), w, n("res_y")?.0)?;
        Ok((model, size))
    };
    let (left, size) = camera("StereoLeft")?;
    let (right, right_size) = camera("StereoRight")?;
    if right_size != size {
        let why = format!("{}×{}, the left camera's is {}×{}", right_size.0, right_size.1, size.0, size.1);
        return Err(value_error(path, ini.number("StereoRight", "res_x", None)?.1, "[StereoRight] res_x", why));
    }
    let r: Vec<f64> =
        (0..9).map(|i| ini.number("StereoRight", &format!("R_{i}"), None).map(|v| v.0)).collect::<Result<_, _>>()?;
    let rotation = Matrix3::from_row_slice(&r);
    let r_line = ini.number("StereoRight", "R_0", None)?.1;
    checked_rotation(path, r_line, "[StereoRight] R_0…R_8", rotation)?;
    let t: Vec<f64> =
        (0..3).map(|i| ini.number("StereoRight", &format!("T_{i}"), None).map(|v| v.0)).collect::<Result<_, _>>()?;
    let translation = Vector3::from_column_slice(&t);
    checked_translation(path, ini.number("StereoRight", "T_0", None)?.1, "[StereoRight] T_0…T_2", translation)?;
    Ok(StereoCalibration {
        source: path.to_path_buf(),
        left,
        right,
        rotation,
        translation,
        size: Some(size),
        given: None,
    })
}

// ---------------------------------------------------------------------------------------------------------
// JSON: StereoMIS camcal.json, SERV-CT rectified

/// The numbers of a JSON array (or of an OpenCV matrix object's `data`), named by `key` for errors.
fn json_numbers(path: &Path, key: &str, value: Option<&serde_json::Value>) -> Result<Vec<f64>, CalibrationError> {
    let value =
        value.ok_or_else(|| CalibrationError::Format { path: path.to_path_buf(), why: format!("missing `{key}`") })?;
    let array = value.get("data").unwrap_or(value).as_array();
    let numbers: Option<Vec<f64>> = array.map(|a| a.iter().map(serde_json::Value::as_f64).collect()).unwrap_or(None);
    numbers.ok_or_else(|| value_error(path, None, key, "expected an array of numbers"))
}

fn json_count(path: &Path, key: &str, v: Vec<f64>, counts: &[usize]) -> Result<Vec<f64>, CalibrationError> {
    if counts.contains(&v.len()) {
        Ok(v)
    } else {
        let expected: Vec<String> = counts.iter().map(ToString::to_string).collect();
        Err(value_error(path, None, key, format!("expected {} numbers, found {}", expected.join(" or "), v.len())))
    }
}

/// Parses a StereoMIS `camcal.json` or a SERV-CT rectified calibration (the text of the file at `path`).
pub fn parse_json(text: &str, path: &Path) -> Result<StereoCalibration, CalibrationError> {
    let root: serde_json::Value = serde_json::from_str(text)
        .map_err(|e| value_error(path, Some(e.line()), "JSON", format!("not valid JSON: {e}")))?;
    if root.get("P1").is_some() || root.get("P2").is_some() {
        return serv_ct(path, &root);
    }
    let data = root.get("data").unwrap_or(&root);
    let Some(intrinsics) = data.get("intrinsics").and_then(|i| i.as_array()) else {
        return Err(CalibrationError::Format {
            path: path.to_path_buf(),
            why: "expected `data.intrinsics` (StereoMIS camcal.json) or `P1`/`P2` (a SERV-CT rectified calibration)"
                .into(),
        });
    };
    if intrinsics.len() != 2 {
        let why = format!("expected the left and the right camera, found {}", intrinsics.len());
        return Err(value_error(path, None, "data.intrinsics", why));
    }
    let camera = |i: usize| -> Result<CameraModel, CalibrationError> {
        let key = |f: &str| format!("data.intrinsics[{i}].{f}");
        let cam = &intrinsics[i];
        let f = json_count(path, &key("f"), json_numbers(path, &key("f"), cam.get("f"))?, &[2])?;
        let c = json_count(path, &key("c"), json_numbers(path, &key("c"), cam.get("c"))?, &[2])?;
        let k = match cam.get("k") {
            Some(k) => json_count(path, &key("k"), json_numbers(path, &key("k"), Some(k))?, &[0, 4, 5, 8])?,
            None => Vec::new(),
        };
        checked_camera(path, None, &key("f"), intrinsic(f[0], f[1], c[0], c[1]), &k)
    };
    let (left, right) = (camera(0)?, camera(1)?);
    let extrinsics = data.get("extrinsics");
    let om = json_count(
        path,
        "data.extrinsics.om",
        json_numbers(path, "data.extrinsics.om", extrinsics.and_then(|e| e.get("om")))?,
        &[3],
    )?;
    let rotation = Rotation3::from_scaled_axis(Vector3::from_column_slice(&om)).into_inner();
    checked_rotation(path, None, "data.extrinsics.om", rotation)?;
    let t = json_count(
        path,
        "data.extrinsics.T",
        json_numbers(path, "data.extrinsics.T", extrinsics.and_then(|e| e.get("T")))?,
        &[3],
    )?;
    let translation = Vector3::from_column_slice(&t);
    checked_translation(path, None, "data.extrinsics.T", translation)?;
    let size = match (data.get("width").and_then(|v| v.as_f64()), data.get("height").and_then(|v| v.as_f64())) {
        (Some(w), Some(h)) => Some(checked_size(path, None, "data.width", w, h)?),
        _ => None,
    };
    Ok(StereoCalibration { source: path.to_path_buf(), left, right, rotation, translation, size, given: None })
}

/// A SERV-CT rectified calibration: the cameras are already rectified (no distortion, the same orientation),
/// so the projections are the rectification, used as given.
fn serv_ct(path: &Path, root: &serde_json::Value) -> Result<StereoCalibration, CalibrationError> {
    let p = |key: &str| -> Result<Matrix3x4<f64>, CalibrationError> {
        let v = json_count(path, key, json_numbers(path, key, root.get(key))?, &[12])?;
        Ok(Matrix3x4::from_row_slice(&v))
    };
    let (p_left, p_right) = (p("P1")?, p("P2")?);
    let camera = |p: &Matrix3x4<f64>, key: &str| {
        checked_camera(path, None, key, intrinsic(p[(0, 0)], p[(1, 1)], p[(0, 2)], p[(1, 2)]), &[])
    };
    let (left, right) = (camera(&p_left, "P1")?, camera(&p_right, "P2")?);
    // P2 = K [I | (tx, ty, 0)] for a rectified pair: tx from the horizontal term, ty from the vertical.
    let t_rect = Vector3::new(p_right[(0, 3)] / p_right[(0, 0)], p_right[(1, 3)] / p_right[(1, 1)], 0.0);
    checked_translation(path, None, "P2", t_rect)?;
    let size = match (root.get("width").and_then(|v| v.as_f64()), root.get("height").and_then(|v| v.as_f64())) {
        (Some(w), Some(h)) => Some(checked_size(path, None, "width", w, h)?),
        _ => None,
    };
    let identity = Matrix3::identity();
    Ok(StereoCalibration {
        source: path.to_path_buf(),
        left,
        right,
        rotation: identity,
        translation: t_rect,
        size,
        given: Some(GivenRectification { r_left: identity, r_right: identity, p_left, p_right }),
    })
}

// ---------------------------------------------------------------------------------------------------------
// Hamlyn text files

/// The numbers of each non-empty line (whitespace or commas between them), with the line numbers.
fn text_rows(path: &Path, text: &str) -> Result<Vec<(usize, Vec<f64>)>, CalibrationError> {
    let mut rows = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let fields: Vec<&str> = line.split(|c: char| c.is_whitespace() || c == ',').filter(|f| !f.is_empty()).collect();
        if fields.is_empty() {
            continue;
        }
        let numbers: Result<Vec<f64>, _> = fields.iter().map(|f| f.parse::<f64>()).collect();
        let numbers = numbers
            .map_err(|_| value_error(path, Some(i + 1), "row", format!("`{}` is not a row of numbers", line.trim())))?;
        rows.push((i + 1, numbers));
    }
    Ok(rows)
}

fn hamlyn_camera(path: &Path, text: &str) -> Result<CameraModel, CalibrationError> {
    let rows = text_rows(path, text)?;
    if rows.len() < 3 || rows[..3].iter().any(|(_, r)| r.len() != 3) {
        return Err(CalibrationError::Format {
            path: path.to_path_buf(),
            why: "expected three rows of the intrinsic matrix K (3 numbers each), then a row of distortion".into(),
        });
    }
    let k = Matrix3::from_row_slice(&rows[..3].iter().flat_map(|(_, r)| r.iter().copied()).collect::<Vec<_>>());
    if k[(1, 0)] != 0.0 || k[(2, 0)] != 0.0 || k[(2, 1)] != 0.0 || k[(2, 2)] != 1.0 {
        let why = "not an intrinsic matrix: the lower rows must be [0 fy cy; 0 0 1]";
        return Err(value_error(path, Some(rows[1].0), "K", why));
    }
    let distortion = rows.get(3).map(|(_, r)| r.clone()).unwrap_or_default();
    checked_camera(path, Some(rows[0].0), "K", k, &distortion)
}

/// Parses a Hamlyn calibration from the texts of its three files ([`HAMLYN_FILES`], in that order) in `dir`.
pub fn parse_hamlyn(dir: &Path, texts: [&str; 3]) -> Result<StereoCalibration, CalibrationError> {
    let [left_file, right_file, extrinsic_file] = HAMLYN_FILES.map(|f| dir.join(f));
    let (left, right) = (hamlyn_camera(&left_file, texts[0])?, hamlyn_camera(&right_file, texts[1])?);
    let rows = text_rows(&extrinsic_file, texts[2])?;
    let shape: Vec<usize> = rows.iter().map(|(_, r)| r.len()).collect();
    let (r, t): (Vec<f64>, Vec<f64>) = match shape.as_slice() {
        [4, 4, 4, ..] => (
            rows[..3].iter().flat_map(|(_, r)| r[..3].to_vec()).collect(),
            rows[..3].iter().map(|(_, r)| r[3]).collect(),
        ),
        [3, 3, 3, 3, ..] => (rows[..3].iter().flat_map(|(_, r)| r.clone()).collect(), rows[3].1.clone()),
        _ => {
            return Err(CalibrationError::Format {
                path: extrinsic_file,
                why: "expected three rows of R then a row of T (3 numbers each), or three rows of [R | T] (4 each)"
                    .into(),
            });
        }
    };
    let rotation = Matrix3::from_row_slice(&r);
    checked_rotation(&extrinsic_file, Some(rows[0].0), "R", rotation)?;
    let translation = Vector3::from_column_slice(&t);
    checked_translation(&extrinsic_file, Some(rows[0].0), "T", translation)?;
    Ok(StereoCalibration { source: dir.to_path_buf(), left, right, rotation, translation, size: None, given: None })
}

fn hamlyn(path: &Path) -> Result<StereoCalibration, CalibrationError> {
    let dir = if path.is_dir() { path } else { path.parent().unwrap_or(Path::new(".")) };
    let mut texts: [String; 3] = Default::default();
    for (text, name) in texts.iter_mut().zip(HAMLYN_FILES) {
        let file = dir.join(name);
        if !file.is_file() {
            return Err(CalibrationError::Format {
                path: file,
                why: format!("missing: a Hamlyn calibration is the three files {}", HAMLYN_FILES.join(", ")),
            });
        }
        *text = std::fs::read_to_string(&file).map_err(|e| SettingsError::Io { path: file.clone(), detail: e })?;
    }
    parse_hamlyn(dir, [&texts[0], &texts[1], &texts[2]])
}

/// Reads a calibration of a layout other than OpenCV YAML.
pub fn load_other(path: &Path, layout: Layout) -> Result<StereoCalibration, CalibrationError> {
    let read = || std::fs::read_to_string(path).map_err(|e| SettingsError::Io { path: path.to_path_buf(), detail: e });
    match layout {
        Layout::StereoMisIni => parse_stereomis_ini(&read()?, path),
        Layout::Json => parse_json(&read()?, path),
        Layout::Hamlyn => hamlyn(path),
        Layout::OpenCvYaml => {
            Err(CalibrationError::Format { path: path.to_path_buf(), why: "an OpenCV YAML file".into() })
        }
    }
}

impl StereoCalibration {
    /// Reads a stereo calibration of any layout: this module's, or OpenCV YAML ([`crate::calib`]).
    pub fn load(path: &Path) -> Result<Self, CalibrationError> {
        match Layout::of(path) {
            Layout::OpenCvYaml => Self::from_raw(&RawSettings::load(path)?),
            other => load_other(path, other),
        }
    }

    /// Whether `path` is a raw stereo calibration (any layout this crate reads), rather than the settings
    /// of an already rectified camera: by its name, and for YAML by its keys.
    pub fn is_calibration(path: &Path) -> bool {
        match Layout::of(path) {
            Layout::OpenCvYaml => RawSettings::load(path)
                .is_ok_and(|raw| ["M1", "M2", "LEFT.K", "RIGHT.K"].iter().any(|k| raw.entries.contains_key(*k))),
            _ => path.exists(),
        }
    }

    /// The rectification of this calibration at `size`: the one the file gives, else Bouguet's (`alpha` as
    /// OpenCV's; `None` keeps the cameras' mean focal length). An error when it is not usable (non-finite or
    /// zero focal length or baseline).
    pub fn rectification(&self, size: (u32, u32), alpha: Option<f64>) -> Result<Rectification, CalibrationError> {
        let rect = match &self.given {
            Some(given) => Rectification::given(given, size),
            None => stereo_rectify(self, size, alpha),
        };
        if !rectification_is_usable(&rect) {
            return Err(CalibrationError::Unusable { path: self.source.clone() });
        }
        Ok(rect)
    }

    /// Both cameras' undistort–rectify maps into `rect`'s image, sampling raw images of `raw` size.
    pub fn maps(&self, rect: &Rectification, raw: (u32, u32)) -> [RectifyMap; 2] {
        let out = (rect.size.0 as usize, rect.size.1 as usize);
        let raw = (raw.0 as usize, raw.1 as usize);
        [
            RectifyMap::new(&self.left, &rect.r_left, &rect.p_left, out, raw),
            RectifyMap::new(&self.right, &rect.r_right, &rect.p_right, out, raw),
        ]
    }

    /// What the file is, for a person checking it: its layout, and whether it is rectified here.
    pub fn layout_name(&self) -> &'static str {
        match (Layout::of(&self.source), self.given.is_some()) {
            (Layout::OpenCvYaml, true) => {
                "ORB-SLAM2 settings with LEFT/RIGHT rectification blocks (the rectification is used as given)"
            }
            (Layout::OpenCvYaml, false) => {
                "OpenCV stereoCalibrate layout (M1 D1 M2 D2 R T, as SCARED): rectified here by Bouguet's method"
            }
            (Layout::StereoMisIni, _) => "StereoMIS StereoCalibration.ini: rectified here by Bouguet's method",
            (Layout::Json, true) => "SERV-CT rectified calibration (P1 P2): already rectified, used as given",
            (Layout::Json, false) => "StereoMIS camcal.json (Rodrigues om): rectified here by Bouguet's method",
            (Layout::Hamlyn, _) => "Hamlyn intrinsic and extrinsic text files: rectified here by Bouguet's method",
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ini_values_before_a_section_and_bad_numbers_are_named_by_line() {
        let p = Path::new("StereoCalibration.ini");
        let e = parse_stereomis_ini("fc_x = 1\n", p).unwrap_err().to_string();
        assert!(e.contains("StereoCalibration.ini:1") && e.contains("before any [section]"), "{e}");
        let e = parse_stereomis_ini("[StereoLeft]\nfc_x = one\n", p).unwrap_err().to_string();
        assert!(e.contains(":2") && e.contains("[StereoLeft] fc_x") && e.contains("not a number"), "{e}");
    }

    #[test]
    fn a_rodrigues_vector_is_the_rotation_about_its_axis_by_its_length() {
        let r = Rotation3::from_scaled_axis(Vector3::new(0.0, 0.0, std::f64::consts::FRAC_PI_2)).into_inner();
        let x = r * Vector3::x();
        assert!((x - Vector3::y()).norm() < 1e-12);
    }
}
