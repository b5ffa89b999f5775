//! Does Baxter & Lin's brush depend on how often it is solved? The large round head pressed
//! 6 mm at a 15 degree lean (0.3 s down, 0.1 s held) and dragged 40 mm, solved every 0.5,
//! 1, 2, 5 and 10 ms, against a solve every 0.25 ms, compared every 10 ms (the times every
//! run solves at).
//!
//! What holds, and is asserted: sliding at writing speed (100 mm/s) gives the same force
//! whatever the rate. What does not yet, and is printed: the landing and the press, where
//! which spines catch on the paper (stiction, §3.4.1) depends on the rate, because each
//! minimisation holds the friction's normal force at the last solve's (§3.4) and re-solves
//! at most twice when it moved; and a slow drag, which starts from the press's stuck spines.
//! Beside them, the reference run again with its path moved a nanometre sideways: a brush
//! whose stick-slip amplified such a nudge would differ between rates for no fault of the
//! rate (docs/models.md).
//!
//! `cargo test --release -p maobi-shared --test baxter_lin_rate -- --nocapture` prints the
//! table `docs/models.md` quotes.

use maobi_shared::baxter_lin::brush::BaxterLinBrush;
use maobi_shared::baxter_lin::head::HeadShape;
use maobi_shared::{presets, Pose, Quat, Vec3};

const REFERENCE_S: f64 = 0.25e-3;
const INTERVALS_S: [f64; 5] = [0.5e-3, 1e-3, 2e-3, 5e-3, 10e-3];
/// Compared every this long (s): a multiple of every interval.
const SAMPLE_S: f64 = 10e-3;
/// The press ends, and the drag starts, at these sample numbers.
const PRESS_END: usize = 40;
const DRAG_START: usize = 50;

fn pose(x: f64, z: f64, tilt_deg: f64) -> Pose<f64> {
    let h = tilt_deg.to_radians() / 2.0;
    Pose::new(
        Vec3::new(x, 0.0, z),
        Quat::from_f64([h.cos(), 0.0, h.sin(), 0.0]),
    )
}

/// How far the nudged reference is moved sideways (mm): a nanometre.
const NUDGE_MM: f64 = 1e-6;

/// The handle at time `t` (s): from 6 mm above the paper at rest to 6 mm into it over
/// 0.3 s (the large head is 40 mm), held 0.1 s, then dragged 40 mm along +x at `speed` mm/s.
fn handle_at(t: f64, speed: f64) -> Pose<f64> {
    let (top, bottom) = (46.0, 34.0);
    if t < 0.3 {
        pose(0.0, top + (bottom - top) * t / 0.3, 15.0)
    } else if t < 0.4 {
        pose(0.0, bottom, 15.0)
    } else {
        pose(((t - 0.4) * speed).min(40.0), bottom, 15.0)
    }
}

/// The force on the handle every [`SAMPLE_S`], the brush solved every `interval` s, its
/// path moved `nudge` mm sideways.
fn forces(speed: f64, interval: f64, nudge: f64) -> Vec<Vec3<f64>> {
    let end = 0.4 + 40.0 / speed;
    let handle_at = |t: f64, speed: f64| {
        let p = handle_at(t, speed);
        Pose::new(p.pos + Vec3::Y.scale(nudge), p.rot)
    };
    let mut b = BaxterLinBrush::of_shape(HeadShape::Round, &presets::LARGE, handle_at(0.0, speed))
        .expect("the large preset's head");
    b.set_solve_interval(interval);
    let every = (SAMPLE_S / interval).round() as usize;
    (1..=(end / interval).round() as usize)
        .filter_map(|k| {
            b.tick(&handle_at(k as f64 * interval, speed));
            (k % every == 0).then(|| b.handle_force())
        })
        .collect()
}

/// RMS of the difference over the samples `range`, relative to the reference's RMS.
fn relative_rms(run: &[Vec3<f64>], reference: &[Vec3<f64>], range: core::ops::Range<usize>) -> f64 {
    let (mut d2, mut f2) = (0.0, 0.0);
    for k in range {
        d2 += (run[k] - reference[k]).norm2();
        f2 += reference[k].norm2();
    }
    (d2 / f2).sqrt()
}

fn mean(v: &[Vec3<f64>]) -> Vec3<f64> {
    v.iter()
        .fold(Vec3::ZERO, |a, f| a + *f)
        .scale(1.0 / v.len() as f64)
}

#[test]
fn the_force_converges_with_the_solve_interval_where_the_brush_slides() {
    for speed in [20.0, 100.0] {
        let reference = forces(speed, REFERENCE_S, 0.0);
        let n = reference.len();
        let drag_ref = mean(&reference[DRAG_START..]);
        let nudged = forces(speed, REFERENCE_S, NUDGE_MM);
        println!(
            "{speed:>3} mm/s, every 0.25 ms, the path moved 1 nm sideways: press {:>5.1}%, drag \
             {:>5.1}% (RMS from the same unmoved)",
            100.0 * relative_rms(&nudged, &reference, 0..PRESS_END),
            100.0 * relative_rms(&nudged, &reference, DRAG_START..n),
        );
        for interval in INTERVALS_S {
            let run = forces(speed, interval, 0.0);
            assert_eq!(run.len(), n);
            let press = relative_rms(&run, &reference, 0..PRESS_END);
            let drag = relative_rms(&run, &reference, DRAG_START..n);
            let drag_mean = mean(&run[DRAG_START..]);
            println!(
                "{speed:>3} mm/s, solved every {:>5.2} ms: press {:>5.1}%, drag {:>5.1}% \
                 (RMS from every 0.25 ms); the drag's mean force x {:.4} z {:.4} N \
                 (reference {:.4} {:.4})",
                interval * 1e3,
                100.0 * press,
                100.0 * drag,
                drag_mean.x,
                drag_mean.z,
                drag_ref.x,
                drag_ref.z
            );
            if speed >= 100.0 {
                assert!(
                    drag < 0.01,
                    "sliding at {speed} mm/s every {interval} s differs by {drag}"
                );
            }
        }
    }
}
