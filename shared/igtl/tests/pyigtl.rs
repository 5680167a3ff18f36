#![allow(clippy::unwrap_used, clippy::expect_used)] // test code: a panic is the failure report
//! Every message type we send, read back by an independent implementation: pyigtl (PyPI) through
//! `tests/interop/igtl_receive.py` — its header parser, its CRC-64, its TRANSFORM, STRING and POINT decoders and
//! its metadata reader; POLYDATA's content by the script's reader of the protocol's table (pyigtl has none).

use std::path::Path;
use std::process::Command;

use bdis_igtl::{DeviceName, Encoder, Timestamp};
use nalgebra::{Isometry3, Vector3};

#[test]
fn pyigtl_reads_every_message_we_send() {
    if !bdis_testkit::service::python_with("pyigtl") {
        return;
    }
    let dir = std::env::temp_dir().join(format!("bdis-igtl-interop-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let mut encoder = Encoder::default();
    let mut bytes = Vec::new();
    let scope = DeviceName::new("CameraToWorld").unwrap();
    let pose = Isometry3::new(Vector3::new(12.5, -3.25, 40.0), Vector3::new(0.1, -0.2, 0.3));
    let time = Timestamp::from_unix_ns(1_764_000_000_250_000_000);
    bytes.extend_from_slice(encoder.transform(&scope, time, &pose, &[("TrackingState", "ok"), ("Frame", "7")]));
    let state = DeviceName::new("TrackingState").unwrap();
    bytes.extend_from_slice(encoder.string(&state, time, "uncertain: low-contrast", &[("Zoll", "größe")]));
    let xyz = [[1.0f32, 2.0, 3.0], [-4.5, 5.25, 60.0], [0.125, 0.0, 7.0]];
    let rgb = [[200u8, 90, 80], [10, 20, 30], [255, 255, 255]];
    let block = DeviceName::new("MapKf42").unwrap();
    bytes.extend_from_slice(encoder.points(&block, time, "MapKf42", &xyz, &rgb, &[]));
    bytes.extend_from_slice(encoder.point_cloud(&block, time, &xyz, &[]));
    bytes.extend_from_slice(encoder.point_cloud(&block, time, &[], &[]));
    let path = DeviceName::new("Trajectory").unwrap();
    bytes.extend_from_slice(encoder.polyline(&path, time, &xyz, &[("Poses", "3")]));
    let file = dir.join("messages.bin");
    std::fs::write(&file, &bytes).unwrap();

    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/interop/igtl_receive.py");
    let out_json = dir.join("messages.json");
    let out =
        Command::new("python3").arg(&script).arg("--file").arg(&file).arg("--out").arg(&out_json).output().unwrap();
    assert!(out.status.success(), "pyigtl refused our messages:\n{}", String::from_utf8_lossy(&out.stderr));
    let read: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&out_json).unwrap()).unwrap();
    std::fs::remove_dir_all(&dir).unwrap();
    let messages = read["messages"].as_array().unwrap();
    assert_eq!(messages.len(), 6);
    for (i, m) in messages.iter().enumerate() {
        assert_eq!(m["header_version"], 2);
        assert_eq!(m["message_id"], i as u64, "ids count up");
        assert!((m["timestamp"].as_f64().unwrap() - 1_764_000_000.25).abs() < 1e-6, "{}", m["timestamp"]);
    }

    let transform = &messages[0];
    assert_eq!((transform["type"].as_str(), transform["device"].as_str()), (Some("TRANSFORM"), Some("CameraToWorld")));
    let m = pose.to_homogeneous();
    for r in 0..4 {
        for c in 0..4 {
            let got = transform["matrix"][r][c].as_f64().unwrap();
            assert!(
                (got - m[(r, c)]).abs() < 1e-5 * m[(r, c)].abs().max(1.0),
                "[{r}][{c}] {got} against {}",
                m[(r, c)]
            );
        }
    }
    assert_eq!(transform["metadata"]["TrackingState"], "ok");
    assert_eq!(transform["metadata"]["Frame"], "7");

    assert_eq!(messages[1]["text"], "uncertain: low-contrast");
    assert_eq!(messages[1]["metadata"]["Zoll"], "größe", "a UTF-8 value");

    let point = &messages[2];
    assert_eq!(point["type"], "POINT");
    for (i, (p, c)) in xyz.iter().zip(&rgb).enumerate() {
        let got: Vec<f32> = point["points"][i].as_array().unwrap().iter().map(|v| v.as_f64().unwrap() as f32).collect();
        assert_eq!(got, p.to_vec());
        let colour: Vec<u64> = point["rgba"][i].as_array().unwrap().iter().map(|v| v.as_u64().unwrap()).collect();
        assert_eq!(colour, vec![u64::from(c[0]), u64::from(c[1]), u64::from(c[2]), 255]);
        assert_eq!(point["groups"][i], "MapKf42");
    }

    let cloud = &messages[3]["polydata"];
    let got: Vec<Vec<f32>> = cloud["points"]
        .as_array()
        .unwrap()
        .iter()
        .map(|p| p.as_array().unwrap().iter().map(|v| v.as_f64().unwrap() as f32).collect())
        .collect();
    assert_eq!(got, xyz.iter().map(|p| p.to_vec()).collect::<Vec<_>>());
    assert_eq!(cloud["n_vertices"], 1);
    assert_eq!(cloud["vertices"], serde_json::json!([3, 0, 1, 2]));
    assert_eq!(cloud["n_lines"], 0);
    let empty = &messages[4]["polydata"];
    assert_eq!((empty["points"].as_array().unwrap().len(), &empty["n_vertices"]), (0, &serde_json::json!(0)));
    let line = &messages[5];
    assert_eq!(line["device"], "Trajectory");
    assert_eq!(line["polydata"]["lines"], serde_json::json!([3, 0, 1, 2]));
    assert_eq!(line["polydata"]["n_vertices"], 0);
    assert_eq!(line["metadata"]["Poses"], "3");
}
