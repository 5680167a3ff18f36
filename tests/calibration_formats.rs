#![allow(clippy::unwrap_used, clippy::expect_used)] // test code: a panic is the failure report
//! Every calibration layout of issue #18 through `bdis-slam calib show`: one rig written in each data set's
//! published layout (`tests/calibrations/`, made by `make_samples.py`) reads to the same cameras and so to the
//! same rectification as the OpenCV YAML of it; the ORB-SLAM2 LEFT/RIGHT layout is made here from our own
//! rectification and reads back to it; bad values get one line naming the file, the line where there is one,
//! and the field.

mod common;

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Duration;

use common::*;

fn samples() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/calibrations")
}

fn show_json(file: &Path) -> serde_json::Value {
    let out = run_with_timeout(
        Command::new(bdis_slam()).args(["calib", "show", "--json", "--size", "1280x1024"]).arg(file),
        Duration::from_secs(60),
    );
    assert!(out.status.success(), "{}: {}", file.display(), text(&out.stderr));
    serde_json::from_slice(&out.stdout).unwrap()
}

fn numbers(v: &serde_json::Value, key: &str) -> Vec<f64> {
    v[key]
        .as_array()
        .unwrap()
        .iter()
        .flat_map(|row| row.as_array().unwrap().iter().map(|x| x.as_f64().unwrap()))
        .collect()
}

/// The largest difference between two rectifications' R1 R2 P1 P2 Q.
fn difference(a: &serde_json::Value, b: &serde_json::Value) -> f64 {
    ["R1", "R2", "P1", "P2", "Q"]
        .iter()
        .flat_map(|k| numbers(a, k).into_iter().zip(numbers(b, k)).map(|(x, y)| (x - y).abs()))
        .fold(0.0, f64::max)
}

#[test]
fn every_layout_reads_to_the_same_rig() {
    let s = samples();
    let yaml8 = show_json(&s.join("scared/endoscope_calibration.yaml"));
    let yaml5 = show_json(&s.join("scared/endoscope_calibration_5.yaml"));
    for (sample, reference) in [
        (s.join("stereomis/StereoCalibration.ini"), &yaml8),
        (s.join("stereomis/camcal.json"), &yaml8),
        (s.join("hamlyn"), &yaml5),
        (s.join("hamlyn/camera_extrinsic.txt"), &yaml5),
    ] {
        let d = difference(&show_json(&sample), reference);
        // The files hold the same numbers; camcal's Rodrigues vector is turned into R here and by numpy.
        assert!(d < 1e-9, "{}: differs from the OpenCV YAML of the same rig by {d:e}", sample.display());
    }
    // SERV-CT is rectified already: its projections are the rectification.
    let servct = show_json(&s.join("servct/Rectified_calibration_001.json"));
    let given: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(s.join("servct/Rectified_calibration_001.json")).unwrap())
            .unwrap();
    for key in ["P1", "P2"] {
        let file: Vec<f64> = given[key]["data"].as_array().unwrap().iter().map(|x| x.as_f64().unwrap()).collect();
        assert_eq!(numbers(&servct, key), file, "{key}");
    }
    assert_eq!(numbers(&servct, "R1"), vec![1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]);
    // The text output says which layout it read.
    for (sample, says) in [
        ("stereomis/StereoCalibration.ini", "StereoMIS StereoCalibration.ini"),
        ("stereomis/camcal.json", "StereoMIS camcal.json"),
        ("hamlyn", "Hamlyn"),
        ("servct/Rectified_calibration_001.json", "SERV-CT rectified calibration"),
        ("scared/endoscope_calibration.yaml", "as SCARED"),
    ] {
        let out = run_with_timeout(
            Command::new(bdis_slam()).args(["calib", "show", "--size", "1280x1024"]).arg(s.join(sample)),
            Duration::from_secs(60),
        );
        assert!(text(&out.stdout).contains(says), "{sample}: {}", text(&out.stdout));
    }
}

#[test]
fn orbslam2_left_right_blocks_read_back_to_the_rectification_they_were_written_from() {
    let tmp = TempDir::new("calib-orbslam2");
    let rect = show_json(&samples().join("scared/endoscope_calibration.yaml"));
    let m = |key: &str, rows: usize, cols: usize, data: &[f64]| {
        let data: Vec<String> = data.iter().map(|v| format!("{v:e}")).collect();
        format!(
            "{key}: !!opencv-matrix\n   rows: {rows}\n   cols: {cols}\n   dt: d\n   data: [ {} ]\n",
            data.join(", ")
        )
    };
    let k1 = [780.25, 0.0, 641.3, 0.0, 781.5, 509.75, 0.0, 0.0, 1.0];
    let k2 = [779.125, 0.0, 637.875, 0.0, 780.375, 512.25, 0.0, 0.0, 1.0];
    let d1 = [-0.31, 0.12, 0.0008, -0.0005, -0.02, 0.05, 0.01, -0.003];
    let d2 = [-0.30, 0.11, -0.0004, 0.0006, -0.018, 0.048, 0.012, -0.002];
    let settings = format!(
        "%YAML:1.0\nLEFT.width: 1280\nLEFT.height: 1024\n{}{}{}{}{}{}{}{}",
        m("LEFT.K", 3, 3, &k1),
        m("LEFT.D", 1, 8, &d1),
        m("LEFT.R", 3, 3, &numbers(&rect, "R1")),
        m("LEFT.P", 3, 4, &numbers(&rect, "P1")),
        m("RIGHT.K", 3, 3, &k2),
        m("RIGHT.D", 1, 8, &d2),
        m("RIGHT.R", 3, 3, &numbers(&rect, "R2")),
        m("RIGHT.P", 3, 4, &numbers(&rect, "P2")),
    );
    let path = tmp.path().join("orbslam2.yaml");
    std::fs::write(&path, settings).unwrap();
    let read = show_json(&path);
    for key in ["R1", "R2", "P1", "P2"] {
        let d = numbers(&read, key).iter().zip(numbers(&rect, key)).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max);
        assert!(d < 1e-9, "{key} differs by {d:e}");
    }
}

#[test]
fn bad_calibrations_get_one_line_with_file_line_and_field() {
    let tmp = TempDir::new("calib-bad");
    let s = samples();
    let edit = |sample: &str, name: &str, from: &str, to: &str| -> PathBuf {
        let text = std::fs::read_to_string(s.join(sample)).unwrap();
        assert!(text.contains(from), "{sample} has no `{from}`");
        let path = tmp.path().join(name);
        std::fs::create_dir_all(path.parent().unwrap()).unwrap();
        std::fs::write(&path, text.replacen(from, to, 1)).unwrap();
        path
    };
    let ini_r = edit("stereomis/StereoCalibration.ini", "r/StereoCalibration.ini", "R_0 = 0.99992", "R_0 = 1.3");
    let ini_f = edit("stereomis/StereoCalibration.ini", "f/StereoCalibration.ini", "fc_x = 779.125", "fc_x = -779");
    let json_f = edit("stereomis/camcal.json", "camcal.json", "779.125", "-779.125");
    let json_cut = tmp.path().join("cut.json");
    std::fs::write(&json_cut, "{\n  \"data\": {\n    \"width\": 1280,\n").unwrap();
    let hamlyn = tmp.path().join("hamlyn");
    std::fs::create_dir_all(&hamlyn).unwrap();
    for f in ["Left_Camera_Calibration_Intrinsic.txt", "Right_Camera_Calibration_Intrinsic.txt"] {
        std::fs::copy(s.join("hamlyn").join(f), hamlyn.join(f)).unwrap();
    }
    let ini_line = |p: &Path, key: &str| {
        let n = std::fs::read_to_string(p).unwrap().lines().position(|l| l.starts_with(key)).unwrap() + 1;
        format!("{}:{n}", p.display())
    };
    let cases: Vec<(PathBuf, Vec<String>)> = vec![
        (ini_r.clone(), vec![ini_line(&ini_r, "R_0 = 1.3"), "[StereoRight] R_0…R_8".into(), "not a rotation".into()]),
        (
            ini_f.clone(),
            vec![ini_f.display().to_string(), "[StereoRight] fc_x".into(), "focal lengths must be > 0".into()],
        ),
        (json_f.clone(), vec![json_f.display().to_string(), "data.intrinsics[1].f".into(), "> 0".into()]),
        (json_cut.clone(), vec![format!("{}:4", json_cut.display()), "not valid JSON".into()]),
        (hamlyn.clone(), vec![hamlyn.join("camera_extrinsic.txt").display().to_string(), "missing".into()]),
    ];
    for (file, expected) in cases {
        let out =
            run_with_timeout(Command::new(bdis_slam()).args(["calib", "show"]).arg(&file), Duration::from_secs(60));
        let stderr = text(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{}: {stderr}", file.display());
        assert!(!stderr.contains("panicked"), "{stderr}");
        let errors: Vec<&str> = stderr.lines().filter(|l| l.starts_with("bdis-slam: error:")).collect();
        assert_eq!(errors.len(), 1, "{stderr}");
        for part in expected {
            assert!(errors[0].contains(&part), "`{part}` not in: {}", errors[0]);
        }
    }
}
