//! The map as the page receives it: one block per keyframe — its points in its own camera frame and the matrix
//! that places them — because the mosaic is anchored per keyframe: when loop closing moves a keyframe, the page
//! moves one matrix, not its points. Little-endian, 4-byte aligned, so the page reads it with typed arrays
//! without copying.
//!
//! ```text
//! "BDISMAP1"  u32 keyframes  u32 0
//! per keyframe (KEYFRAME_HEADER_BYTES):
//!   u32 kf_id low, u32 kf_id high, u32 points n,
//!   f32 grid spacing per unit depth (depth_gap_px / fx: a point at depth z stands for a patch gap·z/fx wide),
//!   f32 fx, fy, cx, cy, width, height (the keyframe's rectified camera, for its frustum),
//!   f32 x 16 world_from_camera, column-major (as three.js Matrix4.fromArray reads it)
//! then f32 x 3n positions, i8 x 3n unit normals x 127 (towards the camera that saw them), u8 x 3n colours,
//! zero padding to a multiple of 4 bytes.
//! ```

use bdis_mosaic::{KeyframeCloud, Mosaic, keyframe_normals};

pub const MAP_MAGIC: &[u8; 8] = b"BDISMAP1";
pub const KEYFRAME_HEADER_BYTES: usize = 4 * (4 + 6 + 16);

pub(crate) fn put_u32(out: &mut Vec<u8>, v: u32) {
    out.extend_from_slice(&v.to_le_bytes());
}

fn put_f32(out: &mut Vec<u8>, v: f64) {
    out.extend_from_slice(&(v as f32).to_le_bytes());
}

/// The whole map into `out` (cleared first; its capacity is reused). Keyframes whose points were all replaced
/// by later views are left out.
pub fn encode_map(mosaic: &Mosaic, out: &mut Vec<u8>) {
    out.clear();
    out.extend_from_slice(MAP_MAGIC);
    let shown: Vec<&KeyframeCloud> = mosaic.keyframes().filter(|k| !k.points.is_empty()).collect();
    put_u32(out, shown.len() as u32);
    put_u32(out, 0);
    let mut scratch = BlockScratch::default();
    for k in shown {
        encode_block(k, mosaic.params.grid_gap(k.intrinsics.width, k.intrinsics.height), &mut scratch, out);
    }
}

/// Reused between blocks: the grid and the normals of one keyframe.
#[derive(Debug, Default)]
pub struct BlockScratch {
    grid: Vec<u32>,
    normals: Vec<[f32; 3]>,
}

/// One keyframe's block (the layout above), appended to `out`.
pub fn encode_block(k: &KeyframeCloud, gap: usize, scratch: &mut BlockScratch, out: &mut Vec<u8>) {
    let c = &k.intrinsics;
    put_u32(out, k.kf_id as u32);
    put_u32(out, (k.kf_id >> 32) as u32);
    put_u32(out, k.points.len() as u32);
    put_f32(out, gap.max(1) as f64 / c.fx);
    for v in [c.fx, c.fy, c.cx, c.cy, f64::from(c.width), f64::from(c.height)] {
        put_f32(out, v);
    }
    put_matrix(out, &k.world_from_camera);
    for p in &k.points {
        for v in p.xyz {
            out.extend_from_slice(&v.to_le_bytes());
        }
    }
    keyframe_normals(k, gap, &mut scratch.grid, &mut scratch.normals);
    for n in &scratch.normals {
        out.extend(n.map(|v| (v * 127.0).round().clamp(-127.0, 127.0) as i8 as u8));
    }
    for p in &k.points {
        out.extend_from_slice(&p.rgb);
    }
    out.resize(out.len().next_multiple_of(4), 0);
}

/// A pose as 16 f32, column-major (as nalgebra stores it and three.js reads it).
pub fn put_matrix(out: &mut Vec<u8>, pose: &nalgebra::Isometry3<f64>) {
    for v in pose.to_homogeneous().as_slice() {
        put_f32(out, *v);
    }
}
