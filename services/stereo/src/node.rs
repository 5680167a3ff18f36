//! The stereo service's node: its ports, the keyframe loop over either input, and the depth keyframe written
//! once into a loaned sample. The matching itself is `bdis_stereo`; the loop is `bdis_node::serve`.

use std::path::PathBuf;

use anyhow::{Context, Result, bail};
use bdis_core::RectifiedCamera;
use bdis_ipc::telemetry::MessageTiming;
use bdis_ipc::validate::{self, Admit, StreamGuard};
use bdis_ipc::{
    DepthHeader, FrameHeader, FrameView, Ipc, KeyframeHeader, KeyframeMeta, StereoIntrinsics, TelemetryPublisher,
    Topic, event_id, monotonic_ns,
};
use bdis_node::{Ended, Flow};
use bdis_stereo::{Algorithm, DisparityMap, GrayImage, Matcher};
use iceoryx2::prelude::*;

/// Where keyframes come from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Input {
    /// Every `every`-th frame from acquisition (no tracker), with on-demand credits.
    Frames { every: u64 },
    /// The tracker's keyframes, with their poses; `standby` waits for the launcher's activation first.
    Keyframes { standby: bool },
}

/// The checked input of one service instance.
#[derive(Debug)]
pub struct Config {
    pub matcher: Matcher,
    pub camera: RectifiedCamera,
    pub input: Input,
    /// The settings file, named in errors about frame sizes.
    pub settings: PathBuf,
    pub name: String,
    pub ipc_prefix: String,
}

/// What one keyframe's depth is published with, whichever topic it came from.
struct DepthOutput {
    matcher: Matcher,
    out: DisparityMap,
    /// The left image with its masked pixels made 0 (no data to the matcher), reused.
    masked_left: Vec<u8>,
    publisher: iceoryx2::port::publisher::Publisher<ipc::Service, [u8], DepthHeader>,
    events: iceoryx2::port::notifier::Notifier<ipc::Service>,
    width: u32,
    height: u32,
    settings: PathBuf,
}

impl DepthOutput {
    /// Runs the matcher once on a textured pair of the settings' size before the first keyframe: its buffers
    /// are sized and their pages touched here, not on the first keyframe (at 1080p that one took 224 ms
    /// against ~56 ms for the rest, and was the run's p99 of capture → map). The output is discarded.
    fn warm_up(&mut self) {
        let (w, h) = (self.width as usize, self.height as usize);
        let texture = |x: usize, y: usize| ((x.wrapping_mul(2_654_435_761) ^ y.wrapping_mul(40_503)) >> 7) as u8 | 1;
        let left: Vec<u8> = (0..w * h).map(|i| texture(i % w, i / w)).collect();
        let right: Vec<u8> = (0..w * h).map(|i| texture(i % w + 4, i / w)).collect();
        let (l, r) = (GrayImage { width: w, height: h, data: &left }, GrayImage { width: w, height: h, data: &right });
        if let Err(e) = self.matcher.compute_into(l, r, &mut self.out) {
            // Not fatal: the first keyframe will say what is wrong with its own frame.
            tracing::warn!("warming the matcher up on a {w}×{h} pair: {e}");
        }
    }

    /// Matches the view's grey images in place and publishes disparity, confidence and RGB with `dh`'s ids,
    /// pose and intrinsics. Returns the density.
    fn publish(&mut self, view: &FrameView, mut dh: DepthHeader) -> Result<f64> {
        let header = view.header;
        if (header.width, header.height) != (self.width, self.height) {
            bail!(
                "frame {} is {}×{}, but {} says Camera.width × Camera.height = {}×{}",
                header.frame_seq,
                header.width,
                header.height,
                self.settings.display(),
                self.width,
                self.height
            );
        }
        let (w, h) = (header.width as usize, header.height as usize);
        // The matcher reads the grey images in place, in shared memory. With a mask, the left image's masked
        // pixels are made 0, which the matcher reads as no data (as the black border of an endoscope image):
        // a patch's cost is then taken over the tissue alone, so the instrument's depth neither is matched nor
        // spreads over the tissue beside it (patches straddling its silhouette would otherwise carry it a patch
        // wide), and the left–right check drops tissue the instrument hides in the right view.
        let left = match view.mask {
            Some(mask) => {
                let stride = header.gray_stride as usize;
                self.masked_left.clear();
                for y in 0..h {
                    let (row, keep_out) = (&view.left_gray[y * stride..y * stride + w], &mask[y * stride..]);
                    self.masked_left.extend(row.iter().zip(keep_out).map(|(&g, &m)| if m != 0 { 0 } else { g }));
                }
                &self.masked_left[..]
            }
            None => view.left_gray,
        };
        self.matcher
            .compute_into(
                GrayImage { width: w, height: h, data: left },
                GrayImage { width: w, height: h, data: view.right_gray },
                &mut self.out,
            )
            .with_context(|| format!("frame {}", header.frame_seq))?;
        // What the keyframe's mask covers (instruments) gives no depth, so the map lifts no point from it.
        if let Some(mask) = view.mask {
            let stride = header.gray_stride as usize;
            for (y, row) in self.out.disparity.chunks_exact_mut(w).enumerate() {
                let confidence = &mut self.out.confidence[y * w..(y + 1) * w];
                for (x, &m) in mask[y * stride..y * stride + w].iter().enumerate() {
                    if m != 0 {
                        row[x] = f32::NAN;
                        confidence[x] = 0.0;
                    }
                }
            }
        }
        let n = w * h;
        let bytes = DepthHeader::payload_len(self.width, self.height);
        let mut loan = self.publisher.loan_slice_uninit(bytes).context("loan a depth keyframe")?;
        dh.density_permille = (self.out.density() * 1000.0).round() as u32;
        dh.set_layout(header.width, header.height);
        let payload = loan.payload_mut();
        let (d, c, r) = (dh.disparity_offset as usize, dh.confidence_offset as usize, dh.rgb_offset as usize);
        let written = bdis_node::copy_floats_into(&mut payload[d..d + 4 * n], &self.out.disparity)
            + bdis_node::copy_floats_into(&mut payload[c..c + 4 * n], &self.out.confidence)
            + bdis_node::copy_into(&mut payload[r..r + 3 * n], view.left_rgb);
        // The matcher's output and the frame's RGB must cover the image: a shorter one leaves bytes unwritten.
        if written != bytes {
            bail!("frame {}: wrote {written} of the depth keyframe's {bytes} bytes", header.frame_seq);
        }
        // SAFETY: the three copies above wrote every byte of the payload (their count was checked).
        let mut depth_sample = unsafe { loan.assume_init() };
        dh.t_publish_ns = monotonic_ns();
        *depth_sample.user_header_mut() = dh;
        depth_sample.send().with_context(|| format!("send depth keyframe {}", dh.meta.kf_id))?;
        bdis_ipc::notify(&self.events, event_id::NEW_SAMPLE)?;
        Ok(self.out.density())
    }

    /// The end of the depth stream, after the end of the input stream.
    fn end_of_stream(&self, frame_seq: u64) -> Result<()> {
        bdis_node::send_end_of_stream(
            &self.publisher,
            DepthHeader {
                frame_seq,
                flags: DepthHeader::END_OF_STREAM,
                t_publish_ns: monotonic_ns(),
                ..Default::default()
            },
        )?;
        bdis_ipc::notify(&self.events, event_id::END_OF_STREAM)?;
        Ok(())
    }
}

/// The depth header every keyframe of this instance starts from: intrinsics from the settings, the algorithm.
fn base_header(camera: &RectifiedCamera, algorithm: Algorithm) -> DepthHeader {
    let mut base = DepthHeader {
        meta: KeyframeMeta { intrinsics: StereoIntrinsics::of(camera), ..Default::default() },
        algorithm: if algorithm == Algorithm::Bdis { DepthHeader::BDIS } else { DepthHeader::DIS },
        ..Default::default()
    };
    // The camera's size: input of another size is refused.
    base.set_layout(camera.width, camera.height);
    base
}

/// A keyframe picked from acquisition's frames: its id is the frame's sequence number, it has no pose.
fn header_for_frame(base: DepthHeader, frame: &FrameHeader) -> DepthHeader {
    DepthHeader {
        meta: KeyframeMeta { kf_id: frame.frame_seq, ..base.meta },
        frame_seq: frame.frame_seq,
        t_capture_ns: frame.t_capture_ns,
        ..base
    }
}

/// A tracker keyframe: what it is (id, pose, intrinsics, correction generation) travels on to the map as is.
fn header_for_keyframe(base: DepthHeader, kh: &KeyframeHeader) -> DepthHeader {
    DepthHeader { meta: kh.meta, frame_seq: kh.frame.frame_seq, t_capture_ns: kh.frame.t_capture_ns, ..base }
}

pub fn run(config: Config) -> Result<()> {
    let algorithm = config.matcher.params().algorithm;
    // Said once at start, so a swap's log shows what validity its depth keyframes carry.
    let matcher_name = match config.matcher.params().lr_tolerance_px() {
        Some(px) => format!("{algorithm:?}, left–right checked to {px} px"),
        None => format!("{algorithm:?}"),
    };
    let ipc = Ipc::open(&config.name, &config.ipc_prefix)?;
    let depth = ipc.depth()?;
    let input_topic = match config.input {
        Input::Frames { .. } => Topic::Frames,
        Input::Keyframes { .. } => Topic::Keyframes,
    };
    let mut telemetry = TelemetryPublisher::new(&ipc, &config.name, Some(input_topic), Some(Topic::Depth))?;
    let mut output = DepthOutput {
        matcher: config.matcher,
        out: DisparityMap::default(),
        masked_left: Vec::new(),
        publisher: ipc.depth_publisher(&depth, DepthHeader::payload_len(config.camera.width, config.camera.height))?,
        events: ipc.notifier(&ipc.events(Topic::Depth)?)?,
        width: config.camera.width,
        height: config.camera.height,
        settings: config.settings,
    };
    let base = base_header(&config.camera, algorithm);
    output.warm_up();
    let published = match config.input {
        Input::Keyframes { standby } => {
            // The subscription exists before ready is reported: nothing sent from now on is missed, and the
            // tracker's history brings the last keyframes before it.
            let keyframes = ipc.keyframes()?;
            let subscriber = ipc.keyframe_subscriber(&keyframes)?;
            let mut resume_after = None;
            if standby {
                let standby = bdis_ipc::control::Standby::open(&ipc)?;
                telemetry.ready();
                tracing::info!("stereo ({matcher_name}, the tracker's keyframes) in standby");
                match standby.wait(|| telemetry.keepalive())? {
                    None => {
                        tracing::info!("stop requested in standby");
                        telemetry.finished();
                        return Ok(());
                    }
                    Some(after) => {
                        resume_after = (after != bdis_ipc::control::Activation::RESUME_FROM_START).then_some(after);
                        tracing::info!(
                            "activated{}",
                            resume_after.map_or(String::new(), |k| format!(": resuming after keyframe {k}"))
                        );
                    }
                }
            } else {
                telemetry.ready();
                tracing::info!("stereo ({matcher_name}, the tracker's keyframes) ready");
            }
            from_keyframes(&ipc, &subscriber, &mut output, &mut telemetry, base, resume_after)?
        }
        Input::Frames { every } => {
            tracing::info!("stereo ({matcher_name}, every {every} frames) ready");
            from_frames(&ipc, &mut output, &mut telemetry, base, every)?
        }
    };
    tracing::info!("{published} keyframes");
    telemetry.finished();
    Ok(())
}

/// Keyframes picked from acquisition's frames (no tracker), with on-demand credits.
fn from_frames(
    ipc: &Ipc,
    output: &mut DepthOutput,
    telemetry: &mut TelemetryPublisher,
    base: DepthHeader,
    every: u64,
) -> Result<u64> {
    let frames = ipc.frames()?;
    let subscriber = ipc.frame_subscriber(&frames)?;
    let frame_events = ipc.listener(&ipc.events(Topic::Frames)?)?;
    let credits = ipc.notifier(&ipc.frames_consumed()?)?;
    let mut stream: StreamGuard = StreamGuard::default();
    let mut join = bdis_ipc::JoinGate::default();
    let mut published = 0u64;
    telemetry.ready();
    // Ready for a frame. An on-demand acquisition that is already running sends again what it sent but nobody
    // released: the frame a killed predecessor was working on. Nothing is taken before that answer (JoinGate).
    bdis_ipc::notify(&credits, event_id::JOINED)?;
    let ended = bdis_node::serve(&[&frame_events], telemetry, |telemetry| -> Result<Flow> {
        while let Some(sample) = subscriber.receive().context("receive a frame")? {
            let t_receive_ns = monotonic_ns();
            let header = *sample.user_header();
            let origin = sample.origin();
            if header.is_end_of_stream() {
                if let Err(rejection) = stream.end_of_stream(header.frame_seq, "frames") {
                    telemetry.rejected(Topic::Frames, &rejection);
                    continue;
                }
                output.end_of_stream(header.frame_seq)?;
                tracing::info!("end of stream: {published} keyframes");
                return Ok(Flow::Finished);
            }
            tracing::debug!("frame {} received (flags {:#x})", header.frame_seq, header.flags);
            // Until acquisition answers this instance's JOINED, frames are not ours: passed over unacknowledged.
            if !join.admit(&header) {
                if join.passed_over() == 1 {
                    tracing::info!("frame {}: passed over until acquisition answers this instance", header.frame_seq);
                }
                continue;
            }
            let checked = stream.admit(header.frame_seq, origin, "frame").and_then(|admit| {
                Ok((admit, validate::packed_frame(&header, sample.payload(), Some((base.width, base.height)))?))
            });
            // A frame that is not a keyframe, one this instance already did (replay), or one refused is released
            // at once; the credit goes back only for what acquisition sent (a stray sample earns none).
            let view = match checked {
                Ok((Admit::New, view)) if header.frame_seq.is_multiple_of(every) => view,
                Ok((admit, _)) => {
                    if admit == Admit::New {
                        stream.taken(header.frame_seq, header.frame_seq, origin);
                    }
                    drop(sample);
                    bdis_ipc::notify(&credits, event_id::CONSUMED)?;
                    continue;
                }
                Err(rejection) => {
                    telemetry.rejected(Topic::Frames, &rejection);
                    let from_producer = !stream.knows_producer() || stream.is_producer(origin);
                    drop(sample);
                    if from_producer {
                        bdis_ipc::notify(&credits, event_id::CONSUMED)?;
                    }
                    continue;
                }
            };
            let density = output.publish(&view, header_for_frame(base, &header))?;
            let t_done_ns = monotonic_ns();
            drop(sample);
            bdis_ipc::notify(&credits, event_id::CONSUMED)?;
            stream.taken(header.frame_seq, header.frame_seq, origin);
            published += 1;
            report(telemetry, header.frame_seq, header.frame_seq, &header, t_receive_ns, t_done_ns, density);
        }
        Ok(Flow::Continue)
    })?;
    if ended == Ended::StopRequested {
        tracing::info!("stop requested after {published} keyframes");
    }
    Ok(published)
}

/// The tracker's keyframes, with their poses. The tracker does not wait for this service (its topic overflows
/// safely), so nothing is acknowledged.
fn from_keyframes(
    ipc: &Ipc,
    subscriber: &iceoryx2::port::subscriber::Subscriber<ipc::Service, [u8], KeyframeHeader>,
    output: &mut DepthOutput,
    telemetry: &mut TelemetryPublisher,
    base: DepthHeader,
    resume_after: Option<u64>,
) -> Result<u64> {
    let events = ipc.listener(&ipc.events(Topic::Keyframes)?)?;
    // Keyframes up to `resume_after` were done by a predecessor (history replays them).
    let mut stream: StreamGuard = StreamGuard::resuming_after(resume_after);
    let mut published = 0u64;
    let ended = bdis_node::serve(&[&events], telemetry, |telemetry| -> Result<Flow> {
        while let Some(sample) = subscriber.receive().context("receive a keyframe")? {
            let t_receive_ns = monotonic_ns();
            let kh = *sample.user_header();
            let origin = sample.origin();
            if kh.frame.is_end_of_stream() {
                if let Err(rejection) = stream.end_of_stream(kh.frame.frame_seq, "keyframes") {
                    telemetry.rejected(Topic::Keyframes, &rejection);
                    continue;
                }
                output.end_of_stream(kh.frame.frame_seq)?;
                tracing::info!("end of stream: {published} keyframes");
                return Ok(Flow::Finished);
            }
            let checked = stream
                .admit(kh.meta.kf_id, origin, "keyframe")
                .and_then(|admit| Ok((admit, validate::keyframe(&kh, sample.payload())?)));
            let view = match checked {
                Ok((Admit::New, (view, _pose))) => view,
                // Done by this instance or its predecessor (history replays them).
                Ok((Admit::Replay, _)) => continue,
                Err(rejection) => {
                    telemetry.rejected(Topic::Keyframes, &rejection);
                    continue;
                }
            };
            if (kh.frame.width, kh.frame.height) != (base.width, base.height) {
                let rejection = validate::Rejection::new(
                    validate::Reason::Dimensions,
                    kh.meta.kf_id,
                    format!(
                        "keyframe {} is {}×{}, but this service's camera is {}×{}",
                        kh.meta.kf_id, kh.frame.width, kh.frame.height, base.width, base.height
                    ),
                );
                telemetry.rejected(Topic::Keyframes, &rejection);
                continue;
            }
            let density = output.publish(&view, header_for_keyframe(base, &kh))?;
            let t_done_ns = monotonic_ns();
            stream.taken(kh.meta.kf_id, kh.frame.frame_seq, origin);
            published += 1;
            report(telemetry, kh.meta.kf_id, kh.frame.frame_seq, &kh.frame, t_receive_ns, t_done_ns, density);
        }
        Ok(Flow::Continue)
    })?;
    if ended == Ended::StopRequested {
        tracing::info!("stop requested after {published} keyframes");
    }
    Ok(published)
}

fn report(
    telemetry: &mut TelemetryPublisher,
    kf_id: u64,
    frame_seq: u64,
    header: &FrameHeader,
    t_receive_ns: u64,
    t_done_ns: u64,
    density: f64,
) {
    tracing::info!(
        "keyframe {kf_id} (frame {frame_seq}): density {:.1} %, {:.1} ms",
        density * 100.0,
        (t_done_ns - t_receive_ns) as f64 / 1e6
    );
    telemetry.message(
        MessageTiming {
            // The keyframe id: the launcher resumes a replacement after the last one done.
            frame_seq: kf_id,
            t_capture_ns: header.t_capture_ns,
            t_upstream_publish_ns: header.t_publish_ns,
            t_receive_ns,
            t_done_ns,
        },
        0,
    );
}

#[cfg(test)]
mod tests {
    use super::*;

    fn camera() -> RectifiedCamera {
        RectifiedCamera { fx: 500.0, fy: 501.0, cx: 320.0, cy: 240.0, bf: 2500.0, width: 640, height: 480 }
    }

    #[test]
    fn a_tracker_keyframe_carries_its_id_pose_intrinsics_and_generation_to_the_map() {
        let base = base_header(&camera(), Algorithm::Bdis);
        assert_eq!(base.algorithm, DepthHeader::BDIS);
        let kh = KeyframeHeader {
            frame: FrameHeader { frame_seq: 77, t_capture_ns: 123, ..Default::default() },
            meta: KeyframeMeta {
                kf_id: 9,
                world_from_camera: [1.0, 2.0, 3.0, 0.0, 0.0, 0.0, 1.0],
                intrinsics: StereoIntrinsics { fx: 250.0, fy: 251.0, cx: 160.0, cy: 120.0, bf: 1250.0 },
                corrections_generation: 4,
            },
        };
        let dh = header_for_keyframe(base, &kh);
        assert_eq!((dh.frame_seq, dh.t_capture_ns), (77, 123));
        // What the keyframe is travels as it is, its own intrinsics over the settings' (a tracker may run at
        // another size).
        assert_eq!(dh.meta, kh.meta);
        assert_eq!(dh.algorithm, DepthHeader::BDIS);
        assert!(!dh.is_end_of_stream());
    }

    #[test]
    fn a_frame_keyframe_has_the_settings_intrinsics_and_no_pose() {
        let base = base_header(&camera(), Algorithm::Dis);
        let dh = header_for_frame(base, &FrameHeader { frame_seq: 10, t_capture_ns: 5, ..Default::default() });
        assert_eq!((dh.meta.kf_id, dh.frame_seq, dh.t_capture_ns), (10, 10, 5));
        assert_eq!((dh.meta.intrinsics.fx, dh.meta.intrinsics.bf), (500.0, 2500.0));
        assert_eq!(dh.algorithm, DepthHeader::DIS);
        // All zero: not a rigid pose, so the mosaic skips it rather than placing it at the origin.
        assert_eq!(dh.meta.world_from_camera, [0.0; 7]);
    }

    /// The node as a whole, in process, over real shared memory: two tracker keyframes in, their depth keyframes
    /// out with what the keyframe is copied through, then the end of the stream, and the node returns.
    #[test]
    #[allow(clippy::unwrap_used, clippy::expect_used)]
    fn keyframes_in_depth_keyframes_out_over_shared_memory() {
        let prefix = format!("bsnode{}_", std::process::id());
        let (w, h) = (320u32, 240u32);
        let camera = RectifiedCamera { fx: 200.0, fy: 200.0, cx: 159.5, cy: 119.5, bf: 1000.0, width: w, height: h };
        let config = Config {
            matcher: Matcher::new(bdis_stereo::Params::default()).unwrap(),
            camera,
            input: Input::Keyframes { standby: false },
            settings: PathBuf::from("test.yaml"),
            name: "stereo".into(),
            ipc_prefix: prefix.clone(),
        };
        let ipc = Ipc::open("node-test", &prefix).unwrap();
        let ready = bdis_ipc::ReadyWatch::open(&ipc).unwrap();
        let depth = ipc.depth().unwrap();
        let depth_subscriber = ipc.depth_subscriber(&depth).unwrap();
        let depth_events = ipc.listener(&ipc.events(Topic::Depth).unwrap()).unwrap();
        let layout = bdis_ipc::FrameLayout::packed(w, h).unwrap();
        let keyframes = ipc.keyframes().unwrap();
        let publisher = ipc.keyframe_publisher(&keyframes, layout.payload_len()).unwrap();
        let keyframe_events = ipc.notifier(&ipc.events(Topic::Keyframes).unwrap()).unwrap();

        let node = std::thread::spawn(move || run(config));
        let deadline = || std::time::Instant::now() + std::time::Duration::from_secs(20);
        assert!(ready.wait("stereo", deadline()).unwrap(), "the node reports ready");

        // A tissue plane 50 mm away, seen with a disparity of 4 px (the renderer's).
        let scene = bdis_synth::PlaneScene { depth_mm: 50.0, texture: bdis_synth::TissueTexture { seed: 11 } };
        let rig = RectifiedCamera { bf: 50.0 * 4.0, ..camera };
        let (mut left, mut right) = (image::RgbImage::new(1, 1), image::RgbImage::new(1, 1));
        scene.render_pair(&rig, 0.0, 0.0, &mut left, &mut right);
        let grey = |img: &image::RgbImage| bdis_core::pixel::gray_of_rgb(img.as_raw());
        let payload: Vec<u8> = [grey(&left), grey(&right), left.into_raw()].concat();
        assert_eq!(payload.len(), layout.payload_len());
        let metas: Vec<KeyframeMeta> = (0..2)
            .map(|k| KeyframeMeta {
                kf_id: 10 + k,
                world_from_camera: [k as f64, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0],
                intrinsics: StereoIntrinsics::of(&camera),
                corrections_generation: 3 + k,
            })
            .collect();
        for (k, meta) in metas.iter().enumerate() {
            let mut loan = publisher.loan_slice_uninit(layout.payload_len()).unwrap();
            assert_eq!(bdis_node::copy_into(loan.payload_mut(), &payload), payload.len());
            // SAFETY: every byte was written just above.
            let mut sample = unsafe { loan.assume_init() };
            let mut frame = FrameHeader { frame_seq: 5 * k as u64, t_capture_ns: monotonic_ns(), ..Default::default() };
            layout.write_into(&mut frame);
            *sample.user_header_mut() = KeyframeHeader { frame, meta: *meta };
            sample.send().unwrap();
            bdis_ipc::notify(&keyframe_events, event_id::NEW_SAMPLE).unwrap();
        }
        let eos = FrameHeader { frame_seq: 10, flags: FrameHeader::END_OF_STREAM, ..Default::default() };
        bdis_node::send_end_of_stream(&publisher, KeyframeHeader { frame: eos, ..Default::default() }).unwrap();
        bdis_ipc::notify(&keyframe_events, event_id::END_OF_STREAM).unwrap();

        let mut received: Vec<(DepthHeader, f64, Option<f64>)> = Vec::new();
        let ended = bdis_ipc::wait_for(&depth_events, deadline(), || {
            while let Some(sample) = depth_subscriber.receive().map_err(bdis_ipc::iox("depth"))? {
                let header = *sample.user_header();
                if header.is_end_of_stream() {
                    return Ok(Some(()));
                }
                let view = bdis_ipc::DepthView::new(sample.user_header(), sample.payload()).unwrap();
                let mut valid: Vec<f64> =
                    view.disparity.iter().filter(|d| d.is_finite()).map(|&d| f64::from(d)).collect();
                let density = valid.len() as f64 / view.disparity.len() as f64;
                received.push((header, density, bdis_core::stats::percentile(&mut valid, 0.5)));
            }
            Ok(None)
        });
        assert!(matches!(ended, Ok(Some(()))), "the depth stream ends after the keyframes'");
        node.join().unwrap().unwrap();
        assert_eq!(received.len(), 2);
        for ((header, density, median), meta) in received.iter().zip(&metas) {
            assert_eq!(header.meta, *meta, "what the keyframe is travels unchanged");
            assert_eq!((header.width, header.height, header.algorithm), (w, h, DepthHeader::BDIS));
            // The matching itself is the library's business (its own tests); here: the pixels were read in
            // place and the answer written back whole.
            assert!(*density > 0.5, "keyframe {}: density {density}", meta.kf_id);
            assert!(
                median.is_some_and(|d| (d - 4.0).abs() < 0.25),
                "keyframe {}: median disparity {median:?}",
                meta.kf_id
            );
        }
        drop((publisher, keyframes, depth_subscriber, depth, ready, ipc));
        bdis_ipc::remove_run_files(&prefix);
    }
}
