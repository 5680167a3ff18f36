//! How well the images support a frame's pose, and the honest status that follows from it: a pose is `Ok` only
//! when enough of its matches are inliers, the optimisation pins it down, and the estimate by appearance (no
//! prior) agrees with it. Every measure here is a ratio or is relative to the scene, so footage in metres and in
//! millimetres, at any image size, is judged alike.

use super::*;

/// How the frame's pose was first found, before the local map refined it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum PoseMethod {
    #[default]
    None,
    /// The first frame: the map starts at it.
    Initialisation,
    /// The constant-velocity prediction and a projection search from the last frame (§5.3).
    MotionModel,
    /// Descriptor matching against the reference keyframe with no prior ([`Tracker::appearance_consensus`]).
    Appearance,
    /// Projection from the last pose into the reference keyframe's points (when appearance found too little).
    ReferenceProjection,
    /// Relocalisation (§5.7).
    Relocalisation,
    /// The motion model's prediction alone, through a veil ([`Tracker::coast`](super::Tracker)), or as the
    /// seed of the local map's search in the frame after one.
    Prediction,
}

impl PoseMethod {
    pub fn name(self) -> &'static str {
        match self {
            Self::None => "none",
            Self::Initialisation => "initialisation",
            Self::MotionModel => "motion-model",
            Self::Appearance => "appearance",
            Self::ReferenceProjection => "reference-projection",
            Self::Relocalisation => "relocalisation",
            Self::Prediction => "prediction",
        }
    }
}

/// Why a tracked frame's pose is not trusted (its state is `Uncertain`), or why the frame was lost.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Doubt {
    /// Fewer inliers than tracking needs (the frame is `Lost`).
    FewInliers,
    /// Most of the matches the pose was optimised on disagree with it.
    LowInlierRatio,
    /// The inliers leave the camera's position poorly determined (far or clustered points).
    IllConditioned,
    /// Matching by appearance, with no prior, puts the camera somewhere the pose does not explain.
    AppearanceDisagrees,
    /// The image keeps too little of the texture contrast of the clearest keyframe of its place (the reference
    /// keyframe and its covisible neighbours): something veils the tissue (smoke, a fogged lens) and biases the
    /// measurements, however many of them agree.
    LowContrast,
    /// The last local bundle adjustment moved the keyframe it was made for by more than
    /// [`MAX_MAP_MOVE_REL`] of its depth: the map this frame was fitted to is still moving, so the fit (and
    /// its σ) does not say where the camera is. Unlike the other doubts it does not stop keyframes: the next
    /// keyframe's adjustment is what settles the map.
    MapMoving,
    /// Tracked on a map segment begun after the tracker was lost where relocalisation found no known place
    /// ([`Tracker::restart`](super::Tracker)): the pose is right relative to that segment, but where the
    /// segment lies in the first map's world is the motion before the loss carried on, a guess. It lasts until
    /// the segment is tied back (a loop closes, or the frame's pose rests on enough of the older points). Like
    /// `MapMoving` it does not stop keyframes: they are what the segment is tracked with.
    Detached,
    /// Posed by appearance alone (the motion model failed or disagreed: a jerk, a stop) and held by fewer
    /// inliers than a pose found without a prior needs ([`PRIORLESS_INLIERS`](super::relocalise::PRIORLESS_INLIERS),
    /// ORB-SLAM2's bar after relocalisation). On renders of a tenfold jerk such frames were off by up to a
    /// tenth of the step while their few inliers fitted well. Like `MapMoving` it does not stop keyframes: in
    /// a jerk the view runs ahead of the map, and the keyframe is what the next frames are tracked against
    /// (withholding it lost more than it saved, BENCHMARKS.md).
    PriorlessFewInliers,
    /// The motion model's pose where matching by appearance found no consensus to check it against and the
    /// pose kept under half the inliers of the last tracked frame: the view changed wholesale between two frames
    /// (frames dropped, a cut in a recording). The projection search is centred on the prediction, so it
    /// returns matches the prediction explains, right or wrong: on renders cut 10–60 mm on it found 34–63
    /// chance inliers, and the frames were `Ok` 12–45 mm off, then made keyframes that the frames after them
    /// rested on. Consecutive frames of one view share most of their points, and appearance finds them; losing
    /// most at once with nothing by appearance never happened in 385 runs of continuous footage (smoke and
    /// dim views included). Such a frame is `Lost` (this is its reason): relocalisation looks for the place
    /// from the next frame on, and a new segment begins where it finds none. Under a veil it is the haze that
    /// takes the points (a scope flying into the thick of smoke that hangs in the cavity: 74 → 31 inliers in
    /// one frame), and the frame is coasted instead ([`Tracker::coast`](super::Tracker)).
    Unconfirmed,
    /// The motion model's pose, predicted from a frame that was itself doubted for its own estimate
    /// ([`Doubt::carries_over`]), and with no consensus by appearance to check it against. The prediction is
    /// the doubted pose carried on by a velocity that ends on it, and the projection search centred on it
    /// returns matches it explains: on a cut relocalised three frames later, the frame after a doubted one
    /// (4.9 mm off) was `Ok` 1.2 mm off. The doubt lasts until something independent of the doubted frame
    /// confirms a pose: appearance, a relocalisation, or a frame predicted from an undoubted one. Like
    /// `MapMoving` it does not stop keyframes: a keyframe is what appearance confirms the next frames against
    /// (tried without: the doubt ran on for 47 frames after a smoke render's veil, each unconfirmed for want of
    /// a newer keyframe).
    UnconfirmedPrior,
    /// The haze coming down: no veil yet (that takes [`MIN_CONTRAST_KEPT`]), but less contrast than clear
    /// footage keeps ([`CONTRAST_RESTORED`] of the clearest view of its place; `Tracker::hazy`). The haze
    /// already shifts what it leaves, and the frames are doubted for it. They are tracked as clear ones and
    /// make keyframes (published, unlike a veil's); in the written trajectory a haze that clears without
    /// becoming a veil is bridged from the clear frames on both sides (`bridge::bridge_hazes`), and one that
    /// becomes a veil is part of the veil's bridge, as before. On the way up the same contrast keeps the veil
    /// down (`LowContrast`), so a frame is `Ok` only when it is as clear as clear footage gets, whichever way
    /// the haze goes. Clear footage meets it rarely: a fast colon flight onto plainer tissue, 8 of 200 frames
    /// (BENCHMARKS.md).
    Hazy,
}

impl Doubt {
    /// Whether the next frame's motion-model pose, unconfirmed by appearance, inherits this doubt
    /// ([`Doubt::UnconfirmedPrior`]): doubts about this frame's own estimate do; those about the map it was
    /// fitted to (`MapMoving`: the next frame is judged by the same rule) or where a segment lies (`Detached`:
    /// its motion is right) do not, nor a loss (the next frame is relocalised, not predicted). Nor a veil
    /// (`LowContrast`): it lifts only once the contrast is back, and the frame that lifts it is judged on its
    /// own. Carried over a veil, the doubt fell on the first clear frame of all seven smoke renders where
    /// appearance found nothing there (the view had moved on from the reference keyframe under the veil), and
    /// those frames were right: bridged over as doubted, the written trajectories came out worse on five
    /// (BENCHMARKS.md).
    pub fn carries_over(self) -> bool {
        matches!(
            self,
            Self::LowInlierRatio
                | Self::IllConditioned
                | Self::AppearanceDisagrees
                | Self::PriorlessFewInliers
                | Self::UnconfirmedPrior
        )
    }

    /// Whether a frame doubted for this still makes keyframes. A map still settling: the next keyframe's
    /// adjustment is what settles it. A detached segment: its keyframes are what it is tracked with. A jerk's
    /// priorless pose: the view has run ahead of the map, and the keyframe is what holds it. An unconfirmed
    /// prior: the keyframe is what appearance can confirm the next frames against. A haze coming down: only
    /// the status says so, the frame is tracked as a clear one. (A veil's keyframes are the tracker's own
    /// decision: only from a frame posed on the map, not coasted.)
    pub fn keeps_keyframes(self) -> bool {
        matches!(
            self,
            Self::MapMoving | Self::Detached | Self::PriorlessFewInliers | Self::UnconfirmedPrior | Self::Hazy
        )
    }

    pub fn name(self) -> &'static str {
        match self {
            Self::FewInliers => "few-inliers",
            Self::LowInlierRatio => "low-inlier-ratio",
            Self::IllConditioned => "ill-conditioned",
            Self::AppearanceDisagrees => "appearance-disagrees",
            Self::LowContrast => "low-contrast",
            Self::MapMoving => "map-moving",
            Self::Detached => "detached",
            Self::PriorlessFewInliers => "priorless-few-inliers",
            Self::Unconfirmed => "unconfirmed",
            Self::UnconfirmedPrior => "unconfirmed-prior",
            Self::Hazy => "hazy",
        }
    }
}

/// Per frame: how its pose was found and how well the images support it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TrackingQuality {
    pub method: PoseMethod,
    /// The motion model was tried and its pose replaced by the one from appearance (the prior was wrong).
    pub prior_rejected: bool,
    /// Links to map points in the final pose optimisation, and of them the inliers.
    pub matched: u32,
    pub inliers: u32,
    /// RMS of the inliers' left-image reprojection error, level-0 px.
    pub reprojection_rms_px: f64,
    /// The camera centre's standard deviation along its worst axis (from the optimisation's information and
    /// the measured σ), over the median depth of the inliers: units-free; 0.001 is 1 mm at 1 m.
    pub position_sigma_rel: f64,
    /// The rotation's standard deviation along its worst axis, degrees.
    pub rotation_sigma_deg: f64,
    /// Matches by appearance to the reference keyframe (ratio and rotation tests passed), and of them the RANSAC
    /// consensus; 0 when appearance matching did not run or found too little.
    pub appearance_matches: u32,
    pub appearance_consensus: u32,
    /// Of that consensus, the fraction the final pose explains; NaN without a consensus.
    pub appearance_agreement: f64,
    pub doubt: Option<Doubt>,
}

impl Default for TrackingQuality {
    fn default() -> Self {
        Self {
            method: PoseMethod::None,
            prior_rejected: false,
            matched: 0,
            inliers: 0,
            reprojection_rms_px: f64::NAN,
            position_sigma_rel: f64::NAN,
            rotation_sigma_deg: f64::NAN,
            appearance_matches: 0,
            appearance_consensus: 0,
            appearance_agreement: f64::NAN,
            doubt: None,
        }
    }
}

/// The appearance consensus must be explained by at least this fraction at the final pose. A right pose explains
/// nearly all of it (the consensus was gated at a coarser 3-point pose; measured 0.88–1.0 on real car footage and
/// 0.93–1.0 on our renders); a pose off by more than the matches' noise explains a minority.
pub const MIN_APPEARANCE_AGREEMENT: f64 = 0.5;
/// Below this agreement the motion model's pose is not taken as it is: the frame is posed from appearance
/// instead (which needs no prior), and the local map decides from there.
pub const PRIOR_AGREEMENT: f64 = 0.8;
/// At least this fraction of the links in the final optimisation must be inliers.
pub const MIN_INLIER_RATIO: f64 = 0.25;
/// A frame whose texture contrast fell below this share of the clearest of its reference keyframe and that
/// keyframe's covisible neighbours brings a veil down ([`Tracker::judge_veil`](super::Tracker)): a veil that
/// takes half the texture away also shifts every measurement it leaves (smoke blends a second, nearer layer
/// into each patch), while moving over tissue changes the contrast far less (measured in BENCHMARKS.md).
pub const MIN_CONTRAST_KEPT: f32 = 0.5;
/// A veil lifts only when the contrast is back above this share of the clearest view: clear footage never
/// fell below 0.756 of the best of its last 30 frames (BENCHMARKS.md), so above it the view is as clear as
/// clear footage gets. Between the two the haze is thinning, and it still shifts every measurement it leaves.
pub const CONTRAST_RESTORED: f32 = 0.75;
/// The longest a veil is taken to last: surgical smoke clears in a second or two.
pub const MAX_VEIL_S: f64 = 2.0;

/// The camera centre's σ may be at most this fraction of the inliers' median depth.
pub const MAX_POSITION_SIGMA_REL: f64 = 0.01;
/// The map may move under the frames by at most this fraction of the depth (the last local bundle adjustment's
/// move of its keyframe, [`crate::mapper::MapperReport::ba_moved_rel`]): the same bound as a frame's own σ,
/// since a map that moves by more makes that σ meaningless. Measured (BENCHMARKS.md): at most 0.5 % wherever
/// the tracker holds (renders and `kitti-a`), 2.4 % at the 90th percentile where it fails.
pub const MAX_MAP_MOVE_REL: f64 = 0.01;

/// Whether the view is seen through a veil ([`Tracker::judge_veil`](super::Tracker)).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Veil {
    Clear,
    /// Down for this many frames so far.
    Down {
        frames: u32,
    },
    /// Dim for longer than a veil lasts: taken as the view until it is clear.
    Accepted,
}

impl Veil {
    pub(super) fn is_down(self) -> bool {
        matches!(self, Self::Down { .. })
    }
}

impl Tracker {
    /// Decides whether the current frame is seen through a veil (smoke), before it is tracked, from its texture
    /// contrast against the clearest view of its place: the reference keyframe and its covisible neighbours
    /// (a veil that thickens slowly would otherwise lower the reference keyframe by keyframe). A veil comes
    /// down below [`MIN_CONTRAST_KEPT`] and lifts above [`CONTRAST_RESTORED`], so a thinning haze is not taken
    /// for a clear view. A view that stays dim for longer than [`MAX_VEIL_S`] is taken as it is until it is
    /// clear again: smoke clears, so what stays is the tissue (less texture, another light), and doubting it
    /// would stop the keyframes that let the reference move on.
    pub(super) fn judge_veil(&mut self) {
        let place = self.reference_kf.and_then(|r| self.map.keyframes.get(r)).map_or(
            crate::frame::ViewTexture::UNKNOWN,
            |kf| {
                kf.ordered
                    .iter()
                    .filter_map(|&(k, _)| self.map.keyframes.get(k))
                    // As `f32::max` would: a NaN (a keyframe without light) never wins over a number.
                    .fold(kf.texture, |clearest, n| {
                        if n.texture.contrast > clearest.contrast || clearest.contrast.is_nan() {
                            n.texture
                        } else {
                            clearest
                        }
                    })
            },
        );
        // No reference (NaN): nothing to judge by, a clear view.
        self.texture_ratio = self.current.texture.over(place);
        self.place_texture = place;
        let ratio = self.texture_ratio.contrast;
        let longest = (MAX_VEIL_S * self.settings.fps).round() as u32;
        self.veil = match self.veil {
            _ if ratio.is_nan() || ratio >= CONTRAST_RESTORED => Veil::Clear,
            Veil::Clear if ratio < MIN_CONTRAST_KEPT => Veil::Down { frames: 1 },
            Veil::Down { frames } if frames >= longest => Veil::Accepted,
            Veil::Down { frames } => Veil::Down { frames: frames + 1 },
            other => other,
        };
    }

    /// Whether the view is hazy ([`Doubt::Hazy`]): no veil down nor one taken as the view, yet a haze seen
    /// ([`Self::haze_seen`]). On the way down the haze shifts what it leaves before the veil comes down (hover
    /// seed 9: 0.05 mm a frame, BENCHMARKS.md).
    pub(super) fn hazy(&self) -> bool {
        self.veil == Veil::Clear && self.haze_seen()
    }

    /// Whether the view has lost contrast as a haze takes it: less than [`CONTRAST_RESTORED`] of the clearest
    /// view of its place, and a narrower brightness range than that view's. Added light narrows the range by
    /// the factor it takes off the texture ([`crate::frame::ViewTexture`]); a view that turned to plainer tissue
    /// or down a dark lumen loses texture with its range kept or widened, and is no haze (a clear colon revisit
    /// at 640×480 had 17–43 of 400 frames doubted `hazy` by the contrast alone, BENCHMARKS.md).
    pub(super) fn haze_seen(&self) -> bool {
        self.texture_ratio.contrast < CONTRAST_RESTORED && self.texture_ratio.brightness_cv < 1.0
    }

    /// Fills the measures of `quality` from the last pose optimisation (the local map's) and the appearance
    /// consensus, and returns the doubt about the pose, if any.
    pub(super) fn assess(&mut self, quality: &mut TrackingQuality) -> Option<Doubt> {
        let Some(pose) = self.current.camera_from_world else { return Some(Doubt::FewInliers) };
        let mut depths = std::mem::take(&mut self.residual_scratch);
        depths.clear();
        let (mut sum_e2, mut n) = (0.0, 0usize);
        for (k, &i) in self.opt_index.iter().enumerate() {
            if self.opt_outlier[k] {
                continue;
            }
            let pc = pose * self.opt_points[k];
            if pc.z <= 0.0 {
                continue;
            }
            let (u, v) = self.cam.project(&pc);
            let kp = &self.current.keypoints[i];
            sum_e2 += (u - f64::from(kp.x)).powi(2) + (v - f64::from(kp.y)).powi(2);
            n += 1;
            depths.push(pc.z);
        }
        quality.matched = self.opt_index.len() as u32;
        quality.reprojection_rms_px = if n > 0 { (sum_e2 / n as f64).sqrt() } else { f64::NAN };
        let median_depth = if depths.is_empty() {
            f64::NAN
        } else {
            let mid = depths.len() / 2;
            *depths.select_nth_unstable_by(mid, f64::total_cmp).1
        };
        self.residual_scratch = depths;
        // The information is in units of each measurement's assumed σ; scale the covariance by the measured
        // spread of the residuals (χ² per degree of freedom), so noisy footage is judged by its real noise.
        let chi2 = self.optimizer.chi2();
        let (mut chi2_sum, mut dof) = (0.0, 0.0);
        for (k, &i) in self.opt_index.iter().enumerate() {
            if !self.opt_outlier[k] && chi2[k].is_finite() {
                chi2_sum += chi2[k];
                dof += if self.current.u_right[i] >= 0.0 { 3.0 } else { 2.0 };
            }
        }
        let noise = if dof > 6.0 { (chi2_sum / (dof - 6.0)).max(1e-12) } else { f64::NAN };
        let (position_sigma, rotation_sigma) = match self.optimizer.information().try_inverse() {
            Some(cov) => {
                let worst = |block: nalgebra::Matrix3<f64>| block.symmetric_eigenvalues().max().max(0.0).sqrt();
                (
                    worst(cov.fixed_view::<3, 3>(3, 3).into_owned()) * noise.sqrt(),
                    worst(cov.fixed_view::<3, 3>(0, 0).into_owned()) * noise.sqrt(),
                )
            }
            None => (f64::INFINITY, f64::INFINITY),
        };
        quality.position_sigma_rel = position_sigma / median_depth;
        quality.rotation_sigma_deg = rotation_sigma.to_degrees();
        if quality.appearance_consensus > 0 {
            quality.appearance_agreement = self.appearance_agreement(&pose);
        }
        let ratio = f64::from(quality.inliers) / f64::from(quality.matched.max(1));
        if quality.method == PoseMethod::MotionModel
            && quality.appearance_consensus == 0
            && 2 * (quality.inliers as usize) < self.confirmed_inliers
        {
            // First: the frame is lost, whatever else is wrong with it.
            Some(Doubt::Unconfirmed)
        } else if self.veil.is_down() {
            Some(Doubt::LowContrast)
        } else if quality.method == PoseMethod::MotionModel
            && quality.appearance_consensus == 0
            && self.last_doubt.is_some_and(Doubt::carries_over)
        {
            Some(Doubt::UnconfirmedPrior)
        } else if quality.appearance_agreement < MIN_APPEARANCE_AGREEMENT {
            Some(Doubt::AppearanceDisagrees)
        } else if ratio < MIN_INLIER_RATIO {
            Some(Doubt::LowInlierRatio)
        } else if quality.position_sigma_rel.is_nan() || quality.position_sigma_rel > MAX_POSITION_SIGMA_REL {
            Some(Doubt::IllConditioned)
        } else if quality.method == PoseMethod::Appearance
            && (quality.inliers as usize) < super::relocalise::PRIORLESS_INLIERS
        {
            Some(Doubt::PriorlessFewInliers)
        } else if self.map_moved_rel > MAX_MAP_MOVE_REL {
            Some(Doubt::MapMoving)
        } else if self.hazy() {
            Some(Doubt::Hazy)
        } else {
            None
        }
    }
}

// The integration tests' colon flight (shared/track/tests/common/flight.rs).
#[cfg(test)]
#[path = "../../tests/common/flight.rs"]
mod test_flight;

#[cfg(test)]
mod tests {
    use super::*;

    use super::test_flight::colon_flight;

    /// While the map under the frames is still moving by more than the bound, the frames are `Uncertain`
    /// (`map-moving`) — yet keyframes still come, since the next adjustment is what settles the map, and once
    /// one has moved its keyframe by less, the frames are `Ok` again.
    #[test]
    fn frames_on_a_map_still_moving_are_doubted_and_keyframes_go_on_until_it_settles() {
        let cam = RectifiedCamera { fx: 260.0, fy: 260.0, cx: 159.5, cy: 119.5, bf: 1300.0, width: 320, height: 240 };
        let orb = bdis_orb::OrbParams { n_features: 1000, ini_th_fast: 20, min_th_fast: 7, ..Default::default() };
        let Ok(mut tracker) = Tracker::new(cam, TrackerSettings { th_depth: 20.0, fps: 30.0, orb }) else {
            panic!("tracker")
        };
        let frames = colon_flight(28);
        let mut results = Vec::new();
        for (i, (l, r)) in frames.iter().enumerate() {
            if i == 12 {
                // What an adjustment that moved its keyframe by 2 % of the depth leaves behind.
                tracker.map_moved_rel = 2.0 * MAX_MAP_MOVE_REL;
            }
            let Ok(result) = tracker.track(i as u64 * 33_333_333, l, r) else { panic!("frame {i}") };
            results.push(result);
        }
        for (i, result) in results.iter().enumerate().take(12) {
            assert_eq!(result.state, TrackingState::Ok, "frame {i}: {:?}", result.quality);
        }
        // From frame 12 until a keyframe's report brings a measured move (the adjustment made for the keyframe
        // before it, applied then), every frame is doubted for the map; that keyframe is made all the same.
        let settled = (12..results.len())
            .find(|&i| results[i].mapper.as_ref().is_some_and(|m| m.ba_moved_rel.is_some()))
            .unwrap_or_else(|| panic!("no adjustment applied in frames 12–27"));
        for (i, result) in results.iter().enumerate().take(settled).skip(12) {
            assert_eq!(result.state, TrackingState::Uncertain, "frame {i}");
            assert_eq!(result.quality.doubt, Some(Doubt::MapMoving), "frame {i}");
        }
        let keyframes_while_doubted = (12..=settled).filter(|&i| results[i].new_keyframe.is_some()).count();
        assert!(keyframes_while_doubted >= 1, "no keyframe while the map was doubted");
        // This flight's adjustments move their keyframe by a fraction of the bound: the frames are Ok again.
        let moved = results[settled].mapper.as_ref().and_then(|m| m.ba_moved_rel).unwrap_or(f64::NAN);
        assert!(moved < MAX_MAP_MOVE_REL, "the adjustment moved its keyframe by {:.2} %", 100.0 * moved);
        for (i, result) in results.iter().enumerate().skip(settled + 1) {
            assert_eq!(result.state, TrackingState::Ok, "frame {i}: {:?}", result.quality);
        }
    }
}
