//! Targets for the shared-memory validators: the fuzz input is a header, field by field, then the payload.
//! Whatever a validator accepts must be safe to read as the contract says.

use bdis_ipc::validate;
use bdis_ipc::{DepthHeader, FrameHeader, KeyframeHeader, KeyframeMeta, KeyframePose, PoseRecord, StereoIntrinsics};
use bdis_ipc::{TelemetryKind, TelemetryRecord};

/// Reads fields off the input; past its end every field is zero (a short input is a header of zeros).
struct Fields<'a> {
    data: &'a [u8],
}

impl<'a> Fields<'a> {
    fn take<const N: usize>(&mut self) -> [u8; N] {
        let mut out = [0u8; N];
        let n = N.min(self.data.len());
        out[..n].copy_from_slice(&self.data[..n]);
        self.data = &self.data[n..];
        out
    }
    fn u64(&mut self) -> u64 {
        u64::from_le_bytes(self.take())
    }
    fn u32(&mut self) -> u32 {
        u32::from_le_bytes(self.take())
    }
    fn f64(&mut self) -> f64 {
        f64::from_le_bytes(self.take())
    }
    fn pose(&mut self) -> [f64; 7] {
        std::array::from_fn(|_| self.f64())
    }
    /// Dimensions and offsets: mostly small, so the fuzzer reaches the accepting paths, but any value at all
    /// when the high bit of the selector is set.
    fn size(&mut self) -> u32 {
        let v = self.u32();
        if v & 0x8000_0000 != 0 { v } else { v % 64 }
    }
    fn frame_header(&mut self) -> FrameHeader {
        FrameHeader {
            frame_seq: self.u64(),
            width: self.size(),
            height: self.size(),
            left_gray_offset: self.size(),
            right_gray_offset: self.size(),
            left_rgb_offset: self.size(),
            gray_stride: self.size(),
            rgb_stride: self.size(),
            flags: self.u32(),
            ..Default::default()
        }
    }
    fn meta(&mut self) -> KeyframeMeta {
        KeyframeMeta {
            kf_id: self.u64(),
            world_from_camera: self.pose(),
            intrinsics: StereoIntrinsics {
                fx: self.f64(),
                fy: self.f64(),
                cx: self.f64(),
                cy: self.f64(),
                bf: self.f64(),
            },
            corrections_generation: self.u64(),
        }
    }
}

fn check_frame_view(view: &bdis_ipc::FrameView) {
    let h = view.header;
    assert_eq!(view.left_gray.len(), h.gray_stride as usize * h.height as usize);
    assert_eq!(view.right_gray.len(), h.gray_stride as usize * h.height as usize);
    assert_eq!(view.left_rgb.len(), h.rgb_stride as usize * h.height as usize);
    // Every row the consumer reads is inside its image.
    assert!(h.gray_stride >= h.width && h.rgb_stride as u64 >= 3 * h.width as u64);
}

pub fn frame(data: &[u8]) {
    let mut f = Fields { data };
    let header = f.frame_header();
    let payload = f.data;
    if let Ok(view) = validate::frame(&header, payload) {
        check_frame_view(&view);
    }
    let expected = Some((header.width, header.height));
    if let Ok(view) = validate::packed_frame(&header, payload, expected) {
        assert_eq!(view.header.gray_stride, view.header.width);
    }
}

pub fn keyframe(data: &[u8]) {
    let mut f = Fields { data };
    let header = KeyframeHeader { frame: f.frame_header(), meta: f.meta() };
    if let Ok((view, pose)) = validate::keyframe(&header, f.data) {
        check_frame_view(&view);
        assert!(pose.translation.vector.iter().all(|v| v.is_finite()));
        let k = header.meta.intrinsics;
        assert!(k.fx > 0.0 && k.fy > 0.0 && k.bf > 0.0);
    }
}

pub fn depth(data: &[u8]) {
    let mut f = Fields { data };
    let header = DepthHeader {
        meta: f.meta(),
        frame_seq: f.u64(),
        width: f.size(),
        height: f.size(),
        disparity_offset: f.size(),
        confidence_offset: f.size(),
        rgb_offset: f.size(),
        algorithm: f.u32() % 4,
        flags: f.u32(),
        ..Default::default()
    };
    // The payload of a loaned sample is 8-aligned: copy the rest of the input into aligned storage.
    let mut storage = vec![0u64; f.data.len().div_ceil(8)];
    let bytes: &mut [u8] = bytemuck_bytes(&mut storage);
    bytes[..f.data.len()].copy_from_slice(f.data);
    let payload = &bytes[..f.data.len()];
    if let Ok((view, _pose)) = validate::depth(&header, payload) {
        let n = header.width as usize * header.height as usize;
        assert_eq!((view.disparity.len(), view.confidence.len(), view.rgb.len()), (n, n, 3 * n));
    }
}

/// The bytes of u64 storage (8-aligned).
fn bytemuck_bytes(storage: &mut [u64]) -> &mut [u8] {
    let len = storage.len() * 8;
    // SAFETY: u64 storage viewed as bytes: same memory, every byte pattern valid, length in bytes.
    unsafe { std::slice::from_raw_parts_mut(storage.as_mut_ptr().cast::<u8>(), len) }
}

pub fn correction(data: &[u8]) {
    let mut f = Fields { data };
    let c = KeyframePose {
        kf_id: f.u64(),
        world_from_camera: f.pose(),
        generation: f.u64() % 4,
        culled: f.u32() % 3,
        reserved: 0,
    };
    if let Ok(p) = validate::correction(&c) {
        assert!((p.rotation.quaternion().norm() - 1.0).abs() < 1e-6 && c.generation > 0);
    }
}

pub fn pose_record(data: &[u8]) {
    let mut f = Fields { data };
    let r = PoseRecord { frame_seq: f.u64(), world_from_camera: f.pose(), state: f.u32() % 6, ..Default::default() };
    if let Ok(Some(p)) = validate::pose_record(&r) {
        assert!(p.translation.vector.iter().all(|v| v.is_finite()));
    }
}

pub fn telemetry(data: &[u8]) {
    let mut f = Fields { data };
    let mut r = TelemetryRecord { kind: f.u32() % 8, pid: f.u32(), record_seq: f.u64(), ..Default::default() };
    r.process = f.take();
    r.reason = f.u32();
    if let Ok(kind) = bdis_ipc::telemetry::validate(&r) {
        assert_eq!(TelemetryKind::from_u32(r.kind), Some(kind));
        assert!(!r.process().is_empty());
        let _ = validate::Reason::from_u32(r.reason).map(validate::Reason::name);
    }
}
