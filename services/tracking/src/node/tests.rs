use super::*;
use bdis_ipc::FrameLayout;
use bdis_track::TrackerSettings;

/// The node as a whole, in process, over real shared memory: a rendered colon flight in, paced by the
/// tracker's own credits; a pose per frame, every keyframe with its images and what it is, the end of both
/// streams, and the trajectory, summary and journal written.
#[test]
#[allow(clippy::unwrap_used, clippy::expect_used)]
fn frames_in_poses_and_keyframes_out_over_shared_memory() {
    let prefix = format!("btnode{}_", std::process::id());
    let out_dir = std::env::temp_dir().join(format!("bdis-tracking-node-{}", std::process::id()));
    std::fs::create_dir_all(&out_dir).unwrap();
    let (w, h, n) = (320u32, 240u32, 16usize);
    let rig = RectifiedCamera { width: w, height: h, fx: 260.0, fy: 260.0, cx: 160.0, cy: 120.0, bf: 1300.0 };
    let camera = RectifiedCamera { cx: 159.5, cy: 119.5, ..rig };
    let orb = bdis_orb::OrbParams { n_features: 1000, ini_th_fast: 20, min_th_fast: 7, ..Default::default() };
    let tracker = Tracker::new(camera, TrackerSettings { th_depth: 20.0, fps: 30.0, orb }).unwrap();
    let earlier = Continuation::default();
    let config = Config {
        tracker,
        world: WorldFrame::continuing(&earlier),
        earlier,
        journal: JournalWriter::open(&out_dir.join("tracking.journal"), false).unwrap(),
        camera,
        n_features: 1000,
        instruments: None,
        settings: PathBuf::from("test.yaml"),
        out_dir: out_dir.clone(),
        name: "tracking".into(),
        ipc_prefix: prefix.clone(),
    };
    // The frames, as acquisition writes them: left grey, right grey, left RGB.
    let colon = bdis_synth::colon::Colon::default();
    let shading = bdis_synth::render::Shading::default();
    let grey = |img: &image::RgbImage| bdis_core::pixel::gray_of_rgb(img.as_raw());
    let payloads: Vec<Vec<u8>> = (0..n as u64)
        .map(|i| {
            let pair =
                bdis_synth::render::render(&colon, &rig, &shading, &colon.forward_pose(i as f64 / 30.0, 20.0), i);
            [grey(&pair.left), grey(&pair.right), pair.left.into_raw()].concat()
        })
        .collect();

    let ipc = Ipc::open("node-test", &prefix).unwrap();
    let layout = FrameLayout::packed(w, h).unwrap();
    let frames = ipc.frames().unwrap();
    let frame_publisher = ipc.frame_publisher(&frames, layout.payload_len()).unwrap();
    let frame_events = ipc.notifier(&ipc.events(Topic::Frames).unwrap()).unwrap();
    let ready = bdis_ipc::ReadyWatch::open(&ipc).unwrap();
    let poses = ipc.poses().unwrap();
    let pose_events = ipc.listener(&ipc.events(Topic::Poses).unwrap()).unwrap();
    let pose_subscriber = poses.subscriber_builder().buffer_size(qos_poses_buffer()).create().unwrap();
    let keyframes = ipc.keyframes().unwrap();
    let keyframe_subscriber = ipc.keyframe_subscriber(&keyframes).unwrap();

    let node = std::thread::spawn(move || run(config));
    let deadline = || std::time::Instant::now() + std::time::Duration::from_secs(60);
    assert!(ready.wait("tracking", deadline()).unwrap(), "the node reports ready");
    let mut received_poses: Vec<PoseRecord> = Vec::new();
    let mut received_keyframes = Vec::new();
    // Paced by the tracker: the next frame goes out once the last one's pose is back (as on-demand
    // acquisition paces by the tracker's credits).
    let pose_of = |seq: u64, received_poses: &mut Vec<PoseRecord>| {
        let got = bdis_ipc::wait_for(&pose_events, deadline(), || {
            while let Some(p) = pose_subscriber.receive().map_err(bdis_ipc::iox("poses"))? {
                received_poses.push(*p.payload());
            }
            Ok(received_poses.iter().any(|p| p.frame_seq == seq).then_some(()))
        });
        assert!(matches!(got, Ok(Some(()))), "the pose of frame {seq}");
    };
    for (i, payload) in payloads.iter().enumerate() {
        let mut loan = frame_publisher.loan_slice_uninit(layout.payload_len()).unwrap();
        assert_eq!(bdis_node::copy_into(loan.payload_mut(), payload), payload.len());
        // SAFETY: every byte was written just above.
        let mut sample = unsafe { loan.assume_init() };
        let mut header = FrameHeader { frame_seq: i as u64, t_source_ns: i as u64 * 33_333_333, ..Default::default() };
        layout.write_into(&mut header);
        *sample.user_header_mut() = header;
        sample.send().unwrap();
        bdis_ipc::notify(&frame_events, event_id::NEW_SAMPLE).unwrap();
        pose_of(i as u64, &mut received_poses);
        while let Some(k) = keyframe_subscriber.receive().unwrap() {
            let header = *k.user_header();
            // The frame's images, then an empty mask plane the keyframe does not flag (the frame had none).
            let images = &payloads[header.frame.frame_seq as usize][..];
            assert_eq!(&k.payload()[..images.len()], images, "the keyframe's images");
            assert!(k.payload()[images.len()..].iter().all(|&b| b == 0));
            assert_eq!(header.frame.flags & FrameHeader::HAS_MASK, 0);
            received_keyframes.push(header.meta);
        }
    }
    let eos = FrameHeader { frame_seq: n as u64, flags: FrameHeader::END_OF_STREAM, ..Default::default() };
    bdis_node::send_end_of_stream(&frame_publisher, eos).unwrap();
    bdis_ipc::notify(&frame_events, event_id::END_OF_STREAM).unwrap();
    pose_of(n as u64, &mut received_poses);
    node.join().unwrap().unwrap();
    let end = keyframe_subscriber.receive().unwrap().expect("the end of the keyframe stream");
    assert!(end.user_header().frame.is_end_of_stream());

    // A pose per frame, in order, then the end of the stream.
    let (last, per_frame) = received_poses.split_last().unwrap();
    assert_eq!(last.state, tracking_state::END_OF_STREAM);
    assert_eq!(per_frame.iter().map(|p| p.frame_seq).collect::<Vec<_>>(), (0..n as u64).collect::<Vec<_>>());
    assert!(per_frame.iter().all(|p| p.state == tracking_state::OK), "tracked every frame");
    // Keyframe ids consecutive from 0, each announced by its frame's pose, with the camera it was seen with.
    assert!(received_keyframes.len() >= 2);
    for (k, meta) in received_keyframes.iter().enumerate() {
        assert_eq!(meta.kf_id, k as u64);
        assert_eq!(meta.intrinsics, StereoIntrinsics::of(&camera));
        assert!(per_frame.iter().any(|p| p.new_keyframe == meta.kf_id));
    }
    let summary = TrackingSummary::read(&out_dir.join("tracking.json")).unwrap();
    assert_eq!((summary.frames, summary.lost), (n as u64, 0));
    assert!(summary.lost_reasons.is_empty(), "{:?}", summary.lost_reasons);
    assert_eq!(summary.keyframes_created, received_keyframes.len() as u64);
    let trajectory = bdis_core::formats::trajectory::read_tum(&out_dir.join("trajectory.tum")).unwrap();
    assert_eq!(trajectory.len(), n);
    let journal = Continuation::parse(&std::fs::read_to_string(out_dir.join("tracking.journal")).unwrap()).unwrap();
    assert_eq!((journal.frames.len(), journal.next_kf_id()), (n, received_keyframes.len() as u64));

    drop((frame_publisher, pose_subscriber, keyframe_subscriber, frames, poses, keyframes, ready, ipc));
    let _ = std::fs::remove_dir_all(&out_dir);
    bdis_ipc::remove_run_files(&prefix);
}

fn qos_poses_buffer() -> usize {
    bdis_ipc::qos::POSES_BUFFER
}

/// Every doubt the tracker can give.
const DOUBTS: [Doubt; 11] = [
    Doubt::FewInliers,
    Doubt::LowInlierRatio,
    Doubt::IllConditioned,
    Doubt::AppearanceDisagrees,
    Doubt::LowContrast,
    Doubt::MapMoving,
    Doubt::Detached,
    Doubt::PriorlessFewInliers,
    Doubt::Unconfirmed,
    Doubt::UnconfirmedPrior,
    Doubt::Hazy,
];

/// The contract's doubt names (what consumers such as the OpenIGTLink output report) are the tracker's own.
#[test]
fn every_doubt_travels_under_the_trackers_name_for_it() {
    for d in DOUBTS {
        assert_eq!(doubt::name(doubt_code(Some(d))), d.name());
    }
    assert_eq!(doubt::name(doubt_code(None)), "");
}

/// Every doubt and method the tracker can give passes the consumers' check of a pose record (the viewer, the
/// OpenIGTLink output and the bridge drop a record that fails it): a new one must move the contract's bound.
#[test]
fn every_doubt_and_method_the_tracker_gives_is_accepted_by_consumers() {
    let methods = [
        PoseMethod::None,
        PoseMethod::Initialisation,
        PoseMethod::MotionModel,
        PoseMethod::Appearance,
        PoseMethod::ReferenceProjection,
        PoseMethod::Relocalisation,
        PoseMethod::Prediction,
    ];
    let record = |doubt: u32, method: u32| bdis_ipc::track::PoseRecord {
        state: tracking_state::UNCERTAIN,
        world_from_camera: bdis_ipc::track::pose_to_array(&nalgebra::Isometry3::identity()),
        doubt,
        method,
        ..Default::default()
    };
    for d in DOUBTS {
        let r = record(doubt_code(Some(d)), pose_method::MOTION_MODEL);
        assert!(bdis_ipc::validate::pose_record(&r).is_ok(), "doubt {}", d.name());
    }
    for m in methods {
        let r = record(doubt::LOW_CONTRAST, method_code(m));
        assert!(bdis_ipc::validate::pose_record(&r).is_ok(), "method {}", m.name());
    }
}
