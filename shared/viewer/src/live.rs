//! What a running pipeline looks like to the page, kept by the thread that owns it, and the messages that bring a
//! page up to date. The map is a replica of the mosaic's, built by the same library under the same rule from the
//! same topics (depth keyframes, pose corrections applied in the tracker's generations): the mosaic's snapshots
//! give points in world coordinates, and a page that holds one block per keyframe — in the keyframe's camera
//! frame under the keyframe's pose — needs the points in their keyframe's frame. So
//!
//! * a keyframe new to the page is sent once, whole (`BLK1` + the block of `encode.rs`);
//! * points a later view replaced are taken out by a mask over what the page holds (`TRM1` + id + count + one
//!   bit per point, set = kept): points are never sent twice;
//! * a keyframe all of whose points were replaced is dropped (`DEL1` + id);
//! * a pose correction moves a whole keyframe with one matrix (`COR1` + id + 16 f32, column-major);
//! * the newest depth keyframe is shown beside the map (`IMG1` + width + height + left RGB + depth coloured RGB).
//!
//! Ids are two u32 (low, high), everything little-endian. The path and the processes' health travel as JSON text
//! messages (`{"type": "poses" | "health", ...}`).

use std::collections::BTreeMap;

use bdis_mosaic::{KeyframeCloud, Mosaic};
use serde::Serialize;

use crate::encode::{BlockScratch, encode_block, put_matrix, put_u32};
use crate::run::PathPose;

pub const TAG_BLOCK: &[u8; 4] = b"BLK1";
pub const TAG_TRIM: &[u8; 4] = b"TRM1";
pub const TAG_DROP: &[u8; 4] = b"DEL1";
pub const TAG_MOVE: &[u8; 4] = b"COR1";
pub const TAG_IMAGE: &[u8; 4] = b"IMG1";

/// A message for the page.
#[derive(Debug, Clone, PartialEq)]
pub enum Update {
    Binary(Vec<u8>),
    Text(String),
}

/// What the page holds: per keyframe, the block as it was sent and trimmed since, and the path.
#[derive(Debug, Default)]
pub struct LiveMap {
    shown: BTreeMap<u64, KeyframeCloud>,
    path: Vec<PathPose>,
    scratch: BlockScratch,
    /// The map's parameters (each keyframe's grid step: `MosaicParams::grid_gap`).
    params: bdis_mosaic::MosaicParams,
    /// Bumped by every message that changes the map on the page.
    pub map_messages: u64,
}

fn id_bytes(out: &mut Vec<u8>, kf_id: u64) {
    put_u32(out, kf_id as u32);
    put_u32(out, (kf_id >> 32) as u32);
}

impl LiveMap {
    pub fn keyframes_shown(&self) -> usize {
        self.shown.len()
    }

    pub fn points_shown(&self) -> usize {
        self.shown.values().map(|k| k.points.len()).sum()
    }

    /// New poses of the path; the message that extends the page's path.
    pub fn poses(&mut self, poses: Vec<PathPose>) -> Option<Update> {
        if poses.is_empty() {
            return None;
        }
        #[derive(Serialize)]
        struct Poses<'a> {
            r#type: &'static str,
            poses: &'a [PathPose],
        }
        let text = serde_json::to_string(&Poses { r#type: "poses", poses: &poses }).ok();
        self.path.extend(poses);
        text.map(Update::Text)
    }

    /// The messages that bring the page from what it holds to `map`.
    pub fn sync(&mut self, map: &Mosaic, out: &mut Vec<Update>) {
        self.params = map.params;
        let params = map.params;
        let gap = |k: &bdis_mosaic::KeyframeCloud| params.grid_gap(k.intrinsics.width, k.intrinsics.height);
        let before = out.len();
        for k in map.keyframes() {
            match self.shown.get_mut(&k.kf_id) {
                None if k.points.is_empty() => {}
                None => {
                    let mut message = TAG_BLOCK.to_vec();
                    encode_block(k, gap(k), &mut self.scratch, &mut message);
                    out.push(Update::Binary(message));
                    self.shown.insert(k.kf_id, k.clone());
                }
                Some(_) if k.points.is_empty() => {
                    self.shown.remove(&k.kf_id);
                    let mut message = TAG_DROP.to_vec();
                    id_bytes(&mut message, k.kf_id);
                    out.push(Update::Binary(message));
                }
                Some(shown) => {
                    if shown.points.len() != k.points.len() {
                        // The mosaic only takes points away from an earlier keyframe, keeping the order: the kept
                        // ones are found by walking both lists.
                        let mut keep = vec![false; shown.points.len()];
                        let mut j = 0;
                        for (i, p) in shown.points.iter().enumerate() {
                            if k.points.get(j).is_some_and(|q| q.xyz == p.xyz) {
                                keep[i] = true;
                                j += 1;
                            }
                        }
                        if j != k.points.len() {
                            // Not a subset (cannot happen with the mosaic's rule): the block is sent again whole.
                            let mut message = TAG_BLOCK.to_vec();
                            encode_block(k, gap(k), &mut self.scratch, &mut message);
                            out.push(Update::Binary(message));
                            *shown = k.clone();
                            continue;
                        }
                        let mut message = TAG_TRIM.to_vec();
                        id_bytes(&mut message, k.kf_id);
                        put_u32(&mut message, keep.len() as u32);
                        let mut bits = vec![0u8; keep.len().div_ceil(8)];
                        for (i, _) in keep.iter().enumerate().filter(|(_, kept)| **kept) {
                            bits[i / 8] |= 1 << (i % 8);
                        }
                        message.extend(bits);
                        out.push(Update::Binary(message));
                        shown.points = k.points.clone();
                    }
                    if shown.world_from_camera != k.world_from_camera {
                        shown.world_from_camera = k.world_from_camera;
                        let mut message = TAG_MOVE.to_vec();
                        id_bytes(&mut message, k.kf_id);
                        put_matrix(&mut message, &k.world_from_camera);
                        out.push(Update::Binary(message));
                    }
                }
            }
        }
        self.map_messages += (out.len() - before) as u64;
    }

    /// Everything the page needs when it connects: every block as it stands, and the path.
    pub fn replay(&mut self) -> Vec<Update> {
        let mut out = Vec::with_capacity(self.shown.len() + 1);
        for cloud in self.shown.values() {
            let mut message = TAG_BLOCK.to_vec();
            encode_block(
                cloud,
                self.params.grid_gap(cloud.intrinsics.width, cloud.intrinsics.height),
                &mut self.scratch,
                &mut message,
            );
            out.push(Update::Binary(message));
        }
        let path = std::mem::take(&mut self.path);
        out.extend(self.poses(path));
        out
    }
}

/// The newest depth keyframe for the page: the left image and the depth in colour, at most `max_width` wide.
pub fn image_update(width: usize, height: usize, rgb: &[u8], disparity: &[f32], max_width: usize) -> Option<Update> {
    if width == 0 || height == 0 || rgb.len() < 3 * width * height || disparity.len() < width * height {
        return None;
    }
    let step = width.div_ceil(max_width.max(1)).max(1);
    let (w, h) = (width / step, height / step);
    let mut finite: Vec<f32> = disparity.iter().step_by(7).copied().filter(|d| d.is_finite() && *d > 0.0).collect();
    finite.sort_by(f32::total_cmp);
    let (lo, hi) = match (finite.get(finite.len() / 50), finite.get(finite.len() * 49 / 50)) {
        (Some(&lo), Some(&hi)) if hi > lo => (lo, hi),
        _ => (0.0, 1.0),
    };
    let mut out = TAG_IMAGE.to_vec();
    put_u32(&mut out, w as u32);
    put_u32(&mut out, h as u32);
    for y in 0..h {
        for x in 0..w {
            let i = (y * step) * width + x * step;
            out.extend_from_slice(&rgb[3 * i..3 * i + 3]);
        }
    }
    for y in 0..h {
        for x in 0..w {
            let d = disparity[(y * step) * width + x * step];
            out.extend(if d.is_finite() && d > 0.0 { colour_ramp((d - lo) / (hi - lo)) } else { [0, 0, 0] });
        }
    }
    Some(Update::Binary(out))
}

/// Near is warm, far is cool: blue, cyan, green, yellow, red over [0, 1] (disparity grows as depth shrinks).
fn colour_ramp(t: f32) -> [u8; 3] {
    const STOPS: [[f32; 3]; 5] =
        [[30., 60., 200.], [0., 200., 230.], [60., 200., 60.], [250., 220., 40.], [220., 40., 30.]];
    let t = t.clamp(0.0, 1.0) * (STOPS.len() - 1) as f32;
    let i = (t.floor() as usize).min(STOPS.len() - 2);
    let f = t - i as f32;
    [0, 1, 2].map(|c| (STOPS[i][c] * (1.0 - f) + STOPS[i + 1][c] * f) as u8)
}
