use super::*;

const HAMLYN6: &str = "%YAML:1.0\n\n# Camera calibration\nCamera.fx: 695.877\nCamera.fy: 695.877\n\
Camera.cx: 280.402\nCamera.cy: 252.380\n\nCamera.k1: 0.0\nCamera.k2: 0.0\nCamera.p1: 0.0\nCamera.p2: 0.0\n\
Camera.width: 640\nCamera.height: 480\nCamera.fps: 25.0\nCamera.bf: 3743.1\nCamera.RGB: 1\nThDepth: 20\n\
ORBextractor.nFeatures: 2000\nORBextractor.scaleFactor: 1.2\nORBextractor.nLevels: 8\nORBextractor.iniThFAST: 20\n\
ORBextractor.minThFAST: 15\nBDISparam.patchsz: 10\nBDISparam.min_prob: 0.15\nViewer3D.depth_gap: 5\n\
Viewer.KeyFrameSize: 0.05\nLEFT.K: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n   data:[695.877, 0.0, 280.402,\n     0.0, 695.877, 252.38, 0.0, 0.0, 1.0]\n";

fn parse(text: &str) -> Result<Settings, SettingsError> {
    Settings::from_raw(&RawSettings::parse_opencv_yaml(text, Path::new("s.yaml"))?)
}

#[test]
fn reads_a_bdis_slam_settings_file() {
    let s = parse(HAMLYN6).unwrap();
    assert_eq!(s.camera.fx, 695.877);
    assert_eq!(s.camera.cy, 252.380);
    assert_eq!(s.camera.width, Some(640));
    assert!((s.camera.baseline() - 3743.1 / 695.877).abs() < 1e-12);
    assert_eq!(s.fps, 25.0);
    assert_eq!(s.orb.n_levels, 8);
    assert_eq!(s.bdis.min_prob, 0.15);
    assert_eq!(s.bdis.patchsz, 10);
    assert_eq!(s.bdis.lv_f, 5, "defaults fill missing BDISparam keys");
    assert!(s.ignored_keys.contains(&"LEFT.K".to_string()));
}

#[test]
fn rejects_the_hamlyn1_typo_with_line_and_key() {
    let text = HAMLYN6.replace("Camera.bf: 3743.1", "Camera.bf: 2055.77s");
    let e = parse(&text).unwrap_err().to_string();
    assert_eq!(e, "s.yaml:16: `Camera.bf`: `2055.77s` is not a number");
}

#[test]
fn rejects_missing_nan_and_non_positive_values() {
    let e = parse(&HAMLYN6.replace("Camera.fx: 695.877\n", "")).unwrap_err().to_string();
    assert_eq!(e, "s.yaml: missing required key `Camera.fx`");
    let e = parse(&HAMLYN6.replace("Camera.fy: 695.877", "Camera.fy: .nan")).unwrap_err().to_string();
    assert!(e.contains("`Camera.fy`: must be a finite number"), "{e}");
    let e = parse(&HAMLYN6.replace("Camera.fx: 695.877", "Camera.fx: -1")).unwrap_err().to_string();
    assert_eq!(e, "s.yaml:4: `Camera.fx`: must be > 0, found -1");
    let e = parse(&HAMLYN6.replace("Camera.bf: 3743.1", "Camera.bf: 0")).unwrap_err().to_string();
    assert_eq!(e, "s.yaml:16: `Camera.bf`: must be > 0, found 0");
}

#[test]
fn rejects_unknown_keys_and_bad_syntax() {
    let e = parse(&HAMLYN6.replace("Camera.fps", "Camera.fsp")).unwrap_err().to_string();
    assert!(e.starts_with("s.yaml:15: unknown key `Camera.fsp`"), "{e}");
    let e = parse("Camera.fx: 1\n").unwrap_err().to_string();
    assert!(e.contains("%YAML:1.0"), "{e}");
    let e = parse("%YAML:1.0\nCamera.fx 1\n").unwrap_err().to_string();
    assert_eq!(e, "s.yaml:2: expected `key: value`, found `Camera.fx 1`");
    let e = parse("%YAML:1.0\nM: !!opencv-matrix\n  rows: 2\n  cols: 2\n  data: [1, 2, 3]\n").unwrap_err().to_string();
    assert!(e.contains("2×2 matrix with 3 values"), "{e}");
}

#[test]
fn toml_uses_the_same_names_and_checks() {
    let text = "ThDepth = 20\n[Camera]\nfx = 520.0\nfy = 520\ncx = 320\ncy = 240\nbf = 260\n[BDISparam]\npatchsz = 8\n";
    let s = Settings::from_raw(&RawSettings::parse_toml(text, Path::new("c.toml")).unwrap()).unwrap();
    assert_eq!(s.camera.fy, 520.0);
    assert_eq!(s.bdis.patchsz, 8);
    let e = Settings::from_raw(
        &RawSettings::parse_toml(&text.replace("bf = 260", "bf = -2"), Path::new("c.toml")).unwrap(),
    )
    .unwrap_err()
    .to_string();
    assert_eq!(e, "c.toml: `Camera.bf`: must be > 0, found -2");
    let e = RawSettings::parse_toml("[Camera\nfx=1", Path::new("c.toml")).unwrap_err().to_string();
    assert!(e.starts_with("c.toml:1:"), "{e}");
}

#[test]
fn reads_the_first_detection_level_and_names_a_bad_one() {
    assert_eq!(parse(HAMLYN6).unwrap().orb.first_level, None, "absent: chosen by the image size");
    let with = |v: &str| {
        HAMLYN6
            .replace("ORBextractor.nLevels: 8\n", &format!("ORBextractor.nLevels: 8\nORBextractor.firstLevel: {v}\n"))
    };
    assert_eq!(parse(&with("3")).unwrap().orb.first_level, Some(3));
    let e = parse(&with("40")).unwrap_err().to_string();
    assert!(e.contains("ORBextractor.firstLevel") && e.contains("0..=16"), "{e}");
    let e = parse(&with("1.5")).unwrap_err().to_string();
    assert!(e.contains("ORBextractor.firstLevel"), "{e}");
}

#[test]
fn reads_the_bdis_level_offset_absent_as_automatic() {
    assert_eq!(parse(HAMLYN6).unwrap().bdis.level_offset, None);
    let text = HAMLYN6.replace("BDISparam.patchsz: 10\n", "BDISparam.patchsz: 10\nBDISparam.level_offset: 1\n");
    assert_eq!(parse(&text).unwrap().bdis.level_offset, Some(1));
    let text = HAMLYN6.replace("BDISparam.patchsz: 10\n", "BDISparam.patchsz: 10\nBDISparam.level_offset: -1\n");
    let e = parse(&text).unwrap_err().to_string();
    assert!(e.contains("BDISparam.level_offset"), "{e}");
}
