//! Does Baxter & Lin's brush depend on how often it is solved? The large round head pressed
//! 6 mm at a 15 degree lean (0.3 s down, 0.1 s held) and dragged 40 mm at 20 and 100 mm/s,
//! its force compared every 10 ms (a time every run ticks at) with the brush ticked, and
//! solved, every 25 us:
//!
//! * ticked every 0.05, 0.1 and 0.25 ms, one solve a tick: the solve's own step. Stiction
//!   makes the brush follow the path it is solved along, so this is the convergence the
//!   brush's [`MAX_SOLVE_INTERVAL_S`] rests on;
//! * ticked every 0.5 to 10 ms (the local force model's 100 Hz, a solver thread's gaps),
//!   each tick solved in substeps of at most [`MAX_SOLVE_INTERVAL_S`] along the path
//!   interpolated between the ticks: the brush any caller gets.
//!
//! Both are asserted within 1% RMS, for the press and for the drag. Printed beside them:
//! the spines solved once a tick of 1, 2 and 10 ms without substeps (what the substeps are
//! for), and the reference again with its path moved a nanometre sideways (a brush whose
//! stick-slip amplified such a nudge would differ between rates for no fault of the rate;
//! docs/models.md).
//!
//! `cargo test --release -p maobi-shared --test baxter_lin_rate -- --nocapture` prints the
//! table `docs/models.md` quotes.

use maobi_shared::baxter_lin::brush::{BaxterLinBrush, MAX_SOLVE_INTERVAL_S};
use maobi_shared::baxter_lin::head::HeadShape;
use maobi_shared::{presets, Pose, Quat, Vec3};

const REFERENCE_S: f64 = 25e-6;
/// Ticks of one solve each (at most [`MAX_SOLVE_INTERVAL_S`]), then ticks solved in substeps.
const INTERVALS_S: [f64; 8] = [0.05e-3, 0.1e-3, 0.25e-3, 0.5e-3, 1e-3, 2e-3, 5e-3, 10e-3];
/// Compared every this long (s): a multiple of every interval.
const SAMPLE_S: f64 = 10e-3;
/// The press ends, and the drag starts, at these sample numbers.
const PRESS_END: usize = 40;
const DRAG_START: usize = 50;
/// The largest RMS difference from the reference, relative to its RMS force.
const TOLERANCE: f64 = 0.01;

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

/// The force on the handle every [`SAMPLE_S`], the brush ticked every `interval` s, its
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

/// [`forces`] with the brush's spines solved once a tick, without substeps: what the
/// substeps are for.
fn forces_one_solve_a_tick(speed: f64, interval: f64) -> Vec<Vec3<f64>> {
    let end = 0.4 + 40.0 / speed;
    let b = BaxterLinBrush::of_shape(HeadShape::Round, &presets::LARGE, handle_at(0.0, speed))
        .expect("the large preset's head");
    let mut spines = b.spines().to_vec();
    for s in &mut spines {
        s.set_solve_interval(interval);
    }
    let every = (SAMPLE_S / interval).round() as usize;
    (1..=(end / interval).round() as usize)
        .filter_map(|k| {
            let at = handle_at(k as f64 * interval, speed);
            for s in &mut spines {
                s.solve(&at, Vec3::ZERO);
            }
            (k % every == 0).then(|| spines.iter().fold(Vec3::ZERO, |a, s| a + s.handle_force()))
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
fn the_force_converges_with_the_solve_interval_and_substeps_make_any_tick_the_same_brush() {
    let mut threads = Vec::new();
    for speed in [20.0, 100.0] {
        threads.push(std::thread::spawn(move || {
            let reference = forces(speed, REFERENCE_S, 0.0);
            let nudged = forces(speed, REFERENCE_S, NUDGE_MM);
            let runs: Vec<_> = INTERVALS_S
                .iter()
                .map(|&i| (i, forces(speed, i, 0.0)))
                .collect();
            let unsplit: Vec<_> = [1e-3, 2e-3, 10e-3]
                .iter()
                .map(|&i| (i, forces_one_solve_a_tick(speed, i)))
                .collect();
            (speed, reference, nudged, runs, unsplit)
        }));
    }
    let mut worst = 0.0f64;
    for t in threads {
        let (speed, reference, nudged, runs, unsplit) = t.join().expect("a speed's runs");
        let n = reference.len();
        let drag_ref = mean(&reference[DRAG_START..]);
        println!(
            "{speed:>3} mm/s, every 0.025 ms, the path moved 1 nm sideways: press {:>5.1}%, \
             drag {:>5.1}% (RMS from the same unmoved)",
            100.0 * relative_rms(&nudged, &reference, 0..PRESS_END),
            100.0 * relative_rms(&nudged, &reference, DRAG_START..n),
        );
        for (interval, run) in runs {
            assert_eq!(run.len(), n);
            let press = relative_rms(&run, &reference, 0..PRESS_END);
            let drag = relative_rms(&run, &reference, DRAG_START..n);
            let drag_mean = mean(&run[DRAG_START..]);
            let substeps = (interval / MAX_SOLVE_INTERVAL_S - 1e-9).ceil().max(1.0);
            println!(
                "{speed:>3} mm/s, ticked every {:>5.2} ms (solves a tick: {substeps:>2}): press \
                 {:>5.2}%, drag {:>5.2}% (RMS from every 0.025 ms); the drag's mean force x \
                 {:.4} z {:.4} N (reference {:.4} {:.4})",
                interval * 1e3,
                100.0 * press,
                100.0 * drag,
                drag_mean.x,
                drag_mean.z,
                drag_ref.x,
                drag_ref.z
            );
            worst = worst.max(press).max(drag);
            assert!(
                press < TOLERANCE && drag < TOLERANCE,
                "{speed} mm/s ticked every {interval} s: press {press}, drag {drag} from the \
                 reference"
            );
        }
        for (interval, run) in unsplit {
            println!(
                "{speed:>3} mm/s, ticked every {:>5.2} ms, one solve a tick (no substeps): press \
                 {:>5.1}%, drag {:>5.1}% (RMS from every 0.025 ms)",
                interval * 1e3,
                100.0 * relative_rms(&run, &reference, 0..PRESS_END),
                100.0 * relative_rms(&run, &reference, DRAG_START..n),
            );
        }
    }
    println!("worst {:.2}%", 100.0 * worst);
}
