//! Matcher parameters, with the BDIS-SLAM settings names and shipped defaults.

use bdis_core::settings::BdisSettings;

/// Which matcher runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Algorithm {
    /// Bayesian Dense Inverse Searching: sCRF patch confidence, level likelihoods, Gaussian-weighted fusion,
    /// `min_prob` threshold.
    Bdis,
    /// Plain DIS: the same pyramid, search and speckle filter, with every searched patch trusted equally
    /// (uniform fusion weights, no confidence, no threshold). The baseline the Bayesian parts are measured against.
    Dis,
}

/// Parameters of the matcher (`BDISparam.*`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Params {
    pub algorithm: Algorithm,
    /// Coarsest pyramid level searched.
    pub lv_f: u32,
    /// Finest level searched; the output is upsampled by 2^lv_l.
    pub lv_l: u32,
    /// Inverse-compositional iterations per patch (maximum; `miniter` before the rate tests apply).
    pub maxiter: u32,
    pub miniter: u32,
    pub mindprate: f64,
    pub mindrrate: f64,
    pub minimgerr: f64,
    /// Patch size p (even).
    pub patch_size: u32,
    /// Patch overlap in [0, 1): stride = max(1, floor(p·(1 − overlap))) computed in f32, as the original.
    pub overlap: f64,
    /// Minimum fraction of valid pixels for a patch to count.
    pub ratio_patch_valid: f64,
    /// W: the confidence probes 2W disturbed positions.
    pub num_window: u32,
    /// δ: spacing of the disturbed positions, in level pixels.
    pub unit_disturb: f64,
    /// Pixels whose fused probability is ≤ this are invalid.
    pub min_prob: f64,
    /// Also compute a per-pixel disparity variance.
    pub variance: bool,
    /// Left–right consistency (not in the original): a pixel is kept only when matching the mirrored pair the
    /// other way finds the same disparity within this many pixels of the finest searched level (`lv_l`); 0 turns
    /// it off. On by default: it halves the matcher's speed, and buys a map without gross errors whatever the
    /// algorithm (plain DIS has no confidence at all; BDIS's still lets ~1 % of far-off depths through, which
    /// stay in the map as "occluded" points). Measured in BENCHMARKS.md, "Left–right check".
    pub lr_check: f64,
    /// How many times the pair is halved (2×2 means, the pyramid's own rule) before level 0 of the levels
    /// above (not in the original): `lv_f`, `lv_l`, the patch size, σ_s and every other length here are in the
    /// pixels of that halved pair, and the output is upsampled to the input by 2^(lv_l + offset). `None` =
    /// `bdis_core::scale::reference_halvings` for the input's size (640×480 and smaller: 0; 1280×720 and
    /// 1920×1080: 1; 3840×2160: 2 — as every pixel parameter of the pipeline scales). Why: the parameters were published for images of about
    /// 640×480; on HD the same patch size and levels search 2–3× finer detail than those images have (and
    /// cost the pixels' square), while the coarsest level no longer covers HD's larger disparities.
    pub level_offset: Option<u32>,
}

impl Default for Params {
    /// The BDIS-SLAM yaml values (patch 10, overlap 0.60 → stride 3).
    fn default() -> Self {
        Self::from_settings(&BdisSettings::default())
    }
}

/// Parameters that cannot work, named as in the settings file.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("BDISparam.{name}: {message}")]
pub struct ParamError {
    pub name: &'static str,
    pub message: String,
}

fn bad(name: &'static str, message: impl Into<String>) -> ParamError {
    ParamError { name, message: message.into() }
}

impl Params {
    pub fn from_settings(s: &BdisSettings) -> Self {
        Self {
            algorithm: Algorithm::Bdis,
            lv_f: s.lv_f,
            lv_l: s.lv_l,
            maxiter: s.maxiter,
            miniter: s.miniter,
            mindprate: s.mindprate,
            mindrrate: s.mindrrate,
            minimgerr: s.minimgerr,
            patch_size: s.patchsz,
            overlap: s.poverl,
            ratio_patch_valid: s.ratio_patch_valid,
            num_window: s.num_window,
            unit_disturb: s.unit_disturb,
            min_prob: s.min_prob,
            variance: s.bool_var,
            lr_check: 1.0,
            level_offset: s.level_offset,
        }
    }

    /// The left–right tolerance in finest-level pixels, or `None` when the check is off.
    pub fn lr_tolerance_level_px(&self) -> Option<f32> {
        (self.lr_check > 0.0).then_some(self.lr_check as f32)
    }

    /// The same in the pixels of the (halved, see `level_offset`) pair the levels count from: one
    /// finest-level pixel is 2^lv_l of them.
    pub fn lr_tolerance_px(&self) -> Option<f32> {
        self.lr_tolerance_level_px().map(|t| t * (1u32 << self.lv_l) as f32)
    }

    /// The level offset used for a `width`×`height` pair: the one set, or the one the size calls for.
    pub fn level_offset_for(&self, width: usize, height: usize) -> u32 {
        self.level_offset.unwrap_or_else(|| bdis_core::scale::reference_halvings(width, height))
    }

    /// The same parameters without the left–right check: the matcher as the original has it, for comparisons
    /// with its published figures.
    pub fn as_published(self) -> Self {
        Self { lr_check: 0.0, ..self }
    }

    /// The authors' parameters for the synthetic colon sets (patch 8, overlap 0.40, δ = 1).
    pub fn colon() -> Self {
        Self { patch_size: 8, overlap: 0.40, unit_disturb: 1.0, min_prob: 0.05, ..Self::default() }
    }

    /// Patch stride, computed in f32 like the original (10 · (1 − 0.6f) = 3.9999998 → 3).
    pub fn stride(&self) -> u32 {
        ((self.patch_size as f32) * (1.0 - self.overlap as f32)).floor().max(1.0) as u32
    }

    /// Checks every value; the matcher refuses parameters that cannot work.
    pub fn validate(&self) -> Result<(), ParamError> {
        if self.patch_size < 2 || !self.patch_size.is_multiple_of(2) || self.patch_size > 64 {
            return Err(bad("patchsz", format!("must be even and in 2..=64, found {}", self.patch_size)));
        }
        if self.lv_l == 0 {
            return Err(bad("lv_l", "must be ≥ 1 (the level likelihood 1/s is undefined at level 0)"));
        }
        if self.lv_f < self.lv_l {
            return Err(bad("lv_f", format!("must be ≥ lv_l ({}), found {}", self.lv_l, self.lv_f)));
        }
        if let Some(offset) = self.level_offset
            && offset > 8
        {
            return Err(bad("level_offset", format!("must be in 0..=8, found {offset}")));
        }
        if self.lv_f > 10 {
            return Err(bad("lv_f", format!("must be ≤ 10, found {}", self.lv_f)));
        }
        if self.maxiter == 0 || self.maxiter > 1000 {
            return Err(bad("maxiter", format!("must be in 1..=1000, found {}", self.maxiter)));
        }
        if !(self.overlap.is_finite() && (0.0..1.0).contains(&self.overlap)) {
            return Err(bad("poverl", format!("must be in [0, 1), found {}", self.overlap)));
        }
        if !(self.ratio_patch_valid.is_finite() && (0.0..=1.0).contains(&self.ratio_patch_valid)) {
            return Err(bad("ratio_patch_valid", format!("must be in [0, 1], found {}", self.ratio_patch_valid)));
        }
        if self.num_window == 0 || self.num_window > 16 {
            return Err(bad("num_window", format!("must be in 1..=16, found {}", self.num_window)));
        }
        if !(self.unit_disturb.is_finite() && self.unit_disturb > 0.0 && self.unit_disturb <= self.patch_size as f64) {
            return Err(bad("unit_disturb", format!("must be in (0, patchsz], found {}", self.unit_disturb)));
        }
        if !(self.min_prob.is_finite() && (0.0..1.0).contains(&self.min_prob)) {
            return Err(bad("min_prob", format!("must be in [0, 1), found {}", self.min_prob)));
        }
        if !(self.lr_check.is_finite() && self.lr_check >= 0.0) {
            return Err(bad("lr_check", format!("must be a finite number ≥ 0 (0 = off), found {}", self.lr_check)));
        }
        for (name, v) in [("mindprate", self.mindprate), ("mindrrate", self.mindrrate), ("minimgerr", self.minimgerr)] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(bad(name, format!("must be a finite number ≥ 0, found {v}")));
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn strides_follow_the_original_float_rounding() {
        assert_eq!(Params::default().stride(), 3);
        assert_eq!(Params::colon().stride(), 4);
        assert_eq!(Params { overlap: 0.55, ..Params::default() }.stride(), 4);
    }

    #[test]
    fn absurd_parameters_are_refused_by_name() {
        let e = Params { patch_size: 0, ..Params::default() }.validate().unwrap_err();
        assert_eq!(e.to_string(), "BDISparam.patchsz: must be even and in 2..=64, found 0");
        let e = Params { lv_f: 1, lv_l: 2, ..Params::default() }.validate().unwrap_err();
        assert_eq!(e.to_string(), "BDISparam.lv_f: must be ≥ lv_l (2), found 1");
        assert!(Params { min_prob: f64::NAN, ..Params::default() }.validate().is_err());
        assert!(Params::default().validate().is_ok() && Params::colon().validate().is_ok());
        let e = Params { lr_check: -1.0, ..Params::default() }.validate().unwrap_err();
        assert_eq!(e.to_string(), "BDISparam.lr_check: must be a finite number ≥ 0 (0 = off), found -1");
    }

    #[test]
    fn the_left_right_check_is_on_unless_turned_off_and_scales_with_the_finest_level() {
        let p = Params::default();
        assert_eq!(p.lr_tolerance_px(), Some(2.0), "one pixel of level 1 is two image pixels");
        assert_eq!(Params { lv_l: 2, ..p }.lr_tolerance_px(), Some(4.0));
        assert_eq!(Params { lr_check: 0.5, ..p }.lr_tolerance_px(), Some(1.0));
        assert_eq!(p.as_published().lr_tolerance_px(), None);
        assert_eq!(Params { algorithm: Algorithm::Dis, ..Params::colon() }.lr_tolerance_px(), Some(2.0));
    }
}

impl Params {
    /// Sets one parameter by its settings name (`BDISparam.` prefix optional), e.g. from `--param patchsz=8`.
    pub fn set(&mut self, name: &str, value: &str) -> Result<(), ParamError> {
        let key = name.strip_prefix("BDISparam.").unwrap_or(name);
        let key: &'static str = match key {
            "lv_f" => "lv_f",
            "lv_l" => "lv_l",
            "maxiter" => "maxiter",
            "miniter" => "miniter",
            "mindprate" => "mindprate",
            "mindrrate" => "mindrrate",
            "minimgerr" => "minimgerr",
            "patchsz" => "patchsz",
            "poverl" => "poverl",
            "ratio_patch_valid" => "ratio_patch_valid",
            "num_window" => "num_window",
            "unit_disturb" => "unit_disturb",
            "min_prob" => "min_prob",
            "bool_var" => "bool_var",
            "lr_check" => "lr_check",
            "level_offset" => "level_offset",
            other => {
                return Err(ParamError {
                    name: "?",
                    message: format!(
                        "unknown parameter `{other}` (known: lv_f lv_l maxiter miniter mindprate mindrrate minimgerr patchsz poverl ratio_patch_valid num_window unit_disturb min_prob bool_var lr_check level_offset)"
                    ),
                });
            }
        };
        let number: f64 = value.trim().parse().map_err(|_| bad(key, format!("`{value}` is not a number")))?;
        let whole = || -> Result<u32, ParamError> {
            if number.fract() == 0.0 && (0.0..=f64::from(u32::MAX)).contains(&number) {
                Ok(number as u32)
            } else {
                Err(bad(key, format!("must be a whole number ≥ 0, found {value}")))
            }
        };
        match key {
            "lv_f" => self.lv_f = whole()?,
            "lv_l" => self.lv_l = whole()?,
            "maxiter" => self.maxiter = whole()?,
            "miniter" => self.miniter = whole()?,
            "patchsz" => self.patch_size = whole()?,
            "num_window" => self.num_window = whole()?,
            "bool_var" => self.variance = whole()? != 0,
            "mindprate" => self.mindprate = number,
            "mindrrate" => self.mindrrate = number,
            "minimgerr" => self.minimgerr = number,
            "poverl" => self.overlap = number,
            "ratio_patch_valid" => self.ratio_patch_valid = number,
            "unit_disturb" => self.unit_disturb = number,
            "lr_check" => self.lr_check = number,
            "level_offset" => self.level_offset = Some(whole()?),
            _ => self.min_prob = number,
        }
        Ok(())
    }
}

#[cfg(test)]
mod set_tests {
    use super::*;

    #[test]
    fn set_by_settings_name() {
        let mut p = Params::default();
        p.set("patchsz", "8").unwrap();
        p.set("BDISparam.poverl", "0.4").unwrap();
        assert_eq!((p.patch_size, p.stride()), (8, 4));
        assert_eq!(
            p.set("patchsz", "8.5").unwrap_err().to_string(),
            "BDISparam.patchsz: must be a whole number ≥ 0, found 8.5"
        );
        assert!(p.set("nope", "1").unwrap_err().to_string().contains("unknown parameter `nope`"));
    }
}

impl Params {
    /// Applies command-line overrides: `NAME=VALUE` settings (`--param`) and the algorithm's name (`bdis`, `dis`).
    pub fn apply_overrides(&mut self, assignments: &[String], algorithm: &str) -> Result<(), ParamError> {
        for a in assignments {
            let (name, value) = a
                .split_once('=')
                .ok_or_else(|| ParamError { name: "?", message: format!("`{a}`: expected NAME=VALUE") })?;
            self.set(name, value)?;
        }
        self.algorithm = match algorithm {
            "bdis" => Algorithm::Bdis,
            "dis" => Algorithm::Dis,
            other => {
                return Err(ParamError {
                    name: "algorithm",
                    message: format!("`{other}` is not an algorithm (bdis, dis)"),
                });
            }
        };
        self.validate()
    }
}
