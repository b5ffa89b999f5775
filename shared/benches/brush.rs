//! Cost of the brush model on the host: one substep, one full 1 ms tick (25 substeps plus
//! the per-tick skeleton and surface update), and one footprint.
//!
//! `cargo bench -p maobi-shared --bench brush`

use criterion::{criterion_group, criterion_main, Criterion};
use maobi_shared::footprint::for_each_polygon;
use maobi_shared::{presets, Brush, Fx, Pose, Quat, Scalar, Vec3};
use std::hint::black_box;

/// A handle moving along a pressed stroke, so contacts, drag and surface spreading all work.
fn stroke_pose<S: Scalar>(k: usize) -> Pose<S> {
    let t = (k % 2000) as f64 * 1e-3;
    let x = 80.0 * (t * 0.5 * std::f64::consts::PI).sin();
    let h = 15f64.to_radians() / 2.0;
    Pose::new(
        Vec3::from_f64([x, 0.0, 34.0]),
        Quat::from_f64([h.cos(), 0.0, h.sin(), 0.0]),
    )
}

fn bench_scalar<S: Scalar>(c: &mut Criterion) {
    let mut b = Brush::<S>::new(presets::LARGE, stroke_pose(0)).unwrap();
    for k in 0..200 {
        b.tick(stroke_pose(k));
    }
    let mut k = 200;
    c.bench_function(&format!("substep/large/{}", S::NAME), |bench| {
        bench.iter(|| {
            k += 1;
            b.substep(black_box(stroke_pose(k / 25)));
        })
    });
    c.bench_function(&format!("tick_25_substeps/large/{}", S::NAME), |bench| {
        bench.iter(|| {
            k += 25;
            b.tick(black_box(stroke_pose(k / 25)));
        })
    });
    c.bench_function(&format!("footprint/large/{}", S::NAME), |bench| {
        bench.iter(|| {
            let mut vertices = 0;
            for_each_polygon(&b, |_, poly| vertices += poly.len());
            black_box(vertices)
        })
    });
}

fn benches(c: &mut Criterion) {
    bench_scalar::<Fx>(c);
    bench_scalar::<f32>(c);
    bench_scalar::<f64>(c);
}

criterion_group!(brush, benches);
criterion_main!(brush);
