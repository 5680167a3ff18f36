//! Settings files: the ORB-SLAM2 / BDIS-SLAM OpenCV-FileStorage YAML (`%YAML:1.0`) and the project's own TOML.
//!
//! Both syntaxes are read into one flat table of `Family.key → value` entries (the TOML uses tables named like
//! the YAML prefixes: `[Camera] fx = 520.0`), and one typed extraction validates that table. So a setting has a
//! single name, a single default and a single check, whichever file it came from.
//!
//! Why a hand-written reader: OpenCV's YAML dialect (`%YAML:1.0`, `data:[...]` without a space, `!!opencv-matrix`)
//! is not YAML 1.2 and breaks the Rust YAML crates (see CRATES.md). We read the subset those files use and reject
//! everything else with the line number, so a typo such as `Camera.bf: 2055.77s` is an error, not a silent 0.

pub mod raw;

pub use raw::{MatrixEntry, RawEntry, RawSettings, RawValue};

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
    /// The I/O error is in the message and deliberately not the error's source, so that a report that walks
    /// the chain (`{:#}`) prints it once.
    #[error("{path}: cannot read settings: {detail}")]
    Io { path: PathBuf, detail: std::io::Error },
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
    /// A value error at `path`:`line` for `key`.
    pub fn value(path: &Path, line: Option<usize>, key: &str, message: impl Into<String>) -> Self {
        Self::Value { at: Location { path: path.to_path_buf(), line }, key: key.to_string(), message: message.into() }
    }
}

/// ORB extractor settings (`ORBextractor.*`).
#[derive(Debug, Clone, PartialEq)]
pub struct OrbSettings {
    pub n_features: u32,
    pub scale_factor: f64,
    pub n_levels: u32,
    pub ini_th_fast: u32,
    pub min_th_fast: u32,
    /// `ORBextractor.firstLevel` (not in ORB-SLAM2): the pyramid level detection starts on; absent = chosen by
    /// the image size (`bdis_orb::auto_first_level`: HD detects on a level of about VGA's pixels).
    pub first_level: Option<u32>,
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
    /// `BDISparam.level_offset` (not in the original): how many times the pair is halved before the levels
    /// above count; absent = chosen by the image size (`crate::scale::reference_halvings`).
    pub level_offset: Option<u32>,
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
            level_offset: None,
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
const ORB_KEYS: &[&str] = &["nFeatures", "scaleFactor", "nLevels", "iniThFAST", "minThFAST", "firstLevel"];
const BDIS_KEYS: &[&str] = &[
    "level_offset",
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
        Ok(self.u32_opt(key)?.unwrap_or(default))
    }

    fn u32_opt(&self, key: &str) -> Result<Option<u32>, SettingsError> {
        match self.raw.number(key)? {
            None => Ok(None),
            Some((v, line)) => {
                if v.fract() != 0.0 || v < 0.0 || v > f64::from(u32::MAX) {
                    Err(SettingsError::value(
                        &self.raw.path,
                        line,
                        key,
                        format!("must be a whole number ≥ 0, found {v}"),
                    ))
                } else {
                    Ok(Some(v as u32))
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
            first_level: r.u32_opt("ORBextractor.firstLevel")?,
        };
        if let Some(first) = orb.first_level
            && first > 16
        {
            let key = "ORBextractor.firstLevel";
            return Err(SettingsError::value(&raw.path, r.at(key), key, format!("must be in 0..=16, found {first}")));
        }
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
            level_offset: r.u32_opt("BDISparam.level_offset")?,
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
mod tests;
