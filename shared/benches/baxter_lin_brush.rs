//! Cost of one tick of Baxter & Lin's whole brush on the host: the large round head (seven
//! spines of the paper's three joints, [`BaxterLinBrush::of_preset`]) solved, skinned and
//! inked, pressed and dragged back and forth at up to 80 mm/s, as a stroke drives it at
//! 1 kHz. The tick must take well under a millisecond for the desktop to run it in real time.
//!
//! Also the device loop the app's built-in simulator runs with this head
//! ([`BaxterLinLoop`]: a solve and a local force model rebuilt every tenth tick, the model
//! evaluated, the guide and output stage every tick), measured over ten ticks: a tenth of
//! that is its mean cost per 1 kHz tick, and the tick that solves is most of it.
//!
//! `cargo bench -p maobi-shared --bench baxter_lin_brush`

use criterion::{criterion_group, criterion_main, Criterion};
use maobi_shared::baxter_lin::brush::BaxterLinBrush;
use maobi_shared::baxter_lin::force_loop::BaxterLinLoop;
use maobi_shared::force::PHANTOM_OMNI;
use maobi_shared::force_loop::{Gate, TickIn};
use maobi_shared::guide::DEFAULT_GUIDE;
use maobi_shared::protocol::Faults;
use maobi_shared::{presets, Pose, Quat, Vec3};
use std::hint::black_box;

/// The handle tilted 15 degrees, the 40 mm head pressed 6 mm, moving along x at up to
/// 80 mm/s and across in y.
fn drag_pose(k: usize, z: f64) -> Pose<f64> {
    let t = (k % 2000) as f64 * 1e-3;
    let x = 25.0 * (t * std::f64::consts::PI).sin();
    let y = 5.0 * (2.0 * t * std::f64::consts::PI).sin();
    let h = 15f64.to_radians() / 2.0;
    Pose::new(Vec3::new(x, y, z), Quat::new(h.cos(), 0.0, h.sin(), 0.0))
}

fn bench_round(c: &mut Criterion) {
    let pressed = 40.0 * 15f64.to_radians().cos() - 6.0;
    let mut b = BaxterLinBrush::of_preset(&presets::LARGE, drag_pose(0, pressed + 8.0)).unwrap();
    // Pressed down from free air, then a stroke's worth of drag before measuring.
    for k in 0..=200 {
        b.tick(&drag_pose(0, pressed + 8.0 * (1.0 - k as f64 / 200.0)));
    }
    let mut k = 0;
    for _ in 0..500 {
        k += 1;
        b.tick(&drag_pose(k, pressed));
    }
    c.bench_function("baxter_lin/brush/large-round/pressed-drag", |bench| {
        bench.iter(|| {
            k += 1;
            b.tick(black_box(&drag_pose(k, pressed)));
        })
    });
    let touching = b
        .spines()
        .iter()
        .filter(|s| (0..s.joints() + 1).any(|i| s.in_contact(i)))
        .count();
    println!(
        "large round head: {} spines, {touching} touching the paper at the end, ink {:.1} left",
        b.spines().len(),
        b.ink_load()
    );
}

fn bench_loop(c: &mut Criterion) {
    let pressed = 40.0 * 15f64.to_radians().cos() - 6.0;
    let start = drag_pose(0, pressed + 8.0);
    let brush = BaxterLinBrush::of_preset(&presets::LARGE, start).unwrap();
    let mut lp = BaxterLinLoop::new(brush, start, PHANTOM_OMNI, DEFAULT_GUIDE).unwrap();
    let gate = Gate::new(true, Faults::empty());
    let tick = |lp: &mut BaxterLinLoop, pose: Pose<f64>| {
        lp.tick(TickIn {
            pose: Some(pose),
            guide: None,
            gate,
        })
    };
    for k in 0..=200 {
        tick(
            &mut lp,
            drag_pose(0, pressed + 8.0 * (1.0 - k as f64 / 200.0)),
        );
    }
    let mut k = 0;
    for _ in 0..500 {
        k += 1;
        tick(&mut lp, drag_pose(k, pressed));
    }
    c.bench_function(
        "baxter_lin/loop/large-round/pressed-drag/10-ticks",
        |bench| {
            bench.iter(|| {
                for _ in 0..10 {
                    k += 1;
                    black_box(tick(&mut lp, black_box(drag_pose(k, pressed))));
                }
            })
        },
    );
}

criterion_group!(benches, bench_round, bench_loop);
criterion_main!(benches);
