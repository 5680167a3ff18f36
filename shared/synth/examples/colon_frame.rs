//! Renders one colon frame to /tmp (development aid).
fn main() {
    let colon = bdis_synth::colon::Colon::default();
    let rig = bdis_synth::StereoRig::default();
    let t = std::time::Instant::now();
    let pose = colon.forward_pose(1.0, 20.0);
    let pair = bdis_synth::colon::render_colon(&colon, &rig, &bdis_synth::colon::Shading::default(), &pose, 0);
    println!("{:.0} ms", t.elapsed().as_secs_f64() * 1000.0);
    pair.left.save("/tmp/colon_left.png").unwrap();
    let finite: Vec<f32> = pair.depth.iter().copied().filter(|z| z.is_finite()).collect();
    println!("depth: {} px, min {:?} max {:?}", finite.len(), finite.iter().cloned().fold(f32::INFINITY, f32::min), finite.iter().cloned().fold(0.0, f32::max));
}
