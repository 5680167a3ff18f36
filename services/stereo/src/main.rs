//! `bdis-stereo`: the dense stereo service. Until the tracker publishes keyframes, it takes every N-th frame from
//! acquisition as a keyframe, matches it in place in shared memory (BDIS or plain DIS), and publishes a depth
//! keyframe (disparity, confidence, RGB, intrinsics) written once into a loaned sample.
//!
//! Hot-swappable: started with `--standby` (by the launcher, for a swap or a restart), it opens its ports,
//! reports ready and waits for the launcher's activation, which comes after its predecessor has stopped and says
//! after which keyframe to resume. The tracker keeps its last keyframes in the topic's history, so the new
//! instance receives the ones its predecessor did not finish.
//!
//! With frames as input it is replaceable at any moment too: with on-demand pacing, acquisition sends a frame only when a consumer has released
//! the last one, and when a consumer joins it sends again the frames nobody released, so a new instance first
//! receives the frame its predecessor died on. A keyframe may therefore be published twice; consumers
//! de-duplicate by keyframe id.

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

use anyhow::{Context, Result, anyhow, bail};
use bdis_ipc::telemetry::MessageTiming;
use bdis_ipc::{DepthHeader, FrameView, Ipc, TelemetryPublisher, Topic, event_id, monotonic_ns};
use bdis_stereo::{Algorithm, DisparityMap, GrayImage, Matcher, Params};
use clap::Parser;
use iceoryx2::prelude::*;
use iceoryx2::waitset::WaitSetRunResult;

/// Dense stereo service: frames in, depth keyframes out.
#[derive(Debug, Parser)]
// A later flag overrides an earlier one, so a swap can append `--algorithm dis` to the service's arguments.
#[command(name = "bdis-stereo", version, args_override_self = true)]
struct Args {
    /// Settings file: the camera (fx, fy, cx, cy, bf) and `BDISparam.*`.
    #[arg(long)]
    settings: PathBuf,
    /// Take every N-th frame as a keyframe (frame_seq divisible by N), with `--input frames`.
    #[arg(long, default_value_t = 5)]
    every: u64,
    /// `frames`: keyframes picked from acquisition's frames (no tracker); `keyframes`: the tracker's keyframes,
    /// with their poses.
    #[arg(long, default_value = "frames")]
    input: String,
    /// `bdis` or `dis` (plain DIS).
    #[arg(long, default_value = "bdis")]
    algorithm: String,
    /// Override a BDIS parameter, e.g. `--param patchsz=8` (repeatable).
    #[arg(long = "param", value_name = "NAME=VALUE")]
    params: Vec<String>,
    /// Open the ports, report ready, then wait for the launcher's activation before taking keyframes (a
    /// replacement instance: make-before-break).
    #[arg(long)]
    standby: bool,
    /// Name of this process in the run.
    #[arg(long, env = "BDIS_SERVICE_NAME", default_value = "stereo")]
    name: String,
    /// Shared-memory name prefix of the run (set by the launcher).
    #[arg(long, env = bdis_ipc::PREFIX_ENV, default_value = bdis_ipc::DEFAULT_PREFIX)]
    ipc_prefix: String,
}

fn main() -> ExitCode {
    bdis_ipc::process::init_logging();
    bdis_ipc::process::finish("bdis-stereo", run(Args::parse()))
}

fn iox(what: &'static str) -> impl FnOnce(&dyn std::fmt::Debug) -> anyhow::Error {
    move |e| anyhow!("{what}: {e:?}")
}

/// Writes f32s as bytes into a loaned payload.
fn write_floats(dst: &mut [std::mem::MaybeUninit<u8>], values: &[f32]) {
    for (chunk, v) in dst.chunks_exact_mut(4).zip(values) {
        for (d, b) in chunk.iter_mut().zip(v.to_ne_bytes()) {
            d.write(b);
        }
    }
}

/// What one keyframe's depth is published with, whichever topic it came from.
struct DepthOutput<'a> {
    matcher: &'a mut Matcher,
    out: DisparityMap,
    publisher: iceoryx2::port::publisher::Publisher<ipc::Service, [u8], DepthHeader>,
    events: iceoryx2::port::notifier::Notifier<ipc::Service>,
    width: u32,
    height: u32,
    settings: PathBuf,
}

impl DepthOutput<'_> {
    /// Matches the view's grey images in place and publishes disparity, confidence and RGB with `base`'s ids,
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
        // The matcher reads the grey images in place, in shared memory.
        self.matcher
            .compute_into(
                GrayImage { width: w, height: h, data: view.left_gray },
                GrayImage { width: w, height: h, data: view.right_gray },
                &mut self.out,
            )
            .with_context(|| format!("frame {}", header.frame_seq))?;
        let bytes = DepthHeader::payload_len(self.width, self.height);
        let mut loan = self.publisher.loan_slice_uninit(bytes).map_err(|e| anyhow!("loan a depth keyframe: {e:?}"))?;
        dh.density_permille = (self.out.density() * 1000.0).round() as u32;
        dh.set_layout(header.width, header.height);
        {
            let payload = loan.payload_mut();
            let n = w * h;
            write_floats(
                &mut payload[dh.disparity_offset as usize..dh.disparity_offset as usize + 4 * n],
                &self.out.disparity,
            );
            write_floats(
                &mut payload[dh.confidence_offset as usize..dh.confidence_offset as usize + 4 * n],
                &self.out.confidence,
            );
            for (d, &b) in payload[dh.rgb_offset as usize..dh.rgb_offset as usize + 3 * n].iter_mut().zip(view.left_rgb)
            {
                d.write(b);
            }
        }
        // SAFETY: the three arrays above fill the whole payload (payload_len = 8n + 3n bytes).
        let mut depth_sample = unsafe { loan.assume_init() };
        dh.t_publish_ns = monotonic_ns();
        *depth_sample.user_header_mut() = dh;
        depth_sample.send().map_err(|e| anyhow!("send depth keyframe {}: {e:?}", dh.kf_id))?;
        bdis_ipc::notify(&self.events, event_id::NEW_SAMPLE)?;
        Ok(self.out.density())
    }
}

fn run(args: Args) -> Result<()> {
    // Everything that can be wrong with the input is found before shared memory is touched.
    let settings = bdis_core::Settings::load(&args.settings)?;
    let mut params = Params::from_settings(&settings.bdis);
    params.apply_overrides(&args.params, &args.algorithm)?;
    if args.every == 0 {
        bail!("--every: must be ≥ 1");
    }
    let from_tracker = match args.input.as_str() {
        "frames" => false,
        "keyframes" => true,
        other => bail!("--input: `{other}` is not an input (frames, keyframes)"),
    };
    if args.standby && !from_tracker {
        bail!("--standby: only with --input keyframes (with frames as input a new instance simply joins)");
    }
    let mut matcher = Matcher::new(params)?;
    let camera = settings.camera;
    let (Some(width), Some(height)) = (camera.width, camera.height) else {
        bail!(
            "{}: the stereo service needs `Camera.width` and `Camera.height` (it sizes its shared memory from them)",
            args.settings.display()
        );
    };

    let ipc = Ipc::open(&args.name, &args.ipc_prefix)?;
    let depth = ipc.depth()?;
    let input_topic = if from_tracker { Topic::Keyframes } else { Topic::Frames };
    let mut telemetry = TelemetryPublisher::new(&ipc, &args.name, Some(input_topic), Some(Topic::Depth))?;
    let mut output = DepthOutput {
        matcher: &mut matcher,
        out: DisparityMap::default(),
        publisher: ipc.depth_publisher(&depth, DepthHeader::payload_len(width, height))?,
        events: ipc.notifier(&ipc.events(Topic::Depth)?)?,
        width,
        height,
        settings: args.settings.clone(),
    };
    let algorithm_id = if params.algorithm == Algorithm::Bdis { DepthHeader::BDIS } else { DepthHeader::DIS };
    let base = DepthHeader {
        fx: camera.fx,
        fy: camera.fy,
        cx: camera.cx,
        cy: camera.cy,
        bf: camera.bf,
        algorithm: algorithm_id,
        ..Default::default()
    };
    let published = if from_tracker {
        // The subscription exists before ready is reported: nothing sent from now on is missed, and the tracker's
        // history brings the last keyframes before it.
        let keyframes = ipc.keyframes()?;
        let subscriber = ipc.keyframe_subscriber(&keyframes)?;
        let mut resume_after = None;
        if args.standby {
            let standby = bdis_ipc::control::Standby::open(&ipc)?;
            telemetry.ready();
            tracing::info!("stereo ({:?}, the tracker's keyframes) in standby", params.algorithm);
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
            tracing::info!("stereo ({:?}, the tracker's keyframes) ready", params.algorithm);
        }
        from_keyframes(&ipc, &subscriber, &mut output, &mut telemetry, base, resume_after)?
    } else {
        tracing::info!("stereo ({:?}, every {} frames) ready", params.algorithm, args.every);
        from_frames(&ipc, &mut output, &mut telemetry, base, args.every)?
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
    let waitset = WaitSetBuilder::new().create::<ipc::Service>().map_err(|e| iox("create a WaitSet")(&e))?;
    let guard = waitset
        .attach_deadline(&frame_events, Duration::from_secs(1))
        .map_err(|e| iox("attach the frames listener")(&e))?;
    let mut last_kf: Option<u64> = None;
    let mut published = 0u64;
    telemetry.ready();
    // Ready for a frame. An on-demand acquisition that is already running sends again what it sent but nobody
    // released: the frame a killed predecessor was working on.
    bdis_ipc::notify(&credits, event_id::JOINED)?;
    'outer: loop {
        let result =
            waitset.wait_and_process_once(|_| CallbackProgression::Continue).map_err(|e| iox("wait for frames")(&e))?;
        if matches!(result, WaitSetRunResult::TerminationRequest | WaitSetRunResult::Interrupt) {
            tracing::info!("stop requested after {published} keyframes");
            break;
        }
        let _ = bdis_ipc::drain_events(&frame_events);
        let _ = &guard;
        telemetry.keepalive();
        loop {
            let sample = match subscriber.receive() {
                Ok(Some(s)) => s,
                Ok(None) => break,
                Err(e) => bail!("receive a frame: {e:?}"),
            };
            let t_receive_ns = monotonic_ns();
            let header = *sample.user_header();
            if header.is_end_of_stream() {
                send_end_of_stream(&output.publisher, header.frame_seq)?;
                bdis_ipc::notify(&output.events, event_id::END_OF_STREAM)?;
                tracing::info!("end of stream: {published} keyframes");
                break 'outer;
            }
            // A frame that is not a keyframe, or one this instance already did (history replay), is released at once.
            let is_keyframe = header.frame_seq % every == 0 && last_kf.is_none_or(|k| header.frame_seq > k);
            if !is_keyframe {
                drop(sample);
                bdis_ipc::notify(&credits, event_id::CONSUMED)?;
                continue;
            }
            let view = frame_view(sample.user_header(), sample.payload())?;
            let dh = DepthHeader {
                kf_id: header.frame_seq,
                frame_seq: header.frame_seq,
                t_capture_ns: header.t_capture_ns,
                ..base
            };
            let density = output.publish(&view, dh)?;
            let t_done_ns = monotonic_ns();
            drop(sample);
            bdis_ipc::notify(&credits, event_id::CONSUMED)?;
            last_kf = Some(header.frame_seq);
            published += 1;
            report(telemetry, header.frame_seq, header.frame_seq, &header, t_receive_ns, t_done_ns, density);
        }
    }
    Ok(published)
}

/// The tracker's keyframes, with their poses. The tracker does not wait for this service (its topic overflows
/// safely), so nothing is acknowledged.
fn from_keyframes(
    ipc: &Ipc,
    subscriber: &iceoryx2::port::subscriber::Subscriber<ipc::Service, [u8], bdis_ipc::KeyframeHeader>,
    output: &mut DepthOutput,
    telemetry: &mut TelemetryPublisher,
    base: DepthHeader,
    resume_after: Option<u64>,
) -> Result<u64> {
    let events = ipc.listener(&ipc.events(Topic::Keyframes)?)?;
    let waitset = WaitSetBuilder::new().create::<ipc::Service>().map_err(|e| iox("create a WaitSet")(&e))?;
    let guard = waitset
        .attach_deadline(&events, Duration::from_secs(1))
        .map_err(|e| iox("attach the keyframes listener")(&e))?;
    // Keyframes up to `resume_after` were done by a predecessor (history replays them).
    let mut last_kf: Option<u64> = resume_after;
    let mut published = 0u64;
    'outer: loop {
        let result = waitset
            .wait_and_process_once(|_| CallbackProgression::Continue)
            .map_err(|e| iox("wait for keyframes")(&e))?;
        if matches!(result, WaitSetRunResult::TerminationRequest | WaitSetRunResult::Interrupt) {
            tracing::info!("stop requested after {published} keyframes");
            break;
        }
        let _ = bdis_ipc::drain_events(&events);
        let _ = &guard;
        telemetry.keepalive();
        loop {
            let sample = match subscriber.receive() {
                Ok(Some(s)) => s,
                Ok(None) => break,
                Err(e) => bail!("receive a keyframe: {e:?}"),
            };
            let t_receive_ns = monotonic_ns();
            let kh = *sample.user_header();
            if kh.frame.is_end_of_stream() {
                send_end_of_stream(&output.publisher, kh.frame.frame_seq)?;
                bdis_ipc::notify(&output.events, event_id::END_OF_STREAM)?;
                tracing::info!("end of stream: {published} keyframes");
                break 'outer;
            }
            if last_kf.is_some_and(|k| kh.kf_id <= k) {
                continue;
            }
            let view = frame_view(&sample.user_header().frame, sample.payload())?;
            let dh = DepthHeader {
                kf_id: kh.kf_id,
                frame_seq: kh.frame.frame_seq,
                t_capture_ns: kh.frame.t_capture_ns,
                world_from_camera: kh.world_from_camera,
                fx: kh.fx,
                fy: kh.fy,
                cx: kh.cx,
                cy: kh.cy,
                bf: kh.bf,
                corrections_generation: kh.corrections_generation,
                ..base
            };
            let density = output.publish(&view, dh)?;
            let t_done_ns = monotonic_ns();
            last_kf = Some(kh.kf_id);
            published += 1;
            report(telemetry, kh.kf_id, kh.frame.frame_seq, &kh.frame, t_receive_ns, t_done_ns, density);
        }
    }
    Ok(published)
}

fn frame_view<'a>(header: &'a bdis_ipc::FrameHeader, payload: &'a [u8]) -> Result<FrameView<'a>> {
    match FrameView::new(header, payload) {
        Ok(v) if v.header.gray_stride == v.header.width => Ok(v),
        Ok(_) => bail!("frame {}: padded grey rows are not supported", header.frame_seq),
        Err(e) => bail!("{e}"),
    }
}

fn report(
    telemetry: &mut TelemetryPublisher,
    kf_id: u64,
    frame_seq: u64,
    header: &bdis_ipc::FrameHeader,
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

fn send_end_of_stream(
    publisher: &iceoryx2::port::publisher::Publisher<ipc::Service, [u8], DepthHeader>,
    frame_seq: u64,
) -> Result<()> {
    let loan = publisher.loan_slice_uninit(0).map_err(|e| anyhow!("loan the end-of-stream sample: {e:?}"))?;
    // SAFETY: a zero-length payload has nothing to initialise.
    let mut sample = unsafe { loan.assume_init() };
    *sample.user_header_mut() = DepthHeader {
        frame_seq,
        flags: DepthHeader::END_OF_STREAM,
        t_publish_ns: monotonic_ns(),
        ..Default::default()
    };
    sample.send().map_err(|e| anyhow!("send the end-of-stream sample: {e:?}"))?;
    Ok(())
}
