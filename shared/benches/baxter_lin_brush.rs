//! Cost of one tick of Baxter & Lin's whole brush on the host: the large round head (seven
//! spines of the paper's three joints, [`BaxterLinBrush::of_preset`]) solved, skinned and
//! inked, pressed and dragged back and forth at up to 80 mm/s, as a stroke drives it at
//! 1 kHz. The tick must take well under a millisecond for the desktop to run it in real time.
//!
//! `cargo bench -p maobi-shared --bench baxter_lin_brush`

use criterion::{criterion_group, criterion_main, Criterion};
use maobi_shared::baxter_lin::brush::BaxterLinBrush;
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

criterion_group!(benches, bench_round);
criterion_main!(benches);
