//! Cost of one solve of Baxter & Lin's spine on the host: a 3-joint spine (the paper's) and
//! an 8-joint one ([`MAX_JOINTS`]), pressed on the paper and dragged back and forth, so
//! contacts slide, stick and the SQP works every solve.
//!
//! And the local force model (`baxter_lin::local_force`) on the round head: one rebuild (the
//! probe solves of every spine) and one evaluation, what the 1 kHz loop runs between
//! rebuilds.
//!
//! `cargo bench -p maobi-shared --bench baxter_lin`

use criterion::{criterion_group, criterion_main, Criterion};
use maobi_shared::baxter_lin::brush::{BaxterLinBrush, InkParams};
use maobi_shared::baxter_lin::head::HeadShape;
use maobi_shared::baxter_lin::local_force::{LocalForceModel, LocalForceParams};
use maobi_shared::baxter_lin::{Spine, SpineParams, MAX_JOINTS};
use maobi_shared::force::PHANTOM_OMNI;
use maobi_shared::{Pose, Quat, Vec3};
use std::hint::black_box;

/// The handle tilted 20 degrees, its root 16 mm above the paper (a 30 mm spine pressed),
/// moving along x at up to 80 mm/s at 1 kHz and across in y.
fn drag_pose(k: usize) -> Pose<f64> {
    let t = (k % 2000) as f64 * 1e-3;
    let x = 25.0 * (t * std::f64::consts::PI).sin();
    let y = 5.0 * (2.0 * t * std::f64::consts::PI).sin();
    let h = 20f64.to_radians() / 2.0;
    Pose::new(Vec3::new(x, y, 16.0), Quat::new(h.cos(), 0.0, h.sin(), 0.0))
}

fn bench_joints(c: &mut Criterion, joints: u8) {
    let params = SpineParams {
        joints,
        ..SpineParams::DEFAULT
    };
    let mut s = Spine::new(
        params,
        Pose::new(Vec3::new(0.0, 0.0, 40.0), drag_pose(0).rot),
    )
    .unwrap();
    // Pressed down from free air, then a stroke's worth of drag before measuring.
    for z in 0..240 {
        let mut p = drag_pose(0);
        p.pos.z = 40.0 - 0.1 * z as f64;
        s.solve(&p, Vec3::ZERO);
    }
    let mut k = 0;
    for _ in 0..500 {
        k += 1;
        s.solve(&drag_pose(k), Vec3::ZERO);
    }
    let (_, fallbacks_before, unconverged_before, _) = s.counts();
    let mut iterations = 0u64;
    let mut solves = 0u64;
    c.bench_function(
        &format!("baxter_lin/solve/{joints}-joint/pressed-drag"),
        |b| {
            b.iter(|| {
                k += 1;
                let r = s.solve(black_box(&drag_pose(k)), Vec3::ZERO);
                iterations += r.iterations as u64;
                solves += 1;
                black_box(r)
            })
        },
    );
    let (_, fallbacks, unconverged, _) = s.counts();
    println!(
        "{joints}-joint: {:.2} SQP iterations a solve, {} touching at the end, {} fallbacks and {} unconverged over {solves} solves",
        iterations as f64 / solves.max(1) as f64,
        (1..=s.joints()).filter(|&i| s.in_contact(i)).count(),
        fallbacks - fallbacks_before,
        unconverged - unconverged_before,
    );
}

/// The round head (seven spines) pressed 6 mm and dragged as `drag_pose` drags, then one
/// rebuild of the local model at the next pose (the handle moving along x) and one
/// evaluation.
fn bench_local_force(c: &mut Criterion) {
    let head = HeadShape::Round.head();
    let top = head.length_mm() - 6.0;
    let ink = InkParams {
        capacity: 0.4,
        wetness: 0.6,
        footprint_eps_mm: 0.1,
    };
    let at = |k: usize| {
        let mut p = drag_pose(k);
        p.pos.z = top;
        p
    };
    let mut above = at(0);
    above.pos.z += 10.0;
    let mut b = BaxterLinBrush::new(head, SpineParams::DEFAULT, ink, above).unwrap();
    for z in 1..=100 {
        let mut p = at(0);
        p.pos.z = top + 10.0 * (1.0 - z as f64 / 100.0);
        b.tick(&p);
    }
    for k in 0..500 {
        b.tick(&at(k));
    }
    let params = LocalForceParams::for_device(&PHANTOM_OMNI);
    let (pose, motion) = (at(500), at(500).pos - at(490).pos);
    c.bench_function("baxter_lin/local_force/rebuild/round-head", |bench| {
        bench.iter(|| {
            black_box(LocalForceModel::build(
                black_box(b.spines()),
                black_box(&pose),
                black_box(motion),
                params.min_probe_mm,
                params.max_stiffness_n_per_mm,
            ))
        })
    });
    let model = LocalForceModel::build(
        b.spines(),
        &pose,
        motion,
        params.min_probe_mm,
        params.max_stiffness_n_per_mm,
    );
    let next = at(503).pos;
    c.bench_function("baxter_lin/local_force/evaluate", |bench| {
        bench.iter(|| black_box(&model).force(black_box(next)))
    });
    c.bench_function("baxter_lin/brush/tick/round-head", |bench| {
        let mut k = 500;
        bench.iter(|| {
            k += 1;
            b.tick(black_box(&at(k)));
        })
    });
}

fn benches(c: &mut Criterion) {
    bench_joints(c, 3);
    bench_joints(c, MAX_JOINTS as u8);
    bench_local_force(c);
}

criterion_group!(baxter_lin, benches);
criterion_main!(baxter_lin);
