use super::*;

fn rec(process: &str, kind: TelemetryKind, seq: u64, t: [u64; 4], input: &str, output: &str) -> TelemetryRecord {
    let mut r = TelemetryRecord { kind: kind as u32, pid: 7, record_seq: seq, ..Default::default() };
    r.process[..process.len()].copy_from_slice(process.as_bytes());
    r.input_topic[..input.len()].copy_from_slice(input.as_bytes());
    r.output_topic[..output.len()].copy_from_slice(output.as_bytes());
    [r.t_capture_ns, r.t_upstream_publish_ns, r.t_receive_ns, r.t_done_ns] = t;
    r
}

#[test]
fn derives_hops_and_percentiles_and_counts_lost_records() {
    let mut agg = LatencyAggregator::new();
    agg.record(&rec("acq", TelemetryKind::Ready, 0, [0; 4], "", "frames"));
    agg.record(&rec("probe", TelemetryKind::Ready, 0, [0; 4], "frames", ""));
    for i in 0..100u64 {
        let t0 = 1_000_000_000 + i * 40_000_000;
        // acquisition: capture → publish takes 10 ms.
        agg.record(&rec("acq", TelemetryKind::Message, i + 1, [t0, 0, 0, t0 + 10_000_000], "", "frames"));
        // probe: receives 50 µs (+i ns) after publish, works 1 ms.
        let rx = t0 + 10_000_000 + 50_000 + i;
        if i != 50 {
            agg.record(&rec(
                "probe",
                TelemetryKind::Message,
                i + 1 - u64::from(i > 50),
                [t0, t0 + 10_000_000, rx, rx + 1_000_000],
                "frames",
                "",
            ));
        }
    }
    assert!(agg.is_ready("acq") && agg.is_ready("probe"));
    let report = agg.report();
    let hop = &report.hops[0];
    assert_eq!((hop.from.as_str(), hop.to.as_str(), hop.topic.as_str()), ("acq", "probe", "frames"));
    assert_eq!(hop.latency_us.count, 99);
    assert!((hop.latency_us.p50 - 50.0).abs() < 0.1, "{hop:?}");
    let acq = report.processes.iter().find(|p| p.name == "acq").unwrap();
    assert!((acq.processing_us.unwrap().p50 - 10_000.0).abs() < 10.0);
    assert!((acq.rate_hz - 25.0).abs() < 1e-6);
    let probe = report.processes.iter().find(|p| p.name == "probe").unwrap();
    assert!((probe.age_us.unwrap().p50 - 11_050.0).abs() < 15.0);
    assert_eq!(report.telemetry_records_lost, 0);
    // A gap in record numbers is reported.
    agg.record(&rec("acq", TelemetryKind::Finished, 105, [0; 4], "", "frames"));
    assert_eq!(agg.report().telemetry_records_lost, 4);
    assert!(agg.report().table().contains("acq→probe (frames)"));
}

#[test]
fn instances_of_a_service_are_told_apart_for_readiness_liveness_and_resume_points() {
    let mut agg = LatencyAggregator::new();
    let with_pid = |mut r: TelemetryRecord, pid: u32, item: u64| {
        r.pid = pid;
        r.frame_seq = item;
        r
    };
    agg.record(&with_pid(rec("mosaic", TelemetryKind::Ready, 0, [0; 4], "depth", ""), 9, 0));
    agg.record(&with_pid(rec("stereo", TelemetryKind::Ready, 0, [0; 4], "keyframes", "depth"), 1, 0));
    for kf in 0..5u64 {
        let t = [1_000 + kf, 2_000, 3_000, 4_000 + kf];
        agg.record(&with_pid(rec("stereo", TelemetryKind::Message, kf + 1, t, "keyframes", "depth"), 1, kf));
        if kf < 3 {
            agg.record(&with_pid(rec("mosaic", TelemetryKind::Message, kf + 1, t, "depth", ""), 9, kf));
        }
    }
    // A replacement reports ready while the old instance still sends (make-before-break); its record
    // numbers start at 0 again without counting as lost.
    agg.record(&with_pid(rec("stereo", TelemetryKind::Ready, 0, [0; 4], "keyframes", "depth"), 2, 0));
    assert!(agg.is_pid_ready(2) && agg.is_pid_ready(1) && !agg.is_pid_ready(3));
    agg.record(&with_pid(rec("stereo", TelemetryKind::Heartbeat, 6, [0; 4], "keyframes", "depth"), 1, 0));
    assert_eq!(agg.last_item_of_pid(1), Some(4));
    assert_eq!(agg.last_item_of_pid(2), None);
    assert_eq!(agg.output_topic("stereo").as_deref(), Some("depth"));
    assert_eq!(agg.last_item_consumed("depth"), Some(2), "the mosaic took in keyframes 0–2");
    // Every consumer must have it: a probe that saw keyframes 0–4 does not move the resume point.
    agg.record(&with_pid(rec("probe", TelemetryKind::Ready, 0, [0; 4], "depth", ""), 11, 0));
    assert_eq!(agg.last_item_consumed("depth"), None, "the probe has nothing yet");
    for kf in 0..5u64 {
        agg.record(&with_pid(rec("probe", TelemetryKind::Message, kf + 1, [1, 2, 3, 4], "depth", ""), 11, kf));
    }
    assert_eq!(agg.last_item_consumed("depth"), Some(2));
    // A restarted mosaic has what it restored from its checkpoint, not what its predecessor had.
    let mut ready = with_pid(rec("mosaic", TelemetryKind::Ready, 0, [0; 4], "depth", ""), 12, 0);
    ready.restored_next = 2;
    agg.record(&ready);
    assert_eq!((agg.last_item_of("mosaic"), agg.last_item_consumed("depth")), (Some(1), Some(1)));
    // It then takes in keyframe 4 (sent while it was down, 2–3 lost): it still has everything up to 1 only.
    agg.record(&with_pid(rec("mosaic", TelemetryKind::Message, 1, [1, 2, 3, 4], "depth", ""), 12, 4));
    assert_eq!((agg.last_item_of("mosaic"), agg.restored_of("mosaic")), (Some(4), Some(1)));
    assert!(agg.has_consumer("depth") && !agg.has_consumer("poses"));
    assert!(agg.last_heard(1).is_some() && agg.last_heard(7).is_none());
    let report = agg.report();
    assert_eq!(report.telemetry_records_lost, 0);
    let stereo = report.processes.iter().find(|p| p.name == "stereo").unwrap();
    assert_eq!((stereo.restarts, stereo.pid, stereo.messages), (1, 2, 5));
    assert_eq!(report.end_to_end.len(), 1, "the mosaic's output age is capture → map");
    assert_eq!(report.end_to_end[0].path, "capture → map");
}

#[test]
fn the_plot_has_a_bar_per_process_and_hop_scaled_by_p50() {
    let p = |p50: f64| Percentiles { count: 10, p50, p90: p50 * 2.0, p99: p50 * 3.0, max: p50 * 4.0, mean: p50 };
    let process = |name: &str, us: f64| ProcessReport {
        name: name.into(),
        pid: 1,
        input_topic: String::new(),
        output_topic: String::new(),
        messages: 10,
        dropped: 0,
        rate_hz: 30.0,
        cpu_time_s: 0.1,
        processing_us: Some(p(us)),
        queue_wait_us: None,
        age_us: Some(p(us * 2.0)),
        ended: "finished".into(),
        restarts: 0,
        rejected: Default::default(),
    };
    let report = LatencyReport {
        processes: vec![process("fast", 50.0), process("slow<&>", 20_000.0)],
        hops: vec![HopReport {
            from: "fast".into(),
            to: "slow<&>".into(),
            topic: "frames".into(),
            latency_us: p(80.0),
        }],
        end_to_end: Vec::new(),
        telemetry_records_lost: 0,
        telemetry_records_refused: 0,
    };
    let svg = report.svg();
    assert!(svg.starts_with("<svg") && svg.trim_end().ends_with("</svg>"));
    assert_eq!(svg.matches("class=\"p50\"").count(), 5, "2 processing + 2 age + 1 hop bars");
    assert!(svg.contains("slow&lt;&amp;&gt;") && !svg.contains("slow<&>"), "labels are escaped");
    let widths: Vec<f64> = svg
        .match_indices("class=\"p50\"")
        .map(|(i, _)| {
            let before = &svg[..i];
            let w = before.rfind("width=\"").unwrap() + 7;
            before[w..].split('"').next().unwrap().parse().unwrap()
        })
        .collect();
    assert!(widths[1] > widths[0], "the slower process has the longer bar: {widths:?}");
}

#[test]
fn poses_and_corrections_are_hops_from_the_process_that_publishes_keyframes() {
    let mut agg = LatencyAggregator::new();
    agg.record(&rec("tracking", TelemetryKind::Ready, 0, [0; 4], "frames", "keyframes"));
    agg.record(&rec("igtl", TelemetryKind::Ready, 0, [0; 4], "poses", ""));
    let t0 = 1_000_000_000u64;
    agg.record(&rec("tracking", TelemetryKind::Message, 1, [t0, t0, t0 + 10, t0 + 5_000_000], "frames", "keyframes"));
    agg.record(&rec(
        "igtl",
        TelemetryKind::Message,
        1,
        [t0, t0 + 5_000_000, t0 + 5_100_000, t0 + 5_200_000],
        "poses",
        "",
    ));
    let report = agg.report();
    let hop = report.hops.iter().find(|h| h.topic == "poses").unwrap();
    assert_eq!((hop.from.as_str(), hop.to.as_str()), ("tracking", "igtl"));
}

#[test]
fn a_bridge_sending_depth_is_not_taken_for_the_map() {
    let mut agg = LatencyAggregator::new();
    agg.record(&rec("bridge", TelemetryKind::Ready, 0, [0; 4], "depth", ""));
    let t0 = 1_000_000_000u64;
    agg.record(&rec("bridge", TelemetryKind::Message, 1, [t0, t0 + 1_000, t0 + 2_000, t0 + 3_000], "depth", ""));
    let report = agg.report();
    assert_eq!(report.end_to_end.len(), 1);
    assert_eq!(report.end_to_end[0].path, "capture → bridge");
}
