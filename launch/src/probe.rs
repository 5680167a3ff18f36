//! What `bdis-slam probe` checks about a stream of frames, independent of the transport: order, gaps,
//! integrity (checksums), where the pixels live, and the rate / age / hop-latency figures it prints.

use bdis_ipc::{FrameView, clock};
use hdrhistogram::Histogram;
use serde::{Deserialize, Serialize};

use crate::latency::Percentiles;

/// FNV-1a, 64 bit: a cheap, well-known checksum an independent reader can recompute.
pub fn fnv1a64(bytes: &[u8]) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for &b in bytes {
        h ^= u64::from(b);
        h = h.wrapping_mul(0x0000_0100_0000_01b3);
    }
    h
}

/// The probe's final report (written as JSON, summarised on stdout).
#[derive(Debug, Clone, Default, Serialize, Deserialize, PartialEq)]
pub struct ProbeSummary {
    pub topic: String,
    pub frames_received: u64,
    pub first_frame_seq: Option<u64>,
    pub last_frame_seq: Option<u64>,
    /// Frames skipped in the sequence (lost to a slow consumer or a dying producer).
    pub frames_missing: u64,
    pub out_of_order: u64,
    /// Producer restarts seen (sequence numbers starting again from 0).
    pub restarts: u64,
    pub end_of_stream: bool,
    pub width: u32,
    pub height: u32,
    /// Source image number of every received frame, in arrival order.
    pub source_indices: Vec<u32>,
    /// FNV-1a 64 of each frame's left RGB bytes, hex, when checksums were asked for.
    pub left_rgb_fnv1a64: Vec<String>,
    /// The file behind the mapping that held the first payload (proof of zero copy: a `/dev/shm` file).
    pub payload_mapping: Option<String>,
    /// True when every payload read lay in the run's shared memory.
    pub payload_in_shared_memory: bool,
    pub rate_hz: f64,
    /// receive − publish.
    pub hop_latency_us: Option<Percentiles>,
    /// receive − capture.
    pub age_us: Option<Percentiles>,
    /// Frames whose header did not describe their payload.
    pub malformed: u64,
}

/// Accumulates what the probe sees.
#[derive(Debug)]
pub struct FrameChecker {
    summary: ProbeSummary,
    checksums: bool,
    prefix: String,
    next_seq: Option<u64>,
    hop: Histogram<u64>,
    age: Histogram<u64>,
    first_rx_ns: u64,
    last_rx_ns: u64,
    all_in_shm: bool,
}

fn hist() -> Histogram<u64> {
    Histogram::new(3).unwrap_or_else(|_| std::process::abort())
}

impl FrameChecker {
    pub fn new(topic: &str, checksums: bool, prefix: &str) -> Self {
        Self {
            summary: ProbeSummary { topic: topic.to_string(), ..Default::default() },
            checksums,
            prefix: prefix.to_string(),
            next_seq: None,
            hop: hist(),
            age: hist(),
            first_rx_ns: 0,
            last_rx_ns: 0,
            all_in_shm: true,
        }
    }

    /// Checks one received frame (read in place); `t_receive_ns` is when `receive()` returned it.
    pub fn frame(&mut self, view: &FrameView<'_>, t_receive_ns: u64) {
        let h = view.header;
        let s = &mut self.summary;
        if let Some(expected) = self.next_seq {
            if h.frame_seq == 0 && expected > 0 {
                s.restarts += 1;
            } else if h.frame_seq > expected {
                s.frames_missing += h.frame_seq - expected;
            } else if h.frame_seq < expected {
                s.out_of_order += 1;
            }
        } else if h.frame_seq > 0 {
            s.frames_missing += h.frame_seq;
        }
        self.next_seq = Some(h.frame_seq + 1);
        s.first_frame_seq.get_or_insert(h.frame_seq);
        s.last_frame_seq = Some(h.frame_seq);
        s.frames_received += 1;
        s.width = h.width;
        s.height = h.height;
        s.source_indices.push(h.source_index);
        let ptr = view.left_rgb.as_ptr();
        if s.payload_mapping.is_none() {
            s.payload_mapping = bdis_ipc::shm::mapping_file_of(ptr).map(|p| p.display().to_string());
        }
        // Checking every frame's mapping costs a /proc read; the first frame and every 64th are enough to show
        // the pixels are never copied to the heap.
        if s.frames_received == 1 || s.frames_received.is_multiple_of(64) {
            self.all_in_shm &= bdis_ipc::shm::is_in_run_shared_memory(ptr, &self.prefix);
        }
        if self.checksums {
            s.left_rgb_fnv1a64.push(format!("{:016x}", fnv1a64(view.left_rgb)));
        }
        let _ = self.hop.record(clock::elapsed_ns(h.t_publish_ns, t_receive_ns).max(1));
        let _ = self.age.record(clock::elapsed_ns(h.t_capture_ns, t_receive_ns).max(1));
        if self.first_rx_ns == 0 {
            self.first_rx_ns = t_receive_ns;
        }
        self.last_rx_ns = t_receive_ns;
    }

    pub fn malformed(&mut self) {
        self.summary.malformed += 1;
    }

    pub fn end_of_stream(&mut self) {
        self.summary.end_of_stream = true;
    }

    pub fn frames_received(&self) -> u64 {
        self.summary.frames_received
    }

    /// Frames skipped so far.
    pub fn frames_missing(&self) -> u64 {
        self.summary.frames_missing
    }

    /// The one-line status printed every second.
    pub fn status_line(&self, window_frames: u64, window_s: f64) -> String {
        let p50 = |h: &Histogram<u64>| if h.is_empty() { 0.0 } else { h.value_at_quantile(0.5) as f64 / 1000.0 };
        format!(
            "{}: {:6.1} Hz | {} frames, {} missing | hop p50 {:.0} µs | age p50 {:.1} ms",
            self.summary.topic,
            window_frames as f64 / window_s.max(1e-9),
            self.summary.frames_received,
            self.summary.frames_missing,
            p50(&self.hop),
            p50(&self.age) / 1000.0
        )
    }

    pub fn summary(&self) -> ProbeSummary {
        let mut s = self.summary.clone();
        s.payload_in_shared_memory = s.frames_received > 0 && self.all_in_shm;
        let span = (self.last_rx_ns.saturating_sub(self.first_rx_ns)) as f64 / 1e9;
        s.rate_hz = if s.frames_received > 1 && span > 0.0 { (s.frames_received - 1) as f64 / span } else { 0.0 };
        s.hop_latency_us = percentiles(&self.hop);
        s.age_us = percentiles(&self.age);
        s
    }
}

fn percentiles(h: &Histogram<u64>) -> Option<Percentiles> {
    Percentiles::of(h)
}

#[cfg(test)]
mod tests {
    use super::*;
    use bdis_ipc::{FrameHeader, FrameLayout};

    #[test]
    fn fnv_matches_the_published_test_vectors() {
        assert_eq!(fnv1a64(b""), 0xcbf29ce484222325);
        assert_eq!(fnv1a64(b"a"), 0xaf63dc4c8601ec8c);
        assert_eq!(fnv1a64(b"foobar"), 0x85944171f73967e8);
    }

    #[test]
    fn counts_gaps_reordering_and_restarts() {
        let layout = FrameLayout::packed(2, 1).unwrap();
        let payload = vec![1u8; layout.payload_len()];
        let mut c = FrameChecker::new("frames", true, "bdis_");
        for seq in [0u64, 1, 3, 2, 0] {
            let mut h = FrameHeader { frame_seq: seq, t_publish_ns: 100, t_capture_ns: 50, ..Default::default() };
            layout.write_into(&mut h);
            c.frame(&FrameView::new(&h, &payload).unwrap(), 200);
        }
        let s = c.summary();
        assert_eq!(s.frames_received, 5);
        assert_eq!(s.frames_missing, 1);
        assert_eq!(s.out_of_order, 1);
        assert_eq!(s.restarts, 1);
        assert_eq!(s.left_rgb_fnv1a64.len(), 5);
        assert!(!s.payload_in_shared_memory, "heap memory is not shared memory");
        assert_eq!(s.hop_latency_us.unwrap().p50, 0.1);
    }
}

/// What the probe reports about a depth topic.
#[derive(Debug, Clone, Default, Serialize, Deserialize, PartialEq)]
pub struct DepthSummary {
    pub topic: String,
    pub samples_received: u64,
    /// Every keyframe id seen, ascending, once each.
    pub keyframe_ids: Vec<u64>,
    /// Samples whose keyframe id had been seen before (a replacement stereo instance re-did it).
    pub duplicates: u64,
    pub end_of_stream: bool,
    pub width: u32,
    pub height: u32,
    /// Mean fraction of pixels with a disparity over the received keyframes.
    pub mean_density: f64,
    pub payload_mapping: Option<String>,
    pub payload_in_shared_memory: bool,
    pub hop_latency_us: Option<Percentiles>,
    pub age_us: Option<Percentiles>,
    pub malformed: u64,
}

/// Accumulates what the probe sees on the depth topic.
#[derive(Debug)]
pub struct DepthChecker {
    summary: DepthSummary,
    seen: std::collections::BTreeSet<u64>,
    prefix: String,
    density_sum: f64,
    hop: Histogram<u64>,
    age: Histogram<u64>,
    all_in_shm: bool,
}

impl DepthChecker {
    pub fn new(topic: &str, prefix: &str) -> Self {
        Self {
            summary: DepthSummary { topic: topic.to_string(), ..Default::default() },
            seen: Default::default(),
            prefix: prefix.to_string(),
            density_sum: 0.0,
            hop: hist(),
            age: hist(),
            all_in_shm: true,
        }
    }

    pub fn keyframe(&mut self, view: &bdis_ipc::DepthView<'_>, t_receive_ns: u64) {
        let h = view.header;
        let s = &mut self.summary;
        s.samples_received += 1;
        if !self.seen.insert(h.meta.kf_id) {
            s.duplicates += 1;
        }
        s.width = h.width;
        s.height = h.height;
        let valid = view.disparity.iter().filter(|d| d.is_finite()).count();
        self.density_sum += valid as f64 / view.disparity.len().max(1) as f64;
        let ptr = view.disparity.as_ptr().cast::<u8>();
        if s.payload_mapping.is_none() {
            s.payload_mapping = bdis_ipc::shm::mapping_file_of(ptr).map(|p| p.display().to_string());
        }
        self.all_in_shm &= bdis_ipc::shm::is_in_run_shared_memory(ptr, &self.prefix);
        let _ = self.hop.record(clock::elapsed_ns(h.t_publish_ns, t_receive_ns).max(1));
        let _ = self.age.record(clock::elapsed_ns(h.t_capture_ns, t_receive_ns).max(1));
    }

    pub fn malformed(&mut self) {
        self.summary.malformed += 1;
    }

    pub fn end_of_stream(&mut self) {
        self.summary.end_of_stream = true;
    }

    pub fn received(&self) -> u64 {
        self.summary.samples_received
    }

    pub fn status_line(&self) -> String {
        let p50 = |h: &Histogram<u64>| if h.is_empty() { 0.0 } else { h.value_at_quantile(0.5) as f64 / 1000.0 };
        format!(
            "{}: {} keyframes ({} duplicates) | hop p50 {:.0} µs | age p50 {:.1} ms",
            self.summary.topic,
            self.seen.len(),
            self.summary.duplicates,
            p50(&self.hop),
            p50(&self.age) / 1000.0
        )
    }

    pub fn summary(&self) -> DepthSummary {
        let mut s = self.summary.clone();
        s.keyframe_ids = self.seen.iter().copied().collect();
        s.mean_density = self.density_sum / s.samples_received.max(1) as f64;
        s.payload_in_shared_memory = s.samples_received > 0 && self.all_in_shm;
        s.hop_latency_us = percentiles(&self.hop);
        s.age_us = percentiles(&self.age);
        s
    }
}
