use super::*;
use crate::frame::FrameLayout;

fn packed_frame_header(w: u32, h: u32, seq: u64) -> FrameHeader {
    let mut header = FrameHeader { frame_seq: seq, ..Default::default() };
    FrameLayout::packed(w, h).unwrap().write_into(&mut header);
    header
}

const IDENTITY: [f64; 7] = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0];
const CAMERA: StereoIntrinsics = StereoIntrinsics { fx: 100.0, fy: 100.0, cx: 2.0, cy: 1.0, bf: 5.0 };

#[test]
fn frames_are_checked_against_their_payload_without_overflow() {
    let payload = vec![0u8; 40];
    let h = packed_frame_header(4, 2, 3);
    assert!(frame(&h, &payload).is_ok());
    assert_eq!(frame(&h, &payload[..39]).unwrap_err().reason, Reason::PayloadSize);
    // Offsets and sizes that wrap 32- or 64-bit arithmetic are refused, not sliced.
    let mut huge = h;
    huge.left_rgb_offset = u32::MAX;
    assert_eq!(frame(&huge, &payload).unwrap_err().reason, Reason::PayloadSize);
    let mut huge = h;
    (huge.width, huge.height, huge.gray_stride, huge.rgb_stride) = (u32::MAX, u32::MAX, u32::MAX, u32::MAX);
    assert_eq!(frame(&huge, &payload).unwrap_err().reason, Reason::Layout, "rgb stride < 3·width");
    let mut zero = h;
    zero.height = 0;
    assert_eq!(frame(&zero, &payload).unwrap_err().reason, Reason::Layout);
    assert_eq!(packed_frame(&h, &payload, Some((8, 2))).unwrap_err().reason, Reason::Dimensions);
    let mut padded = packed_frame_header(4, 2, 3);
    padded.gray_stride = 5;
    assert_eq!(packed_frame(&padded, &[0u8; 64], None).unwrap_err().reason, Reason::Layout);
}

#[test]
fn keyframes_need_a_rigid_pose_and_a_camera() {
    let payload = vec![0u8; 40];
    let mut kh = KeyframeHeader {
        frame: packed_frame_header(4, 2, 9),
        meta: KeyframeMeta { kf_id: 2, world_from_camera: IDENTITY, intrinsics: CAMERA, corrections_generation: 0 },
    };
    assert!(keyframe(&kh, &payload).is_ok());
    for bad in [f64::NAN, f64::INFINITY] {
        kh.meta.world_from_camera[0] = bad;
        assert_eq!(keyframe(&kh, &payload).unwrap_err().reason, Reason::Pose);
    }
    kh.meta.world_from_camera = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.01];
    assert_eq!(keyframe(&kh, &payload).unwrap_err().reason, Reason::Pose, "quaternion off unit length");
    kh.meta.world_from_camera = IDENTITY;
    for (fx, bf) in [(0.0, 5.0), (-100.0, 5.0), (100.0, 0.0), (f64::NAN, 5.0)] {
        kh.meta.intrinsics = StereoIntrinsics { fx, bf, ..CAMERA };
        let e = keyframe(&kh, &payload).unwrap_err();
        assert_eq!((e.reason, e.id), (Reason::Intrinsics, 2));
    }
}

#[test]
fn depth_layout_is_checked_with_wide_arithmetic() {
    let storage = [0u64; 11];
    // SAFETY: u64 storage viewed as bytes, 8-aligned like a loaned payload.
    let payload = unsafe { std::slice::from_raw_parts(storage.as_ptr().cast::<u8>(), 88) };
    let mut dh = DepthHeader {
        meta: KeyframeMeta { kf_id: 1, world_from_camera: IDENTITY, intrinsics: CAMERA, corrections_generation: 0 },
        algorithm: DepthHeader::BDIS,
        ..Default::default()
    };
    dh.set_layout(4, 2);
    assert!(depth(&dh, payload).unwrap().1.is_some());
    dh.meta.world_from_camera = [0.0; 7];
    assert!(depth(&dh, payload).unwrap().1.is_none(), "all zero: a keyframe without a pose");
    // 65536 × 65536 floats would wrap a 32-bit count; the header's claim is compared in 64 bits.
    let mut huge = dh;
    (huge.width, huge.height) = (65_536, 65_536);
    assert_eq!(depth(&huge, payload).unwrap_err().reason, Reason::PayloadSize);
    let mut past = dh;
    past.rgb_offset = u32::MAX - 2;
    assert_eq!(depth(&past, payload).unwrap_err().reason, Reason::PayloadSize);
    let mut unaligned = dh;
    (unaligned.disparity_offset, unaligned.confidence_offset, unaligned.rgb_offset) = (1, 33, 64);
    assert_eq!(depth(&unaligned, payload).unwrap_err().reason, Reason::Layout);
    let mut algorithm = dh;
    algorithm.algorithm = 7;
    assert_eq!(depth(&algorithm, payload).unwrap_err().reason, Reason::UnknownValue);
}

#[test]
fn corrections_poses_and_telemetry_have_defined_values() {
    let good = KeyframePose { kf_id: 4, world_from_camera: IDENTITY, generation: 1, culled: 0, reserved: 0 };
    assert!(correction(&good).is_ok());
    assert_eq!(correction(&KeyframePose { generation: 0, ..good }).unwrap_err().reason, Reason::UnknownValue);
    assert_eq!(correction(&KeyframePose { culled: 2, ..good }).unwrap_err().reason, Reason::UnknownValue);
    let mut nan = good;
    nan.world_from_camera[5] = f64::NAN;
    assert_eq!(correction(&nan).unwrap_err().reason, Reason::Pose);

    let ok = PoseRecord { frame_seq: 5, world_from_camera: IDENTITY, state: tracking_state::OK, ..Default::default() };
    assert!(pose_record(&ok).unwrap().is_some());
    assert!(pose_record(&PoseRecord { state: tracking_state::LOST, ..ok }).unwrap().is_none());
    assert_eq!(pose_record(&PoseRecord { state: 77, ..ok }).unwrap_err().reason, Reason::UnknownValue);
    assert!(pose_record(&PoseRecord { state: tracking_state::UNCERTAIN, ..ok }).unwrap().is_some());
    let (doubt, method) = (crate::track::doubt::LAST + 1, crate::track::pose_method::LAST + 1);
    assert_eq!(pose_record(&PoseRecord { doubt, ..ok }).unwrap_err().reason, Reason::UnknownValue);
    assert_eq!(pose_record(&PoseRecord { method, ..ok }).unwrap_err().reason, Reason::UnknownValue);
    let (doubt, method) = (crate::track::doubt::LAST, crate::track::pose_method::LAST);
    assert!(pose_record(&PoseRecord { state: tracking_state::UNCERTAIN, doubt, method, ..ok }).is_ok());
    assert_eq!(pose_record(&PoseRecord { world_from_camera: [0.0; 7], ..ok }).unwrap_err().reason, Reason::Pose);
}

#[test]
fn a_stream_skips_its_producers_replays_and_refuses_strays() {
    let (producer, rogue) = (1u8, 2u8);
    let mut g = StreamGuard::<u8>::default();
    assert_eq!(g.admit(0, rogue, "frame"), Ok(Admit::New));
    assert!(g.end_of_stream(0, "frames").is_ok(), "an empty stream may end");
    g.taken(0, 0, producer);
    g.taken(1, 1, producer);
    assert_eq!(g.admit(2, producer, "frame"), Ok(Admit::New));
    assert_eq!(g.admit(1, producer, "frame"), Ok(Admit::Replay), "the producer replays");
    assert_eq!(g.admit(1, rogue, "frame").unwrap_err().reason, Reason::StaleId);
    assert_eq!(g.admit(0, rogue, "frame").unwrap_err().reason, Reason::StaleId);
    assert_eq!(g.end_of_stream(1, "frames").unwrap_err().reason, Reason::StrayEndOfStream);
    assert!(g.end_of_stream(2, "frames").is_ok(), "the stream's count ends it, from whoever (a restarted producer)");
    // A resumed consumer takes any replay of what it had as a replay.
    let resumed = StreamGuard::<u8>::resuming_after(Some(5));
    assert_eq!(resumed.admit(3, rogue, "keyframe"), Ok(Admit::Replay));
    assert_eq!(resumed.admit(6, rogue, "keyframe"), Ok(Admit::New));
    for r in Reason::ALL {
        assert_eq!(Reason::from_u32(r as u32), Some(r));
    }
}
