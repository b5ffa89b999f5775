//! Cost of the brush model on the host: one substep, one full 1 ms tick (25 substeps plus
//! the per-tick skeleton and surface update), and one footprint.
//!
//! `cargo bench -p maobi-shared --bench brush`

use criterion::{criterion_group, criterion_main, Criterion};
use maobi_shared::footprint::for_each_polygon;
use maobi_shared::force::{ForceModel, OutputStage, DEFAULT_FORCES, PHANTOM_OMNI};
use maobi_shared::kinematics::{Pen, PenConfig, RawReadings};
use maobi_shared::{presets, Brush, BrushScalar, Fx, Pose, Quat, Vec3};
use std::hint::black_box;

/// A handle moving along a pressed stroke, so contacts, drag and surface spreading all work.
fn stroke_pose<S: BrushScalar>(k: usize) -> Pose<S> {
    let t = (k % 2000) as f64 * 1e-3;
    let x = 80.0 * (t * 0.5 * std::f64::consts::PI).sin();
    let h = 15f64.to_radians() / 2.0;
    Pose::new(
        Vec3::from_f64([x, 0.0, 34.0]),
        Quat::from_f64([h.cos(), 0.0, h.sin(), 0.0]),
    )
}

fn bench_scalar<S: BrushScalar>(c: &mut Criterion) {
    let mut b = Brush::<S>::new(presets::LARGE, stroke_pose(0)).unwrap();
    for k in 0..200 {
        b.tick(stroke_pose(k));
    }
    // The presets' rate is one substep per tick: a substep is a tick without its
    // once-per-tick skeleton and surface.
    let mut k = 200;
    c.bench_function(&format!("substep/large/{}", S::NAME), |bench| {
        bench.iter(|| {
            k += 1;
            b.substep(black_box(stroke_pose(k)));
        })
    });
    // The default brush's whole 1 ms tick (its substeps, skeleton, surface): the real-time
    // figure.
    c.bench_function(&format!("tick/large/{}", S::NAME), |bench| {
        bench.iter(|| {
            k += 1;
            b.tick(black_box(stroke_pose(k)));
        })
    });
    // Everything the force loop does per tick besides the brush: raw sensors to joint angles,
    // forward kinematics, the force model, the output stage, J^T F and motor commands.
    let mut pen = Pen::<S>::new(PenConfig::OMNI_LIKE).unwrap();
    let zero = RawReadings::default();
    pen.calibrate(zero);
    let mut model = ForceModel::<S>::new(DEFAULT_FORCES).unwrap();
    let mut stage = OutputStage::<S>::new(PHANTOM_OMNI).unwrap();
    stage.enable();
    let mut n = 0i64;
    c.bench_function(&format!("force_and_kinematics/{}", S::NAME), |bench| {
        bench.iter(|| {
            n += 1;
            let raw = RawReadings {
                encoders: [n % 400, -(n % 300), n % 500],
                gimbal: [(n % 100) as i32, 7, -3],
            };
            let j = pen.joints(black_box(&raw)).unwrap();
            let pose = pen.forward(&j);
            let f = model.tick(&b, pose.pos);
            let cmd = stage.apply(f.total, Vec3::ZERO);
            let tau = pen.torques(&j.arm, cmd);
            black_box(pen.motor_commands(&tau))
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
