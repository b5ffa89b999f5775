//! Footprint plus stamp of the large brush at 10 px/mm, per 1 ms tick (issue target: at most
//! 50 us per stamp), on real states of a pressed stroke at 100 mm/s, inked per unit of travel
//! from tick to tick (walked back and forth, so every stamp follows its neighbour tick).
//!
//! `cargo bench -p maobi --bench stamp`

use criterion::{criterion_group, criterion_main, Criterion};
use maobi::raster::{Canvas, Frame};
use maobi::render::Inker;
use maobi_shared::{presets, Brush, Fx, Pose, Quat, Vec3};
use std::hint::black_box;

fn pose(x: f64) -> Pose<Fx> {
    let h = 15f64.to_radians() / 2.0;
    Pose::new(
        Vec3::from_f64([x, 0.0, 33.0]),
        Quat::from_f64([h.cos(), 0.0, h.sin(), 0.0]),
    )
}

fn stamp(c: &mut Criterion) {
    // 300 ticks of a stroke along +x, pressed ~6 mm, after 200 ms of settling.
    let mut brush = Brush::<Fx>::new(presets::LARGE, pose(0.0)).unwrap();
    for _ in 0..200 {
        brush.tick(pose(0.0));
    }
    let states: Vec<Brush<Fx>> = (1..=300)
        .map(|k| {
            brush.tick(pose(0.1 * k as f64));
            brush.clone()
        })
        .collect();
    let frame = Frame::covering([-50.0, -50.0], [80.0, 50.0], 0.0, 10.0);
    let mut canvas = Canvas::new(1300, 1000);
    let mut inker = Inker::new(frame, brush.len());
    let mut i = 0;
    let n = states.len();
    c.bench_function("footprint_and_stamp/large/10px_per_mm", |b| {
        b.iter(|| {
            i = (i + 1) % (2 * n - 2);
            let k = if i < n { i } else { 2 * n - 2 - i };
            black_box(inker.stamp(&states[k], &mut canvas))
        })
    });
}

criterion_group!(benches, stamp);
criterion_main!(benches);
