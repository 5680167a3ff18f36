//! Settings files: the ORB-SLAM2 / BDIS-SLAM OpenCV-FileStorage YAML (`%YAML:1.0`) and the project's own TOML.
//!
//! Both syntaxes are read into one flat table of `Family.key → value` entries (the TOML uses tables named like
//! the YAML prefixes: `[Camera] fx = 520.0`), and one typed extraction validates that table. So a setting has a
//! single name, a single default and a single check, whichever file it came from.
//!
//! Why a hand-written reader: OpenCV's YAML dialect (`%YAML:1.0`, `data:[...]` without a space, `!!opencv-matrix`)
//! is not YAML 1.2 and breaks the Rust YAML crates (see CRATES.md). We read the subset those files use and reject
//! everything else with the line number, so a typo such as `Camera.bf: 2055.77s` is an error, not a silent 0.

use std::collections::BTreeMap;
use std::fmt;
use std::path::{Path, PathBuf};

use crate::calib::{Distortion, StereoCamera};

/// Where an error points: a file, and the line when the syntax gives one.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Location {
    pub path: PathBuf,
    pub line: Option<usize>,
}

impl fmt::Display for Location {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.line {
            Some(line) => write!(f, "{}:{}", self.path.display(), line),
            None => write!(f, "{}", self.path.display()),
        }
    }
}

#[derive(Debug, thiserror::Error)]
pub enum SettingsError {
    #[error("{path}: cannot read settings: {source}")]
    Io { path: PathBuf, source: std::io::Error },
    #[error("{at}: {message}")]
    Syntax { at: Location, message: String },
    #[error("{path}: missing required key `{key}`")]
    Missing { path: PathBuf, key: &'static str },
    #[error("{at}: `{key}`: {message}")]
    Value { at: Location, key: String, message: String },
    #[error("{at}: unknown key `{key}` (a typo? known keys of this family: {known})")]
    Unknown { at: Location, key: String, known: String },
    #[error("{path}: unsupported settings format (expected .yaml, .yml or .toml)")]
    Format { path: PathBuf },
}

impl SettingsError {
    fn value(path: &Path, line: Option<usize>, key: &str, message: impl Into<String>) -> Self {
        Self::Value { at: Location { path: path.to_path_buf(), line }, key: key.to_string(), message: message.into() }
    }
}

/// One value of a settings file, as written.
#[derive(Debug, Clone, PartialEq)]
pub enum RawValue {
    /// A scalar as written (unquoted). Parsed to a number only when a typed field asks for one.
    Scalar(String),
    /// A quoted string.
    Text(String),
    /// An `!!opencv-matrix` block.
    Matrix { rows: usize, cols: usize, data: Vec<f64> },
}

#[derive(Debug, Clone, PartialEq)]
pub struct RawEntry {
    pub value: RawValue,
    pub line: Option<usize>,
}

/// The flat `Family.key → value` table of one settings file.
#[derive(Debug, Clone)]
pub struct RawSettings {
    pub path: PathBuf,
    pub entries: BTreeMap<String, RawEntry>,
}

fn syntax(path: &Path, line: usize, message: impl Into<String>) -> SettingsError {
    SettingsError::Syntax { at: Location { path: path.to_path_buf(), line: Some(line) }, message: message.into() }
}

/// Removes a trailing `# comment` that is outside quotes.
fn strip_comment(line: &str) -> &str {
    let mut in_quotes = false;
    for (i, c) in line.char_indices() {
        match c {
            '"' => in_quotes = !in_quotes,
            '#' if !in_quotes => return &line[..i],
            _ => {}
        }
    }
    line
}

fn unquote(s: &str) -> Option<&str> {
    let s = s.trim();
    if s.len() >= 2 && ((s.starts_with('"') && s.ends_with('"')) || (s.starts_with('\'') && s.ends_with('\''))) {
        Some(&s[1..s.len() - 1])
    } else {
        None
    }
}

/// Splits `key: value` (OpenCV also writes `data:[...]` without the space).
fn split_key_value(text: &str) -> Option<(&str, &str)> {
    let colon = text.find(':')?;
    let key = text[..colon].trim();
    if key.is_empty() || key.contains(char::is_whitespace) {
        return None;
    }
    Some((key, text[colon + 1..].trim()))
}

impl RawSettings {
    /// Reads a settings file, choosing the syntax by its extension (`.yaml`/`.yml` or `.toml`).
    pub fn load(path: &Path) -> Result<Self, SettingsError> {
        let text =
            std::fs::read_to_string(path).map_err(|source| SettingsError::Io { path: path.to_path_buf(), source })?;
        match path.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase).as_deref() {
            Some("yaml") | Some("yml") => Self::parse_opencv_yaml(&text, path),
            Some("toml") => Self::parse_toml(&text, path),
            _ => Err(SettingsError::Format { path: path.to_path_buf() }),
        }
    }

    /// Parses the OpenCV FileStorage YAML subset used by ORB-SLAM2 and BDIS-SLAM settings files.
    pub fn parse_opencv_yaml(text: &str, path: &Path) -> Result<Self, SettingsError> {
        let mut entries = BTreeMap::new();
        let lines: Vec<&str> = text.lines().collect();
        let mut i = 0;
        let mut seen_content = false;
        while i < lines.len() {
            let line_no = i + 1;
            let raw = lines[i];
            i += 1;
            let line = strip_comment(raw).trim_end();
            if line.trim().is_empty() {
                continue;
            }
            if !seen_content {
                seen_content = true;
                if line.trim().starts_with("%YAML") {
                    continue;
                }
                return Err(syntax(path, line_no, "not an OpenCV settings file: the first line must be `%YAML:1.0`"));
            }
            if line.trim() == "---" {
                continue;
            }
            if line.starts_with(char::is_whitespace) {
                return Err(syntax(path, line_no, format!("unexpected indented line `{}`", line.trim())));
            }
            let Some((key, value)) = split_key_value(line) else {
                return Err(syntax(path, line_no, format!("expected `key: value`, found `{}`", line.trim())));
            };
            let value = if value.starts_with("!!opencv-matrix") {
                let (matrix, next) = parse_matrix_block(&lines, i, path, key)?;
                i = next;
                matrix
            } else if value.is_empty() {
                return Err(syntax(path, line_no, format!("`{key}` has no value (nested maps are not supported)")));
            } else if value.starts_with('[') || value.starts_with('{') || value.starts_with('!') || value == "|" {
                return Err(syntax(path, line_no, format!("`{key}`: unsupported value `{value}`")));
            } else if let Some(text) = unquote(value) {
                RawValue::Text(text.to_string())
            } else {
                RawValue::Scalar(value.to_string())
            };
            if entries.insert(key.to_string(), RawEntry { value, line: Some(line_no) }).is_some() {
                return Err(syntax(path, line_no, format!("`{key}` is given twice")));
            }
        }
        if !seen_content {
            return Err(syntax(path, 1, "the file is empty"));
        }
        Ok(Self { path: path.to_path_buf(), entries })
    }

    /// Parses the project's TOML settings: tables named like the YAML families (`[Camera]`, `[ORBextractor]`,
    /// `[BDISparam]`, `[Viewer3D]`) and top-level keys (`ThDepth`).
    pub fn parse_toml(text: &str, path: &Path) -> Result<Self, SettingsError> {
        let table: toml::Table = text.parse().map_err(|e: toml::de::Error| {
            let line = e.span().map(|span| text[..span.start.min(text.len())].matches('\n').count() + 1);
            SettingsError::Syntax { at: Location { path: path.to_path_buf(), line }, message: e.message().to_string() }
        })?;
        let mut entries = BTreeMap::new();
        fn scalar(path: &Path, key: &str, v: &toml::Value) -> Result<RawValue, SettingsError> {
            Ok(match v {
                toml::Value::Integer(i) => RawValue::Scalar(i.to_string()),
                toml::Value::Float(f) => RawValue::Scalar(f.to_string()),
                toml::Value::Boolean(b) => RawValue::Scalar(if *b { "1".into() } else { "0".into() }),
                toml::Value::String(s) => RawValue::Text(s.clone()),
                _ => return Err(SettingsError::value(path, None, key, "expected a number, a boolean or a string")),
            })
        }
        for (family, value) in &table {
            match value {
                toml::Value::Table(inner) => {
                    for (name, v) in inner {
                        let key = format!("{family}.{name}");
                        let raw = scalar(path, &key, v)?;
                        entries.insert(key, RawEntry { value: raw, line: None });
                    }
                }
                v => {
                    entries.insert(family.clone(), RawEntry { value: scalar(path, family, v)?, line: None });
                }
            }
        }
        Ok(Self { path: path.to_path_buf(), entries })
    }

    fn number(&self, key: &str) -> Result<Option<(f64, Option<usize>)>, SettingsError> {
        let Some(entry) = self.entries.get(key) else { return Ok(None) };
        let text = match &entry.value {
            RawValue::Scalar(s) => s.as_str(),
            RawValue::Text(s) => {
                return Err(SettingsError::value(
                    &self.path,
                    entry.line,
                    key,
                    format!("expected a number, found the string \"{s}\""),
                ));
            }
            RawValue::Matrix { .. } => {
                return Err(SettingsError::value(&self.path, entry.line, key, "expected a number, found a matrix"));
            }
        };
        // Only plain decimal numbers: OpenCV refuses `2055.77s`, and so do we. `.nan`/`inf` spellings parse
        // here and are rejected by the finiteness check below with a clearer message.
        let parsed = match text {
            ".nan" | ".NaN" | ".NAN" | "nan" | "NaN" => f64::NAN,
            ".inf" | ".Inf" | "inf" | "+.inf" => f64::INFINITY,
            "-.inf" | "-.Inf" | "-inf" => f64::NEG_INFINITY,
            _ => text
                .parse::<f64>()
                .map_err(|_| SettingsError::value(&self.path, entry.line, key, format!("`{text}` is not a number")))?,
        };
        if !parsed.is_finite() {
            return Err(SettingsError::value(
                &self.path,
                entry.line,
                key,
                format!("must be a finite number, found `{text}`"),
            ));
        }
        Ok(Some((parsed, entry.line)))
    }
}

/// Reads the rows/cols/dt/data lines of an `!!opencv-matrix` block starting at line index `start`.
fn parse_matrix_block(
    lines: &[&str],
    start: usize,
    path: &Path,
    key: &str,
) -> Result<(RawValue, usize), SettingsError> {
    let mut rows = None;
    let mut cols = None;
    let mut data: Option<Vec<f64>> = None;
    let mut i = start;
    while i < lines.len() {
        let line = strip_comment(lines[i]);
        if line.trim().is_empty() {
            i += 1;
            continue;
        }
        if !line.starts_with(char::is_whitespace) {
            break;
        }
        let line_no = i + 1;
        i += 1;
        let Some((field, value)) = split_key_value(line.trim()) else {
            return Err(syntax(path, line_no, format!("`{key}`: expected `field: value` inside the matrix")));
        };
        match field {
            "rows" | "cols" => {
                let n: usize = value
                    .parse()
                    .map_err(|_| syntax(path, line_no, format!("`{key}.{field}`: `{value}` is not a count")))?;
                if field == "rows" { rows = Some(n) } else { cols = Some(n) }
            }
            "dt" => {}
            "data" => {
                // The list may span several lines up to the closing bracket.
                let mut text = value.to_string();
                while !text.contains(']') && i < lines.len() {
                    text.push(' ');
                    text.push_str(strip_comment(lines[i]).trim());
                    i += 1;
                }
                let inner = text
                    .trim()
                    .strip_prefix('[')
                    .and_then(|t| t.split(']').next())
                    .ok_or_else(|| syntax(path, line_no, format!("`{key}.data` must be a `[ ... ]` list")))?;
                let mut values = Vec::new();
                for item in inner.split(',').map(str::trim).filter(|s| !s.is_empty()) {
                    let v: f64 = item
                        .parse()
                        .map_err(|_| syntax(path, line_no, format!("`{key}.data`: `{item}` is not a number")))?;
                    if !v.is_finite() {
                        return Err(syntax(path, line_no, format!("`{key}.data`: `{item}` is not finite")));
                    }
                    values.push(v);
                }
                data = Some(values);
            }
            other => return Err(syntax(path, line_no, format!("`{key}`: unknown matrix field `{other}`"))),
        }
    }
    let (Some(rows), Some(cols), Some(data)) = (rows, cols, data) else {
        return Err(syntax(path, start, format!("`{key}`: an opencv-matrix needs rows, cols and data")));
    };
    if rows * cols != data.len() {
        return Err(syntax(path, start, format!("`{key}`: {rows}×{cols} matrix with {} values", data.len())));
    }
    Ok((RawValue::Matrix { rows, cols, data }, i))
}

/// ORB extractor settings (`ORBextractor.*`).
#[derive(Debug, Clone, PartialEq)]
pub struct OrbSettings {
    pub n_features: u32,
    pub scale_factor: f64,
    pub n_levels: u32,
    pub ini_th_fast: u32,
    pub min_th_fast: u32,
}

/// BDIS matcher settings (`BDISparam.*`), with the names and shipped defaults of the BDIS-SLAM yaml files.
/// Range checks that depend on the algorithm live with the matcher; here every value is finite and typed.
#[derive(Debug, Clone, PartialEq)]
pub struct BdisSettings {
    pub lv_f: u32,
    pub lv_l: u32,
    pub maxiter: u32,
    pub miniter: u32,
    pub mindprate: f64,
    pub mindrrate: f64,
    pub minimgerr: f64,
    pub patchsz: u32,
    pub poverl: f64,
    pub usefbcon: u32,
    pub patnorm: u32,
    pub costfct: u32,
    pub verbosity: u32,
    pub ratio_patch_valid: f64,
    pub num_window: u32,
    pub unit_disturb: f64,
    pub min_prob: f64,
    pub bool_var: bool,
}

impl Default for BdisSettings {
    fn default() -> Self {
        Self {
            lv_f: 5,
            lv_l: 1,
            maxiter: 12,
            miniter: 12,
            mindprate: 0.05,
            mindrrate: 0.95,
            minimgerr: 0.0,
            patchsz: 10,
            poverl: 0.60,
            usefbcon: 0,
            patnorm: 1,
            costfct: 0,
            verbosity: 0,
            ratio_patch_valid: 0.25,
            num_window: 2,
            unit_disturb: 0.5,
            min_prob: 0.05,
            bool_var: false,
        }
    }
}

/// Everything a settings file configures.
#[derive(Debug, Clone, PartialEq)]
pub struct Settings {
    /// The file these settings were read from (for messages).
    pub source: PathBuf,
    pub camera: StereoCamera,
    /// `Camera.fps`: the nominal frame rate.
    pub fps: f64,
    /// `Camera.RGB`: 1 when the images are RGB ordered. Our image decoder always yields RGB, so this is kept
    /// for reference only (the original applied it to OpenCV's BGR images and swapped the grey weights).
    pub rgb: bool,
    /// `ThDepth`: close/far limit in baselines.
    pub th_depth: f64,
    pub orb: OrbSettings,
    pub bdis: BdisSettings,
    /// `Viewer3D.depth_gap`: sample every n-th row and column when adding dense points to the map.
    pub depth_gap_px: u32,
    /// Keys that were recognised but are not used (GUI settings, rectification maps).
    pub ignored_keys: Vec<String>,
}

const CAMERA_KEYS: &[&str] =
    &["fx", "fy", "cx", "cy", "k1", "k2", "k3", "p1", "p2", "width", "height", "fps", "bf", "RGB", "name", "type"];
const ORB_KEYS: &[&str] = &["nFeatures", "scaleFactor", "nLevels", "iniThFAST", "minThFAST"];
const BDIS_KEYS: &[&str] = &[
    "lv_f",
    "lv_l",
    "maxiter",
    "miniter",
    "mindprate",
    "mindrrate",
    "minimgerr",
    "patchsz",
    "poverl",
    "usefbcon",
    "patnorm",
    "costfct",
    "verbosity",
    "ratio_patch_valid",
    "num_window",
    "unit_disturb",
    "min_prob",
    "bool_var",
];
const VIEWER3D_KEYS: &[&str] = &["depth_gap"];
const TOP_LEVEL_KEYS: &[&str] = &["ThDepth", "DepthMapFactor"];
/// Families read by other programs (the original's GUI and its rectification step): accepted and ignored.
const IGNORED_FAMILIES: &[&str] = &["Viewer", "LEFT", "RIGHT"];

struct Reader<'a> {
    raw: &'a RawSettings,
}

impl Reader<'_> {
    fn at(&self, key: &str) -> Option<usize> {
        self.raw.entries.get(key).and_then(|e| e.line)
    }

    fn required(&self, key: &'static str) -> Result<(f64, Option<usize>), SettingsError> {
        self.raw.number(key)?.ok_or_else(|| SettingsError::Missing { path: self.raw.path.clone(), key })
    }

    fn f64_or(&self, key: &str, default: f64) -> Result<f64, SettingsError> {
        Ok(self.raw.number(key)?.map_or(default, |(v, _)| v))
    }

    fn positive(&self, key: &'static str, required: bool, default: f64) -> Result<f64, SettingsError> {
        let (v, line) = if required { self.required(key)? } else { (self.f64_or(key, default)?, self.at(key)) };
        if v <= 0.0 {
            return Err(SettingsError::value(&self.raw.path, line, key, format!("must be > 0, found {v}")));
        }
        Ok(v)
    }

    fn u32_or(&self, key: &str, default: u32) -> Result<u32, SettingsError> {
        match self.raw.number(key)? {
            None => Ok(default),
            Some((v, line)) => {
                if v.fract() != 0.0 || v < 0.0 || v > f64::from(u32::MAX) {
                    Err(SettingsError::value(
                        &self.raw.path,
                        line,
                        key,
                        format!("must be a whole number ≥ 0, found {v}"),
                    ))
                } else {
                    Ok(v as u32)
                }
            }
        }
    }
}

impl Settings {
    /// Reads and validates a settings file (`.yaml`/`.yml` in the ORB-SLAM2 format, or the project's `.toml`).
    pub fn load(path: &Path) -> Result<Self, SettingsError> {
        Self::from_raw(&RawSettings::load(path)?)
    }

    /// Validates a parsed table into typed settings. Unknown keys are errors (they are usually typos).
    pub fn from_raw(raw: &RawSettings) -> Result<Self, SettingsError> {
        let mut ignored_keys = Vec::new();
        for (key, entry) in &raw.entries {
            let (family, name) = key.split_once('.').unwrap_or(("", key.as_str()));
            let known: &[&str] = match family {
                "Camera" => CAMERA_KEYS,
                "ORBextractor" => ORB_KEYS,
                "BDISparam" => BDIS_KEYS,
                "Viewer3D" => VIEWER3D_KEYS,
                "" => TOP_LEVEL_KEYS,
                f if IGNORED_FAMILIES.contains(&f) => {
                    ignored_keys.push(key.clone());
                    continue;
                }
                _ => &[],
            };
            if !known.contains(&name) {
                let known = if known.is_empty() {
                    "Camera.*, ORBextractor.*, BDISparam.*, Viewer3D.*, ThDepth".to_string()
                } else {
                    known.join(", ")
                };
                return Err(SettingsError::Unknown {
                    at: Location { path: raw.path.clone(), line: entry.line },
                    key: key.clone(),
                    known,
                });
            }
            if matches!(key.as_str(), "Camera.name" | "Camera.type" | "DepthMapFactor") {
                ignored_keys.push(key.clone());
            }
        }

        let r = Reader { raw };
        let fx = r.positive("Camera.fx", true, 0.0)?;
        let fy = r.positive("Camera.fy", true, 0.0)?;
        let (cx, _) = r.required("Camera.cx")?;
        let (cy, _) = r.required("Camera.cy")?;
        let bf = r.positive("Camera.bf", true, 0.0)?;
        let dimension = |key: &'static str| -> Result<Option<u32>, SettingsError> {
            if !raw.entries.contains_key(key) {
                return Ok(None);
            }
            let v = r.u32_or(key, 0)?;
            if v == 0 {
                return Err(SettingsError::value(&raw.path, r.at(key), key, "must be ≥ 1"));
            }
            Ok(Some(v))
        };
        let camera = StereoCamera {
            fx,
            fy,
            cx,
            cy,
            bf,
            distortion: Distortion {
                k1: r.f64_or("Camera.k1", 0.0)?,
                k2: r.f64_or("Camera.k2", 0.0)?,
                p1: r.f64_or("Camera.p1", 0.0)?,
                p2: r.f64_or("Camera.p2", 0.0)?,
                k3: r.f64_or("Camera.k3", 0.0)?,
            },
            width: dimension("Camera.width")?,
            height: dimension("Camera.height")?,
        };
        let fps = r.positive("Camera.fps", false, 30.0)?;
        let rgb = r.u32_or("Camera.RGB", 1)? != 0;
        let th_depth = r.positive("ThDepth", false, 20.0)?;

        let scale_factor = r.f64_or("ORBextractor.scaleFactor", 1.2)?;
        if scale_factor <= 1.0 {
            return Err(SettingsError::value(
                &raw.path,
                r.at("ORBextractor.scaleFactor"),
                "ORBextractor.scaleFactor",
                format!("must be > 1, found {scale_factor}"),
            ));
        }
        let orb = OrbSettings {
            n_features: r.u32_or("ORBextractor.nFeatures", 2000)?,
            scale_factor,
            n_levels: r.u32_or("ORBextractor.nLevels", 8)?,
            ini_th_fast: r.u32_or("ORBextractor.iniThFAST", 20)?,
            min_th_fast: r.u32_or("ORBextractor.minThFAST", 15)?,
        };
        for (key, v) in [("ORBextractor.nFeatures", orb.n_features), ("ORBextractor.nLevels", orb.n_levels)] {
            if v == 0 {
                return Err(SettingsError::value(&raw.path, r.at(key), key, "must be ≥ 1"));
            }
        }

        let d = BdisSettings::default();
        let bdis = BdisSettings {
            lv_f: r.u32_or("BDISparam.lv_f", d.lv_f)?,
            lv_l: r.u32_or("BDISparam.lv_l", d.lv_l)?,
            maxiter: r.u32_or("BDISparam.maxiter", d.maxiter)?,
            miniter: r.u32_or("BDISparam.miniter", d.miniter)?,
            mindprate: r.f64_or("BDISparam.mindprate", d.mindprate)?,
            mindrrate: r.f64_or("BDISparam.mindrrate", d.mindrrate)?,
            minimgerr: r.f64_or("BDISparam.minimgerr", d.minimgerr)?,
            patchsz: r.u32_or("BDISparam.patchsz", d.patchsz)?,
            poverl: r.f64_or("BDISparam.poverl", d.poverl)?,
            usefbcon: r.u32_or("BDISparam.usefbcon", d.usefbcon)?,
            patnorm: r.u32_or("BDISparam.patnorm", d.patnorm)?,
            costfct: r.u32_or("BDISparam.costfct", d.costfct)?,
            verbosity: r.u32_or("BDISparam.verbosity", d.verbosity)?,
            ratio_patch_valid: r.f64_or("BDISparam.ratio_patch_valid", d.ratio_patch_valid)?,
            num_window: r.u32_or("BDISparam.num_window", d.num_window)?,
            unit_disturb: r.f64_or("BDISparam.unit_disturb", d.unit_disturb)?,
            min_prob: r.f64_or("BDISparam.min_prob", d.min_prob)?,
            bool_var: r.u32_or("BDISparam.bool_var", u32::from(d.bool_var))? != 0,
        };
        let depth_gap_px = r.u32_or("Viewer3D.depth_gap", 5)?;
        if depth_gap_px == 0 {
            return Err(SettingsError::value(
                &raw.path,
                r.at("Viewer3D.depth_gap"),
                "Viewer3D.depth_gap",
                "must be ≥ 1",
            ));
        }

        Ok(Self { source: raw.path.clone(), camera, fps, rgb, th_depth, orb, bdis, depth_gap_px, ignored_keys })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const HAMLYN6: &str = "%YAML:1.0\n\n# Camera calibration\nCamera.fx: 695.877\nCamera.fy: 695.877\n\
Camera.cx: 280.402\nCamera.cy: 252.380\n\nCamera.k1: 0.0\nCamera.k2: 0.0\nCamera.p1: 0.0\nCamera.p2: 0.0\n\
Camera.width: 640\nCamera.height: 480\nCamera.fps: 25.0\nCamera.bf: 3743.1\nCamera.RGB: 1\nThDepth: 20\n\
ORBextractor.nFeatures: 2000\nORBextractor.scaleFactor: 1.2\nORBextractor.nLevels: 8\nORBextractor.iniThFAST: 20\n\
ORBextractor.minThFAST: 15\nBDISparam.patchsz: 10\nBDISparam.min_prob: 0.15\nViewer3D.depth_gap: 5\n\
Viewer.KeyFrameSize: 0.05\nLEFT.K: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n   data:[695.877, 0.0, 280.402,\n     0.0, 695.877, 252.38, 0.0, 0.0, 1.0]\n";

    fn parse(text: &str) -> Result<Settings, SettingsError> {
        Settings::from_raw(&RawSettings::parse_opencv_yaml(text, Path::new("s.yaml"))?)
    }

    #[test]
    fn reads_a_bdis_slam_settings_file() {
        let s = parse(HAMLYN6).unwrap();
        assert_eq!(s.camera.fx, 695.877);
        assert_eq!(s.camera.cy, 252.380);
        assert_eq!(s.camera.width, Some(640));
        assert!((s.camera.baseline() - 3743.1 / 695.877).abs() < 1e-12);
        assert_eq!(s.fps, 25.0);
        assert_eq!(s.orb.n_levels, 8);
        assert_eq!(s.bdis.min_prob, 0.15);
        assert_eq!(s.bdis.patchsz, 10);
        assert_eq!(s.bdis.lv_f, 5, "defaults fill missing BDISparam keys");
        assert!(s.ignored_keys.contains(&"LEFT.K".to_string()));
    }

    #[test]
    fn rejects_the_hamlyn1_typo_with_line_and_key() {
        let text = HAMLYN6.replace("Camera.bf: 3743.1", "Camera.bf: 2055.77s");
        let e = parse(&text).unwrap_err().to_string();
        assert_eq!(e, "s.yaml:16: `Camera.bf`: `2055.77s` is not a number");
    }

    #[test]
    fn rejects_missing_nan_and_non_positive_values() {
        let e = parse(&HAMLYN6.replace("Camera.fx: 695.877\n", "")).unwrap_err().to_string();
        assert_eq!(e, "s.yaml: missing required key `Camera.fx`");
        let e = parse(&HAMLYN6.replace("Camera.fy: 695.877", "Camera.fy: .nan")).unwrap_err().to_string();
        assert!(e.contains("`Camera.fy`: must be a finite number"), "{e}");
        let e = parse(&HAMLYN6.replace("Camera.fx: 695.877", "Camera.fx: -1")).unwrap_err().to_string();
        assert_eq!(e, "s.yaml:4: `Camera.fx`: must be > 0, found -1");
        let e = parse(&HAMLYN6.replace("Camera.bf: 3743.1", "Camera.bf: 0")).unwrap_err().to_string();
        assert_eq!(e, "s.yaml:16: `Camera.bf`: must be > 0, found 0");
    }

    #[test]
    fn rejects_unknown_keys_and_bad_syntax() {
        let e = parse(&HAMLYN6.replace("Camera.fps", "Camera.fsp")).unwrap_err().to_string();
        assert!(e.starts_with("s.yaml:15: unknown key `Camera.fsp`"), "{e}");
        let e = parse("Camera.fx: 1\n").unwrap_err().to_string();
        assert!(e.contains("%YAML:1.0"), "{e}");
        let e = parse("%YAML:1.0\nCamera.fx 1\n").unwrap_err().to_string();
        assert_eq!(e, "s.yaml:2: expected `key: value`, found `Camera.fx 1`");
        let e =
            parse("%YAML:1.0\nM: !!opencv-matrix\n  rows: 2\n  cols: 2\n  data: [1, 2, 3]\n").unwrap_err().to_string();
        assert!(e.contains("2×2 matrix with 3 values"), "{e}");
    }

    #[test]
    fn toml_uses_the_same_names_and_checks() {
        let text =
            "ThDepth = 20\n[Camera]\nfx = 520.0\nfy = 520\ncx = 320\ncy = 240\nbf = 260\n[BDISparam]\npatchsz = 8\n";
        let s = Settings::from_raw(&RawSettings::parse_toml(text, Path::new("c.toml")).unwrap()).unwrap();
        assert_eq!(s.camera.fy, 520.0);
        assert_eq!(s.bdis.patchsz, 8);
        let e = Settings::from_raw(
            &RawSettings::parse_toml(&text.replace("bf = 260", "bf = -2"), Path::new("c.toml")).unwrap(),
        )
        .unwrap_err()
        .to_string();
        assert_eq!(e, "c.toml: `Camera.bf`: must be > 0, found -2");
        let e = RawSettings::parse_toml("[Camera\nfx=1", Path::new("c.toml")).unwrap_err().to_string();
        assert!(e.starts_with("c.toml:1:"), "{e}");
    }
}
