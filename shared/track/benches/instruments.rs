#![allow(clippy::expect_used)] // benchmark code: a panic is the failure report
//! Criterion benchmark: our instrument-mask estimate (`bdis_track::instruments`) on one 640×480 frame of the
//! synthetic laparoscope hover with two graspers (`synth --instruments`), single thread; and, for scale, the same
//! frame without instruments (nothing found: the cost of the colour pass alone); and the frame with graspers
//! without the opacity test (`opacity: false`), for that test's share.
//!
//! cargo bench -p bdis-track --bench instruments

use bdis_synth::abdomen::{Abdomen, STANDOFF_MM};
use bdis_synth::instruments::{InstrumentKind, Instruments};
use bdis_synth::render::{Shading, render_scene};
use bdis_track::instruments::{InstrumentMasker, InstrumentParams};
use criterion::{Criterion, criterion_group, criterion_main};

fn bench(c: &mut Criterion) {
    let rig = bdis_synth::default_camera();
    let abdomen = Abdomen::default();
    let shading = Shading { exposure_distance_mm: 65.0, ..Shading::default() };
    let pose = abdomen.hover_pose(1.0);
    let tools = Instruments::new(InstrumentKind::Laparoscopic, STANDOFF_MM, shading.exposure_distance_mm);
    let with_tools = render_scene(&abdomen, &tools.parts_at(1.0, &pose), &rig, &shading, &pose, 30);
    let clean = render_scene(&abdomen, &[], &rig, &shading, &pose, 30);
    let (w, h) = (rig.width as usize, rig.height as usize);
    let mut masker = InstrumentMasker::new(InstrumentParams::default());
    let mut group = c.benchmark_group("instrument mask 640x480");
    group.bench_function("two graspers", |b| b.iter(|| masker.estimate(with_tools.left.as_raw(), w, h)));
    group.bench_function("no instrument", |b| b.iter(|| masker.estimate(clean.left.as_raw(), w, h)));
    // The opacity test's share: the same frame judged by colour, place and size alone.
    let mut by_colour = InstrumentMasker::new(InstrumentParams { opacity: false, ..Default::default() });
    group.bench_function("two graspers, colour alone", |b| {
        b.iter(|| by_colour.estimate(with_tools.left.as_raw(), w, h))
    });
    group.finish();
    let found = masker.estimate(with_tools.left.as_raw(), w, h);
    assert!(found.regions > 0, "{found:?}");
}

criterion_group!(benches, bench);
criterion_main!(benches);
