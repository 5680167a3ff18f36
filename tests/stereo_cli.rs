#![allow(clippy::unwrap_used, clippy::expect_used)] // test code: a panic is the failure report
//! `bdis-slam stereo` from the command line: outputs a person and a program can read, clear errors.

mod common;

use std::process::Command;
use std::time::Duration;

use common::*;

#[test]
fn one_pair_writes_disparity_confidence_and_preview() {
    let tmp = TempDir::new("stereo1");
    let seq = tmp.path().join("seq");
    // A tissue plane whose ground-truth disparity is exactly 4 px.
    let rig = bdis_synth::RectifiedCamera {
        width: 256,
        height: 192,
        fx: 260.0,
        fy: 260.0,
        cx: 128.0,
        cy: 96.0,
        bf: 50.0 * 4.0,
    };
    let scene = bdis_synth::PlaneScene { depth_mm: 50.0, texture: bdis_synth::TissueTexture { seed: 11 } };
    assert!((scene.disparity_px(&rig) - 4.0).abs() < 1e-9);
    bdis_synth::write_plane_sweep(&seq, &rig, &scene, 1, 30.0, 0.0, |_| {}).unwrap();
    let out = tmp.path().join("d.pfm");
    let run = run_with_timeout(
        Command::new(bdis_slam())
            .args(["stereo", "--left"])
            .arg(seq.join("left/1.png"))
            .arg("--right")
            .arg(seq.join("right/1.png"))
            .arg("--out")
            .arg(&out)
            .args(["--confidence", "--preview", "--preset", "colon"]),
        Duration::from_secs(60),
    );
    assert!(run.status.success(), "{}", text(&run.stderr));
    let d = bdis_core::formats::pfm::read_disparity(&out).unwrap();
    assert_eq!((d.width, d.height), (256, 192));
    let valid: Vec<f32> = d.data.iter().copied().filter(|v| v.is_finite()).collect();
    assert!(valid.len() > d.data.len() / 3, "density {}", valid.len() as f64 / d.data.len() as f64);
    let median = {
        let mut v = valid.clone();
        v.sort_by(f32::total_cmp);
        v[v.len() / 2]
    };
    assert!((median - 4.0).abs() < 0.5, "the pair is shifted by 4 px, median disparity {median}");
    let c = bdis_core::formats::pfm::read(&tmp.path().join("d.conf.pfm")).unwrap();
    assert!(c.data.iter().all(|v| (0.0..=1.0).contains(v)));
    let preview = image::open(tmp.path().join("d.png")).unwrap();
    assert_eq!((preview.width(), preview.height()), (512, 192));
}

#[test]
fn bad_input_is_one_line_and_exit_1() {
    let tmp = TempDir::new("stereo-bad");
    let seq = tmp.path().join("seq");
    write_sequence(&seq, 1, 64, 48, 2);
    image::RgbImage::new(60, 48).save(seq.join("right/1.png")).unwrap();
    let base = |extra: &[&str]| {
        let mut c = Command::new(bdis_slam());
        c.args(["stereo", "--left"])
            .arg(seq.join("left/1.png"))
            .arg("--right")
            .arg(seq.join("right/1.png"))
            .arg("--out")
            .arg(tmp.path().join("x.pfm"))
            .args(extra);
        run_with_timeout(&mut c, Duration::from_secs(30))
    };
    let out = base(&[]);
    assert_eq!(out.status.code(), Some(1));
    let stderr = text(&out.stderr);
    assert!(stderr.contains("left image is 64×48, right image is 60×48"), "{stderr}");
    assert_eq!(stderr.lines().count(), 1, "{stderr}");
    let out = base(&["--param", "patchsz=0"]);
    assert_eq!(out.status.code(), Some(1));
    assert!(
        text(&out.stderr).contains("BDISparam.patchsz: must be even and in 2..=64, found 0"),
        "{}",
        text(&out.stderr)
    );
    assert!(!tmp.path().join("x.pfm").exists(), "nothing is written on error");
}
