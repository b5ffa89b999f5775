//! One step of the raw paper over the wet region a stroke leaves: the large brush drawn
//! 60 mm at 100 mm/s at 10 px/mm, the paper taken just as the brush lifts (its last
//! ~0.5 s of ink still wet), cloned for each step measured.
//!
//! `cargo bench -p maobi --bench paper`

use std::fmt::Write as _;

use criterion::{criterion_group, criterion_main, BatchSize, Criterion};
use maobi::offline::simulate;
use maobi::paper::{Canvas, PaperKind, PaperSpec};
use maobi::poses::PoseTrack;
use maobi::raster::Frame;
use maobi::render::Inker;
use maobi_shared::{presets, Fx};
use std::hint::black_box;

fn wet_stroke() -> Canvas {
    let h = 15f64.to_radians() / 2.0;
    let (qw, qy) = (h.cos(), h.sin());
    let mut csv = String::from("t,x,y,z,qw,qx,qy,qz\n");
    for k in 0..=800 {
        let t = k as f64 * 1e-3;
        let x = ((t - 0.2).max(0.0) * 100.0).min(60.0);
        let _ = writeln!(csv, "{t:.3},{x},0,33,{qw},0,{qy},0");
    }
    let track = PoseTrack::from_reader("bench.csv", csv.as_bytes()).unwrap();
    let params = presets::LARGE;
    let frame = Frame::covering([-45.0, -15.0], [65.0, 15.0], 0.0, 10.0);
    let mut canvas = Canvas::with_paper(frame.width, frame.height, PaperSpec::new(PaperKind::Raw));
    let mut inker = Inker::new(frame, params.layers as usize - 1);
    simulate::<Fx>(params, &track, |tick| {
        inker.stamp(tick.brush, &mut canvas);
        canvas.tick();
        Ok(())
    })
    .unwrap();
    assert!(canvas.is_wet());
    canvas
}

fn paper_step(c: &mut Criterion) {
    let wet = wet_stroke();
    c.bench_function("paper_step/raw/stroke_60mm_at_100mm_s", |b| {
        b.iter_batched_ref(
            || wet.clone(),
            |canvas| black_box(canvas.step()),
            BatchSize::LargeInput,
        )
    });
}

criterion_group!(benches, paper_step);
criterion_main!(benches);
