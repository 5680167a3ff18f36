//! The carried topics' headers as bytes, field by field, little-endian: nothing about the in-memory layout (its
//! padding, the host's byte order) crosses the link. What comes back is checked by the receiver with the same
//! `bdis_ipc::validate` every consumer runs before it is published.

use bdis_ipc::map::{MapPoint, MapQuery, MapSnapshotHeader};
use bdis_ipc::track::{KeyframeMeta, KeyframePose, PoseRecord, StereoIntrinsics};
use bdis_ipc::{DepthHeader, FrameHeader, KeyframeHeader};

use crate::BridgeError;

struct Put<'a>(&'a mut Vec<u8>);

impl Put<'_> {
    fn u64(&mut self, v: u64) -> &mut Self {
        self.0.extend_from_slice(&v.to_le_bytes());
        self
    }
    fn u32(&mut self, v: u32) -> &mut Self {
        self.0.extend_from_slice(&v.to_le_bytes());
        self
    }
    fn f64(&mut self, v: f64) -> &mut Self {
        self.0.extend_from_slice(&v.to_le_bytes());
        self
    }
    fn f32(&mut self, v: f32) -> &mut Self {
        self.0.extend_from_slice(&v.to_le_bytes());
        self
    }
}

struct Take<'a> {
    bytes: &'a [u8],
    at: usize,
}

impl Take<'_> {
    fn bytes<const N: usize>(&mut self) -> [u8; N] {
        let mut out = [0u8; N];
        if let Some(b) = self.bytes.get(self.at..self.at + N) {
            out.copy_from_slice(b);
        }
        self.at += N;
        out
    }
    fn u64(&mut self) -> u64 {
        u64::from_le_bytes(self.bytes())
    }
    fn u32(&mut self) -> u32 {
        u32::from_le_bytes(self.bytes())
    }
    fn f64(&mut self) -> f64 {
        f64::from_le_bytes(self.bytes())
    }
    fn f32(&mut self) -> f32 {
        f32::from_le_bytes(self.bytes())
    }
}

fn put_meta(p: &mut Put<'_>, m: &KeyframeMeta) {
    p.u64(m.kf_id);
    for &v in &m.world_from_camera {
        p.f64(v);
    }
    let i = &m.intrinsics;
    p.f64(i.fx).f64(i.fy).f64(i.cx).f64(i.cy).f64(i.bf).u64(m.corrections_generation);
}

fn take_meta(t: &mut Take<'_>) -> KeyframeMeta {
    let kf_id = t.u64();
    let world_from_camera = std::array::from_fn(|_| t.f64());
    let intrinsics = StereoIntrinsics { fx: t.f64(), fy: t.f64(), cx: t.f64(), cy: t.f64(), bf: t.f64() };
    KeyframeMeta { kf_id, world_from_camera, intrinsics, corrections_generation: t.u64() }
}

/// Bytes of a depth header on the wire.
pub const DEPTH_HEADER_BYTES: usize = (1 + 7 + 5 + 1) * 8 + 3 * 8 + 8 * 4;

pub fn put_depth_header(out: &mut Vec<u8>, h: &DepthHeader) {
    let mut p = Put(out);
    put_meta(&mut p, &h.meta);
    p.u64(h.frame_seq).u64(h.t_capture_ns).u64(h.t_publish_ns);
    p.u32(h.width).u32(h.height).u32(h.disparity_offset).u32(h.confidence_offset).u32(h.rgb_offset);
    p.u32(h.algorithm).u32(h.flags).u32(h.density_permille);
}

pub fn depth_header(bytes: &[u8]) -> Result<DepthHeader, BridgeError> {
    if bytes.len() != DEPTH_HEADER_BYTES {
        return Err(BridgeError::HeaderSize("depth"));
    }
    let mut t = Take { bytes, at: 0 };
    let meta = take_meta(&mut t);
    Ok(DepthHeader {
        meta,
        frame_seq: t.u64(),
        t_capture_ns: t.u64(),
        t_publish_ns: t.u64(),
        width: t.u32(),
        height: t.u32(),
        disparity_offset: t.u32(),
        confidence_offset: t.u32(),
        rgb_offset: t.u32(),
        algorithm: t.u32(),
        flags: t.u32(),
        density_permille: t.u32(),
    })
}

/// Bytes of a keyframe header on the wire: the frame's header, then what the keyframe is.
pub const KEYFRAME_HEADER_BYTES: usize = 4 * 8 + 10 * 4 + (1 + 7 + 5 + 1) * 8;

pub fn put_keyframe_header(out: &mut Vec<u8>, h: &KeyframeHeader) {
    let mut p = Put(out);
    let f = &h.frame;
    p.u64(f.frame_seq).u64(f.t_capture_ns).u64(f.t_publish_ns).u64(f.t_source_ns);
    p.u32(f.width).u32(f.height).u32(f.left_gray_offset).u32(f.right_gray_offset).u32(f.left_rgb_offset);
    p.u32(f.gray_stride).u32(f.rgb_stride).u32(f.flags).u32(f.source_index).u32(f.mask_offset);
    put_meta(&mut p, &h.meta);
}

pub fn keyframe_header(bytes: &[u8]) -> Result<KeyframeHeader, BridgeError> {
    if bytes.len() != KEYFRAME_HEADER_BYTES {
        return Err(BridgeError::HeaderSize("keyframe"));
    }
    let mut t = Take { bytes, at: 0 };
    let frame = FrameHeader {
        frame_seq: t.u64(),
        t_capture_ns: t.u64(),
        t_publish_ns: t.u64(),
        t_source_ns: t.u64(),
        width: t.u32(),
        height: t.u32(),
        left_gray_offset: t.u32(),
        right_gray_offset: t.u32(),
        left_rgb_offset: t.u32(),
        gray_stride: t.u32(),
        rgb_stride: t.u32(),
        flags: t.u32(),
        source_index: t.u32(),
        mask_offset: t.u32(),
    };
    Ok(KeyframeHeader { frame, meta: take_meta(&mut t) })
}

/// Bytes of a correction on the wire.
pub const CORRECTION_BYTES: usize = 8 + 7 * 8 + 8 + 4 + 4;

pub fn put_correction(out: &mut Vec<u8>, c: &KeyframePose) {
    let mut p = Put(out);
    p.u64(c.kf_id);
    for &v in &c.world_from_camera {
        p.f64(v);
    }
    p.u64(c.generation).u32(c.culled).u32(c.reserved);
}

pub fn correction(bytes: &[u8]) -> Result<KeyframePose, BridgeError> {
    if bytes.len() != CORRECTION_BYTES {
        return Err(BridgeError::HeaderSize("correction"));
    }
    let mut t = Take { bytes, at: 0 };
    Ok(KeyframePose {
        kf_id: t.u64(),
        world_from_camera: std::array::from_fn(|_| t.f64()),
        generation: t.u64(),
        culled: t.u32(),
        reserved: t.u32(),
    })
}

/// Bytes of a pose record on the wire.
pub const POSE_BYTES: usize = 4 * 8 + 7 * 8 + 2 * 4 + 2 * 8 + 4 * 4 + 3 * 8;

pub fn put_pose(out: &mut Vec<u8>, r: &PoseRecord) {
    let mut p = Put(out);
    p.u64(r.frame_seq).u64(r.t_capture_ns).u64(r.t_source_ns).u64(r.t_publish_ns);
    for &v in &r.world_from_camera {
        p.f64(v);
    }
    p.u32(r.state).u32(r.inliers).u64(r.new_keyframe).u64(r.cpu_ns);
    p.u32(r.matched).u32(r.doubt).u32(r.method).u32(r.prior_rejected);
    p.f64(r.reprojection_rms_px).f64(r.position_sigma_rel).f64(r.appearance_agreement);
}

pub fn pose(bytes: &[u8]) -> Result<PoseRecord, BridgeError> {
    if bytes.len() != POSE_BYTES {
        return Err(BridgeError::HeaderSize("pose"));
    }
    let mut t = Take { bytes, at: 0 };
    Ok(PoseRecord {
        frame_seq: t.u64(),
        t_capture_ns: t.u64(),
        t_source_ns: t.u64(),
        t_publish_ns: t.u64(),
        world_from_camera: std::array::from_fn(|_| t.f64()),
        state: t.u32(),
        inliers: t.u32(),
        new_keyframe: t.u64(),
        cpu_ns: t.u64(),
        matched: t.u32(),
        doubt: t.u32(),
        method: t.u32(),
        prior_rejected: t.u32(),
        reprojection_rms_px: t.f64(),
        position_sigma_rel: t.f64(),
        appearance_agreement: t.f64(),
    })
}

/// Bytes of a map-snapshot request on the wire.
pub const QUERY_BYTES: usize = 2 * 8;

pub fn put_query(out: &mut Vec<u8>, q: &MapQuery) {
    Put(out).u64(q.max_points).u64(q.reserved);
}

pub fn query(bytes: &[u8]) -> Result<MapQuery, BridgeError> {
    if bytes.len() != QUERY_BYTES {
        return Err(BridgeError::HeaderSize("map query"));
    }
    let mut t = Take { bytes, at: 0 };
    Ok(MapQuery { max_points: t.u64(), reserved: t.u64() })
}

/// Bytes of a map snapshot's header on the wire; its points follow, [`MAP_POINT_BYTES`] each.
pub const SNAPSHOT_HEADER_BYTES: usize = 6 * 8;
pub const MAP_POINT_BYTES: usize = 3 * 4 + 3 + 1 + 4;

pub fn put_snapshot(out: &mut Vec<u8>, h: &MapSnapshotHeader, points: &[MapPoint]) {
    out.reserve(SNAPSHOT_HEADER_BYTES + MAP_POINT_BYTES * points.len());
    let mut p = Put(out);
    p.u64(h.points_in_map).u64(h.stride).u64(h.keyframes).u64(h.keyframes_inserted);
    p.u64(h.corrections_applied).u64(h.t_publish_ns);
    for point in points {
        p.f32(point.xyz[0]).f32(point.xyz[1]).f32(point.xyz[2]);
        p.0.extend_from_slice(&point.rgb);
        p.0.push(point.confidence);
        p.u32(point.kf_id);
    }
}

/// A snapshot's header and how many points follow it (the bytes must hold exactly that many).
pub fn snapshot_header(bytes: &[u8]) -> Result<(MapSnapshotHeader, usize), BridgeError> {
    let points = bytes.len().checked_sub(SNAPSHOT_HEADER_BYTES).ok_or(BridgeError::HeaderSize("map snapshot"))?;
    if points % MAP_POINT_BYTES != 0 {
        return Err(BridgeError::HeaderSize("map snapshot"));
    }
    let mut t = Take { bytes, at: 0 };
    let header = MapSnapshotHeader {
        points_in_map: t.u64(),
        stride: t.u64(),
        keyframes: t.u64(),
        keyframes_inserted: t.u64(),
        corrections_applied: t.u64(),
        t_publish_ns: t.u64(),
    };
    Ok((header, points / MAP_POINT_BYTES))
}

/// The snapshot's points into `out` (as many as [`snapshot_header`] counted); a point that is not finite is an
/// error, as it would be from the mosaic itself.
pub fn snapshot_points(bytes: &[u8], out: &mut [MapPoint]) -> Result<(), BridgeError> {
    let points = bytes.get(SNAPSHOT_HEADER_BYTES..).ok_or(BridgeError::HeaderSize("map snapshot"))?;
    if points.len() != out.len() * MAP_POINT_BYTES {
        return Err(BridgeError::HeaderSize("map snapshot"));
    }
    for (chunk, point) in points.chunks_exact(MAP_POINT_BYTES).zip(out.iter_mut()) {
        let mut t = Take { bytes: chunk, at: 0 };
        let xyz = [t.f32(), t.f32(), t.f32()];
        if !xyz.iter().all(|v| v.is_finite()) {
            return Err(BridgeError::NotFinite("map point"));
        }
        let [r, g, b, confidence] = t.bytes::<4>();
        *point = MapPoint { xyz, rgb: [r, g, b], confidence, kf_id: t.u32() };
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_field_crosses_unchanged() {
        let h = DepthHeader {
            meta: KeyframeMeta {
                kf_id: 77,
                world_from_camera: [1.0, 2.0, 3.0, 0.1, 0.2, 0.3, 0.9],
                intrinsics: StereoIntrinsics { fx: 260.0, fy: 261.0, cx: 159.5, cy: 119.5, bf: 1300.0 },
                corrections_generation: 12,
            },
            frame_seq: 300,
            t_capture_ns: 1,
            t_publish_ns: 2,
            width: 320,
            height: 240,
            disparity_offset: 0,
            confidence_offset: 307_200,
            rgb_offset: 614_400,
            algorithm: DepthHeader::BDIS,
            flags: 0,
            density_permille: 768,
        };
        let mut bytes = Vec::new();
        put_depth_header(&mut bytes, &h);
        assert_eq!(bytes.len(), DEPTH_HEADER_BYTES);
        assert_eq!(depth_header(&bytes), Ok(h));
        assert!(depth_header(&bytes[1..]).is_err());
        let c = KeyframePose {
            kf_id: 5,
            world_from_camera: [0.5, -1.0, 2.0, 0.0, 0.0, 0.0, 1.0],
            generation: 9,
            culled: 1,
            reserved: 0,
        };
        let mut bytes = Vec::new();
        put_correction(&mut bytes, &c);
        assert_eq!(correction(&bytes), Ok(c));
        let r = PoseRecord {
            frame_seq: 17,
            t_capture_ns: 3,
            t_source_ns: 4,
            t_publish_ns: 5,
            world_from_camera: [1.0, 2.0, 3.0, 0.0, 0.0, 0.0, 1.0],
            state: 4,
            inliers: 200,
            new_keyframe: u64::MAX,
            cpu_ns: 9_000_000,
            matched: 230,
            doubt: 5,
            method: 3,
            prior_rejected: 1,
            reprojection_rms_px: 0.9,
            position_sigma_rel: 1e-4,
            appearance_agreement: 0.97,
        };
        let k = KeyframeHeader {
            frame: FrameHeader {
                frame_seq: 44,
                t_capture_ns: 1,
                t_publish_ns: 2,
                t_source_ns: 3,
                width: 320,
                height: 240,
                left_gray_offset: 0,
                right_gray_offset: 76_800,
                left_rgb_offset: 153_600,
                gray_stride: 320,
                rgb_stride: 960,
                flags: FrameHeader::HAS_MASK,
                source_index: 45,
                mask_offset: 384_000,
            },
            meta: h.meta,
        };
        let mut bytes = Vec::new();
        put_keyframe_header(&mut bytes, &k);
        assert_eq!(bytes.len(), KEYFRAME_HEADER_BYTES);
        assert_eq!(keyframe_header(&bytes), Ok(k));
        let mut bytes = Vec::new();
        put_pose(&mut bytes, &r);
        assert_eq!(bytes.len(), POSE_BYTES);
        assert_eq!(pose(&bytes), Ok(r));
    }

    #[test]
    fn a_snapshot_crosses_unchanged_and_a_broken_one_is_refused() {
        let q = MapQuery { max_points: 5000, reserved: 0 };
        let mut bytes = Vec::new();
        put_query(&mut bytes, &q);
        assert_eq!(query(&bytes), Ok(q));
        assert!(query(&bytes[1..]).is_err());
        let h = MapSnapshotHeader {
            points_in_map: 10,
            stride: 5,
            keyframes: 3,
            keyframes_inserted: 4,
            corrections_applied: 7,
            t_publish_ns: 99,
        };
        let points = [
            MapPoint { xyz: [1.0, -2.0, 55.5], rgb: [200, 100, 50], confidence: 255, kf_id: 2 },
            MapPoint { xyz: [0.0, 0.25, 60.0], rgb: [1, 2, 3], confidence: 7, kf_id: 3 },
        ];
        let mut bytes = Vec::new();
        put_snapshot(&mut bytes, &h, &points);
        assert_eq!(bytes.len(), SNAPSHOT_HEADER_BYTES + 2 * MAP_POINT_BYTES);
        assert_eq!(snapshot_header(&bytes), Ok((h, 2)));
        let mut back = [MapPoint::default(); 2];
        snapshot_points(&bytes, &mut back).unwrap();
        assert_eq!(back, points);
        assert!(snapshot_header(&bytes[..bytes.len() - 1]).is_err());
        assert!(snapshot_points(&bytes, &mut [MapPoint::default(); 1]).is_err());
        let at = SNAPSHOT_HEADER_BYTES + MAP_POINT_BYTES;
        bytes[at..at + 4].copy_from_slice(&f32::NAN.to_le_bytes());
        assert_eq!(snapshot_points(&bytes, &mut back), Err(BridgeError::NotFinite("map point")));
    }
}
