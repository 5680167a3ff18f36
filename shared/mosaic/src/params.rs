//! The map's parameters (`--map-param NAME=VALUE`).

use serde::{Deserialize, Serialize};

/// How an earlier point that agrees with the new surface is treated.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
pub enum Fusion {
    /// Algorithm 1: the newest keyframe's point replaces it.
    Replace,
    /// It is averaged into the new point of the same grid cell, weighted by confidence; the colour stays the
    /// newest (blending colours blurs texture, the paper's argument). What is averaged is how far the earlier
    /// point lies from the new view's surface where it falls (its depth there, interpolated): carried to the
    /// cell's centre along that surface, a point off the centre does not pull a slope flat (averaging raw depths
    /// did, by up to half the depth change across the offset, and the bias grew with every keyframe that fused
    /// the place again). The default: breathing tissue is seen at a different phase by every keyframe, and the
    /// average of the views is the mean surface where the newest view is one phase of it (issue #22); on still
    /// tissue it is the better map too (issue #17, sixth part: the circle's maps 25 % closer to the mesh).
    #[default]
    Weighted,
}

#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct MosaicParams {
    /// Lift every `depth_gap_px`-th row and column (the original's `depth_gap`, 5 → 1/25 of the pixels).
    pub depth_gap_px: usize,
    /// Pixels whose three colour channels are all below this are skipped (dark, unlit: 40 in the original).
    pub min_colour: u8,
    /// Pixels whose BDIS confidence is below this are skipped. Measured on the synthetic colon and abdomen with
    /// ground-truth depth: the depth outliers (> 5 mm) have confidence 0.25–0.3 (median 0.25, inliers 0.34–0.56),
    /// and 0.3 removes 91 % (colon) and 85 % (abdomen) of them. This matters more than in one depth map: an
    /// outlier far behind the surface passes every later depth test as "occluded" and stays.
    pub min_confidence: f32,
    /// Pixels whose disparity is below this are skipped: depth error grows as depth² / bf, so the far part of a
    /// view is left to keyframes that come closer. The original had no limit on new points and culled within
    /// 8 px of disparity.
    pub min_disparity_px: f32,
    /// Depth test: an earlier point is replaced when it lies less than `tolerance` behind the new surface, with
    /// tolerance = `depth_tolerance_ratio` · max(z_new, z_old) + `disparity_tolerance_px` · (z_new² + z_old²) / bf
    /// (a share of the depth, plus the depth uncertainty of a disparity error in either view). Farther behind, it
    /// is occluded and stays. A share, not a length: the map's unit is the calibration's (millimetres for an
    /// endoscope, metres for `kitti-a`); 0.01 is the 0.5 mm this was at a 50 mm stand-off.
    #[serde(default = "default_depth_tolerance_ratio")]
    pub depth_tolerance_ratio: f64,
    pub disparity_tolerance_px: f64,
    /// An earlier point that agrees with the new surface is kept, and the new view adds no point in that grid
    /// cell, when the earlier keyframe saw it from less than this fraction of the new view's depth: depth error
    /// grows with depth², so the closer look is the better one (a scope backing out of the colon no longer
    /// overwrites close views with distant ones). 0 = the newest view always wins (Algorithm 1).
    pub keep_closer_ratio: f32,
    pub fusion: Fusion,
    /// With [`Fusion::Weighted`], a point's accumulated weight stops growing here, so the map keeps following
    /// newer views.
    pub max_weight: f32,
    /// A new point is dropped when an earlier keyframe that looked at its place saw a surface behind it, farther
    /// by more than this much disparity (px, in that keyframe's view: a depth margin that grows with depth² as
    /// the depth's own uncertainty does). Such a point is transient — an instrument, smoke, depth smeared across
    /// a silhouette — or wrong. 0 = off.
    pub carve_disparity_px: f32,
}

fn default_depth_tolerance_ratio() -> f64 {
    0.01
}

impl Default for MosaicParams {
    fn default() -> Self {
        Self {
            depth_gap_px: 5,
            min_colour: 40,
            min_confidence: 0.3,
            min_disparity_px: 8.0,
            depth_tolerance_ratio: default_depth_tolerance_ratio(),
            disparity_tolerance_px: 1.0,
            keep_closer_ratio: 0.8,
            fusion: Fusion::Weighted,
            max_weight: 8.0,
            carve_disparity_px: 3.0,
        }
    }
}

impl MosaicParams {
    /// These parameters for keyframes of `width`×`height`: the ones in pixels (`depth_gap_px`,
    /// `min_disparity_px`, `disparity_tolerance_px`, `carve_disparity_px`) are in pixels of a 640×480-class image
    /// and scale by 2^[`bdis_core::scale::reference_halvings`] — as BDIS matches an HD pair halved, a 1080p
    /// keyframe's depth has the detail of a 960×540 one, and a grid every 5 px of 1920 would lift 4× the points
    /// that detail supports (9× a VGA keyframe's, for the same tissue).
    pub fn for_size(&self, width: usize, height: usize) -> Self {
        let k = bdis_core::scale::reference_halvings(width, height);
        let factor = (1u32 << k) as f32;
        Self {
            depth_gap_px: self.depth_gap_px << k,
            min_disparity_px: self.min_disparity_px * factor,
            disparity_tolerance_px: self.disparity_tolerance_px * f64::from(factor),
            carve_disparity_px: self.carve_disparity_px * factor,
            ..*self
        }
    }

    /// The grid step a keyframe of `width`×`height` is lifted with ([`MosaicParams::for_size`]).
    pub fn grid_gap(&self, width: u32, height: u32) -> usize {
        self.for_size(width as usize, height as usize).depth_gap_px.max(1)
    }

    /// The names `--map-param NAME=VALUE` accepts.
    pub const NAMES: [&str; 10] = [
        "depth_gap_px",
        "min_colour",
        "min_confidence",
        "min_disparity_px",
        "depth_tolerance_ratio",
        "disparity_tolerance_px",
        "keep_closer_ratio",
        "fusion",
        "max_weight",
        "carve_disparity_px",
    ];

    /// Sets one parameter from text (`fusion` is `replace` or `weighted`).
    pub fn set(&mut self, name: &str, value: &str) -> Result<(), String> {
        fn num<T: std::str::FromStr>(name: &str, value: &str) -> Result<T, String> {
            value.trim().parse().map_err(|_| format!("{name}: `{value}` is not a number of the right kind"))
        }
        fn non_negative(name: &str, v: f64) -> Result<f64, String> {
            if v.is_finite() && v >= 0.0 { Ok(v) } else { Err(format!("{name}: {v} must be finite and ≥ 0")) }
        }
        match name {
            "depth_gap_px" => {
                let v: usize = num(name, value)?;
                if v == 0 {
                    return Err("depth_gap_px: must be ≥ 1".into());
                }
                self.depth_gap_px = v;
            }
            "min_colour" => self.min_colour = num(name, value)?,
            "min_confidence" => self.min_confidence = non_negative(name, num(name, value)?)? as f32,
            "min_disparity_px" => self.min_disparity_px = non_negative(name, num(name, value)?)? as f32,
            "depth_tolerance_ratio" => self.depth_tolerance_ratio = non_negative(name, num(name, value)?)?,
            "depth_tolerance_mm" => {
                return Err("depth_tolerance_mm: now `depth_tolerance_ratio`, a share of the depth whatever the \
                            calibration's unit (0.01 = 0.5 mm at 50 mm)"
                    .into());
            }
            "disparity_tolerance_px" => self.disparity_tolerance_px = non_negative(name, num(name, value)?)?,
            "keep_closer_ratio" => self.keep_closer_ratio = non_negative(name, num(name, value)?)? as f32,
            "max_weight" => self.max_weight = non_negative(name, num(name, value)?)? as f32,
            "carve_disparity_px" => self.carve_disparity_px = non_negative(name, num(name, value)?)? as f32,
            "fusion" => {
                self.fusion = match value.trim() {
                    "replace" => Fusion::Replace,
                    "weighted" => Fusion::Weighted,
                    other => return Err(format!("fusion: `{other}` is not `replace` or `weighted`")),
                }
            }
            other => return Err(format!("`{other}` is not a map parameter ({})", Self::NAMES.join(", "))),
        }
        Ok(())
    }

    /// Applies `NAME=VALUE` assignments in order.
    pub fn apply_overrides(&mut self, assignments: &[String]) -> Result<(), String> {
        for a in assignments {
            let Some((name, value)) = a.split_once('=') else {
                return Err(format!("`{a}`: expected NAME=VALUE"));
            };
            self.set(name.trim(), value)?;
        }
        Ok(())
    }
}
