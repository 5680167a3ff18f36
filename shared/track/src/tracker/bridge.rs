//! The written trajectory across a veil (smoke). A frame seen through a veil is `Uncertain`: its measurements
//! are shifted by the haze blended into every patch, or there were too few to pose it and the motion model
//! coasted it. Live, that pose is the best there is and goes out flagged. Once the frames after the veil are
//! tracked again, the trajectory written at the end (which bundle adjustment's corrections also reach) bridges
//! the veil instead: the smoothest path between the clear frames on both sides, leaving each side at the
//! speed it was moving and turning at the rate it was turning. The veiled frames' own positions are kept only
//! where they agree with the bridge as well as bridges agree with the clear frames near it: a veil's error is
//! mostly not noise that an average would remove but a shift that follows the haze (at 320×240), yet where
//! the veiled frames were measured well (a colon flight at 640×480: within 0.02 mm) they are closer than any
//! curve through the veil (BENCHMARKS.md).
//!
//! Each end of a bridge is read off the clear frames beside it: the end frame's position and the slope through
//! them. After the veil, a frame that strays from a robust line through them further than their scatter
//! explains is left out of both, where the frames lie along a line at all and do not bend beyond their jitter
//! ([`stray_frames`]): the first clear frame after a veil is measured on a map the veil disturbed, and can be
//! tracked `Ok` and be half a millimetre off. Before the veil the tracker has been tracking all along, and a
//! last clear frame off the line is as likely the path turning as a bad pose: it is kept.

use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};

/// The clear frames at each end of a veil whose motion gives the bridge its end velocities: long enough to
/// average a few frames' jitter, short enough to stay the motion of the moment.
pub(super) const VELOCITY_WINDOW_S: f64 = 0.2;

/// How a frame was seen, as far as the bridge is concerned.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum View {
    /// Tracked without doubt, or doubted only for a moving map or a detached segment (both doubt where the
    /// frame is in the world, not its motion), in a clear view: the bridge may end here and take its velocity
    /// from here.
    Clear,
    /// Tracked with no doubt, but its contrast was short of a clear view's ([`super::quality::CONTRAST_RESTORED`]):
    /// a haze coming or going.
    Hazy,
    /// Tracked but doubted for a reason other than a veil (`Uncertain`).
    Doubted,
    /// Seen through a veil (doubted for low contrast), and measured there.
    Veiled,
    /// Under a veil too thick to measure through: the motion model's prediction carried the pose (coasted). Its
    /// position is an extrapolation from one side, which a bridge, made from both, always replaces.
    Coasted,
    /// Lost: extrapolated, not tracked.
    Lost,
}

impl View {
    /// Whether the frame's pose was measured in its own images and not doubted for its fit: clear, hazy or
    /// veiled. A veil's doubt is a shift the haze gives every measurement, bounded; the other doubts say the
    /// pose itself may be wrong (few inliers, no consensus, a jerk's priorless pose), and coasted and lost
    /// frames were not measured at all.
    pub(super) fn is_sound_measurement(self) -> bool {
        matches!(self, Self::Clear | Self::Hazy | Self::Veiled)
    }
}

/// Bridges every run of `Veiled` and `Coasted` frames that has a `Clear` frame on both sides. The bridge also
/// takes in the `Hazy` and `Doubted` frames just before the veil (the haze coming down, before it was thick
/// enough to doubt) and the `Doubted` frames just after it (tracking picking up again: the first frames after a
/// veil are often doubted, and a bridge that ended on one would take its end and its velocity from a pose
/// nobody trusts), but no longer an aftermath than the veil itself: past that the doubted frames' own poses say
/// more than a curve through the veil would. `Lost` frames after the veil are taken in too, when tracking
/// resumes after them. The veil lifts only once the view is clear, so no hazy frame follows one. `t_s` are the
/// frames' times (s), `world_from_camera` their poses, rewritten in place.
pub(super) fn bridge_veils(t_s: &[f64], world_from_camera: &mut [Isometry3<f64>], views: &[View]) {
    let n = t_s.len();
    let clear = |k: usize| views[k] == View::Clear;
    let veiled = |k: usize| matches!(views[k], View::Veiled | View::Coasted);
    let mut k = 0;
    while k < n {
        if !veiled(k) {
            k += 1;
            continue;
        }
        let mut start = k;
        while start > 0 && matches!(views[start - 1], View::Hazy | View::Doubted) {
            start -= 1;
        }
        while k < n && veiled(k) {
            k += 1;
        }
        // The aftermath: doubted frames, for no longer than the veil lasted; lost frames, however long (their
        // poses are extrapolations, which the bridge is too, and a better one once tracking is back).
        let (veil_start_s, veil_end_s) = (t_s[start], t_s[k - 1]);
        while k < n
            && match views[k] {
                View::Lost => true,
                View::Doubted => t_s[k] - veil_end_s <= veil_end_s - veil_start_s,
                _ => false,
            }
        {
            k += 1;
        }
        // Frames start..k are bridged, from start − 1 to k.
        if start == 0 || k == n || !clear(start - 1) || !clear(k) {
            continue;
        }
        bridge_span(t_s, world_from_camera, views, start - 1, k);
    }
}

/// Bridges every run of `Hazy` frames that has a `Clear` frame on both sides: a haze that came down and cleared
/// without thickening into a veil (`Doubt::Hazy`). Its frames are shifted by the haze as a veil's are, only
/// less, and the clear frames on both sides say more: the thin sheet over a 20 fps hover kept its contrast
/// above the veil's half, and its hazy frames were written up to 0.8 mm off (BENCHMARKS.md, fifteenth part).
/// Hazy frames just before a veil are its bridge's ([`bridge_veils`]); a dim view taken as the view after a
/// veil (hazy too) follows that veil, not a clear frame, and is left as it was.
pub(super) fn bridge_hazes(t_s: &[f64], world_from_camera: &mut [Isometry3<f64>], views: &[View]) {
    bridge_runs_between_clear_frames(t_s, world_from_camera, views, View::Hazy);
}

/// Bridges every run of `Lost` frames that has a `Clear` frame on both sides and no veil before it (a veil's
/// bridge takes in the lost frames after it): frames dropped, a cut in the footage, a scope taken out and put
/// back. Live, a lost frame's pose is the motion model's extrapolation; once tracking is back, the frames on
/// both sides say more, above all when a loop has since moved one side (a segment tied back after the loss).
pub(super) fn bridge_losses(t_s: &[f64], world_from_camera: &mut [Isometry3<f64>], views: &[View]) {
    bridge_runs_between_clear_frames(t_s, world_from_camera, views, View::Lost);
}

/// Bridges every run of `view` frames that has a `Clear` frame on both sides.
fn bridge_runs_between_clear_frames(t_s: &[f64], world_from_camera: &mut [Isometry3<f64>], views: &[View], view: View) {
    let n = t_s.len();
    let mut k = 0;
    while k < n {
        if views[k] != view {
            k += 1;
            continue;
        }
        let start = k;
        while k < n && views[k] == view {
            k += 1;
        }
        if start > 0 && k < n && views[start - 1] == View::Clear && views[k] == View::Clear {
            bridge_span(t_s, world_from_camera, views, start - 1, k);
        }
    }
}

/// How a bridge turns the camera between its ends.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Turn {
    /// A cubic in the rotation vector from the first end, meeting both ends' orientations and turn rates: it
    /// follows a turn that speeds up or reverses (a swing through its far end).
    Hermite,
    /// At one steady rate from end to end (a slerp): for motion that turns faster than the end rates say about
    /// the middle (a scope swinging to and fro more than once under a veil), where the cubic overshoots.
    Steady,
}

/// The two ends of a bridge from `Clear` frame `a` to `Clear` frame `b`: their poses and motion.
struct Ends {
    a: usize,
    span: f64,
    p_a: Vector3<f64>,
    p_b: Vector3<f64>,
    v_a: Vector3<f64>,
    v_b: Vector3<f64>,
    r_a: UnitQuaternion<f64>,
    /// The turn from a to b, in the world's frame (as [`Motion::angular`]).
    turn: Vector3<f64>,
    w_a: Vector3<f64>,
    w_b: Vector3<f64>,
}

impl Ends {
    /// `None` when the ends are at one time.
    fn of(t_s: &[f64], world_from_camera: &[Isometry3<f64>], views: &[View], a: usize, b: usize) -> Option<Self> {
        let span = t_s[b] - t_s[a];
        if span <= 0.0 {
            return None;
        }
        let r_a = world_from_camera[a].rotation;
        let turn = (world_from_camera[b].rotation * r_a.inverse()).scaled_axis();
        let (motion_a, motion_b) =
            (motion_at(t_s, world_from_camera, views, a, true), motion_at(t_s, world_from_camera, views, b, false));
        let p_a = motion_a.map_or(world_from_camera[a].translation.vector, |m| m.position);
        let p_b = motion_b.map_or(world_from_camera[b].translation.vector, |m| m.position);
        // Where an end has too few clear frames for its motion: the chord and the steady turn.
        let (chord, steady) = ((p_b - p_a) / span, turn / span);
        let motion = |m: Option<Motion>| m.map_or((chord, steady), |m| (m.velocity, m.angular));
        let ((v_a, w_a), (v_b, w_b)) = (motion(motion_a), motion(motion_b));
        Some(Self { a, span, p_a, p_b, v_a, v_b, r_a, turn, w_a, w_b })
    }

    /// The bridge's pose at time `t`: a cubic Hermite curve meeting both ends' positions and velocities, and the
    /// orientation as `turn` says.
    fn pose_at(&self, t_s: &[f64], t: f64, turn: Turn) -> Isometry3<f64> {
        let u = ((t - t_s[self.a]) / self.span).clamp(0.0, 1.0);
        let (u2, u3) = (u * u, u * u * u);
        let (h_start, h_start_rate) = (2.0 * u3 - 3.0 * u2 + 1.0, self.span * (u3 - 2.0 * u2 + u));
        let (h_end, h_end_rate) = (3.0 * u2 - 2.0 * u3, self.span * (u3 - u2));
        let p = self.p_a * h_start + self.v_a * h_start_rate + self.p_b * h_end + self.v_b * h_end_rate;
        // The same cubic for the rotation vector from a: 0 there, `turn` at b, the turn rates at both ends.
        let from_a = match turn {
            Turn::Hermite => self.w_a * h_start_rate + self.turn * h_end + self.w_b * h_end_rate,
            Turn::Steady => self.turn * u,
        };
        Isometry3::from_parts(Translation3::from(p), UnitQuaternion::from_scaled_axis(from_a) * self.r_a)
    }
}

/// At most this many runs of clear frames are scored on each side of a bridge ([`near_runs`]): a run starting at
/// every frame while there are no more, evenly spaced beyond, so the choice costs a bounded number of bridges
/// however long a run of lost frames is.
const MAX_RUNS_PER_SIDE: usize = 128;

/// What the footage's own clear frames near a bridge say about bridging it.
struct NearRuns {
    /// The way of turning that predicts them better.
    turn: Turn,
    /// The mean squared distance of their positions from bridges over them: how far off a bridge of this
    /// length is here, in position (with the clear poses' own noise). `None` when no run was near.
    position_var: Option<f64>,
}

/// Bridges the runs of clear frames near the bridge from `a` to `b`: each run as long as the bridge, within
/// twice its length before `a` or after `b`, is bridged from its own ends both ways and scored against the
/// frames' measured poses. The motion the veil hides is most like the motion around it; the cubic turn where
/// nothing says otherwise.
fn near_runs(t_s: &[f64], world_from_camera: &[Isometry3<f64>], views: &[View], a: usize, b: usize) -> NearRuns {
    let (n, length, span) = (t_s.len(), b - a, t_s[b] - t_s[a]);
    // Clear frames before each index: whether a run is all clear in one subtraction.
    let mut clear_before = Vec::with_capacity(n + 1);
    clear_before.push(0usize);
    for v in views {
        clear_before.push(clear_before.last().copied().unwrap_or(0) + usize::from(*v == View::Clear));
    }
    let step = (2 * length).div_ceil(MAX_RUNS_PER_SIDE).max(1);
    let before = (a.saturating_sub(3 * length)..=a.saturating_sub(length)).filter(|&j| j + length <= a);
    let after = (b..=b + 2 * length).filter(|&j| j + length < n);
    let (mut hermite, mut steady, mut position_sq, mut positions) = (0.0, 0.0, 0.0, 0usize);
    for j in before.step_by(step).chain(after.step_by(step)) {
        let e = j + length;
        let near = if e <= a { t_s[a] - t_s[j] <= 2.0 * span } else { t_s[e] - t_s[b] <= 2.0 * span };
        if !near || clear_before[e + 1] - clear_before[j] != length + 1 {
            continue;
        }
        let Some(ends) = Ends::of(t_s, world_from_camera, views, j, e) else { continue };
        for i in j + 1..e {
            let measured = &world_from_camera[i];
            let cubic = ends.pose_at(t_s, t_s[i], Turn::Hermite);
            hermite += cubic.rotation.angle_to(&measured.rotation).powi(2);
            steady += ends.pose_at(t_s, t_s[i], Turn::Steady).rotation.angle_to(&measured.rotation).powi(2);
            position_sq += (cubic.translation.vector - measured.translation.vector).norm_squared();
            positions += 1;
        }
    }
    NearRuns {
        turn: if steady < hermite { Turn::Steady } else { Turn::Hermite },
        position_var: (positions > 0).then(|| position_sq / positions as f64),
    }
}

/// Rewrites the frames strictly between `Clear` frames `a` and `b` as the smoothest path between them, leaving
/// each end moving and turning as it was ([`Ends::pose_at`]), unless turning steadily from end to end predicts
/// the clear frames around it better ([`near_runs`]). Slerped between the ends alone (what this was), the
/// orientation under smoke over a colon flight was 1.9° off (0.06° clear; BENCHMARKS.md).
///
/// The veiled frames' own measured positions are kept instead where they stray from the bridge no further than
/// bridges over the clear frames near it stray from those frames' poses (mean squared distance,
/// [`NearRuns`]): nothing then says the haze shifted them, and a measured position has what a bridge cannot
/// see (a colon flight's wobble under a 1.2 s veil at 640×480: the bridge 0.07 mm off, the tracked poses
/// 0.02 mm). Where they stray further, the haze shifted them (at 320×240 by 0.2–1.7 mm) and the bridge stands.
/// The orientation is the bridge's either way. A blend weighted by the two spreads was tried and lost on
/// renders where the haze's shift is a bias, not noise (BENCHMARKS.md).
///
/// Coasted frames are no measurement: they are written as the bridge either way. They do count in the
/// comparison, as the veil's: a veil thick enough to coast through shifted the frames measured beside it too
/// (left out, the positions of more such veils were kept, and the colon renders under a cloud at 320×240 came
/// out 2–8 % worse; BENCHMARKS.md).
fn bridge_span(t_s: &[f64], world_from_camera: &mut [Isometry3<f64>], views: &[View], a: usize, b: usize) {
    let Some(ends) = Ends::of(t_s, world_from_camera, views, a, b) else { return };
    let near = near_runs(t_s, world_from_camera, views, a, b);
    let veiled = || (a + 1..b).filter(|&i| matches!(views[i], View::Veiled | View::Coasted));
    let bridged = |i: usize| ends.pose_at(t_s, t_s[i], near.turn);
    let strayed_sq: f64 = veiled()
        .map(|i| (world_from_camera[i].translation.vector - bridged(i).translation.vector).norm_squared())
        .sum();
    let count = veiled().count();
    let keep_measured = near.position_var.is_some_and(|var| count > 0 && strayed_sq <= var * count as f64);
    for i in a + 1..b {
        let mut pose = bridged(i);
        if keep_measured && views[i] == View::Veiled {
            pose.translation = world_from_camera[i].translation;
        }
        world_from_camera[i] = pose;
    }
}

/// Where the camera is at time `t` (s) if it kept the motion it had at the last frame soundly measured in its
/// own images ([`View::is_sound_measurement`]): that frame's pose carried on at the mean twist, in the camera's
/// own frame, of the sound frames within [`VELOCITY_WINDOW_S`] before it (ORB-SLAM2's constant velocity, over
/// a window rather than one step, whose jitter a long gap would multiply); left where it was when fewer than
/// three frames give a motion. `None` when no frame was soundly measured.
///
/// From the last sound frame, veiled or not: dead reckoning's error grows with the time it is carried over, and
/// a veiled frame is off by no more than the haze shifts it (a colon flight that turned under a 1.1 s veil: a
/// segment begun 16° off carried on from the last clear frame, 1.7° from the last veiled one). A twist in the
/// camera's frame rather than a world velocity and turn rate: a scope that turns along a bend moves along an
/// arc, and over seven colon renders under smoke the twist's ATE was lower than or equal to the world
/// velocity's on all but one (BENCHMARKS.md).
pub(super) fn carried_on(
    t_s: &[f64],
    world_from_camera: &[Isometry3<f64>],
    views: &[View],
    t: f64,
) -> Option<Isometry3<f64>> {
    let last = views.iter().rposition(|v| v.is_sound_measurement())?;
    let mut first = last;
    while first > 0 && views[first - 1].is_sound_measurement() && t_s[last] - t_s[first - 1] <= VELOCITY_WINDOW_S {
        first -= 1;
    }
    let span = t_s[last] - t_s[first];
    let camera_from_world = world_from_camera[last].inverse();
    if last - first < 2 || span <= 0.0 {
        return Some(world_from_camera[last]);
    }
    // The mean twist over the window, in the camera's frame: C_last · C_first⁻¹ per second.
    let twist = crate::loop_closing::log_se3(&(camera_from_world * world_from_camera[first])) / span;
    let dt = (t - t_s[last]).max(0.0);
    Some((crate::geometry::exp_se3(&(twist * dt)) * camera_from_world).inverse())
}

/// The motion at a clear frame, from the clear frames next to it on one side.
#[derive(Debug, Clone, Copy)]
struct Motion {
    /// World position per second.
    velocity: Vector3<f64>,
    /// World rotation per second (axis × angle).
    angular: Vector3<f64>,
    /// Where the frame is, as its window has it: its own position, or where the line through the rest of the
    /// window puts it when it strays ([`stray_frames`]).
    position: Vector3<f64>,
}

/// χ²'s 95 % quantile with three degrees of freedom (the stereo gate's, [`crate::optim::CHI2_STEREO`]): a
/// position's squared distance from a line, in units of the scatter's variance per axis, beyond which it strays.
const STRAY_CHI2: f64 = crate::optim::CHI2_STEREO;

/// Which of a window's positions stray from it: with the window as a straight line (per axis the median of the
/// pairwise slopes, Theil–Sen, and the median intercept, so one frame off in seven cannot tilt it), those
/// further from it than [`STRAY_CHI2`] times the scatter about the least-squares line. `None` where no line is
/// to be had: fewer than four frames, or a window a quadratic fits better than its scatter explains (an F-test
/// of the quadratic term over the three axes pooled, at 95 %), as a colon's wobble bends the path within 0.2 s
/// and its last frame is then no stray but the bend.
fn stray_frames(t: &[f64], p: &[Vector3<f64>]) -> Option<Vec<bool>> {
    let n = t.len();
    if n < 4 {
        return None;
    }
    let count = n as f64;
    let t_mean = t.iter().sum::<f64>() / count;
    // Least squares in (1, dt, dt²) with dt from the mean time, all axes at once.
    let (mut normal, mut rhs) = (nalgebra::Matrix3::<f64>::zeros(), nalgebra::Matrix3::<f64>::zeros());
    for (&ti, pi) in t.iter().zip(p) {
        let dt = ti - t_mean;
        let basis = Vector3::new(1.0, dt, dt * dt);
        normal += basis * basis.transpose();
        rhs += basis * pi.transpose();
    }
    let quadratic = normal.cholesky()?.solve(&rhs);
    let p_mean = rhs.row(0).transpose() / count;
    let slope = rhs.row(1).transpose() / normal[(1, 1)];
    let (mut rss_line, mut rss_quadratic) = (0.0, 0.0);
    for (&ti, pi) in t.iter().zip(p) {
        let dt = ti - t_mean;
        rss_line += (pi - p_mean - slope * dt).norm_squared();
        rss_quadratic += (pi - quadratic.transpose() * Vector3::new(1.0, dt, dt * dt)).norm_squared();
    }
    // F = ((RSS_line − RSS_quad) / 3) / (RSS_quad / 3(n − 3)), compared without dividing (both may be 0).
    let residual_dof = 3.0 * (count - 3.0);
    let critical = crate::stats::f_quantile(0.95, 3.0, residual_dof);
    if (rss_line - rss_quadratic) * residual_dof > critical * 3.0 * rss_quadratic {
        return None;
    }
    let (mut robust_slope, mut robust_at_mean) = (Vector3::zeros(), Vector3::zeros());
    let mut values = Vec::with_capacity(n * (n - 1) / 2);
    for axis in 0..3 {
        values.clear();
        for i in 0..n {
            values.extend((i + 1..n).filter(|&j| t[j] != t[i]).map(|j| (p[j][axis] - p[i][axis]) / (t[j] - t[i])));
        }
        robust_slope[axis] = median(&mut values)?;
        values.clear();
        values.extend(t.iter().zip(p).map(|(&ti, pi)| pi[axis] - robust_slope[axis] * (ti - t_mean)));
        robust_at_mean[axis] = median(&mut values)?;
    }
    let scatter_var = rss_line / (3.0 * (count - 2.0));
    let off_line =
        |(&ti, pi): (&f64, &Vector3<f64>)| (pi - robust_at_mean - robust_slope * (ti - t_mean)).norm_squared();
    Some(t.iter().zip(p).map(|x| off_line(x) > STRAY_CHI2 * scatter_var).collect())
}

/// The median of `values` (reordered), the mean of the middle two for an even count; `None` when empty.
fn median(values: &mut [f64]) -> Option<f64> {
    let n = values.len();
    if n == 0 {
        return None;
    }
    values.sort_by(f64::total_cmp);
    Some(if n % 2 == 1 { values[n / 2] } else { 0.5 * (values[n / 2 - 1] + values[n / 2]) })
}

/// The least-squares line through the positions `p` at times `t` that `keep` keeps: (mean time, mean position,
/// slope). `None` without two distinct times kept.
fn line_through(
    t: &[f64],
    p: &[Vector3<f64>],
    keep: impl Fn(usize) -> bool,
) -> Option<(f64, Vector3<f64>, Vector3<f64>)> {
    let kept = || (0..t.len()).filter(|&i| keep(i));
    let count = kept().count() as f64;
    let t_mean = kept().map(|i| t[i]).sum::<f64>() / count;
    let p_mean = kept().map(|i| p[i]).sum::<Vector3<f64>>() / count;
    let (mut num, mut den) = (Vector3::zeros(), 0.0);
    for i in kept() {
        let dt = t[i] - t_mean;
        num += (p[i] - p_mean) * dt;
        den += dt * dt;
    }
    (den > 0.0).then(|| (t_mean, p_mean, num / den))
}

/// The motion at `Clear` frame `from`, from the clear frames within [`VELOCITY_WINDOW_S`] of it on one side
/// (`towards_past`: before it): the least-squares slope of position over time through them (a slope through
/// many frames, not a difference of two, so the frames' own jitter does not bend what is made of it), and the
/// rotation across the window over its time. `None` with fewer than three such frames.
///
/// After a gap (`towards_past` false: `from` is the first clear frame after a veil or a loss), the frames that
/// stray ([`stray_frames`]) are left out while three are kept, and `from`'s position, if it strays, is where
/// the rest put it. Before a gap nothing is left out: on a colon flight at 60 fps the last clear frame before
/// the veil strayed by 0.05 mm (over 4 σ) and was where the camera was; put on the line, it took that run's
/// ATE from 0.042 to 0.051 mm (BENCHMARKS.md).
fn motion_at(
    t_s: &[f64],
    world_from_camera: &[Isometry3<f64>],
    views: &[View],
    from: usize,
    towards_past: bool,
) -> Option<Motion> {
    let n = t_s.len();
    let clear = |k: usize| views[k] == View::Clear;
    let mut far = from;
    loop {
        let next = if towards_past { far.checked_sub(1) } else { Some(far + 1).filter(|&j| j < n) };
        match next {
            Some(j) if clear(j) && (t_s[j] - t_s[from]).abs() <= VELOCITY_WINDOW_S => far = j,
            _ => break,
        }
    }
    let (lo, hi) = if towards_past { (far, from) } else { (from, far) };
    let span = t_s[hi] - t_s[lo];
    if hi - lo < 2 || span <= 0.0 {
        return None;
    }
    let times = &t_s[lo..=hi];
    let positions: Vec<Vector3<f64>> = world_from_camera[lo..=hi].iter().map(|w| w.translation.vector).collect();
    let strays = (!towards_past)
        .then(|| stray_frames(times, &positions))
        .flatten()
        .filter(|s| s.iter().filter(|&&x| !x).count() >= 3);
    let strayed = |i: usize| strays.as_ref().is_some_and(|s| s[i]);
    let (t_mean, p_mean, velocity) = line_through(times, &positions, |i| !strayed(i))?;
    let position = if strayed(from - lo) {
        p_mean + velocity * (t_s[from] - t_mean)
    } else {
        world_from_camera[from].translation.vector
    };
    let turn = world_from_camera[hi].rotation * world_from_camera[lo].rotation.inverse();
    Some(Motion { velocity, angular: turn.scaled_axis() / span, position })
}

#[cfg(test)]
mod tests;
