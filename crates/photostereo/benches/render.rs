//! Rendering speed: one 128×128 scene under 96 lights (`dome-96`), Blinn–Phong, 0.5% noise,
//! with ray-marched cast shadows and ground truth, in memory. Target: under 1 s.

use criterion::{criterion_group, criterion_main, Criterion};
use photostereo::scene::{synthesize, Rig, SceneKind, SynthSpec};
use std::hint::black_box;

fn render(c: &mut Criterion) {
    let mut group = c.benchmark_group("render");
    group.sample_size(10);
    for kind in [SceneKind::Blocks, SceneKind::Face] {
        let spec = SynthSpec::new(kind, Rig::Dome(96));
        group.bench_function(format!("{}_128_dome96", kind.name()), |b| {
            b.iter(|| black_box(synthesize(black_box(&spec)).expect("renders")))
        });
    }
    group.finish();
}

criterion_group!(benches, render);
criterion_main!(benches);
