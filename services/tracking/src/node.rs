//! The tracking node: its ports, the per-frame loop (track, publish the pose, a new keyframe with its images,
//! the corrections bundle adjustment made), the end of the stream, and the trajectories and summary written at
//! the end. The tracker itself is `bdis_track`; the loop is `bdis_node::serve`. It never waits for a consumer
//! of its outputs: their topics overflow safely.

use std::path::{Path, PathBuf};

use crate::counts::Counts;
use anyhow::{Context, Result, bail};
use bdis_core::RectifiedCamera;
use bdis_core::formats::summary::TrackingSummary;
use bdis_core::geometry::StampedPose;
use bdis_ipc::telemetry::MessageTiming;
use bdis_ipc::track::{doubt, pose_method, pose_to_array, tracking_state};
use bdis_ipc::validate::{self, Admit, StreamGuard};
use bdis_ipc::{
    FrameHeader, FrameView, Ipc, KeyframeHeader, KeyframeMeta, KeyframePose, PoseRecord, StereoIntrinsics,
    TelemetryPublisher, Topic, event_id, monotonic_ns,
};
use bdis_node::{Ended, Flow};
use bdis_track::mapper::MapperReport;
use bdis_track::{Doubt, PoseMethod, Tracker, TrackingState};
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::update_connections::UpdateConnections;
use iceoryx2::prelude::*;
use nalgebra::Isometry3;

use crate::journal::{self, Continuation, JournalWriter};
use crate::world::WorldFrame;

/// A checked tracker, ready to run, and what earlier instances of the run published.
#[derive(Debug)]
pub struct Config {
    pub tracker: Tracker,
    pub earlier: Continuation,
    pub world: WorldFrame,
    pub journal: JournalWriter,
    /// The camera: its intrinsics go out with every keyframe, its size is every frame's.
    pub camera: RectifiedCamera,
    pub n_features: u32,
    /// Our own instrument estimate for frames without a mask; `None`: off.
    pub instruments: Option<bdis_track::instruments::InstrumentMasker>,
    /// The settings file, named in errors about frame sizes.
    pub settings: PathBuf,
    pub out_dir: PathBuf,
    pub name: String,
    pub ipc_prefix: String,
}

fn state_code(state: TrackingState) -> u32 {
    match state {
        TrackingState::NotInitialized => tracking_state::NOT_INITIALIZED,
        TrackingState::Ok => tracking_state::OK,
        TrackingState::Uncertain => tracking_state::UNCERTAIN,
        TrackingState::Lost => tracking_state::LOST,
    }
}

fn doubt_code(doubt: Option<Doubt>) -> u32 {
    match doubt {
        None => doubt::NONE,
        Some(Doubt::FewInliers) => doubt::FEW_INLIERS,
        Some(Doubt::LowInlierRatio) => doubt::LOW_INLIER_RATIO,
        Some(Doubt::IllConditioned) => doubt::ILL_CONDITIONED,
        Some(Doubt::AppearanceDisagrees) => doubt::APPEARANCE_DISAGREES,
        Some(Doubt::LowContrast) => doubt::LOW_CONTRAST,
        Some(Doubt::MapMoving) => doubt::MAP_MOVING,
        Some(Doubt::Detached) => doubt::DETACHED,
        Some(Doubt::PriorlessFewInliers) => doubt::PRIORLESS_FEW_INLIERS,
        Some(Doubt::Unconfirmed) => doubt::UNCONFIRMED,
        Some(Doubt::UnconfirmedPrior) => doubt::UNCONFIRMED_PRIOR,
        Some(Doubt::Hazy) => doubt::HAZY,
    }
}

fn method_code(method: PoseMethod) -> u32 {
    match method {
        PoseMethod::None => pose_method::NONE,
        PoseMethod::Initialisation => pose_method::INITIALISATION,
        PoseMethod::MotionModel => pose_method::MOTION_MODEL,
        PoseMethod::Appearance => pose_method::APPEARANCE,
        PoseMethod::ReferenceProjection => pose_method::REFERENCE_PROJECTION,
        PoseMethod::Relocalisation => pose_method::RELOCALISATION,
        PoseMethod::Prediction => pose_method::PREDICTION,
    }
}

/// The tracker's three outputs, in the run's world frame, each journalled before it goes out.
struct Outputs {
    poses: Publisher<ipc::Service, PoseRecord, ()>,
    pose_events: Notifier<ipc::Service>,
    keyframes: Publisher<ipc::Service, [u8], KeyframeHeader>,
    keyframe_events: Notifier<ipc::Service>,
    corrections: Publisher<ipc::Service, KeyframePose, ()>,
    correction_events: Notifier<ipc::Service>,
    world: WorldFrame,
    journal: JournalWriter,
    /// The generation of the last correction sent.
    generation: u64,
    camera: RectifiedCamera,
    /// A keyframe's payload: the packed images of the run's size and a mask plane.
    keyframe_layout: bdis_ipc::FrameLayout,
}

impl Outputs {
    /// A new keyframe with its images and `mask` (the frame's or our estimate), copied from the frame, which
    /// goes back to acquisition, packed whatever the frame's layout.
    fn keyframe(&mut self, tracker: &Tracker, kf: usize, view: &FrameView, mask: Option<&[u8]>) -> Result<()> {
        let header = view.header;
        let pose = self.world.to_world(&tracker.map().keyframes[kf].camera_from_world.inverse());
        let kf_id = self.world.kf_id(kf);
        // Journalled before it goes out: a crash in between leaves a gap in the ids, never a reused id.
        self.journal.write(|line| journal::keyframe_line(line, kf_id, header.t_source_ns, &pose));
        let layout = self.keyframe_layout;
        let bytes = layout.payload_len();
        let mut loan = self.keyframes.loan_slice_uninit(bytes).context("loan a keyframe sample")?;
        let payload = loan.payload_mut();
        let n = layout.width as usize * layout.height as usize;
        let mask_offset = layout.mask_offset.unwrap_or_default() as usize;
        let mut written = 0;
        for (offset, len, image) in [
            (layout.left_gray_offset as usize, n, view.left_gray),
            (layout.right_gray_offset as usize, n, view.right_gray),
            (layout.left_rgb_offset as usize, 3 * n, view.left_rgb),
        ] {
            written += bdis_node::copy_into(&mut payload[offset..offset + len], image);
        }
        match mask {
            Some(mask) => written += bdis_node::copy_into(&mut payload[mask_offset..mask_offset + n], mask),
            None => {
                payload[mask_offset..mask_offset + n].iter_mut().for_each(|b| {
                    b.write(0);
                });
                written += n;
            }
        }
        if written != bytes {
            bail!("frame {}: wrote {written} of a keyframe's {bytes} bytes", header.frame_seq);
        }
        // SAFETY: all bytes of the loan were written (counted just above).
        let mut sample = unsafe { loan.assume_init() };
        let mut frame = FrameHeader {
            t_publish_ns: monotonic_ns(),
            // ANSWERS_JOIN is acquisition's word to its own consumers; it does not travel on.
            flags: header.flags & !FrameHeader::ANSWERS_JOIN,
            ..*header
        };
        // The keyframe's own layout; the mask plane counts only when the frame had a mask.
        let carried = if mask.is_some() { layout } else { bdis_ipc::FrameLayout { mask_offset: None, ..layout } };
        carried.write_into(&mut frame);
        *sample.user_header_mut() = KeyframeHeader {
            frame,
            meta: KeyframeMeta {
                kf_id,
                world_from_camera: pose_to_array(&pose),
                intrinsics: StereoIntrinsics::of(&self.camera),
                corrections_generation: self.generation,
            },
        };
        sample.send().with_context(|| format!("send keyframe {kf_id}"))?;
        bdis_ipc::notify(&self.keyframe_events, event_id::NEW_SAMPLE)?;
        Ok(())
    }

    /// Corrections for every keyframe bundle adjustment moved, and for the culled keyframes that moved with
    /// them, as one new generation.
    fn corrections(&mut self, tracker: &Tracker, report: &MapperReport) -> Result<()> {
        if report.moved.is_empty() {
            return Ok(());
        }
        self.generation += 1;
        let culled = tracker.map().culled_following(&report.moved);
        let moved = report.moved.iter().map(|&k| (k, 0)).chain(culled.into_iter().map(|k| (k, 1)));
        // Veiled keyframes were never published (`run`): nothing downstream holds them.
        for (k, culled) in moved.filter(|&(k, _)| !tracker.map().keyframes[k].veiled) {
            let pose = self.world.to_world(&tracker.map().keyframe_pose(k).inverse());
            let kf_id = self.world.kf_id(k);
            let record = KeyframePose {
                kf_id,
                world_from_camera: pose_to_array(&pose),
                generation: self.generation,
                culled,
                reserved: 0,
            };
            self.corrections.send_copy(record).context("send a correction")?;
            let generation = self.generation;
            self.journal.write(|line| journal::correction_line(line, kf_id, generation, &pose));
        }
        bdis_ipc::notify(&self.correction_events, event_id::NEW_SAMPLE)?;
        Ok(())
    }

    /// The end of the keyframe and pose streams, after the input's.
    fn end_of_stream(&self, header: &FrameHeader) -> Result<()> {
        bdis_node::send_end_of_stream(&self.keyframes, KeyframeHeader { frame: *header, ..Default::default() })?;
        bdis_ipc::notify(&self.keyframe_events, event_id::END_OF_STREAM)?;
        let record =
            PoseRecord { frame_seq: header.frame_seq, state: tracking_state::END_OF_STREAM, ..Default::default() };
        self.poses.send_copy(record).context("send the end-of-stream pose")?;
        bdis_ipc::notify(&self.pose_events, event_id::END_OF_STREAM)?;
        Ok(())
    }
}

pub fn run(config: Config) -> Result<()> {
    let Config {
        mut tracker,
        earlier,
        world,
        journal,
        camera,
        n_features,
        mut instruments,
        settings,
        out_dir,
        name,
        ipc_prefix,
    } = config;
    let (width, height) = (camera.width, camera.height);
    let ipc = Ipc::open(&name, &ipc_prefix)?;
    let frames = ipc.frames()?;
    let subscriber = ipc.frame_subscriber(&frames)?;
    let frame_events = ipc.listener(&ipc.events(Topic::Frames)?)?;
    let credits = ipc.notifier(&ipc.frames_consumed()?)?;
    let keyframe_layout = bdis_ipc::FrameLayout::packed(width, height)
        .and_then(bdis_ipc::FrameLayout::with_mask_plane)
        .with_context(|| format!("{width}×{height}: no frame layout"))?;
    let keyframes = ipc.keyframes()?;
    let mut out = Outputs {
        poses: ipc.poses()?.publisher_builder().create().context("create the poses publisher")?,
        pose_events: ipc.notifier(&ipc.events(Topic::Poses)?)?,
        keyframes: ipc.keyframe_publisher(&keyframes, keyframe_layout.payload_len())?,
        keyframe_events: ipc.notifier(&ipc.events(Topic::Keyframes)?)?,
        corrections: ipc.corrections()?.publisher_builder().create().context("create the corrections publisher")?,
        correction_events: ipc.notifier(&ipc.events(Topic::Corrections)?)?,
        world,
        journal,
        generation: earlier.generation,
        camera,
        keyframe_layout,
    };
    // Its declared output is the keyframes topic: that is what the dense stereo consumes (poses and corrections
    // have no process downstream yet).
    let mut telemetry = TelemetryPublisher::new(&ipc, &name, Some(Topic::Frames), Some(Topic::Keyframes))?;

    let mut finished = false;
    // Frames this run's earlier instances tracked are replays to skip; ids must grow; an end of stream must be
    // numbered after the last frame (see bdis_ipc::validate::StreamGuard).
    let mut stream: StreamGuard = StreamGuard::resuming_after(earlier.last_frame_seq());
    let mut counts =
        Counts { frame_ms: Vec::with_capacity(4096), keyframe_ms: Vec::with_capacity(1024), ..Default::default() };
    let mut quality_log = crate::quality_log::QualityLog::open(&out_dir, earlier.last_frame_seq().is_some())?;
    // Frames acquisition published that this instance never saw (overwritten while it was busy); the stream's
    // frames are numbered from 0, so a first frame numbered later says how many were missed before it.
    let (mut missed_frames, mut last_tracked): (u64, Option<u64>) = (0, earlier.last_frame_seq());
    telemetry.ready();
    bdis_ipc::notify(&credits, event_id::JOINED)?;
    tracing::info!("tracking ready ({width}×{height}, {n_features} features)");

    let ended = bdis_node::serve(&[&frame_events], &mut telemetry, |telemetry| -> Result<Flow> {
        // A stereo instance that joined since the last wake-up (a swap, a restart) receives the keyframe history
        // now rather than at the next keyframe, which may be seconds away while the endoscope hovers. Cheap when
        // nothing changed (a generation counter compare).
        if let Err(e) = out.keyframes.update_connections() {
            tracing::warn!("keyframes: connecting a new subscriber: {e:?}");
        }
        while let Some(sample) = subscriber.receive().context("receive a frame")? {
            let t_receive_ns = monotonic_ns();
            let header = *sample.user_header();
            let origin = sample.origin();
            if header.is_end_of_stream() {
                if let Err(rejection) = stream.end_of_stream(header.frame_seq, "frames") {
                    telemetry.rejected(Topic::Frames, &rejection);
                    continue;
                } // The last bundle adjustment's corrections go out before the end of the stream, so the mosaic,
                // which stops at the end of the depth stream, has applied them when it writes the map.
                // Frames between the last one taken and the end of the stream were overwritten unseen.
                missed_frames += header.frame_seq.saturating_sub(last_tracked.map_or(0, |last| last + 1));
                telemetry.set_dropped(missed_frames);
                let last = tracker.finish();
                out.corrections(&tracker, &last)?;
                finished = true;
                out.end_of_stream(&header)?;
                tracing::info!("end of stream after {} frames", counts.frames);
                return Ok(Flow::Finished);
            }
            // A frame refused, or sent again after a consumer joined (on-demand replay) that this instance already
            // tracked, is released at once. The credit goes back only for what acquisition sent (it waits for
            // it); a stray publisher's sample earns none, or it would make acquisition run ahead and overflow.
            let checked = stream.admit(header.frame_seq, origin, "frame").and_then(|admit| {
                let view =
                    validate::packed_frame(&header, sample.payload(), Some((width, height))).map_err(|mut r| {
                        if r.reason == validate::Reason::Dimensions {
                            r.detail += &format!(" (Camera.width × Camera.height in {})", settings.display());
                        }
                        r
                    })?;
                Ok((admit, view))
            });
            let view = match checked {
                Ok((Admit::New, view)) => view,
                Ok((Admit::Replay, _)) | Err(_) => {
                    if let Err(rejection) = &checked {
                        telemetry.rejected(Topic::Frames, rejection);
                    }
                    let from_producer = !stream.knows_producer() || stream.is_producer(origin);
                    drop(sample);
                    if from_producer {
                        bdis_ipc::notify(&credits, event_id::CONSUMED)?;
                    }
                    continue;
                }
            };
            missed_frames += header.frame_seq.saturating_sub(last_tracked.map_or(0, |last| last + 1));
            last_tracked = Some(header.frame_seq);
            // The tracking thread's CPU (bundle adjustment runs on a worker thread and is not part of it).
            let cpu_start = bdis_ipc::clock::thread_cpu_ns();
            // The frame's own mask, else our estimate (its cost is the tracking thread's: it is counted).
            let keep_out = match (view.mask, &mut instruments) {
                (Some(mask), _) => Some(mask),
                (None, Some(masker)) => {
                    let found = masker.estimate(view.left_rgb, width as usize, height as usize);
                    (found.regions > 0).then(|| masker.mask())
                }
                (None, None) => None,
            };
            let result = tracker
                .track_masked(header.t_source_ns, view.left_gray, view.right_gray, keep_out)
                .with_context(|| format!("frame {}", header.frame_seq))?;
            let cpu_ns = bdis_ipc::clock::thread_cpu_ns().saturating_sub(cpu_start);
            // A restarted tracker's new map is placed where its predecessor's motion says this frame is.
            if let Some(camera_from_map) = &result.camera_from_world {
                out.world.anchor(&earlier, header.frame_seq, &camera_from_map.inverse());
            }
            // A keyframe made under a veil (smoke) serves tracking: its images are no view to take depth from,
            // so the dense map never hears of it.
            let published = result.new_keyframe.filter(|&k| !tracker.map().keyframes[k].veiled);
            if let Some(kf) = published {
                out.keyframe(&tracker, kf, &view, keep_out)?;
            }
            counts.keyframes += u64::from(result.new_keyframe.is_some());
            drop(sample);
            if let Some(report) = &result.mapper {
                out.corrections(&tracker, report)?;
                counts.loop_report(report);
            }
            let world_from_camera = result.camera_from_world.map(|p| out.world.to_world(&p.inverse()));
            let t_publish_ns = monotonic_ns();
            let record = PoseRecord {
                frame_seq: header.frame_seq,
                t_capture_ns: header.t_capture_ns,
                t_source_ns: header.t_source_ns,
                t_publish_ns,
                world_from_camera: world_from_camera.map(|p| pose_to_array(&p)).unwrap_or([0.0; 7]),
                state: state_code(result.state),
                inliers: result.inliers as u32,
                new_keyframe: published.map_or(u64::MAX, |k| out.world.kf_id(k)),
                cpu_ns,
                matched: result.quality.matched,
                doubt: doubt_code(result.quality.doubt),
                method: method_code(result.quality.method),
                prior_rejected: u32::from(result.quality.prior_rejected),
                reprojection_rms_px: result.quality.reprojection_rms_px,
                position_sigma_rel: result.quality.position_sigma_rel,
                appearance_agreement: result.quality.appearance_agreement,
            };
            out.poses.send_copy(record).with_context(|| format!("send pose {}", header.frame_seq))?;
            bdis_ipc::notify(&out.pose_events, event_id::NEW_SAMPLE)?;
            out.journal.write(|line| {
                journal::frame_line(line, header.frame_seq, header.t_source_ns, world_from_camera.as_ref())
            });
            // Released only once journalled: acquisition sends a replacement instance every frame this one has
            // not released, and one released before its journal line would be lost with a crash in between.
            bdis_ipc::notify(&credits, event_id::CONSUMED)?;
            counts.frames += 1;
            if result.state == TrackingState::Lost {
                counts.lost += 1;
                if let Some(d) = result.quality.doubt {
                    *counts.lost_reasons.entry(d.name()).or_default() += 1;
                }
            }
            if result.state == TrackingState::Uncertain {
                counts.uncertain += 1;
                if let Some(d) = result.quality.doubt {
                    *counts.doubts.entry(d.name()).or_default() += 1;
                }
            }
            if result.quality.method == PoseMethod::Appearance {
                counts.appearance_frames += 1;
                counts.appearance_ms.push(cpu_ns as f64 / 1e6);
            }
            counts.priors_rejected += u64::from(result.quality.prior_rejected);
            quality_log.frame(header.frame_seq, &result, cpu_ns, result.new_keyframe.map(|k| out.world.kf_id(k)))?;
            counts.relocalised += u64::from(result.relocalised);
            counts.segments_begun += u64::from(result.new_segment);
            if result.new_keyframe.is_some() {
                counts.keyframe_ms.push(cpu_ns as f64 / 1e6);
            } else {
                counts.frame_ms.push(cpu_ns as f64 / 1e6);
            }
            stream.taken(header.frame_seq, header.frame_seq, origin);
            if result.state != TrackingState::Ok || result.new_keyframe.is_some() || header.frame_seq % 50 == 0 {
                tracing::info!(
                    "frame {}: {:?}{}, {} inliers, posed by {}{}, {:.1} ms CPU",
                    header.frame_seq,
                    result.state,
                    result.quality.doubt.map(|d| format!(" ({})", d.name())).unwrap_or_default(),
                    result.inliers,
                    result.quality.method.name(),
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
                // On demand the tracker takes every frame (a slow tracker slows acquisition); behind a rate or a
                // live device, the frames it was too slow for are gaps in the frame numbers.
                missed_frames,
            );
        }
        Ok(Flow::Continue)
    })?;
    if ended == Ended::StopRequested {
        tracing::info!("stop requested after {} frames", counts.frames);
    }
    // The last keyframe's bundle adjustment (unless the end of the stream did it), then the trajectories from
    // the final keyframe poses.
    if !finished {
        let last = tracker.finish();
        out.corrections(&tracker, &last)?;
    }
    quality_log.finish()?;
    write_trajectories(&tracker, &earlier, &out.world, &out_dir)?;
    write_summary(&tracker, &earlier, &out.world, &mut counts, &out_dir)?;
    tracing::info!(
        "{} frames, {} keyframes, {} lost; trajectories in {}",
        counts.frames,
        counts.keyframes,
        counts.lost,
        out_dir.display()
    );
    telemetry.finished();
    Ok(())
}

/// tracking.json: what this run of the tracker did, over every instance.
fn write_summary(
    tracker: &Tracker,
    earlier: &Continuation,
    world: &WorldFrame,
    counts: &mut Counts,
    dir: &Path,
) -> Result<()> {
    use bdis_core::stats::percentile;
    let summary = TrackingSummary {
        schema: TrackingSummary::SCHEMA.to_string(),
        frames: earlier.frames.len() as u64 + counts.frames,
        frames_of_earlier_instances: earlier.frames.len() as u64,
        lost: counts.lost,
        lost_reasons: counts.lost_reasons.iter().map(|(k, v)| ((*k).to_string(), *v)).collect(),
        uncertain: counts.uncertain,
        doubts: counts.doubts.iter().map(|(k, v)| ((*k).to_string(), *v)).collect(),
        appearance_frames: counts.appearance_frames,
        priors_rejected: counts.priors_rejected,
        appearance_frame_cpu_ms_p50: percentile(&mut counts.appearance_ms, 0.5),
        appearance_frame_cpu_ms_p99: percentile(&mut counts.appearance_ms, 0.99),
        relocalisations: counts.relocalised,
        segments_begun: counts.segments_begun,
        keyframes_created: world.kf_offset + counts.keyframes,
        keyframes_in_map: tracker.map().n_good_keyframes() as u64,
        map_points: tracker.map().points.iter().filter(|p| !p.bad).count() as u64,
        frame_cpu_ms_p50: percentile(&mut counts.frame_ms, 0.5),
        frame_cpu_ms_p99: percentile(&mut counts.frame_ms, 0.99),
        keyframe_cpu_ms_p50: percentile(&mut counts.keyframe_ms, 0.5),
        keyframe_cpu_ms_p99: percentile(&mut counts.keyframe_ms, 0.99),
        loops_closed: tracker.loops_closed().iter().map(|&(a, b)| (world.kf_id(a), world.kf_id(b))).collect(),
        loop_detection_ms_p50: percentile(&mut counts.loop_detection_ms, 0.5),
        loop_detection_ms_max: percentile(&mut counts.loop_detection_ms, 1.0),
        pose_graph_ms: counts.pose_graph_ms.clone(),
        global_ba_ms: counts.global_ba_ms.clone(),
    };
    summary.write(&dir.join("tracking.json"))?;
    Ok(())
}

/// trajectory.tum / trajectory.kitti (every tracked frame, from the final keyframe poses; frames of crashed
/// earlier instances as they were published) and keyframes.tum.
fn write_trajectories(tracker: &Tracker, earlier: &Continuation, world: &WorldFrame, dir: &Path) -> Result<()> {
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

#[cfg(test)]
mod tests;
