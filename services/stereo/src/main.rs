//! `bdis-stereo`: the dense stereo service. Until the tracker publishes keyframes, it takes every N-th frame from
//! acquisition as a keyframe, matches it in place in shared memory (BDIS or plain DIS), and publishes a depth
//! keyframe (disparity, confidence, RGB, intrinsics) written once into a loaned sample.
//!
//! Replaceable at any moment: with on-demand pacing, acquisition sends a frame only when a consumer has released
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
#[command(name = "bdis-stereo", version)]
struct Args {
    /// Settings file: the camera (fx, fy, cx, cy, bf) and `BDISparam.*`.
    #[arg(long)]
    settings: PathBuf,
    /// Take every N-th frame as a keyframe (frame_seq divisible by N).
    #[arg(long, default_value_t = 5)]
    every: u64,
    /// `bdis` or `dis` (plain DIS).
    #[arg(long, default_value = "bdis")]
    algorithm: String,
    /// Override a BDIS parameter, e.g. `--param patchsz=8` (repeatable).
    #[arg(long = "param", value_name = "NAME=VALUE")]
    params: Vec<String>,
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

fn run(args: Args) -> Result<()> {
    // Everything that can be wrong with the input is found before shared memory is touched.
    let settings = bdis_core::Settings::load(&args.settings)?;
    let mut params = Params::from_settings(&settings.bdis);
    params.apply_overrides(&args.params, &args.algorithm)?;
    if args.every == 0 {
        bail!("--every: must be ≥ 1");
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
    let frames = ipc.frames()?;
    let subscriber = ipc.frame_subscriber(&frames)?;
    let frame_events = ipc.listener(&ipc.events(Topic::Frames)?)?;
    let credits = ipc.notifier(&ipc.frames_consumed()?)?;
    let depth = ipc.depth()?;
    let depth_events = ipc.notifier(&ipc.events(Topic::Depth)?)?;
    let mut telemetry = TelemetryPublisher::new(&ipc, &args.name, Some(Topic::Frames), Some(Topic::Depth))?;
    let waitset = WaitSetBuilder::new().create::<ipc::Service>().map_err(|e| iox("create a WaitSet")(&e))?;
    let guard = waitset
        .attach_deadline(&frame_events, Duration::from_secs(1))
        .map_err(|e| iox("attach the frames listener")(&e))?;

    let publisher = ipc.depth_publisher(&depth, DepthHeader::payload_len(width, height))?;
    let mut out = DisparityMap::default();
    let mut last_kf: Option<u64> = None;
    let mut published = 0u64;
    telemetry.ready();
    // Ready for a frame. An on-demand acquisition that is already running sends again what it sent but nobody
    // released: the frame a killed predecessor was working on.
    bdis_ipc::notify(&credits, event_id::JOINED)?;
    tracing::info!("stereo ({:?}, every {} frames) ready", params.algorithm, args.every);

    let algorithm_id = if params.algorithm == Algorithm::Bdis { DepthHeader::BDIS } else { DepthHeader::DIS };
    'outer: loop {
        let result =
            waitset.wait_and_process_once(|_| CallbackProgression::Continue).map_err(|e| iox("wait for frames")(&e))?;
        if matches!(result, WaitSetRunResult::TerminationRequest | WaitSetRunResult::Interrupt) {
            tracing::info!("stop requested after {published} keyframes");
            break;
        }
        let _ = bdis_ipc::drain_events(&frame_events);
        let _ = &guard;
        loop {
            let sample = match subscriber.receive() {
                Ok(Some(s)) => s,
                Ok(None) => break,
                Err(e) => bail!("receive a frame: {e:?}"),
            };
            let t_receive_ns = monotonic_ns();
            let header = *sample.user_header();
            if header.is_end_of_stream() {
                send_end_of_stream(&publisher, header.frame_seq)?;
                bdis_ipc::notify(&depth_events, event_id::END_OF_STREAM)?;
                tracing::info!("end of stream: {published} keyframes");
                break 'outer;
            }
            // A frame that is not a keyframe, or one this instance already did (history replay), is released at once.
            let is_keyframe = header.frame_seq % args.every == 0 && last_kf.is_none_or(|k| header.frame_seq > k);
            if !is_keyframe {
                drop(sample);
                bdis_ipc::notify(&credits, event_id::CONSUMED)?;
                continue;
            }
            let view = match FrameView::new(sample.user_header(), sample.payload()) {
                Ok(v) if v.header.gray_stride == v.header.width => v,
                Ok(_) => bail!("frame {}: padded grey rows are not supported", header.frame_seq),
                Err(e) => bail!("{e}"),
            };
            let (w, h) = (header.width as usize, header.height as usize);
            // The matcher reads the grey images in place, in shared memory.
            matcher
                .compute_into(
                    GrayImage { width: w, height: h, data: view.left_gray },
                    GrayImage { width: w, height: h, data: view.right_gray },
                    &mut out,
                )
                .with_context(|| format!("frame {}", header.frame_seq))?;
            if (header.width, header.height) != (width, height) {
                bail!(
                    "frame {} is {}×{}, but {} says Camera.width × Camera.height = {width}×{height}",
                    header.frame_seq,
                    header.width,
                    header.height,
                    args.settings.display()
                );
            }
            let bytes = DepthHeader::payload_len(width, height);
            let mut loan = publisher.loan_slice_uninit(bytes).map_err(|e| anyhow!("loan a depth keyframe: {e:?}"))?;
            let mut dh = DepthHeader {
                kf_id: header.frame_seq,
                frame_seq: header.frame_seq,
                t_capture_ns: header.t_capture_ns,
                fx: camera.fx,
                fy: camera.fy,
                cx: camera.cx,
                cy: camera.cy,
                bf: camera.bf,
                algorithm: algorithm_id,
                density_permille: (out.density() * 1000.0).round() as u32,
                ..Default::default()
            };
            dh.set_layout(header.width, header.height);
            {
                let payload = loan.payload_mut();
                let n = w * h;
                write_floats(
                    &mut payload[dh.disparity_offset as usize..dh.disparity_offset as usize + 4 * n],
                    &out.disparity,
                );
                write_floats(
                    &mut payload[dh.confidence_offset as usize..dh.confidence_offset as usize + 4 * n],
                    &out.confidence,
                );
                for (d, &b) in
                    payload[dh.rgb_offset as usize..dh.rgb_offset as usize + 3 * n].iter_mut().zip(view.left_rgb)
                {
                    d.write(b);
                }
            }
            // SAFETY: the three arrays above fill the whole payload (payload_len = 8n + 3n bytes).
            let mut depth_sample = unsafe { loan.assume_init() };
            let t_publish_ns = monotonic_ns();
            dh.t_publish_ns = t_publish_ns;
            *depth_sample.user_header_mut() = dh;
            depth_sample.send().map_err(|e| anyhow!("send depth keyframe {}: {e:?}", header.frame_seq))?;
            bdis_ipc::notify(&depth_events, event_id::NEW_SAMPLE)?;
            drop(sample);
            bdis_ipc::notify(&credits, event_id::CONSUMED)?;
            last_kf = Some(header.frame_seq);
            published += 1;
            tracing::info!(
                "keyframe {}: density {:.1} %, {:.1} ms",
                header.frame_seq,
                out.density() * 100.0,
                (t_publish_ns - t_receive_ns) as f64 / 1e6
            );
            telemetry.message(
                MessageTiming {
                    frame_seq: header.frame_seq,
                    t_capture_ns: header.t_capture_ns,
                    t_upstream_publish_ns: header.t_publish_ns,
                    t_receive_ns,
                    t_done_ns: t_publish_ns,
                },
                0,
            );
        }
    }
    telemetry.finished();
    Ok(())
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
