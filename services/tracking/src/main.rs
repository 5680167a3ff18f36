//! `bdis-tracking`: the tracking service. Reads each frame's grey images in place in shared memory, tracks it
//! (`bdis-track`), and publishes a pose per frame, each new keyframe with its stereo images, pose and
//! intrinsics (for the dense stereo service), and the keyframes bundle adjustment moved. It never waits for a
//! consumer of its outputs: their topics overflow safely. On the end of the stream it writes the trajectory
//! (TUM and KITTI) and the keyframe trajectory into the run folder.

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

use anyhow::{Context, Result, anyhow, bail};
use bdis_core::geometry::StampedPose;
use bdis_ipc::telemetry::MessageTiming;
use bdis_ipc::track::{pose_to_array, tracking_state};
use bdis_ipc::{
    FrameView, Ipc, KeyframeHeader, KeyframePose, PoseRecord, TelemetryPublisher, Topic, event_id, monotonic_ns,
};
use bdis_track::journal::{self, Continuation};
use bdis_track::{StereoCamera, Tracker, TrackerSettings, TrackingState};
use clap::Parser;
use iceoryx2::port::update_connections::UpdateConnections;
use iceoryx2::prelude::*;
use iceoryx2::waitset::WaitSetRunResult;
use nalgebra::Isometry3;

/// Tracking service: stereo frames in; poses, keyframes and pose corrections out.
#[derive(Debug, Parser)]
#[command(name = "bdis-tracking", version)]
struct Args {
    /// Settings file: the camera (fx, fy, cx, cy, bf, width, height, fps), `ThDepth`, `ORBextractor.*`.
    #[arg(long)]
    settings: PathBuf,
    /// Folder for the trajectories (default: the run folder the launcher gives, else the current folder).
    #[arg(long, env = "BDIS_RUN_DIR")]
    out: Option<PathBuf>,
    /// Where local bundle adjustment runs: `worker` (its own thread; the per-frame path never waits for it) or
    /// `inline` (in the tracking thread, at each keyframe: single-core targets, or measuring its cost).
    #[arg(long, default_value = "worker", value_parser = ["worker", "inline"])]
    ba: String,
    /// Keypoint measurements: `aligned` (each match moved to sub-pixel precision by aligning the patch its map
    /// point was first seen with; ATE 2–8× lower on the synthetic sequences, +1–2 ms per frame) or `whole-pixel`
    /// (ORB-SLAM2's FAST positions as they are).
    #[arg(long, default_value = "aligned", value_parser = ["aligned", "whole-pixel"])]
    measurements: String,
    /// Continue after a crashed predecessor: its journal (`tracking.journal` in the run folder) gives the frames
    /// it tracked, the keyframe ids it published and the world frame; a new map continues the same trajectory.
    #[arg(long)]
    resume: bool,
    /// Name of this process in the run.
    #[arg(long, env = "BDIS_SERVICE_NAME", default_value = "tracking")]
    name: String,
    /// Shared-memory name prefix of the run (set by the launcher).
    #[arg(long, env = bdis_ipc::PREFIX_ENV, default_value = bdis_ipc::DEFAULT_PREFIX)]
    ipc_prefix: String,
}

fn main() -> ExitCode {
    bdis_ipc::process::init_logging();
    bdis_ipc::process::finish("bdis-tracking", run(Args::parse()))
}

fn iox(what: &'static str) -> impl FnOnce(&dyn std::fmt::Debug) -> anyhow::Error {
    move |e| anyhow!("{what}: {e:?}")
}

fn state_code(state: TrackingState) -> u32 {
    match state {
        TrackingState::NotInitialized => tracking_state::NOT_INITIALIZED,
        TrackingState::Ok => tracking_state::OK,
        TrackingState::Lost => tracking_state::LOST,
    }
}

fn run(args: Args) -> Result<()> {
    // Everything that can be wrong with the input is found before shared memory is touched.
    let settings = bdis_core::Settings::load(&args.settings)?;
    let camera = settings.camera;
    let (Some(width), Some(height)) = (camera.width, camera.height) else {
        bail!("{}: the tracker needs `Camera.width` and `Camera.height`", args.settings.display());
    };
    if !camera.distortion.is_zero() {
        bail!("{}: Camera.k1…: stereo tracking needs rectified images (no distortion)", args.settings.display());
    }
    let cam = StereoCamera::from_settings(&camera, width as usize, height as usize);
    let tracker_settings = TrackerSettings {
        th_depth: settings.th_depth,
        fps: settings.fps,
        orb: bdis_orb::OrbParams::from_settings(&settings.orb),
    };
    let mut tracker = Tracker::new(cam, tracker_settings).with_context(|| format!("{}", args.settings.display()))?;
    if args.ba == "inline" {
        tracker.set_ba_mode(bdis_track::mapper::BaMode::Inline);
    }
    tracker.set_refinement(args.measurements == "aligned");
    let out_dir = args.out.clone().unwrap_or_else(|| PathBuf::from("."));
    // What earlier instances of this run published (a restart after a crash), and this instance's own journal.
    let journal_path = out_dir.join("tracking.journal");
    let earlier = if args.resume && journal_path.is_file() {
        let text = std::fs::read_to_string(&journal_path)
            .with_context(|| format!("{}: cannot read", journal_path.display()))?;
        Continuation::parse(&text).map_err(|e| anyhow!("{}: {e}", journal_path.display()))?
    } else {
        Continuation::default()
    };
    let mut journal = Journal::open(&journal_path, args.resume)?;
    let mut frame = WorldFrame::continuing(&earlier);
    if let Some(seq) = earlier.last_frame_seq() {
        tracing::info!(
            "resuming after frame {seq}: {} frames and {} keyframes of earlier instances; keyframe ids from {}",
            earlier.frames.len(),
            earlier.keyframes.len(),
            frame.kf_offset
        );
    }

    let ipc = Ipc::open(&args.name, &args.ipc_prefix)?;
    let frames = ipc.frames()?;
    let subscriber = ipc.frame_subscriber(&frames)?;
    let frame_events = ipc.listener(&ipc.events(Topic::Frames)?)?;
    let credits = ipc.notifier(&ipc.frames_consumed()?)?;
    let poses = ipc.poses()?;
    let pose_publisher = poses.publisher_builder().create().map_err(|e| iox("create the poses publisher")(&e))?;
    let pose_events = ipc.notifier(&ipc.events(Topic::Poses)?)?;
    let keyframes = ipc.keyframes()?;
    let frame_bytes = bdis_ipc::FrameLayout::packed(width, height)
        .ok_or_else(|| anyhow!("{width}×{height}: no frame layout"))?
        .payload_len();
    let keyframe_publisher = ipc.keyframe_publisher(&keyframes, frame_bytes)?;
    let keyframe_events = ipc.notifier(&ipc.events(Topic::Keyframes)?)?;
    let corrections = ipc.corrections()?;
    let correction_publisher =
        corrections.publisher_builder().create().map_err(|e| iox("create the corrections publisher")(&e))?;
    let correction_events = ipc.notifier(&ipc.events(Topic::Corrections)?)?;
    // Its declared output is the keyframes topic: that is what the dense stereo consumes (poses and corrections
    // have no process downstream yet).
    let mut telemetry = TelemetryPublisher::new(&ipc, &args.name, Some(Topic::Frames), Some(Topic::Keyframes))?;
    let waitset = WaitSetBuilder::new().create::<ipc::Service>().map_err(|e| iox("create a WaitSet")(&e))?;
    let guard = waitset
        .attach_deadline(&frame_events, Duration::from_secs(1))
        .map_err(|e| iox("attach the frames listener")(&e))?;

    let mut generation = earlier.generation;
    let mut finished = false;
    let mut last_seq: Option<u64> = earlier.last_frame_seq();
    let (mut n_frames, mut n_keyframes, mut n_lost, mut n_relocalised) = (0u64, 0u64, 0u64, 0u64);
    // Per-frame CPU (frames without a new keyframe) and per-keyframe CPU (tracking plus local mapping), ms.
    let (mut frame_ms, mut keyframe_ms) = (Vec::<f64>::with_capacity(4096), Vec::<f64>::with_capacity(1024));
    telemetry.ready();
    bdis_ipc::notify(&credits, event_id::JOINED)?;
    tracing::info!("tracking ready ({}×{}, {} features)", width, height, settings.orb.n_features);

    'outer: loop {
        let result =
            waitset.wait_and_process_once(|_| CallbackProgression::Continue).map_err(|e| iox("wait for frames")(&e))?;
        if matches!(result, WaitSetRunResult::TerminationRequest | WaitSetRunResult::Interrupt) {
            tracing::info!("stop requested after {n_frames} frames");
            break;
        }
        let _ = bdis_ipc::drain_events(&frame_events);
        let _ = &guard;
        telemetry.keepalive();
        // A stereo instance that joined since the last wake-up (a swap, a restart) receives the keyframe history
        // now rather than at the next keyframe, which may be seconds away while the endoscope hovers. Cheap when
        // nothing changed (a generation counter compare).
        if let Err(e) = keyframe_publisher.update_connections() {
            tracing::warn!("keyframes: connecting a new subscriber: {e:?}");
        }
        loop {
            let sample = match subscriber.receive() {
                Ok(Some(s)) => s,
                Ok(None) => break,
                Err(e) => bail!("receive a frame: {e:?}"),
            };
            let t_receive_ns = monotonic_ns();
            let header = *sample.user_header();
            if header.is_end_of_stream() {
                // The last bundle adjustment's corrections go out before the end of the stream, so the mosaic,
                // which stops at the end of the depth stream, has applied them when it writes the map.
                let last = tracker.finish();
                let out = Corrections { publisher: &correction_publisher, events: &correction_events, frame: &frame };
                out.publish(&tracker, &last, &mut generation, &mut journal)?;
                finished = true;
                let mut end = keyframe_publisher
                    .loan_slice_uninit(0)
                    .map_err(|e| anyhow!("loan the end-of-stream keyframe: {e:?}"))?;
                end.user_header_mut().frame = header;
                // SAFETY: a zero-length payload has nothing to initialise.
                let end = unsafe { end.assume_init() };
                end.send().map_err(|e| anyhow!("send the end-of-stream keyframe: {e:?}"))?;
                bdis_ipc::notify(&keyframe_events, event_id::END_OF_STREAM)?;
                let record = PoseRecord {
                    frame_seq: header.frame_seq,
                    state: tracking_state::END_OF_STREAM,
                    ..Default::default()
                };
                pose_publisher.send_copy(record).map_err(|e| anyhow!("send the end-of-stream pose: {e:?}"))?;
                bdis_ipc::notify(&pose_events, event_id::END_OF_STREAM)?;
                tracing::info!("end of stream after {n_frames} frames");
                break 'outer;
            }
            // A frame sent again after a consumer joined (on-demand replay) that this instance already tracked.
            if last_seq.is_some_and(|l| header.frame_seq <= l) {
                drop(sample);
                bdis_ipc::notify(&credits, event_id::CONSUMED)?;
                continue;
            }
            let view = match FrameView::new(sample.user_header(), sample.payload()) {
                Ok(v) if v.header.gray_stride == v.header.width => v,
                Ok(_) => bail!("frame {}: padded grey rows are not supported", header.frame_seq),
                Err(e) => bail!("{e}"),
            };
            if (header.width, header.height) != (width, height) {
                bail!(
                    "frame {} is {}×{}, but {} says Camera.width × Camera.height = {width}×{height}",
                    header.frame_seq,
                    header.width,
                    header.height,
                    args.settings.display()
                );
            }
            // The tracking thread's CPU (bundle adjustment runs on a worker thread and is not part of it).
            let cpu_start = bdis_ipc::clock::thread_cpu_ns();
            let result = tracker
                .track(header.t_source_ns, view.left_gray, view.right_gray)
                .with_context(|| format!("frame {}", header.frame_seq))?;
            let cpu_ns = bdis_ipc::clock::thread_cpu_ns().saturating_sub(cpu_start);
            // A restarted tracker's new map is placed where its predecessor's motion says this frame is.
            if let Some(camera_from_map) = &result.camera_from_world {
                frame.anchor(&earlier, header.frame_seq, &camera_from_map.inverse());
            }
            // A new keyframe goes out with its images (copied from the frame, which goes back to acquisition).
            if let Some(kf) = result.new_keyframe {
                let pose = frame.to_world(&tracker.map.keyframes[kf].camera_from_world.inverse());
                let kf_id = frame.kf_offset + kf as u64;
                // Journalled before it goes out: a crash in between leaves a gap in the ids, never a reused id.
                journal.write(|line| journal::keyframe_line(line, kf_id, header.t_source_ns, &pose));
                let mut loan = keyframe_publisher
                    .loan_slice_uninit(frame_bytes)
                    .map_err(|e| anyhow!("loan a keyframe sample: {e:?}"))?;
                let payload = sample.payload();
                for (d, &b) in loan.payload_mut().iter_mut().zip(&payload[..frame_bytes.min(payload.len())]) {
                    d.write(b);
                }
                // SAFETY: the frame's payload has frame_bytes bytes (checked by FrameView against its layout,
                // and the layout is the packed one of this size), all copied above.
                let mut kf_sample = unsafe { loan.assume_init() };
                *kf_sample.user_header_mut() = KeyframeHeader {
                    frame: bdis_ipc::FrameHeader { t_publish_ns: monotonic_ns(), ..header },
                    kf_id,
                    world_from_camera: pose_to_array(&pose),
                    fx: camera.fx,
                    fy: camera.fy,
                    cx: camera.cx,
                    cy: camera.cy,
                    bf: camera.bf,
                    corrections_generation: generation,
                };
                kf_sample.send().map_err(|e| anyhow!("send keyframe {kf_id}: {e:?}"))?;
                bdis_ipc::notify(&keyframe_events, event_id::NEW_SAMPLE)?;
                n_keyframes += 1;
            }
            drop(sample);
            bdis_ipc::notify(&credits, event_id::CONSUMED)?;
            // Corrections for every keyframe bundle adjustment moved.
            if let Some(report) = &result.mapper {
                let out = Corrections { publisher: &correction_publisher, events: &correction_events, frame: &frame };
                out.publish(&tracker, report, &mut generation, &mut journal)?;
            }
            let world_from_camera = result.camera_from_world.map(|p| frame.to_world(&p.inverse()));
            let t_publish_ns = monotonic_ns();
            let record = PoseRecord {
                frame_seq: header.frame_seq,
                t_capture_ns: header.t_capture_ns,
                t_source_ns: header.t_source_ns,
                t_publish_ns,
                world_from_camera: world_from_camera.map(|p| pose_to_array(&p)).unwrap_or([0.0; 7]),
                state: state_code(result.state),
                inliers: result.inliers as u32,
                new_keyframe: result.new_keyframe.map_or(u64::MAX, |k| frame.kf_offset + k as u64),
                cpu_ns,
            };
            pose_publisher.send_copy(record).map_err(|e| anyhow!("send pose {}: {e:?}", header.frame_seq))?;
            bdis_ipc::notify(&pose_events, event_id::NEW_SAMPLE)?;
            journal.write(|line| {
                journal::frame_line(line, header.frame_seq, header.t_source_ns, world_from_camera.as_ref())
            });
            n_frames += 1;
            n_lost += u64::from(result.state == TrackingState::Lost);
            n_relocalised += u64::from(result.relocalised);
            if result.new_keyframe.is_some() {
                keyframe_ms.push(cpu_ns as f64 / 1e6);
            } else {
                frame_ms.push(cpu_ns as f64 / 1e6);
            }
            last_seq = Some(header.frame_seq);
            if result.state != TrackingState::Ok || result.new_keyframe.is_some() || header.frame_seq % 50 == 0 {
                tracing::info!(
                    "frame {}: {:?}, {} inliers{}, {:.1} ms CPU",
                    header.frame_seq,
                    result.state,
                    result.inliers,
                    result.new_keyframe.map(|k| format!(", keyframe {k}")).unwrap_or_default(),
                    cpu_ns as f64 / 1e6
                );
            }
            telemetry.message(
                MessageTiming {
                    frame_seq: header.frame_seq,
                    t_capture_ns: header.t_capture_ns,
                    t_upstream_publish_ns: header.t_publish_ns,
                    t_receive_ns,
                    t_done_ns: t_publish_ns,
                },
                // The tracker takes every frame: nothing dropped (a slow tracker slows on-demand acquisition).
                0,
            );
        }
    }
    // The last keyframe's bundle adjustment (unless the end of the stream did it), then the trajectories from
    // the final keyframe poses.
    if !finished {
        let last = tracker.finish();
        let out = Corrections { publisher: &correction_publisher, events: &correction_events, frame: &frame };
        out.publish(&tracker, &last, &mut generation, &mut journal)?;
    }
    write_trajectories(&tracker, &earlier, &frame, &out_dir)?;
    let median = |v: &mut Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v.get(v.len() / 2).copied()
    };
    let p99 = |v: &[f64]| v.get(((v.len() as f64 * 0.99) as usize).min(v.len().saturating_sub(1))).copied();
    let summary = serde_json::json!({
        "schema": "bdis.v1.tracking",
        "frames": earlier.frames.len() as u64 + n_frames,
        "frames_of_earlier_instances": earlier.frames.len(),
        "lost": n_lost,
        "relocalisations": n_relocalised,
        "keyframes_created": frame.kf_offset + n_keyframes,
        "keyframes_in_map": tracker.map.n_good_keyframes(),
        "map_points": tracker.map.points.iter().filter(|p| !p.bad).count(),
        "frame_cpu_ms_p50": median(&mut frame_ms),
        "frame_cpu_ms_p99": p99(&frame_ms),
        "keyframe_cpu_ms_p50": median(&mut keyframe_ms),
        "keyframe_cpu_ms_p99": p99(&keyframe_ms),
    });
    let summary_path = out_dir.join("tracking.json");
    std::fs::write(&summary_path, serde_json::to_string_pretty(&summary)?)
        .with_context(|| format!("{}: cannot write", summary_path.display()))?;
    tracing::info!("{n_frames} frames, {n_keyframes} keyframes, {n_lost} lost; trajectories in {}", out_dir.display());
    telemetry.finished();
    Ok(())
}

/// Where a tracker instance's map sits in the run's world frame, and where its keyframe ids start. The first
/// instance's map is the world; a restarted one's is anchored at its first tracked frame.
#[derive(Debug)]
struct WorldFrame {
    world_from_map: Option<Isometry3<f64>>,
    kf_offset: u64,
}

impl WorldFrame {
    fn continuing(earlier: &Continuation) -> Self {
        let first = earlier.frames.is_empty();
        Self { world_from_map: first.then(Isometry3::identity), kf_offset: earlier.next_kf_id() }
    }

    /// Places a restarted tracker's map the first time it has a pose: there, `frame_seq` is where the
    /// predecessor's motion predicts it.
    fn anchor(&mut self, earlier: &Continuation, frame_seq: u64, map_from_camera: &Isometry3<f64>) {
        if self.world_from_map.is_none() {
            let world_from_camera = earlier.predict(frame_seq).unwrap_or_else(Isometry3::identity);
            self.world_from_map = Some(world_from_camera * map_from_camera.inverse());
        }
    }

    fn to_world(&self, map_from_camera: &Isometry3<f64>) -> Isometry3<f64> {
        self.world_from_map.unwrap_or_else(Isometry3::identity) * map_from_camera
    }
}

/// The journal this instance appends to (see [`bdis_track::journal`]). A failed write costs only the ability
/// to resume, so it is reported once and tracking goes on.
struct Journal {
    file: Option<std::fs::File>,
    path: PathBuf,
    /// The line being written, reused: journalling a frame allocates nothing once warmed up.
    line: String,
}

impl Journal {
    fn open(path: &std::path::Path, append: bool) -> Result<Self> {
        let file = std::fs::OpenOptions::new()
            .create(true)
            .append(append)
            .write(true)
            .truncate(!append)
            .open(path)
            .with_context(|| format!("{}: cannot open the tracking journal", path.display()))?;
        Ok(Self { file: Some(file), path: path.to_path_buf(), line: String::with_capacity(256) })
    }

    fn write(&mut self, format: impl FnOnce(&mut String)) {
        use std::io::Write;
        let Some(f) = &mut self.file else { return };
        self.line.clear();
        format(&mut self.line);
        // One write per line: a crash leaves at most the last line torn, which the reader ignores.
        if let Err(e) = f.write_all(self.line.as_bytes()) {
            tracing::warn!("{}: {e}; a restarted tracker could not continue from here", self.path.display());
            self.file = None;
        }
    }
}

/// The corrections topic, with the frame the poses are published in.
struct Corrections<'a> {
    publisher: &'a iceoryx2::port::publisher::Publisher<ipc::Service, KeyframePose, ()>,
    events: &'a iceoryx2::port::notifier::Notifier<ipc::Service>,
    frame: &'a WorldFrame,
}

impl Corrections<'_> {
    fn publish(
        &self,
        tracker: &Tracker,
        report: &bdis_track::mapper::MapperReport,
        generation: &mut u64,
        journal: &mut Journal,
    ) -> Result<()> {
        if report.moved.is_empty() {
            return Ok(());
        }
        *generation += 1;
        let mut send = |k: usize, culled: u32| -> Result<()> {
            let pose = self.frame.to_world(&tracker.map.keyframe_pose(k).inverse());
            let kf_id = self.frame.kf_offset + k as u64;
            let record = KeyframePose {
                kf_id,
                world_from_camera: pose_to_array(&pose),
                generation: *generation,
                culled,
                reserved: 0,
            };
            self.publisher.send_copy(record).map_err(|e| anyhow!("send a correction: {e:?}"))?;
            journal.write(|line| journal::correction_line(line, kf_id, *generation, &pose));
            Ok(())
        };
        for &k in &report.moved {
            send(k, 0)?;
        }
        // A culled keyframe's pose follows its parent's (the mosaic keeps its dense points): it moved too when the
        // first live keyframe up its parent chain did.
        let moved: std::collections::BTreeSet<usize> = report.moved.iter().copied().collect();
        let keyframes = &tracker.map.keyframes;
        for k in (0..keyframes.len()).filter(|&k| keyframes[k].bad) {
            let mut ancestor = keyframes[k].parent;
            for _ in 0..keyframes.len() {
                match ancestor {
                    Some(a) if keyframes[a].bad => ancestor = keyframes[a].parent,
                    _ => break,
                }
            }
            if ancestor.is_some_and(|a| moved.contains(&a)) {
                send(k, 1)?;
            }
        }
        bdis_ipc::notify(self.events, event_id::NEW_SAMPLE)?;
        Ok(())
    }
}

/// trajectory.tum / trajectory.kitti (every tracked frame, from the final keyframe poses; frames of crashed
/// earlier instances as they were published) and keyframes.tum.
fn write_trajectories(
    tracker: &Tracker,
    earlier: &Continuation,
    world: &WorldFrame,
    dir: &std::path::Path,
) -> Result<()> {
    use bdis_core::formats::trajectory::{write_kitti, write_tum};
    let stamped = |t_ns: u64, pose: Isometry3<f64>| StampedPose { t_s: t_ns as f64 * 1e-9, world_from_camera: pose };
    let mut frames: Vec<StampedPose> = Vec::with_capacity(earlier.frames.len() + 4096);
    // An earlier frame without a pose (lost, not initialised) keeps the last pose before it.
    let mut last = Isometry3::identity();
    for &(_, t_ns, pose) in &earlier.frames {
        last = pose.unwrap_or(last);
        frames.push(stamped(t_ns, last));
    }
    frames.extend(tracker.trajectory().into_iter().map(|(t_ns, pose, _lost)| stamped(t_ns, world.to_world(&pose))));
    write_tum(&dir.join("trajectory.tum"), &frames)?;
    let kitti: Vec<_> = frames.iter().map(|p| p.world_from_camera).collect();
    write_kitti(&dir.join("trajectory.kitti"), &kitti)?;
    let mut keyframes: Vec<StampedPose> = earlier.keyframes.values().map(|&(t_ns, pose)| stamped(t_ns, pose)).collect();
    keyframes
        .extend(tracker.keyframe_trajectory().into_iter().map(|(t_ns, pose)| stamped(t_ns, world.to_world(&pose))));
    write_tum(&dir.join("keyframes.tum"), &keyframes)?;
    Ok(())
}
